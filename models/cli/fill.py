"""The options of filling a closed surface with tetrahedra, shared by `magnet generate stl` and
`magnet agglomerate shell.stl --fill` (models.mesh.fill does the work)."""

from __future__ import annotations

import argparse
import sys
import time

from models.errors import ParameterError
from models.mesh.fill import DEFAULT_MAX_CELLS, DEFAULT_REL_SIZE


def add_fill_args(parser: argparse.ArgumentParser, prefix: str = "fill-") -> None:
    """The options of filling a closed surface (`generate stl`: --size-abs, ...; `agglomerate --fill`:
    --fill-size, --fill-size-abs, ...)."""
    if prefix:
        parser.add_argument(
            f"--{prefix}size",
            type=float,
            default=None,
            metavar="F",
            help="--fill: re-mesh the surface at F x its bounding-box diagonal, F in (0, 1] (e.g. 0.02)",
        )
    parser.add_argument(
        f"--{prefix}size-abs",
        type=float,
        default=None,
        metavar="H",
        help="re-mesh the surface at the absolute size H, in the file's own length unit (STL, OBJ, PLY "
        "and OFF carry none: a file in millimetres takes H in millimetres)",
    )
    parser.add_argument(
        "--remesh",
        action="store_true",
        help=f"re-mesh the surface first (at {DEFAULT_REL_SIZE} x the bounding-box diagonal unless a size "
        "is given) instead of keeping its triangles",
    )
    parser.add_argument(
        "--max-cells",
        type=int,
        default=DEFAULT_MAX_CELLS,
        metavar="N",
        help=f"refuse to fill when the estimated number of tetrahedra exceeds N (default {DEFAULT_MAX_CELLS:,})",
    )


class FillProgress:
    """Prints how long a fill has run on stderr, once it takes more than a few seconds."""

    def __init__(self, name: str, after_s: float = 3.0):
        self.name, self.after_s, self.t0, self.shown = name, after_s, time.perf_counter(), False

    def __call__(self, frac: float, stage: str) -> None:
        el = time.perf_counter() - self.t0
        if el < self.after_s or (not sys.stderr.isatty() and int(el * 2) % 10):  # log files: every 5 s
            return
        end = "\r" if sys.stderr.isatty() else "\n"
        print(
            f"filling {self.name}: {el:.0f} s, about {100 * frac:.0f}% (estimated) ", end=end, file=sys.stderr
        )
        sys.stderr.flush()
        self.shown = True

    def close(self) -> None:
        if self.shown and sys.stderr.isatty():
            print(file=sys.stderr)


def fill_options(args: argparse.Namespace, prefix: str = "fill_") -> dict:
    """The fill keywords of models.mesh.fill.fill_surface from parsed arguments."""
    if args.max_cells is not None and args.max_cells < 1:
        raise ParameterError("--max-cells must be >= 1")
    return {
        "size_abs": getattr(args, f"{prefix}size_abs"),
        "remesh": args.remesh,
        "max_cells": args.max_cells,
    }
