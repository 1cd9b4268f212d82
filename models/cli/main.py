"""The `magnet` command line. Runs in-process; the server side adds `serve` and `worker` through
the `magnet.commands` entry points (so this package never imports HTTP or Celery code).

Errors the user can fix (bad mesh, bad parameter) print one line and exit with status 2.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import sys
import time

from models.errors import HoleError, MagnetError, MeshError, ParameterError

EXIT_USER_ERROR = 2
EXIT_INTERNAL = 70  # sysexits' EX_SOFTWARE: our bug, not the user's input
EXIT_PIPE = 141  # a closed pipe, as a command killed by SIGPIPE (128 + 13): no message


def _add_job_args(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--model",
        default="metis",
        help="metis | kmeans | rtree | sage-base | sage-hetero | rl-partitioner (default metis)",
    )
    p.add_argument(
        "--mode",
        help="kway | nref | target-size | mult-factor | segregated | coarsen | multilevel "
        "(default: the one the size flag implies: --k kway, --nref nref, --target-size target-size, "
        "--mult-factor mult-factor; with --subset coarsen)",
    )
    p.add_argument(
        "--refiner",
        choices=["fm", "rl-refiner"],
        help="refine every bisection (every level in multilevel mode); k-way mode: fm (default: none)",
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
    p.add_argument("-k", "--k", type=int, help="number of elements (kway): exactly k unless --allow-extra")
    p.add_argument(
        "--allow-extra",
        action="store_true",
        help="with --k or --nref: keep every connected fragment of a part as an element of its own (more "
        "than k elements), instead of merging fragments and splitting the largest elements to give exactly "
        "k (2^nref)",
    )
    p.add_argument(
        "--nref",
        type=int,
        help="number of refinements: exactly 2^nref elements unless --allow-extra (with --hierarchy: the "
        "last bisection's parts)",
    )
    p.add_argument("--target-size", type=float, help="bisect until every element's diameter is below this")
    p.add_argument("--mult-factor", type=float, help="target size = factor x mesh diameter (0 < f <= 1)")
    p.add_argument(
        "--subset",
        help="file with the cell ids to agglomerate (JSON list or whitespace separated), or the ids themselves (1,2,3); the rest stays",
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
    p.add_argument("--seed", type=int, default=0, help="random seed")
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
        if not os.path.exists(path) and re.fullmatch(r"\s*\d+(\s*[, ]\s*\d+)*\s*", path):
            text = path  # (the ids themselves: --subset 1,2,3)
        else:
            raise ParameterError(f"cannot read subset file {path}: {exc.strerror.lower()}") from None
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


def job_params(args, subset=None) -> dict:
    """The job parameters of a `magnet agglomerate` / `compare` command line, as the service takes
    them (models.params.validate_params checks them: one validation for every way in)."""
    params = {
        "model": args.model,
        "mode": args.mode,
        "k": args.k,
        "nref": args.nref,
        "target_size": args.target_size,
        "mult_factor": args.mult_factor,
        "subset": None if subset is None else subset.tolist(),
        "refiner": args.refiner,
        "options": {
            "seed": args.seed,
            "absorb_fraction": args.absorb,
            "hole_policy": args.hole_policy,
            "physical_tag": args.physical_tag,
            "method": args.method,
            "boundary_tag": args.boundary_tag,
            "size_measure": args.size_measure,
            "threshold": args.threshold,
            "hierarchy": bool(getattr(args, "hierarchy", None)),
            "weld": args.weld,
            "allow_extra": args.allow_extra,
            "keep_groups": {"auto": None, "on": True, "off": False}[args.keep_groups],
        },
    }
    params = {key: v for key, v in params.items() if v is not None}
    params["options"] = {key: v for key, v in params["options"].items() if v is not None}
    return params


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
    from models.agglomeration import run
    from models.params import validate_params

    check_output_path(args.output, "output mesh", (".vtu", ".ucd", ".inp"))
    ucd = os.path.splitext(args.output)[1].lower() in (".ucd", ".inp")
    for what in ("metrics", "labels", "lymph", "plot"):  # (lymph: Matlab's .mat, or its JSON twin)
        check_output_path(getattr(args, what), f"--{what} file", (".mat", ".json") if what == "lymph" else ())
    t0 = time.perf_counter()
    subset = _read_subset(args.subset)
    params = job_params(args, subset)
    validate_params(params)  # a bad flag fails before the mesh is read
    if args.fill:
        source = _fill(args)  # the closed surface filled with tetrahedra (its own progress line)
    else:
        if args.remesh or args.fill_size is not None or args.fill_size_abs is not None:
            raise ParameterError("--remesh, --fill-size and --fill-size-abs go with --fill")
        source = args.mesh
    t_fill = time.perf_counter() - t0
    prog = _Progress(args.progress or sys.stderr.isatty())
    try:
        try:
            result = run(source, params, metrics=bool(args.metrics) or args.model_metrics, progress=prog)
        except MagnetError as exc:
            from models.mesh.fill import is_surface_file, open_surface_refusal

            if (
                isinstance(exc, MeshError)
                and not isinstance(exc, HoleError)  # (found after the read: no reader to name)
                and os.path.basename(args.mesh) not in str(exc)
            ):
                from models.mesh.sandbox import wording  # (found after reading: said as every refusal)

                raise MeshError(wording(str(exc), args.mesh)) from None
            if args.fill or not is_surface_file(args.mesh):
                raise
            refused = open_surface_refusal(args.mesh, exc)
            if refused is not exc:  # open (or crossing): not to be filled either; as check says it
                raise refused from None
            said = str(exc)
            from models.mesh.build import FILL_HINT

            if FILL_HINT in said:  # (the reader's words: this file is the surface)
                raise type(exc)(
                    said.replace(FILL_HINT, f"agglomerate {os.path.basename(args.mesh)} --fill")
                ) from None
            raise  # (unreadable, or k above the cells of a flat surface: filling is no answer to it)
        res, mesh = result.result, result.mesh
        if args.fill:
            res.timings = {"fill": t_fill, **{k: v for k, v in res.timings.items() if k != "read"}}
        if args.hierarchy:
            written: dict = {}
            idx = pipeline.write_hierarchy(res, args.hierarchy, written=written)
            print(
                f"hierarchy: {len(idx['levels'])} levels in {args.hierarchy} "
                f"({' > '.join(str(lv['elements']) for lv in idx['levels'])} elements)"
            )
            if written.get("removed"):
                from models.hierarchy.stale import removed_sentence

                print(f"note: {removed_sentence(written['removed'], args.hierarchy)}")
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
    rc = s.get("recount") or {}
    if rc.get("merged") or rc.get("split"):
        extra.append(
            f"exactly {s['requested']}: {rc['merged']} fragments merged, {rc['split']} elements split again"
        )
    if rc.get("threaded"):
        extra.append(f"{rc['threaded']} holes threaded (a path of cells from the hole to a neighbour)")
    note = f" ({', '.join(extra)})" if extra else ""
    print(f"{s['elements']} elements from {mesh.n_cells} cells{note} | {stages} | total {total:.2f}s")
    from models.agglomeration import count_note
    from models.mesh.dropped import dropped_sentence, ignored_lower_sentence

    counted = count_note(s, bool(args.hierarchy))
    if counted:
        print(f"note: {counted.replace('hierarchy=True', '--hierarchy')}")
    if rc.get("rings_kept"):
        n = rc["rings_kept"]
        print(
            f"warning: {n} element{'s are rings' if n > 1 else ' is a ring'} (around a tunnel of the domain "
            f"or a neighbouring element): {s.get('asked', 'k')} = {s['requested']} cannot be met without "
            f"{'them' if n > 1 else 'it'}; ask for more elements to have none"
        )
    ignored = ignored_lower_sentence(mesh.meta, mesh.dim)
    if ignored:
        print(f"note: {ignored}")
    left_out = dropped_sentence(mesh.meta)
    if left_out:
        print(f"warning: {left_out} (labels: -1 for them)")
    for key in (
        "overlong_cells",
        "open_polyhedra",
        "openfoam_order",
        "fluent_faces",
        "trailing_bytes",
        "rounded_plane",
        "lost_data",
    ):
        if mesh.meta.get(key):
            print(f"warning: {mesh.meta[key]['message']}")
    for key in (
        "merged_points",
        "reordered_cells",
        "reversed_faces",
        "gambit_groups",
        "ghost_cells",
        "repeated_pieces",
        "nonfinite_points",
    ):
        if mesh.meta.get(key):
            print(f"note: {mesh.meta[key]['message']}")
    return 0


def _fill(args):
    """`agglomerate shell.stl --fill`: the closed surface filled with tetrahedra (models.mesh.fill)."""
    from models.cli.fill import FillProgress, fill_options
    from models.mesh.fill import describe_fill, fill_mesh

    if args.physical_tag or args.weld is not None:
        raise ParameterError("--physical-tag and --weld do not apply to --fill (a surface has no groups)")
    prog = FillProgress(os.path.basename(args.mesh))
    try:
        mesh = fill_mesh(args.mesh, size=args.fill_size, progress=prog, seed=args.seed, **fill_options(args))
    finally:
        prog.close()
    print(describe_fill(mesh.meta["fill"]))
    return mesh


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
    from models.agglomeration import read_mesh, run
    from models.params import MODE_SIZES, infer_mode
    from models.quality.plot import metrics_table, plot_metric_boxplots

    base = job_params(args)
    mesh = read_mesh(args.mesh, physical_tag=args.physical_tag, weld=args.weld)
    results = {}
    for spec in args.methods.split(","):
        model, _, mode = spec.strip().partition(":")
        mode = mode or args.mode
        params = dict(base, model=model)
        if mode:  # each method takes the size flag its mode uses (e.g. metis:kway,metis:nref --k 64 --nref 6)
            params["mode"] = mode
            for size in ("k", "nref", "target_size", "mult_factor"):
                if size not in MODE_SIZES.get(mode, ()):
                    params.pop(size, None)
        mode = mode or infer_mode(params)
        t = time.perf_counter()
        res = run(mesh, params).result
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


class _Help(argparse.HelpFormatter):
    """--help shows every default that is set (flags without one say so in their text)."""

    def _get_help_string(self, action):
        text = action.help or ""
        d = action.default
        if d is None or d is argparse.SUPPRESS or d is False or "default" in text or action.nargs == 0:
            return text
        return f"{text} (default {d})" if text else f"(default {d})"


class _Parser(argparse.ArgumentParser):
    """A bad flag or value is one sentence (argparse's own words, which name the flag), not the
    usage block: `--help` shows that."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see `{self.prog} --help`)\n")


def build_parser(argv: list[str]) -> argparse.ArgumentParser:
    import functools

    parser = _Parser(
        prog="magnet", description="Mesh agglomeration (MAGNET service library)", formatter_class=_Help
    )
    sub = parser.add_subparsers(dest="command", required=True)
    sub.add_parser = functools.partial(sub.add_parser, formatter_class=_Help)

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
    p.add_argument(
        "--fill",
        action="store_true",
        help="MESH is a closed surface (.stl, .obj, .ply, .off): fill it with tetrahedra first, keeping its "
        "triangles (see --remesh, --fill-size, --fill-size-abs, --max-cells)",
    )
    from models.cli.fill import add_fill_args

    add_fill_args(p)
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
        (
            "train",
            "models.cli.train",
            "add_train_args",
            "train_main",
            "train a model we ship (SAGE, RL agents)",
        ),
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

    if argv and argv[0] in sub.choices:  # a library command: no need to look for the server side's
        return parser  # (importlib.metadata's scan of the installed packages costs ~60 ms of start-up)
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


_OPTION = re.compile(r"\boptions\.([a-z_]+)")
# a parameter's name where the sentence starts with it ("mult_factor must be in (0, 1]"), and the
# names with an underscore anywhere (no other word has one)
_LEADING = re.compile(r"^([a-z]+(?:_[a-z]+)*)(?= must | is required| does not go)")
_UNDERSCORED = re.compile(r"(?<![\w.=-])([a-z]+(?:_[a-z]+)+)\b(?![=(])")
_FLAG_OF = {"absorb_fraction": "absorb", "fill_remesh": "remesh", "fill_max_cells": "max_cells"}


def cli_words(message: str, args) -> str:
    """A refusal worded for the command line: the service's `options.ratio` and the library's
    `mult_factor` are the flags `--ratio` and `--mult-factor` where this command has them
    (options.absorb_fraction: --absorb); models.params words them for JSON parameters."""
    if getattr(args, "command", None) == "agglomerate":  # (no --ratio: its own command makes those)
        message = message.replace(
            ", or options.ratio (a hierarchy of its own, like `magnet hierarchy`)",
            "; a hierarchy of its own: `magnet hierarchy`",
        )

    def flag(m: re.Match) -> str:
        name = _FLAG_OF.get(m.group(1), m.group(1))
        return f"--{name.replace('_', '-')}" if hasattr(args, name) else m.group(0)

    message = _OPTION.sub(flag, message)
    message = _LEADING.sub(flag, message, count=1)
    return _UNDERSCORED.sub(flag, message)


def _quiet_stdout() -> None:
    """stdout onto /dev/null: the interpreter's final flush of a closed pipe would fail again."""
    try:
        fd = os.open(os.devnull, os.O_WRONLY)
        os.dup2(fd, sys.stdout.fileno())
        os.close(fd)
    except (OSError, ValueError):  # (no real stdout: nothing left to flush)
        pass


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    parser = build_parser(argv)
    args = parser.parse_args(argv)
    if not hasattr(args, "func"):
        parser.error(f"{args.command}: not available")
    try:
        rc = args.func(args)
    except MagnetError as exc:
        said = cli_words(getattr(exc, "options_words", None) or str(exc), args)
        print(f"magnet: error: {said}", file=sys.stderr)
        return EXIT_USER_ERROR
    except BrokenPipeError:  # `magnet check --json x.vtu | head -1`: the reader had enough; say nothing
        _quiet_stdout()
        return EXIT_PIPE
    except OSError as exc:  # an output that cannot be written (disk full, permissions changed, ...)
        where = f": {exc.filename}" if exc.filename else ""
        print(f"magnet: error: {exc.strerror or exc}{where}", file=sys.stderr)
        return EXIT_USER_ERROR
    except KeyboardInterrupt:
        print("magnet: interrupted", file=sys.stderr)
        return 130
    except MemoryError:
        print(
            f"magnet: error: out of memory in '{args.command}': the mesh needs more memory than this "
            "machine has free; try a smaller mesh or a machine with more memory",
            file=sys.stderr,
        )
        return EXIT_USER_ERROR
    except Exception:  # noqa: BLE001  (a bug of ours: one sentence, the traceback on request)
        if os.environ.get("MAGNET_TRACEBACK", "0") not in ("", "0"):
            raise
        print(
            f"magnet: internal error in '{args.command}': this is a bug in magnet, not a fault of your "
            "input; please report it with the command and the file (MAGNET_TRACEBACK=1 shows the details)",
            file=sys.stderr,
        )
        return EXIT_INTERNAL
    return int(rc or 0)


if __name__ == "__main__":
    os.environ.setdefault("MPLBACKEND", "Agg")
    sys.exit(main())
