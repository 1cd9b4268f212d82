"""`magnet generate`: meshes (models.learn.generate) or a training data set (models.learn.dataset).

Kept apart from both so the arrows point one way: generate_cli -> dataset -> generate.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from models.cli.fill import FillProgress, add_fill_args, fill_options
from models.errors import ParameterError
from models.learn.generate import KINDS, generate
from models.mesh.fill import describe_fill


def add_generate_args(parser: argparse.ArgumentParser) -> None:
    """Arguments of `magnet generate`."""
    parser.add_argument("kind", choices=KINDS + ("dataset",), help="mesh kind, or 'dataset' (see --recipe)")
    parser.add_argument(
        "-o",
        "--out",
        required=True,
        help="output file (.vtu, .vtk, .msh, ...), or a folder "
        "when --count > 1, or the .npz file of a dataset",
    )
    parser.add_argument("--seed", type=int, default=0, help="random seed (same seed, same mesh)")
    parser.add_argument("--count", type=int, default=1, help="number of meshes (seeds seed, seed+1, ...)")
    parser.add_argument(
        "--size",
        type=float,
        default=None,
        help="mesh size h (default: random per mesh); kind stl: re-mesh the surface at this fraction "
        "of its bounding-box diagonal, in (0, 1] (e.g. 0.02)",
    )
    parser.add_argument(
        "--n",
        type=int,
        default=None,
        help="delaunay: interior points (4 sqrt(n) more on the boundary); voronoi: cells; holes/inclusions: their number",
    )
    parser.add_argument("--parts", type=int, default=None, help="cube-hetero: number of parts, 1-4")
    parser.add_argument("--regular", action="store_true", help="holes/inclusions on a regular grid")
    parser.add_argument(
        "--stl",
        default=None,
        help="kind stl: the closed surface to fill (.stl ASCII or binary, .obj, .ply, .off); by default "
        "its triangles are kept as the faces of the tetrahedra",
    )
    add_fill_args(parser, prefix="")
    parser.add_argument("--format", default="vtu", help="file suffix when writing a folder (default vtu)")
    parser.add_argument(
        "--recipe", default=None, help="dataset: a recipe name (see models.learn.dataset.RECIPES)"
    )
    parser.add_argument("--meshes", type=int, default=None, help="dataset: override the recipe's mesh count")


def generate_main(args: argparse.Namespace) -> int:
    """Run `magnet generate`; returns the process exit code."""
    if args.kind == "dataset":
        from models.learn.dataset import build_dataset  # torch-free, but only needed here

        if not args.recipe:
            raise ParameterError("generate dataset needs --recipe")
        ds = build_dataset(args.recipe, args.out, seed=args.seed, n_meshes=args.meshes)
        print(f"wrote {args.out}: {len(ds)} graphs, {ds.n_nodes} nodes")
        return 0
    if args.count < 1:
        raise ParameterError("--count must be >= 1")
    out = Path(args.out)
    if args.count > 1:
        out.mkdir(parents=True, exist_ok=True)
    if args.kind != "stl" and (args.size_abs is not None or args.remesh):
        raise ParameterError("--size-abs and --remesh are for kind stl (filling a closed surface)")
    for i in range(args.count):
        seed = args.seed + i
        fill = None
        if args.kind == "stl":
            fill = fill_options(args, prefix="")
            fill["progress"] = prog = FillProgress(Path(args.stl or "").name)
        try:
            mesh = generate(args.kind, seed, args.size, args.n, args.parts, args.regular, args.stl, fill)
        finally:
            if fill:
                prog.close()
        path = out / f"{args.kind}_{seed:05d}.{args.format}" if args.count > 1 else out
        mesh.write(path)
        if mesh.info:
            print(describe_fill(mesh.info))
        print(f"{path}: {mesh.n_cells} cells, {len(mesh.points)} points")
    return 0
