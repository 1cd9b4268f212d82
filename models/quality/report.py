"""Box measures (box ratio, coverage) and the metrics report that gathers every metric of an agglomeration."""

from __future__ import annotations

import numpy as np

from models.mesh.container import PolyMesh
from models.quality.geometry import DEFAULT_REL_TOL, _Geometry, _prepare
from models.quality.inscribed import _check_tol, _inscribed
from models.quality.partition_stats import partition_statistics
from models.quality.shape import (
    _apr,
    _enclosing_radius,
    _ratio,
    _sphericity,
    _uniformity,
    heterogeneity_preservation,
    volume_difference,
)
from models.quality.summary import summarize  # callers import it from here too

# --------------------------------------------------------------------------------------------------
# report


def _box_measure(g: _Geometry) -> np.ndarray:
    side = np.nan_to_num(g.bbox_hi - g.bbox_lo, nan=0.0)
    return np.prod(side, axis=1)


def box_ratio(poly: PolyMesh) -> np.ndarray:
    """|K| / |B_K| per element, B_K its axis-aligned bounding box (1 for a box; R3MG's BR)."""
    return _ratio(np.abs(np.asarray(poly.measure, dtype=np.float64)), _box_measure(_prepare(poly)))


def coverage(box_measures: np.ndarray, measures: np.ndarray) -> float:
    """sum |B_K| / |Omega|: how much the elements' bounding boxes cover (1 = no overlap, no waste).
    Polynomial spaces on bounding boxes pay for it in conditioning (R3MG's coverage)."""
    total = float(np.abs(np.asarray(measures, dtype=np.float64)).sum())
    return float(np.sum(box_measures) / total) if total > 0 else float("nan")


def box_measures(
    points: np.ndarray,
    offsets: np.ndarray,
    connectivity: np.ndarray,
    labels: np.ndarray,
    measures: np.ndarray,
) -> dict:
    """Box ratio per element and coverage straight from the fine mesh (no merged polytopes):
    {"box_ratio": (E,), "coverage": float, "box": (E,) box measures}. Vectorized."""
    labels = np.asarray(labels, dtype=np.int64)
    k = int(labels.max()) + 1
    vl = np.repeat(labels, np.diff(offsets))
    p = np.asarray(points, dtype=np.float64)[connectivity]
    order = np.argsort(vl, kind="stable")
    v = vl[order]
    starts = np.flatnonzero(np.r_[True, v[1:] != v[:-1]])
    lo = np.minimum.reduceat(p[order], starts, axis=0)
    hi = np.maximum.reduceat(p[order], starts, axis=0)
    box = np.zeros(k)
    box[v[starts]] = np.prod(hi - lo, axis=1)
    m = np.bincount(labels, weights=np.abs(measures), minlength=k)
    return {"box_ratio": _ratio(m, box), "coverage": coverage(box, m), "box": box}


def _plain(values: np.ndarray) -> list:
    return [float(x) if np.isfinite(x) else None for x in np.asarray(values, dtype=np.float64)]


def metrics_report(
    poly: PolyMesh,
    indptr: np.ndarray,
    indices: np.ndarray,
    fine_tags: np.ndarray | None = None,
    rel_tol: float = DEFAULT_REL_TOL,
) -> dict:
    """All MISSION.md section 6 metrics of an agglomerated mesh as a JSON-serialisable dict."""
    g = _prepare(poly)
    rel_tol = _check_tol(rel_tol)
    measure = np.asarray(poly.measure, dtype=np.float64)
    inscribed = _inscribed(g, rel_tol)[1]
    per: dict[str, np.ndarray] = {"circle_ratio": _ratio(inscribed, _enclosing_radius(g))}
    if g.dim == 2:
        per["area_perimeter_ratio"] = _apr(g, measure)
    else:
        per["sphericity"] = _sphericity(g, measure)
    per["uniformity_factor"] = _uniformity(g.diameter)
    per["volume_difference"] = volume_difference(measure)
    box = _box_measure(g)
    per["box_ratio"] = _ratio(np.abs(measure), box)
    per["box_circle_ratio"] = _ratio(inscribed, 0.5 * np.linalg.norm(g.bbox_hi - g.bbox_lo, axis=1))
    if fine_tags is not None:
        per["heterogeneity_preservation"] = heterogeneity_preservation(poly.labels, fine_tags, g.n)
    return {
        "elements": int(g.n),
        "dim": int(g.dim),
        "coverage": coverage(box, measure),
        "summary": {k: summarize(v) for k, v in per.items()},
        "per_element": {k: _plain(v) for k, v in per.items()},
        "partition": partition_statistics(indptr, indices, poly.labels),
    }
