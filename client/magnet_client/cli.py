"""`magnet-client agglomerate MESH --server URL`: the flags of `magnet agglomerate`, run remotely."""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time

from magnet_client.client import (
    Client,
    InputError,
    JobFailed,
    MagnetHTTPError,
    check_input_file,
    parse_kappa,
)


def read_subset(path: str) -> list[int]:
    """Cell ids from a file: a JSON list (or {"subset": [...]}) or whitespace/comma separated ints."""
    check_input_file(path, "subset file")
    try:
        text = open(path, encoding="utf-8").read()
    except UnicodeDecodeError:
        raise InputError(f"subset file {path} must hold integer cell ids (it is not text)") from None
    try:
        data = json.loads(text)
        if isinstance(data, dict):
            data = data.get("subset", data.get("cells"))
    except json.JSONDecodeError:
        data = text.replace(",", " ").split()
    try:
        ids = [int(i) for i in data]
    except (TypeError, ValueError):
        raise InputError(f"subset file {path} must hold integer cell ids") from None
    if not ids:
        raise InputError(f"subset file {path} is empty")
    return ids


def finite(text: str) -> float:
    """argparse type of the float flags: a NaN or an infinity cannot be sent to the server."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"invalid number: '{text}'") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be finite, got {text}")
    return value


class Parser(argparse.ArgumentParser):
    """A bad flag or value is one sentence (argparse's own words, which name the flag), not the
    usage block, as `magnet` says it: `--help` shows that."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see `{self.prog} --help`)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(prog="magnet-client", description="Client of a MAGNET agglomeration server")
    parser.add_argument(
        "--server",
        default=os.environ.get("MAGNET_SERVER", "http://127.0.0.1:8000"),
        help="server URL (env MAGNET_SERVER; default http://127.0.0.1:8000)",
    )
    parser.add_argument("--token", default=os.environ.get("MAGNET_TOKEN"), help="API key (env MAGNET_TOKEN)")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser(
        "agglomerate", help="agglomerate a mesh on the server (same flags as `magnet agglomerate`)"
    )
    p.add_argument("mesh")
    p.add_argument("-o", "--output", required=True, help="agglomerated mesh (.vtu)")
    p.add_argument(
        "--model",
        default="metis",
        help="metis | kmeans | sage-base | sage-hetero | rl-partitioner (default metis)",
    )
    p.add_argument(
        "--mode",
        default="kway",
        help="kway | nref | target-size | mult-factor | segregated | coarsen | multilevel",
    )
    p.add_argument("--refiner", help="fm | rl-refiner: refine every bisection (k-way mode: fm)")
    p.add_argument(
        "--threshold", type=int, help="multilevel: coarsen to at most this many nodes (default 200)"
    )
    p.add_argument("--hierarchy", metavar="DIR", help="unpack every nested level of a recursive mode here")
    p.add_argument(
        "--ratio",
        type=finite,
        help="with --hierarchy: nested levels of their own, R times fewer elements "
        "per level, any model (as `magnet hierarchy`)",
    )
    p.add_argument(
        "--coarsest", type=int, help="with --ratio: at most N elements on the coarsest level (default 10)"
    )
    p.add_argument(
        "--finest",
        metavar="{aggregation,cuts,quality,nested}",
        help="with --hierarchy: nested levels of their own, the finest level made this way "
        "(as `magnet hierarchy --finest`)",
    )
    p.add_argument(
        "--boxfit",
        action="store_true",
        help="with --hierarchy: nested levels of their own, boundary units moved towards tighter boxes",
    )
    p.add_argument(
        "--groups",
        action="store_true",
        help="with --ratio, --finest or --boxfit: no element of any level crosses a physical group",
    )
    p.add_argument(
        "--kappa",
        metavar="KX,KY[,KZ]",
        help="with --ratio, --finest or --boxfit: the diagonal diffusion tensor the levels are cut for",
    )
    p.add_argument(
        "--keep-rings",
        action="store_true",
        help="with --ratio, --finest or --boxfit, 3D: keep elements with a handle instead of cutting them",
    )
    p.add_argument("-k", "--k", type=int, help="number of elements (kway)")
    p.add_argument(
        "--allow-extra",
        action="store_true",
        help="keep every connected fragment as an element (more than k where a part is disconnected); "
        "default: exactly k, or the job is refused with the reason",
    )
    p.add_argument(
        "--keep-groups",
        default="auto",
        choices=["auto", "on", "off"],
        help="refiner: cuts prefer physical-group interfaces (auto: on for sage-hetero)",
    )
    p.add_argument("--nref", type=int, help="number of refinements: 2^nref elements")
    p.add_argument("--target-size", type=finite, help="bisect until every element's diameter is below this")
    p.add_argument("--mult-factor", type=finite, help="target size = factor x mesh diameter (0 < f <= 1)")
    p.add_argument(
        "--subset", help="file with the cell ids to agglomerate (JSON list or whitespace separated)"
    )
    p.add_argument("--physical-tag", help="cell-data name holding the physical groups")
    p.add_argument(
        "--absorb",
        type=finite,
        default=0.0,
        metavar="FRACTION",
        help="absorb parts smaller than FRACTION x mean part size into a neighbour",
    )
    p.add_argument("--method", default="kway", choices=["kway", "recursive"], help="METIS k-way or recursive")
    p.add_argument("--hole-policy", default="split", choices=["split", "error"])
    p.add_argument(
        "--weld", type=finite, metavar="TOL", help="merge points closer than TOL first (duplicate points)"
    )
    p.add_argument(
        "--size-measure",
        choices=["centroids", "vertices"],
        help="part size for size modes: cell centroids (server default) or vertices",
    )
    p.add_argument(
        "--boundary-tag", type=int, help="lymph bc_tag of boundary edges without a boundary group (default 1)"
    )
    p.add_argument("--seed", type=int, default=0)
    p.add_argument(
        "--fill",
        action="store_true",
        help="MESH is a closed surface (.stl, .obj, .ply, .off): the server fills it with tetrahedra first, "
        "keeping its triangles (see --remesh, --fill-size, --fill-size-abs, --max-cells)",
    )
    p.add_argument(
        "--fill-size",
        type=finite,
        metavar="F",
        help="--fill: re-mesh the surface at F x its bounding-box diagonal, F in (0, 1] (e.g. 0.02)",
    )
    p.add_argument(
        "--fill-size-abs",
        type=finite,
        metavar="H",
        help="--fill: re-mesh the surface at the absolute size H, in the file's own length unit",
    )
    p.add_argument(
        "--remesh",
        action="store_true",
        help="--fill: re-mesh the surface first instead of keeping its triangles",
    )
    p.add_argument(
        "--max-cells",
        type=int,
        metavar="N",
        help="--fill: refuse when the estimated number of tetrahedra exceeds N (server default 5,000,000)",
    )
    p.add_argument("--metrics", help="write the metrics JSON here")
    p.add_argument("--labels", help="write the fine-cell -> element labels (JSON list) here")
    p.add_argument("--lymph", help="write the lymph structs here (.mat or .json; 2D only)")
    p.add_argument("--plot", help="write a PNG picture of the agglomerated mesh here")
    p.add_argument("--progress", action="store_true", help="always show the progress bar")
    p.set_defaults(func=cmd_agglomerate)

    p = sub.add_parser("models", help="list the server's agglomeration models")
    p.set_defaults(func=lambda client, args: print(json.dumps(client.models(), indent=1)) or 0)
    p = sub.add_parser("status", help="print a job")
    p.add_argument("job_id")
    p.set_defaults(func=lambda client, args: print(json.dumps(client.job(args.job_id), indent=1)) or 0)
    p = sub.add_parser("cancel", help="cancel a job")
    p.add_argument("job_id")
    p.set_defaults(func=lambda client, args: print(json.dumps(client.cancel(args.job_id), indent=1)) or 0)
    # --server / --token also after the sub-command: `magnet-client agglomerate MESH --server URL`
    for action in sub.choices.values():
        action.add_argument(
            "--server", default=argparse.SUPPRESS, help="server URL (also accepted before the sub-command)"
        )
        action.add_argument(
            "--token", default=argparse.SUPPRESS, help="API key (also accepted before the sub-command)"
        )
    return parser


def summary_line(job: dict, seconds: float) -> str:
    """The one line `magnet agglomerate` prints (elements, parts split, fragments absorbed, holed
    elements split), then the job's own stage timings on the server ("job: read ... total"), the
    client's wall time (upload, queue, wait and downloads included) and the job id."""
    result = job.get("result") or {}
    extra = []
    if result.get("parts_split"):
        extra.append(f"{result['parts_split']} parts split")
    if result.get("fragments_absorbed"):
        extra.append(f"{result['fragments_absorbed']} fragments absorbed")
    if result.get("holes_split"):
        extra.append(f"{result['holes_split']} holed elements split")
    if job.get("cached"):
        extra.append("cached result")
    note = f" ({', '.join(extra)})" if extra else ""
    stages = " ".join(f"{k} {v:.2f}s" for k, v in (result.get("timings") or {}).items())
    cells = (job.get("mesh") or {}).get("cells")
    return (
        f"{result.get('elements')} elements from {cells} cells{note} | job: {stages or 'cached'}"
        f" | client wall time {seconds:.2f}s | job {job['id']}"
    )


def cmd_agglomerate(client: Client, args: argparse.Namespace) -> int:
    t0 = time.perf_counter()
    check_input_file(args.mesh)  # before the flags' values: the file is what the user typed first
    kappa = parse_kappa(args.kappa, "--kappa")
    if args.lymph is not None and args.fill:
        raise InputError("--lymph is for 2D meshes only and --fill makes a 3D mesh")
    job = client.agglomerate(
        args.mesh,
        args.output,
        metrics=args.metrics,
        labels=args.labels,
        lymph=args.lymph,
        plot=args.plot,
        progress=args.progress or sys.stderr.isatty(),
        model=args.model,
        mode=args.mode,
        k=args.k,
        nref=args.nref,
        target_size=args.target_size,
        mult_factor=args.mult_factor,
        subset=read_subset(args.subset) if args.subset else None,
        physical_tag=args.physical_tag,
        absorb_fraction=args.absorb,
        method=args.method,
        hole_policy=args.hole_policy,
        boundary_tag=args.boundary_tag,
        seed=args.seed,
        refiner=args.refiner,
        threshold=args.threshold,
        hierarchy=args.hierarchy,
        ratio=args.ratio,
        coarsest=args.coarsest,
        finest=args.finest,
        boxfit=True if args.boxfit else None,
        groups=True if args.groups else None,
        keep_rings=True if args.keep_rings else None,
        kappa=kappa,
        weld=args.weld,
        allow_extra=True if args.allow_extra else None,
        size_measure=args.size_measure,
        keep_groups={"auto": None, "on": True, "off": False}[args.keep_groups],
        fill=True if args.fill else None,
        fill_remesh=True if args.remesh else None,
        fill_size=args.fill_size,
        fill_size_abs=args.fill_size_abs,
        fill_max_cells=args.max_cells,
    )
    print(summary_line(job, time.perf_counter() - t0))
    return 0


def os_words(exc: OSError) -> str:
    """An OSError in one sentence of ours: what could not be done to which file, and why."""
    why = (exc.strerror or "failed").lower()
    return f"{exc.filename}: {why}" if exc.filename else why


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    client = None
    try:
        client = Client(args.server, args.token)
        return args.func(client, args)
    except (InputError, MagnetHTTPError, JobFailed, ConnectionError, TimeoutError) as exc:
        print(f"magnet-client: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"magnet-client: error: {os_words(exc)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(
            "magnet-client: interrupted (a submitted job goes on: `magnet-client cancel ID`)", file=sys.stderr
        )
        return 130
    finally:
        if client is not None:
            client.close()


if __name__ == "__main__":
    sys.exit(main())
