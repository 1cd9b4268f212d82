"""The compiled helper modules, built by setup.py where a C compiler is found: models/quality/_fastmetrics.c
(the metrics' 3D geometry and inscribed balls), models/mesh/_fastmesh.c (the read stage's validation of
fixed-size cells) and models/graph/_fastgraph.c (the rtree model's cuts,
connected pieces, coarse-graph edges, merge_2d's boundary loops). Each of their functions has a
numpy twin next to its caller, which runs where the module was not built or MAGNET_NO_COMPILED=1
(same results; the tests hold them equal)."""

from __future__ import annotations

import importlib
import os


def compiled(name: str):
    """models.<name> (e.g. "graph._fastgraph"), or None where it was not built or MAGNET_NO_COMPILED=1."""
    if os.environ.get("MAGNET_NO_COMPILED", "") not in ("", "0"):
        return None
    try:
        return importlib.import_module(f"models.{name}")
    except ImportError:
        return None


def threads() -> int:
    """Threads for a compiled helper that splits its work: MAGNET_THREADS (a whole number >= 1;
    anything else counts as 1 here), else the cores this process may use."""
    env = os.environ.get("MAGNET_THREADS", "").strip()
    if env:
        try:
            return max(1, int(env))
        except ValueError:
            return 1
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)
