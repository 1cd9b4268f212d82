"""The `magnet` command line. Runs in-process; the server side adds `serve` and `worker` through
the `magnet.commands` entry points (so this package never imports HTTP or Celery code).

Errors the user can fix (bad mesh, bad parameter) print one line and exit with status 2.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

from models.errors import MagnetError, ParameterError

EXIT_USER_ERROR = 2


def _add_job_args(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--model",
        default="metis",
        help="metis | kmeans | rtree | sage-base | sage-hetero | rl-partitioner (default metis)",
    )
    p.add_argument(
        "--mode",
        default="kway",
        help="kway | nref | target-size | mult-factor | segregated | coarsen | multilevel",
    )
    p.add_argument(
        "--refiner",
        choices=["fm", "rl-refiner"],
        help="refine every bisection (every level in multilevel mode); k-way mode: fm",
    )
    p.add_argument(
        "--threshold",
        type=int,
        default=200,
        help="multilevel: coarsen every subgraph to at most this many nodes",
    )
    p.add_argument(
        "--keep-groups",
        default="auto",
        choices=["auto", "on", "off"],
        help="refiner: cuts prefer physical-group interfaces and never leave more cells outside their part's "
        "majority group (auto: on for sage-hetero)",
    )
    p.add_argument("--k", type=int, help="number of elements (kway)")
    p.add_argument("--nref", type=int, help="number of refinements: 2^nref elements")
    p.add_argument("--target-size", type=float, help="bisect until every element's diameter is below this")
    p.add_argument("--mult-factor", type=float, help="target size = factor x mesh diameter (0 < f <= 1)")
    p.add_argument(
        "--subset",
        help="file with the cell ids to agglomerate (JSON list or whitespace separated); the rest stays",
    )
    p.add_argument(
        "--physical-tag",
        help="cell-data name holding the physical groups (default: gmsh:physical, CellEntityIds, ...)",
    )
    p.add_argument(
        "--weld",
        type=float,
        metavar="TOL",
        help="merge points closer than TOL first (duplicate points that split the mesh)",
    )
    p.add_argument(
        "--absorb",
        type=float,
        default=0.0,
        metavar="FRACTION",
        help="absorb parts smaller than FRACTION x mean part size into their longest-interface neighbour",
    )
    p.add_argument(
        "--method", default="kway", choices=["kway", "recursive"], help="METIS k-way or recursive (kway mode)"
    )
    p.add_argument(
        "--boundary-tag",
        type=int,
        default=1,
        metavar="N",
        help="lymph bc_tag of boundary edges without a boundary group (default 1)",
    )
    p.add_argument(
        "--hole-policy",
        default="split",
        choices=["split", "error"],
        help="what to do with elements that enclose a hole",
    )
    p.add_argument("--seed", type=int, default=0)
    p.add_argument(
        "--size-measure",
        default="centroids",
        choices=["centroids", "vertices"],
        help="size of a part for target-size / mult-factor / segregated: largest distance between its cell "
        "centroids (the paper's, default) or between its vertices (every element below h)",
    )


def _read_subset(path: str | None):
    if path is None:
        return None
    import numpy as np

    try:
        text = open(path, encoding="utf-8").read()
    except OSError as exc:
        raise ParameterError(f"cannot read subset file {path}: {exc.strerror}") from None
    try:
        data = json.loads(text)
        if isinstance(data, dict):
            data = data.get("subset", data.get("cells"))
        arr = np.asarray(data)
    except json.JSONDecodeError:
        try:
            arr = np.asarray([int(t) for t in text.replace(",", " ").split()])
        except ValueError:
            raise ParameterError(f"subset file {path} must hold integer cell ids") from None
    if arr.ndim != 1 or arr.size == 0 or not np.issubdtype(arr.dtype, np.integer):
        raise ParameterError(f"subset file {path} must hold a non-empty list of integer cell ids")
    return arr.astype(np.int64)


class _Progress:
    """A tqdm bar on stderr for long runs (only when stderr is a terminal, or forced)."""

    def __init__(self, enabled: bool):
        self.bar = None
        self.enabled = enabled

    def __call__(self, frac: float, stage: str) -> None:
        if not self.enabled:
            return
        if self.bar is None:
            from tqdm import tqdm

            self.bar = tqdm(total=100, file=sys.stderr, bar_format="{l_bar}{bar}| {elapsed}", leave=False)
        self.bar.set_description(stage)
        self.bar.n = int(100 * frac)
        self.bar.refresh()

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def check_output_path(path: str | None, what: str, suffixes: tuple[str, ...] = ()) -> None:
    """Fail early, in one line, on an output path that cannot be written (before any work is done)."""
    if path is None:
        return
    if suffixes and not path.lower().endswith(suffixes):
        raise ParameterError(f"{what} {path!r} must end with {' or '.join(suffixes)}")
    if os.path.isdir(path):
        raise ParameterError(f"{what} {path!r} is a folder; give a file name")
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(folder):
        raise ParameterError(f"cannot write {what} {path!r}: folder {folder!r} does not exist")
    if not os.access(folder, os.W_OK | os.X_OK) or (os.path.exists(path) and not os.access(path, os.W_OK)):
        raise ParameterError(f"cannot write {what} {path!r}: permission denied")


def cmd_agglomerate(args) -> int:
    from models import pipeline
    from models.mesh.sandbox import read_mesh_cli as read_mesh

    check_output_path(args.output, "output mesh", (".vtu", ".ucd", ".inp"))
    ucd = os.path.splitext(args.output)[1].lower() in (".ucd", ".inp")
    for what in ("metrics", "labels", "lymph", "plot"):
        check_output_path(getattr(args, what), f"--{what} file")
    t0 = time.perf_counter()
    subset = _read_subset(args.subset)
    mesh = read_mesh(args.mesh, physical_tag=args.physical_tag, weld=args.weld)
    t_read = time.perf_counter() - t0
    prog = _Progress(args.progress or (sys.stderr.isatty() and mesh.n_cells > 200_000))
    try:
        res = pipeline.run(
            mesh,
            model=args.model,
            mode=args.mode,
            k=args.k,
            nref=args.nref,
            target_size=args.target_size,
            mult_factor=args.mult_factor,
            subset=subset,
            absorb_fraction=args.absorb,
            hole_policy=args.hole_policy,
            seed=args.seed,
            model_options={"method": args.method} if args.model == "metis" else None,
            size_measure=args.size_measure,
            compute_metrics=bool(args.metrics) or args.model_metrics,
            progress=prog,
            refiner=args.refiner,
            threshold=args.threshold,
            record_levels=bool(args.hierarchy),
            keep_groups={"auto": None, "on": True, "off": False}[args.keep_groups],
        )
        res.timings = {"read": t_read, **res.timings}
        if args.hierarchy:
            idx = pipeline.write_hierarchy(res, args.hierarchy)
            print(
                f"hierarchy: {len(idx['levels'])} levels in {args.hierarchy} "
                f"({' > '.join(str(lv['elements']) for lv in idx['levels'])} elements)"
            )
        if args.lymph and mesh.dim != 2:
            raise ParameterError("--lymph is for 2D meshes only")
        if ucd:  # deal.II: the fine cells, material id = agglomerated element (UCD has no polytopes)
            from models.export.ucd import write_ucd

            write_ucd(
                args.output,
                res.mesh,
                material=res.agglomeration.labels,
                comment=f"magnet: {res.poly.n_elements} agglomerated elements; material id = element (0-based)",
            )
        pipeline.write_outputs(
            res,
            vtu=None if ucd else args.output,
            metrics=args.metrics,
            labels=args.labels,
            lymph=args.lymph,
            plot=args.plot,
            boundary_tag=args.boundary_tag,
        )
    finally:
        prog.close()
    total = time.perf_counter() - t0
    s = res.summary()
    stages = " ".join(f"{k} {v:.2f}s" for k, v in res.timings.items())
    extra = []
    if s["parts_split"]:
        extra.append(f"{s['parts_split']} parts split")
    if s["fragments_absorbed"]:
        extra.append(f"{s['fragments_absorbed']} fragments absorbed")
    if s["holes_split"]:
        extra.append(f"{s['holes_split']} holed elements split")
    note = f" ({', '.join(extra)})" if extra else ""
    print(f"{s['elements']} elements from {mesh.n_cells} cells{note} | {stages} | total {total:.2f}s")
    return 0


def cmd_check(args) -> int:
    from models.mesh.check import check_file, format_report

    rep = check_file(args.mesh, physical_tag=args.physical_tag, weld=args.weld)
    print(json.dumps(rep, indent=1) if args.json else format_report(rep))
    return EXIT_USER_ERROR if rep["verdict"] == "error" else 0


def cmd_info(args) -> int:
    from models.api import inspect_mesh

    print(json.dumps(inspect_mesh(args.mesh, physical_tag=args.physical_tag), indent=1))
    return 0


def cmd_plot(args) -> int:
    import numpy as np

    from models import pipeline
    from models.mesh.sandbox import read_mesh_cli as read_mesh
    from models.quality.plot import plot_agglomeration

    mesh = read_mesh(args.mesh, physical_tag=args.physical_tag)
    try:
        labels = np.asarray(json.load(open(args.labels, encoding="utf-8")), dtype=np.int64)
    except (OSError, ValueError, TypeError) as exc:
        raise ParameterError(f"cannot read labels file {args.labels}: {exc}") from None
    if labels.ndim != 1 or labels.size != mesh.n_cells or labels.min() < 0:
        raise ParameterError(
            f"labels must be a list of {mesh.n_cells} non-negative element ids (one per cell)"
        )
    graph, data = pipeline.prepare(mesh)
    from models.partition.agglomerate import compact_labels

    labels = compact_labels(labels)
    poly, _, _ = pipeline.split_holes(mesh, graph, data, labels, "split")
    plot_agglomeration(
        poly, args.output, fine_mesh=mesh if mesh.n_cells <= 200_000 else None, title=args.title
    )
    print(f"wrote {args.output} ({poly.n_elements} elements)")
    return 0


def cmd_compare(args) -> int:
    from models import pipeline
    from models.mesh.sandbox import read_mesh_cli as read_mesh
    from models.quality.plot import metrics_table, plot_metric_boxplots

    mesh = read_mesh(args.mesh, physical_tag=args.physical_tag)
    results = {}
    for spec in args.methods.split(","):
        model, _, mode = spec.strip().partition(":")
        mode = mode or args.mode
        t = time.perf_counter()
        res = pipeline.run(
            mesh,
            model=model,
            mode=mode,
            k=args.k,
            nref=args.nref,
            target_size=args.target_size,
            mult_factor=args.mult_factor,
            absorb_fraction=args.absorb,
            seed=args.seed,
            size_measure=args.size_measure,
            refiner=args.refiner,
            threshold=args.threshold,
            keep_groups={"auto": None, "on": True, "off": False}[args.keep_groups],
        )
        rep = dict(res.metrics)
        rep["time"] = time.perf_counter() - t
        results[f"{model}:{mode}"] = rep
    plot_metric_boxplots(results, args.output)
    table = metrics_table(results)
    print(table)
    if args.table:
        with open(args.table, "w", encoding="utf-8") as fh:
            fh.write(table + "\n")
    if args.json:
        with open(args.json, "w", encoding="utf-8") as fh:
            json.dump(
                {
                    k: {"summary": v["summary"], "partition": v["partition"], "time": v["time"]}
                    for k, v in results.items()
                },
                fh,
                indent=1,
            )
    return 0


def build_parser(argv: list[str]) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="magnet", description="Mesh agglomeration (MAGNET service library)")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("agglomerate", help="agglomerate a mesh in-process")
    p.add_argument("mesh")
    p.add_argument(
        "-o",
        "--output",
        required=True,
        help="agglomerated mesh (.vtu), or .ucd/.inp for deal.II: the fine cells with the element id as material",
    )
    _add_job_args(p)
    p.add_argument("--metrics", help="write the metrics JSON here")
    p.add_argument("--labels", help="write the fine-cell -> element labels (JSON list) here")
    p.add_argument("--lymph", help="write the lymph structs here (.mat or .json; 2D only)")
    p.add_argument("--plot", help="write a PNG picture of the agglomerated mesh here")
    p.add_argument(
        "--hierarchy",
        metavar="OUT_DIR",
        help="write every level of a recursive mode here, nested "
        "(level_L.vtu, level_L.labels.json, level_L.parent.json, level_L.metrics.json, hierarchy.json)",
    )
    p.add_argument("--progress", action="store_true", help="always show the progress bar")
    p.set_defaults(func=cmd_agglomerate, model_metrics=False)

    p = sub.add_parser(
        "check",
        help="report on a mesh (pieces, holes, folded/duplicate/unused/hanging points, ...) with a verdict",
    )
    p.add_argument("mesh")
    p.add_argument("--json", action="store_true", help="print the report as JSON")
    p.add_argument("--physical-tag")
    p.add_argument("--weld", type=float, metavar="TOL", help="merge points closer than TOL first")
    p.set_defaults(func=cmd_check)

    p = sub.add_parser("info", help="read a mesh and print its summary")
    p.add_argument("mesh")
    p.add_argument("--physical-tag")
    p.set_defaults(func=cmd_info)

    p = sub.add_parser(
        "plot", help="draw an agglomeration (fine mesh + labels) to PNG; 3D as an exploded view"
    )
    p.add_argument("mesh")
    p.add_argument("--labels", required=True, help="labels JSON written by `magnet agglomerate --labels`")
    p.add_argument("-o", "--output", required=True)
    p.add_argument("--title")
    p.add_argument("--physical-tag")
    p.set_defaults(func=cmd_plot)

    p = sub.add_parser("compare", help="run several methods on one mesh; box plots of the metrics + a table")
    p.add_argument("mesh")
    p.add_argument(
        "--methods",
        default="metis,kmeans",
        help="comma list of MODEL[:MODE], e.g. metis:kway,kmeans:kway,metis:nref",
    )
    p.add_argument("-o", "--output", required=True, help="PNG with the box plots")
    p.add_argument("--table", help="also write the table here")
    p.add_argument("--json", help="also write the summaries here")
    _add_job_args(p)
    p.set_defaults(func=cmd_compare)

    # generate / train live in modules that import gmsh / torch: load them only when asked for
    for name, module, adder, runner, help_ in (
        (
            "generate",
            "models.cli.generate",
            "add_generate_args",
            "generate_main",
            "generate meshes / data sets (gmsh)",
        ),
        ("train", "models.cli.train", "add_train_args", "train_main", "train a SAGE model"),
        (
            "hierarchy",
            "models.cli.hierarchy",
            "add_hierarchy_args",
            "hierarchy_main",
            "nested levels for multigrid (rtree natively, any model), with aggregation operators",
        ),
        (
            "mgcheck",
            "models.cli.hierarchy",
            "add_mgcheck_args",
            "mgcheck_main",
            "judge a hierarchy with a multigrid solve (pyamg, TPFA Poisson) beside pyamg's own aggregation",
        ),
    ):
        p = sub.add_parser(name, help=help_)
        if len(argv) > 0 and argv[0] == name:
            import importlib

            mod = importlib.import_module(module)
            getattr(mod, adder)(p)
            p.set_defaults(func=getattr(mod, runner))

    from importlib.metadata import entry_points

    for ep in entry_points(group="magnet.commands"):
        if not argv or argv[0] != ep.name:  # load the server side (FastAPI, Celery) only when asked for
            sub.add_parser(ep.name, help=f"{ep.name} (server side: `magnet {ep.name} -h`)")
            continue
        try:
            ep.load()(sub)
        except Exception as exc:  # the server extras may not be installed
            q = sub.add_parser(ep.name, help=f"(unavailable: {exc})")
            q.set_defaults(func=lambda a, e=exc: _unavailable(e))
    return parser


def _unavailable(exc) -> int:
    print(f"magnet: this command needs the service extras: {exc}", file=sys.stderr)
    return EXIT_USER_ERROR


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    parser = build_parser(argv)
    args = parser.parse_args(argv)
    if not hasattr(args, "func"):
        parser.error(f"{args.command}: not available")
    try:
        rc = args.func(args)
    except MagnetError as exc:
        print(f"magnet: error: {exc}", file=sys.stderr)
        return EXIT_USER_ERROR
    except OSError as exc:  # an output that cannot be written (disk full, permissions changed, ...)
        where = f": {exc.filename}" if exc.filename else ""
        print(f"magnet: error: {exc.strerror or exc}{where}", file=sys.stderr)
        return EXIT_USER_ERROR
    except KeyboardInterrupt:
        print("magnet: interrupted", file=sys.stderr)
        return 130
    return int(rc or 0)


if __name__ == "__main__":
    os.environ.setdefault("MPLBACKEND", "Agg")
    sys.exit(main())
