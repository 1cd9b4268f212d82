"""HTTP client of the MAGNET service. Depends on httpx and tqdm only (no torch, no server code)."""

from __future__ import annotations

import json
import math
import os
import re
import time
from collections.abc import Iterator
from pathlib import Path

import httpx

OPTION_NAMES = (
    "seed",
    "groups",
    "keep_rings",
    "kappa",
    "allow_extra",
    "keep_groups",
    "fill",
    "fill_remesh",
    "fill_size",
    "fill_size_abs",
    "fill_max_cells",
    "absorb_fraction",
    "hole_policy",
    "physical_tag",
    "method",
    "boundary_tag",
    "threshold",
    "hierarchy",
    "ratio",
    "coarsest",
    "finest",
    "boxfit",
    "weld",
    "size_measure",
)
PARAM_NAMES = ("model", "mode", "k", "nref", "target_size", "mult_factor", "subset", "refiner")
FINAL = ("succeeded", "failed", "cancelled")


class MagnetHTTPError(Exception):
    """The server answered with an error status; `status` and `detail` say which and why."""

    def __init__(self, status: int, detail: str, method: str, path: str):
        super().__init__(f"HTTP {status} from {method} {path}: {detail}")
        self.status, self.detail, self.method, self.path = status, detail, method, path


class InputError(ValueError):
    """Bad input the client finds itself (a missing file, a folder that does not exist, a value
    that cannot be sent), before the server is asked; the message is one sentence."""


def check_input_file(path: str | os.PathLike, what: str = "") -> Path:
    """The file at `path`, or InputError saying in one sentence why it cannot be read."""
    name = f"{what} {os.fspath(path)}" if what else os.fspath(path)
    p = Path(path)
    if not p.exists():
        link = " (a symbolic link that leads to no file)" if p.is_symlink() else ""
        raise InputError(f"cannot read {name}: no such file{link}")
    if p.is_dir():
        hint = "" if what else " (send a case folder as a .zip)"
        raise InputError(f"cannot read {name}: it is a folder, not a file{hint}")
    if not os.access(p, os.R_OK):
        raise InputError(f"cannot read {name}: permission denied")
    return p


def check_output_path(path: str | os.PathLike | None, what: str) -> None:
    """Refuse, before any work, an output file that cannot be written (the local CLI's words)."""
    if path is None:
        return
    path = os.fspath(path)
    if os.path.isdir(path):
        raise InputError(f"{what} '{path}' is a folder; give a file name")
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(folder):
        raise InputError(f"cannot write {what} '{path}': folder '{folder}' does not exist")
    if not os.access(folder, os.W_OK | os.X_OK) or (os.path.exists(path) and not os.access(path, os.W_OK)):
        raise InputError(f"cannot write {what} '{path}': permission denied")


def check_output_dir(path: str | os.PathLike | None, what: str) -> None:
    """Refuse, before any work, a folder that cannot be made or written (made later if missing)."""
    if path is None:
        return
    path = os.fspath(path)
    if os.path.exists(path) and not os.path.isdir(path):
        raise InputError(f"cannot write {what} to '{path}': it is a file, not a folder")
    existing = os.path.abspath(path)
    while not os.path.exists(existing):
        existing = os.path.dirname(existing)
    if not os.path.isdir(existing):
        raise InputError(f"cannot write {what} to '{path}': '{existing}' is a file, not a folder")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise InputError(f"cannot write {what} to '{path}': permission denied")


def parse_kappa(value, name: str = "kappa") -> list[float] | None:
    """'kx,ky[,kz]' or a sequence -> the diagonal diffusion tensor as a list of positive numbers
    (None stays None); InputError in the words of `magnet hierarchy --kappa`."""
    if value is None:
        return None
    if isinstance(value, str):
        text = value
        parts = value.split(",")
    else:
        try:
            parts = list(value)
        except TypeError:
            parts = [value]
        text = ",".join(str(v) for v in parts)
    try:
        kappa = [float(v) for v in parts if not isinstance(v, bool)]
    except (TypeError, ValueError):
        kappa = None
    if kappa is None or len(kappa) != len(parts):
        raise InputError(f"{name} must be comma-separated numbers kx,ky[,kz], got '{text}'")
    if len(kappa) not in (2, 3) or not all(math.isfinite(v) and v > 0 for v in kappa):
        raise InputError(f"{name} must be two or three positive numbers kx,ky[,kz], got '{text}'")
    return kappa


def check_finite(body: dict, prefix: str = "") -> None:
    """A NaN or infinity cannot be sent as JSON: refuse it in the library's words."""
    for key, value in body.items():
        if isinstance(value, dict):
            check_finite(value, f"{prefix}{key}.")
        elif isinstance(value, float) and not math.isfinite(value):
            raise InputError(f"{prefix}{key} must be finite, got {value}")
        elif isinstance(value, list | tuple) and any(
            isinstance(v, float) and not math.isfinite(v) for v in value
        ):
            raise InputError(f"{prefix}{key} must hold finite numbers, got {list(value)}")


def reason(exc: Exception) -> str:
    """An exception's text without Python's '[Errno 111]' prefix ('connection refused')."""
    text = re.sub(r"^\[Errno -?\d+\]\s*", "", str(exc)).strip().rstrip(".")
    text = text or type(exc).__name__
    return text[:1].lower() + text[1:]


class JobFailed(Exception):
    """The job ended failed or cancelled; `job` is its last record."""

    def __init__(self, job: dict):
        super().__init__(f"job {job['id']} {job['status']}: {job.get('error') or 'no error message'}")
        self.job = job


def job_params(params: dict) -> dict:
    """Split flat keyword arguments into the job's fields and its `options` object."""
    body = {k: params[k] for k in PARAM_NAMES if params.get(k) is not None}
    options = dict(params.get("options") or {})
    options.update({k: params[k] for k in OPTION_NAMES if params.get(k) is not None})
    if options:
        body["options"] = options
    unknown = set(params) - set(PARAM_NAMES) - set(OPTION_NAMES) - {"options"}
    if unknown:
        raise TypeError(f"unknown job parameter(s): {', '.join(sorted(unknown))}")
    if "subset" in body:
        try:
            body["subset"] = [int(i) for i in body["subset"]]
        except (TypeError, ValueError):
            raise InputError("subset must be a list of integer cell ids") from None
    if "kappa" in options:
        options["kappa"] = parse_kappa(options["kappa"])
    check_finite(body)
    return body


def http_error(response: httpx.Response, method: str, path: str) -> MagnetHTTPError:
    try:
        detail = response.json().get("detail", response.text)
    except ValueError:
        detail = response.text
    return MagnetHTTPError(
        response.status_code, detail if isinstance(detail, str) else str(detail), method, path
    )


class Client:
    """A MAGNET server at `url`, used with API key `token` (None for a keyless local server).

    Waits and retries when the server says so (429 too many queued jobs, 503 broker down):
    a refused submission was not queued, so sending it again is safe.
    """

    def __init__(
        self,
        url: str = "http://127.0.0.1:8000",
        token: str | None = None,
        timeout: float = 120.0,
        retries: int = 5,
    ):
        self.url = str(url).rstrip("/")
        try:
            parsed = httpx.URL(self.url)
            ok = parsed.scheme in ("http", "https") and bool(parsed.host)
        except (httpx.InvalidURL, TypeError, ValueError):
            ok = False
        if not ok:
            raise InputError(
                f"the server address '{url}' is not an http:// or https:// URL (e.g. http://127.0.0.1:8000)"
            )
        token = token if token is not None else os.environ.get("MAGNET_TOKEN")
        if token and not (token.isascii() and token.isprintable()):
            raise InputError("the API key must be printable ASCII text, as `magnet keys add` prints it")
        headers = {"Authorization": f"Bearer {token}"} if token else {}
        self.http = httpx.Client(base_url=self.url, headers=headers, timeout=timeout)
        self.retries = retries

    def close(self) -> None:
        self.http.close()

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # --- plumbing ---------------------------------------------------------------------------------

    def _request(self, method: str, path: str, **kwargs) -> httpx.Response:
        for attempt in range(self.retries + 1):
            try:
                response = self.http.request(method, path, **kwargs)
            except httpx.TransportError as exc:
                if method != "GET" or attempt >= min(self.retries, 2):  # a blip, not an outage
                    raise ConnectionError(
                        f"cannot reach the MAGNET server at {self.url} ({reason(exc)})"
                    ) from exc
                time.sleep(2**attempt)
                continue
            if response.status_code in (429, 503) and attempt < self.retries:
                time.sleep(min(float(response.headers.get("Retry-After", 2**attempt)), 30))
                continue
            if response.status_code >= 400:
                raise http_error(response, method, path)
            return response
        raise AssertionError("unreachable")

    def _save(self, path: str, target: str | os.PathLike, **kwargs) -> Path:
        target = Path(target)
        target.write_bytes(self._request("GET", path, **kwargs).content)
        return target

    # --- the API ----------------------------------------------------------------------------------

    def models(self) -> list[dict]:
        return self._request("GET", "/v1/models").json()

    def upload(self, mesh_path: str | os.PathLike) -> dict:
        """Upload a mesh file; returns {id, cells, dim, ...}. The same bytes give the same id."""
        mesh_path = check_input_file(mesh_path)
        with open(mesh_path, "rb") as fh:
            return self._request(
                "POST",
                "/v1/meshes",
                params={"filename": mesh_path.name},
                content=fh.read(),
                headers={"Content-Type": "application/octet-stream"},
            ).json()

    def submit(self, mesh_id: str, **params) -> dict:
        """Queue a job: model, mode, k, nref, target_size, mult_factor, subset, refiner, options, or
        the options flat (seed, absorb_fraction, hole_policy, physical_tag, method, boundary_tag)."""
        return self._request("POST", "/v1/jobs", json={"mesh_id": mesh_id, **job_params(params)}).json()

    def job(self, job_id: str) -> dict:
        return self._request("GET", f"/v1/jobs/{job_id}").json()

    def jobs(self, limit: int = 50, offset: int = 0, status: str | None = None) -> dict:
        params = {"limit": limit, "offset": offset} | ({"status": status} if status else {})
        return self._request("GET", "/v1/jobs", params=params).json()

    def cancel(self, job_id: str) -> dict:
        return self._request("DELETE", f"/v1/jobs/{job_id}").json()

    def events(self, job_id: str, read_timeout: float = 60.0) -> Iterator[dict]:
        """The job's record each time its status, stage or progress changes (the server-sent events
        of GET /v1/jobs/{id}/events), the last one final. The server may close a long stream early
        (restart, 10-minute cap): then the iteration just ends before a final record."""
        path = f"/v1/jobs/{job_id}/events"
        timeout = httpx.Timeout(self.http.timeout.connect, read=read_timeout)
        with self.http.stream("GET", path, timeout=timeout) as response:
            if response.status_code >= 400:
                response.read()
                raise http_error(response, "GET", path)
            data: list[str] = []
            for line in response.iter_lines():
                if line.startswith("data:"):
                    data.append(line[5:].removeprefix(" "))
                elif line == "" and data:
                    record = json.loads("\n".join(data))
                    data = []
                    if "status" in record:
                        yield record

    def follow(self, job_id: str, poll: float = 0.5, read_timeout: float = 60.0) -> Iterator[dict]:
        """The job's record as it changes until it ends: from the event stream (reconnecting when it
        closes early), or by polling every `poll` s from a server without one."""
        streaming, delay = True, min(poll, 0.1)
        while True:
            if streaming:
                try:
                    for job in self.events(job_id, read_timeout):
                        yield job
                        if job["status"] in FINAL:
                            return
                except MagnetHTTPError as exc:
                    if exc.status not in (404, 405):
                        raise
                    streaming = False  # an older server (or an unknown id: self.job says which)
                except httpx.TransportError:
                    streaming = False
            job = self.job(job_id)
            yield job
            if job["status"] in FINAL:
                return
            if not streaming:
                time.sleep(delay)
                delay = min(delay * 1.5, poll)

    def wait(
        self, job_id: str, progress: bool = True, poll: float = 0.5, timeout: float | None = None
    ) -> dict:
        """Follow the job until it ends; a tqdm progress bar on stderr (stage and percentage, as the
        web page shows them) when `progress`. JobFailed unless it succeeded."""
        bar = None
        if progress:
            from tqdm import tqdm

            bar = tqdm(
                total=100,
                desc="queued",
                bar_format="{desc:>12} {bar} {percentage:3.0f}% {elapsed}",
                leave=False,
            )
        deadline = None if timeout is None else time.monotonic() + timeout
        read_timeout = 60.0 if timeout is None else max(1.0, min(60.0, timeout))
        try:
            for job in self.follow(job_id, poll, read_timeout):
                if bar is not None:
                    bar.set_description_str(job.get("stage") or job["status"], refresh=False)
                    bar.n = int(round(100 * job.get("progress", 0.0)))
                    bar.refresh()
                if job["status"] not in FINAL and deadline is not None and time.monotonic() > deadline:
                    raise TimeoutError(f"job {job_id} still {job['status']} after {timeout} s")
        finally:
            if bar is not None:
                bar.close()
        if job["status"] != "succeeded":
            raise JobFailed(job)
        return job

    def download_mesh(self, job_id: str, path: str | os.PathLike) -> Path:
        return self._save(f"/v1/jobs/{job_id}/mesh", path)

    def download_metrics(self, job_id: str, path: str | os.PathLike | None = None) -> dict | Path:
        """The metrics JSON (dict), or saved to `path`."""
        if path is not None:
            return self._save(f"/v1/jobs/{job_id}/metrics", path)
        return self._request("GET", f"/v1/jobs/{job_id}/metrics").json()

    def download_labels(self, job_id: str, path: str | os.PathLike | None = None) -> list | Path:
        if path is not None:
            return self._save(f"/v1/jobs/{job_id}/labels", path)
        return self._request("GET", f"/v1/jobs/{job_id}/labels").json()

    def download_lymph(self, job_id: str, path: str | os.PathLike | None = None) -> dict | Path:
        """lymph structs: a .mat file when `path` ends in .mat, else JSON (dict, or saved to `path`)."""
        if path is not None:
            fmt = "mat" if str(path).lower().endswith(".mat") else "json"
            return self._save(f"/v1/jobs/{job_id}/lymph", path, params={"format": fmt})
        return self._request("GET", f"/v1/jobs/{job_id}/lymph").json()

    def download_preview(self, job_id: str, path: str | os.PathLike) -> Path:
        return self._save(f"/v1/jobs/{job_id}/preview.png", path)

    def download_hierarchy(self, job_id: str, directory: str | os.PathLike) -> Path:
        """The nested levels of a job run with options.hierarchy = true, unpacked into `directory`
        (hierarchy.json, level_L.vtu, level_L.labels.json, level_L.parent.json, ...)."""
        import tempfile
        import zipfile

        directory = Path(directory)
        directory.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryDirectory() as tmp:
            z = self._save(f"/v1/jobs/{job_id}/hierarchy", Path(tmp) / "hierarchy.zip")
            with zipfile.ZipFile(z) as zf:
                for name in zf.namelist():  # flat archive of plain file names: nothing escapes `directory`
                    if "/" in name or "\\" in name or name.startswith("."):
                        raise MagnetHTTPError(
                            0, f"unexpected entry '{name}' in the hierarchy archive", "GET", z.name
                        )
                zf.extractall(directory)
        return directory

    def agglomerate(
        self,
        mesh_path: str | os.PathLike,
        output: str | os.PathLike | None = None,
        *,
        metrics: str | None = None,
        labels: str | None = None,
        lymph: str | None = None,
        plot: str | None = None,
        hierarchy: str | os.PathLike | None = None,
        progress: bool = True,
        timeout: float | None = None,
        **params,
    ) -> dict:
        """Upload, submit, wait, download: the remote `magnet agglomerate`. Returns the finished job.
        hierarchy: a directory to unpack every nested level into (asks the server for them); with
        ratio=R (and coarsest=N), finest="aggregation" | "cuts" | "quality" | "nested" or boxfit=True
        the levels are a hierarchy of their own, as `magnet hierarchy` (aggregation operators
        level_L.agg.npz / .mtx included)."""
        check_input_file(mesh_path)  # what can be known here is refused before the server is asked
        check_output_path(output, "output mesh")
        for value, what in ((metrics, "metrics file"), (labels, "labels file"), (lymph, "lymph file")):
            check_output_path(value, what)
        check_output_path(plot, "plot file")
        check_output_dir(hierarchy, "the hierarchy")
        if hierarchy is not None:
            params["hierarchy"] = True
        job_params(params)  # a bad value (NaN, a kappa that is no list of numbers) before the upload
        mesh = self.upload(mesh_path)
        dim = mesh.get("dim")
        name = Path(mesh_path).name
        if lymph is not None and dim is not None and dim != 2:
            shape = "a closed surface, filled to 3D" if mesh.get("surface") else f"{dim}D"
            raise InputError(
                f"lymph's region/neighbor structs are for 2D meshes only and {name} is {shape}: "
                "leave out the lymph output (nothing was run)"
            )
        kappa = parse_kappa(params.get("kappa") or (params.get("options") or {}).get("kappa"))
        if kappa is not None and dim is not None and len(kappa) != dim:
            raise InputError(
                f"kappa has {len(kappa)} values but the mesh {name} is {dim}D: give one per axis"
            )
        job = self.submit(mesh["id"], **params)
        job = self.wait(job["id"], progress=progress, timeout=timeout)
        if output is not None:
            self.download_mesh(job["id"], output)
        if metrics is not None:
            self.download_metrics(job["id"], metrics)
        if labels is not None:
            self.download_labels(job["id"], labels)
        if lymph is not None:
            self.download_lymph(job["id"], lymph)
        if plot is not None:
            self.download_preview(job["id"], plot)
        if hierarchy is not None:
            self.download_hierarchy(job["id"], hierarchy)
        job["mesh"] = mesh
        return job
