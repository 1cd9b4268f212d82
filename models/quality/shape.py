"""Per-element shape metrics in [0, 1]: circle ratio, area-perimeter ratio (2D), sphericity (3D),
uniformity, volume difference, heterogeneity preservation."""

from __future__ import annotations

import numpy as np

from models.errors import ParameterError
from models.mesh.container import PolyMesh
from models.quality.geometry import DEFAULT_REL_TOL, _compiled, _enclosing_balls, _Geometry, _prepare
from models.quality.inscribed import _check_tol, _inscribed
from models.quality.partition_stats import _compact

# --------------------------------------------------------------------------------------------------
# per-element metrics


def _enclosing_radius(g: _Geometry) -> np.ndarray:
    ext = _compiled() if g.hull_cat is not None else None
    if ext is None:
        return _enclosing_balls(g.hull_pts, g.dim)[1]
    centre = np.zeros((g.n, 3))
    radius = np.zeros(g.n)
    ext.enclosing_balls(np.ascontiguousarray(g.hull_cat), np.ascontiguousarray(g.hull_ptr), centre, radius)
    return radius


def _ratio(num: np.ndarray, den: np.ndarray) -> np.ndarray:
    with np.errstate(divide="ignore", invalid="ignore"):
        out = np.where(den > 0, num / np.where(den > 0, den, 1.0), 0.0)
    return np.clip(out, 0.0, 1.0)


def _circle_ratio(g: _Geometry, rel_tol: float) -> np.ndarray:
    return _ratio(_inscribed(g, rel_tol)[1], _enclosing_radius(g))


def circle_ratio(poly: PolyMesh, rel_tol: float = DEFAULT_REL_TOL) -> np.ndarray:
    """Inscribed / enclosing ball radius per element (exact for convex elements, else within
    rel_tol * diameter / R_enclosing below the true value; see largest_inscribed_ball)."""
    return _circle_ratio(_prepare(poly), _check_tol(rel_tol))


def _apr(g: _Geometry, measure: np.ndarray) -> np.ndarray:
    return _ratio(4.0 * np.pi * np.abs(measure), g.boundary_size**2)


def area_perimeter_ratio(poly: PolyMesh) -> np.ndarray:
    """2D: 4 pi A / P^2 per element, P the total length of all loops (holes included)."""
    g = _prepare(poly)
    if g.dim != 2:
        raise ParameterError("area_perimeter_ratio is a 2D metric (use sphericity in 3D)")
    return _apr(g, np.asarray(poly.measure, dtype=np.float64))


def _sphericity(g: _Geometry, measure: np.ndarray) -> np.ndarray:
    return _ratio(np.cbrt(36.0 * np.pi * measure**2), g.boundary_size)


def sphericity(poly: PolyMesh) -> np.ndarray:
    """3D: (36 pi V^2)^(1/3) / S per element, S the total area of its boundary faces."""
    g = _prepare(poly)
    if g.dim != 3:
        raise ParameterError("sphericity is a 3D metric (use area_perimeter_ratio in 2D)")
    return _sphericity(g, np.asarray(poly.measure, dtype=np.float64))


def element_diameters(poly: PolyMesh) -> np.ndarray:
    """Largest distance between two boundary vertices of each element (over convex hull vertices)."""
    return _prepare(poly).diameter


def _uniformity(diam: np.ndarray) -> np.ndarray:
    top = diam.max() if diam.size else 0.0
    return _ratio(diam, np.full_like(diam, top))


def uniformity_factor(poly: PolyMesh) -> np.ndarray:
    """diam(P) / max over elements of diam."""
    return _uniformity(_prepare(poly).diameter)


def volume_difference(measure: np.ndarray) -> np.ndarray:
    """1 / (1 + |V - V_mean| / V_mean) per element."""
    v = np.abs(np.asarray(measure, dtype=np.float64))
    mean = v.mean() if v.size else 0.0
    if mean <= 0:
        return np.ones_like(v)
    return 1.0 / (1.0 + np.abs(v - mean) / mean)


def heterogeneity_preservation(
    labels: np.ndarray, fine_tags: np.ndarray, n_elements: int | None = None
) -> np.ndarray:
    """Fraction of each element's fine cells that belong to its majority tag group.

    With two groups (tags mapped to 0/1) this is max(p, 1 - p), p the mean tag; with more groups it
    is the majority-group fraction. Elements without fine cells get NaN.
    """
    labels = np.asarray(labels, dtype=np.int64)
    tags = np.asarray(fine_tags)
    if tags.shape != labels.shape:
        raise ParameterError(f"fine_tags has shape {tags.shape}, labels {labels.shape}")
    n = int(labels.max()) + 1 if n_elements is None and labels.size else int(n_elements or 0)
    grp, ng = _compact(tags)
    ng = max(ng, 1)
    counts = np.bincount(labels * ng + grp, minlength=n * ng).reshape(n, ng)
    total = counts.sum(1)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(total > 0, counts.max(1) / np.maximum(total, 1), np.nan)
