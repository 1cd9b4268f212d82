"""Reading an untrusted mesh upload safely: in a child process with memory and time limits.

A compressed VTU "bomb" or a huge cell count kills or stops the child, never the API process.
XML uploads with a DOCTYPE (entity tricks) are refused before any XML library expands them, and a
VTU that declares more cells than allowed is refused before meshio reads it.

Run as `python -m service.mesh_check PATH EXT MAX_CELLS [PHYSICAL_TAG]`: prints one JSON line
{"info": {...}} or {"status": int, "error": str}.
"""

from __future__ import annotations

import json
import os
import re
import resource
import subprocess
import sys
import threading
from pathlib import Path

from models.mesh import formats  # the list of formats, no reader imported (numpy, VTK stay out of the API)
from models.mesh.sandbox import crash_sentence, timeout_sentence, wording

# the readers' extensions (models.mesh.formats), without the dot; multi-file formats come in archives
ALLOWED_EXTENSIONS = tuple(e.lstrip(".") for e in formats.UPLOAD_EXTENSIONS)
XML_EXTENSIONS = ("vtu",)
_PLAIN_HTML_DOCTYPE = re.compile(rb"\s*(?:<\?xml[^>]*>\s*)?<!DOCTYPE\s+html\b[^\[>]*>", re.IGNORECASE)
PACKAGE_ROOT = Path(__file__).resolve().parents[1]
_slots = threading.BoundedSemaphore(max(2, os.cpu_count() or 2))


class UploadRejected(Exception):
    """The upload is refused; `status` is the HTTP status to answer with."""

    def __init__(self, status: int, message: str, field: str = "file"):
        super().__init__(message)
        self.status = status
        self.message = message
        self.field = field


def extension_of(filename: str | None) -> str:
    """The lower-case mesh format extension of `filename`; 422 if missing or unsupported."""
    if filename and any(ord(ch) < 32 or ord(ch) == 127 for ch in filename):
        raise UploadRejected(422, "filename: control characters (e.g. NUL) are not allowed", "filename")
    ext = formats.extension(filename or "").lstrip(".")
    if not filename:
        raise UploadRejected(
            422,
            "filename: missing; send the mesh's file name (query parameter filename=brain.vtu with a raw "
            "body, or the file name of the multipart field 'file'): its extension tells the format, one "
            f"of {', '.join('.' + e for e in ALLOWED_EXTENSIONS)}",
            "filename",
        )
    if "." + ext in formats.ARCHIVE_ONLY:
        shown = os.path.basename((filename or "").replace("\\", "/"))[:100]
        fmt = formats.format_name(shown)
        raise UploadRejected(
            422,
            f"{shown} ({fmt}) refers to other files beside it (its data or its pieces): "
            f"upload a .zip or .tar.gz holding {shown} and those files",
            "filename",
        )
    if ext not in ALLOWED_EXTENSIONS:
        shown = os.path.basename((filename or "").replace("\\", "/"))[:100]
        hint = formats.compressed_hint(shown)
        if hint:
            raise UploadRejected(
                422, f"cannot read {shown}: unknown mesh format {'.' + ext!r}{hint}", "filename"
            )
        if shown:  # (the CLI's words, one sentence: models.mesh.formats.unknown_format)
            raise UploadRejected(422, formats.unknown_format(shown, ("." + ext) if ext else ""), "filename")
        what = "the upload has no file name: it"
        multi = f" ({', '.join(formats.ARCHIVE_ONLY)} with its data files: a .zip or .tar.gz holding them)"
        raise UploadRejected(
            422,
            f"{what} has no mesh format extension we read; use one of: "
            f"{', '.join('.' + e for e in ALLOWED_EXTENSIONS)}"
            + (multi if "." + ext in formats.ARCHIVE_ONLY else ""),
            "filename",
        )
    return ext


def child_env() -> dict[str, str]:
    """Environment for service child processes: our packages importable, one BLAS thread."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(PACKAGE_ROOT), env.get("PYTHONPATH")) if p)
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        env.setdefault(var, "1")
    return env


def inspect_upload(
    path: Path, ext: str, max_cells: int, memory_bytes: int, timeout_s: float, physical_tag: str | None = None
) -> dict:
    """models.api.inspect_mesh of an uploaded file, run in a limited child process (which reads it
    in a forked child of its own: models.mesh.sandbox; a reader's crash is a sentence, not a 500)."""
    cmd = [str(path), ext, str(max_cells)] + ([physical_tag] if physical_tag is not None else [])
    return _run_child(cmd, memory_bytes, timeout_s, path)["info"]


def upload_polygons(path: Path, ext: str, max_cells: int, memory_bytes: int, timeout_s: float) -> dict:
    """The cells of a stored 2D upload as polygons (points, connectivity cut by offsets), read in the
    same limited child process as the upload check; 404 for a 3D mesh, 413 above max_cells."""
    return _run_child(["--polygons", str(path), ext, str(max_cells)], memory_bytes, timeout_s, path)[
        "polygons"
    ]


def level_picture(
    path: Path, ext: str, archive: Path, level: int, out: Path, memory_bytes: int, timeout_s: float
) -> None:
    """The picture of one level of a hierarchy (the job's preview.png style: the exploded view in 3D)
    written to `out`: the level's labels from the job's hierarchy.zip, the elements merged again from
    the stored upload, in the same limited child process as the upload check."""
    _run_child(
        ["--level-picture", str(path), ext, str(archive), str(level), str(out)], memory_bytes, timeout_s, path
    )


def _run_child(args: list[str], memory_bytes: int, timeout_s: float, path: Path) -> dict:
    """Run `python -m service.mesh_check ARGS` under the limits; its answer, or UploadRejected."""

    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (memory_bytes, memory_bytes))
        cpu = int(timeout_s) + 1
        resource.setrlimit(resource.RLIMIT_CPU, (cpu, cpu))

    cmd = [sys.executable, "-m", "service.mesh_check", *args]
    env = child_env()
    # the read inside the child: its own deadline before ours (so the sentence says which reader)
    env["MAGNET_READ_TIMEOUT_S"] = f"{max(1.0, 0.8 * timeout_s):g}"
    env["MAGNET_READ_MEMORY_MB"] = str(max(1, memory_bytes >> 20))
    with _slots:
        try:
            proc = subprocess.run(
                cmd,
                capture_output=True,
                timeout=timeout_s,
                preexec_fn=limit,
                env=env,
                cwd=str(PACKAGE_ROOT),
            )
        except subprocess.TimeoutExpired:
            raise UploadRejected(422, timeout_sentence(path, timeout_s)) from None
    lines = proc.stdout.decode(errors="replace").strip().splitlines()
    try:
        answer = json.loads(lines[-1])
    except (IndexError, ValueError):
        answer = None
    if proc.returncode < 0 and not isinstance(answer, dict):  # killed by a signal: a crash, or the CPU limit
        raise UploadRejected(422, crash_sentence(path))
    if proc.returncode != 0 or not isinstance(answer, dict):
        raise UploadRejected(
            422,
            wording(
                f"it could not be read and checked within the limits ({memory_bytes / 2**30:.1f} GiB memory, "
                f"{timeout_s:g} s)",
                path,
            ),
        )
    if "error" in answer:
        raise UploadRejected(int(answer.get("status", 422)), answer["error"])
    return answer


def check_xml(path: Path, max_cells: int) -> None:
    """Refuse DTDs/entities, and VTU pieces declaring more than max_cells cells, before meshio runs."""
    from xml.etree.ElementTree import ParseError

    import defusedxml.ElementTree as safe_et
    from defusedxml import DefusedXmlException

    cells, pieces = 0, 0
    try:
        for _event, elem in safe_et.iterparse(
            str(path), events=("start",), forbid_dtd=True, forbid_entities=True, forbid_external=True
        ):
            tag = elem.tag.rsplit("}", 1)[-1]
            if tag == "Piece":
                declared = elem.attrib.get("NumberOfCells", "0")
                if not declared.strip().isdigit():
                    shown = declared.strip()[:40]
                    raise UploadRejected(
                        422, wording(f"a piece declares NumberOfCells={shown}: expected a count >= 0", path)
                    )
                cells += int(declared)
                pieces += 1
                if cells > max_cells:
                    raise UploadRejected(
                        413, f"{path.name} declares {cells:,} cells or more; the limit is {max_cells:,}"
                    )
            elif tag == "AppendedData":
                break  # raw binary follows: not XML, and no DTD can come after the root element
        if pieces and cells == 0:
            raise UploadRejected(
                422, wording("the mesh has no cells (every piece declares NumberOfCells=0)", path)
            )
    except DefusedXmlException:
        with open(path, "rb") as fh:
            head = fh.read(4096)
        if _PLAIN_HTML_DOCTYPE.match(head):  # <!DOCTYPE html>, no subset: nothing to expand
            from models.mesh.vtk_readers import xml_fault

            said = xml_fault(str(path), "VTKFile")
            if said:  # a web page saved under a mesh's name: the CLI's words
                raise UploadRejected(422, wording(said, path)) from None
        raise UploadRejected(
            422, wording("XML with a DOCTYPE or entity declarations is not accepted", path)
        ) from None
    except ParseError:
        return  # malformed XML: the reader refuses it, in the same words as the CLI


def polygons_of(path: Path, max_cells: int) -> dict:
    """A 2D mesh's cells as flat polygon loops: points [[x, y], ...] (rounded to ~7 significant
    digits of the extent), connectivity (point ids, counter-clockwise) cut by offsets."""
    import math

    import numpy as np

    from models.mesh.sandbox import read_mesh_safe as read_mesh

    mesh = read_mesh(str(path))
    if mesh.dim != 2:
        raise UploadRejected(404, "polygons are drawn for 2D meshes only")
    if mesh.n_cells > max_cells:
        raise UploadRejected(413, f"the mesh has {mesh.n_cells} cells; at most {max_cells} are drawn")
    points = mesh.points3d()[:, :2]  # the coordinates of the file, as the result files keep them
    extent = float(np.ptp(points, axis=0).max()) or 1.0
    decimals = max(0, 7 - math.ceil(math.log10(extent)))
    return {
        "points": np.round(points, decimals).tolist(),
        "connectivity": mesh.connectivity.tolist(),
        "offsets": mesh.offsets.tolist(),
    }


def draw_level(path: Path, archive: Path, level: int, out: Path) -> None:
    """Merge a hierarchy level's elements (labels from the archive) and plot them (models.quality.plot)."""
    import zipfile

    import numpy as np

    from models.mesh.sandbox import read_mesh_safe as read_mesh
    from models.pipeline import prepare
    from models.polytope.merge import merge
    from models.quality.plot import plot_agglomeration

    with zipfile.ZipFile(archive) as zf:
        index = json.loads(zf.read("hierarchy.json"))
        labels = np.asarray(json.loads(zf.read(index["levels"][level]["labels"])), dtype=np.int64)
    mesh = read_mesh(str(path))
    if labels.shape != (mesh.n_cells,):
        raise UploadRejected(422, f"level {level} has {labels.size} labels for {mesh.n_cells} cells")
    graph, data = prepare(mesh)
    poly = merge(mesh, graph, labels, data.measures)[0]
    fine = mesh if mesh.dim == 2 and mesh.n_cells <= 200_000 else None
    plot_agglomeration(poly, out, fine_mesh=fine, title=f"level {level}: {poly.n_elements} elements", dpi=100)


def _message(exc: Exception, path: Path, what: str) -> str:
    """Our own message (read_mesh_safe's words), or a sentence: never a library's raw text. A file
    inside an archive is said after the archive, as the CLI says it ("cannot read case.zip: cannot
    read big.xdmf as XDMF: ...")."""
    from models.errors import HoleError, MagnetError, MeshError

    if not isinstance(exc, MagnetError):
        return wording(what, path)[:2000]
    said = str(exc)
    if (
        isinstance(exc, MeshError)
        and not isinstance(exc, HoleError)
        and formats.extension(path.name) in formats.ARCHIVES
        and path.name not in said
    ):
        said = wording(said, path)
    return said[:2000]


def _child_main(argv: list[str]) -> int:
    if argv and argv[0] == "--level-picture":
        try:
            draw_level(Path(argv[1]), Path(argv[3]), int(argv[4]), Path(argv[5]))
            out = {"picture": argv[5]}
        except UploadRejected as exc:
            out = {"status": exc.status, "error": exc.message}
        except MemoryError:
            out = {"status": 422, "error": "the level could not be drawn within the memory limit"}
        except Exception as exc:
            out = {"status": 422, "error": _message(exc, Path(argv[1]), "the level could not be drawn")}
        print(json.dumps(out))
        return 0
    if argv and argv[0] == "--polygons":
        try:
            out = {"polygons": polygons_of(Path(argv[1]), int(argv[3]))}
        except UploadRejected as exc:
            out = {"status": exc.status, "error": exc.message}
        except MemoryError:
            out = {"status": 422, "error": "the mesh could not be read within the memory limit"}
        except Exception as exc:
            out = {"status": 422, "error": _message(exc, Path(argv[1]), "its polygons could not be drawn")}
        print(json.dumps(out))
        return 0
    path, ext, max_cells = Path(argv[0]), argv[1], int(argv[2])
    physical_tag = argv[3] if len(argv) > 3 else None
    try:
        if ext in XML_EXTENSIONS:
            check_xml(path, max_cells)
        from models import api

        info = api.inspect_mesh(str(path), physical_tag=physical_tag, check=physical_tag is None)
        if int(info["cells"]) > max_cells:
            raise UploadRejected(
                413, f"the mesh has {int(info['cells']):,} cells; the limit is {max_cells:,}"
            )
        issues = info.get("check", {}).get("issues", [])  # no check report when re-read for a physical_tag
        errors = [i["message"] for i in issues if i["severity"] == "error"]
        if errors:  # read, but it cannot be agglomerated (e.g. not a manifold): say so now, not in a job
            raise UploadRejected(422, errors[0])
        out = {"info": info}
    except UploadRejected as exc:
        out = {"status": exc.status, "error": exc.message}
    except MemoryError:
        out = {"status": 422, "error": "the mesh could not be read within the memory limit; rejected"}
    except Exception as exc:  # any failure to read an untrusted file is the file's fault
        out = {"status": 422, "error": _message(exc, path, "it was read but could not be checked")}
    from jobqueue.storage import _plain

    print(json.dumps(out, default=_plain))
    return 0


if __name__ == "__main__":
    sys.exit(_child_main(sys.argv[1:]))
