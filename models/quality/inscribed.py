"""The largest inscribed ball of every element: exact linear program for convex elements, branch and
bound certified to `rel_tol * diameter` otherwise (compiled in models/quality/_fastmetrics.c (3D) and
_fastcircle.c (2D), numpy here)."""

from __future__ import annotations

import os

import numpy as np
from scipy import sparse

from models.errors import ParameterError
from models.mesh.container import PolyMesh
from models.quality.distance import _BNB_BATCH_PRIMS, _build_ball_tree, _inscribed_bnb
from models.quality.geometry import DEFAULT_REL_TOL, _compiled, _Geometry, _prepare

# moves at most sqrt(3) * trust * best, so every primitive left out stays farther than best)


def _inscribed_lp(g: _Geometry, elems: np.ndarray):
    """Chebyshev centres of convex elements: one block-diagonal LP (max sum of radii) with HiGHS."""
    d = g.dim
    centres = np.full((g.n, d), np.nan)
    radius = np.zeros(g.n)
    elems = np.asarray(elems, dtype=np.int64)
    if elems.size == 0:
        return centres, radius
    eqs = [g.hull_eq[e] for e in elems]
    pts = [g.hull_pts[e] for e in elems]
    nf = np.fromiter((q.shape[0] for q in eqs), dtype=np.int64, count=elems.size)
    npt = np.fromiter((p.shape[0] for p in pts), dtype=np.int64, count=elems.size)
    eq = np.concatenate(eqs)
    row = np.repeat(np.arange(elems.size), nf)  # the element (position in elems) of each facet
    shift = np.add.reduceat(np.concatenate(pts), np.cumsum(npt) - npt, axis=0) / npt[:, None]
    scale = g.diameter[elems]
    nrm = eq[:, :d]
    # n.x' + b' <= 0 in each element's shifted / scaled frame
    b = (eq[:, d] + np.einsum("ij,ij->i", nrm, shift[row])) / scale[row]
    f = eq.shape[0]
    rr = np.repeat(np.arange(f), d + 1)
    cc = (row[:, None] * (d + 1) + np.arange(d + 1)[None, :]).ravel()
    vv = np.column_stack([nrm, np.ones(f)]).ravel()
    nv = elems.size * (d + 1)
    A = sparse.csr_matrix((vv, (rr, cc)), shape=(f, nv))
    c = np.zeros(nv)
    c[d :: d + 1] = -1.0
    bounds = [(None, None)] * d + [(0, None)]
    from scipy.optimize import linprog  # lazy: scipy.optimize takes most of a second to import

    res = linprog(c, A_ub=A, b_ub=-b, bounds=bounds * elems.size, method="highs")
    if res.status != 0 or res.x is None:  # pragma: no cover - bounded and feasible by construction
        raise RuntimeError(f"Chebyshev-centre LP failed: {res.message}")
    x = res.x.reshape(elems.size, d + 1)
    cen = shift + scale[:, None] * x[:, :d]
    # radius = the actual distance from the centre to the facet planes
    slack = -(np.einsum("ij,ij->i", nrm, cen[row]) + eq[:, d])
    centres[elems] = cen
    radius[elems] = np.maximum(0.0, np.minimum.reduceat(slack, np.cumsum(nf) - nf))
    return centres, radius


def _check_tol(rel_tol: float) -> float:
    rel_tol = float(rel_tol)
    if not (0.0 < rel_tol < 1.0):
        raise ParameterError(f"rel_tol must be in (0, 1), got {rel_tol}")
    return rel_tol


_INSCRIBED_METHODS = ("auto", "bnb", "bnb-numpy")
_EXT_MAX_CELLS = 1_000_000  # cells per element before the compiled search hands it to numpy (~100 needed)


def _threads() -> int:
    """Threads for the compiled search: MAGNET_THREADS, else the cores this process may use."""
    env = os.environ.get("MAGNET_THREADS", "")
    if env.strip():
        try:
            return max(1, int(env))
        except ValueError:
            raise ParameterError(f"MAGNET_THREADS must be a whole number, got {env!r}") from None
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


def _inscribed_compiled(ext, g: _Geometry, elems: np.ndarray, rel_tol: float):
    """Compiled best-first search over `elems` (3D: _fastmetrics.c's inscribed; 2D: _fastcircle.c's
    inscribed2d), in threads (the module releases the GIL; each element is searched by one thread,
    so the result does not depend on their number). Returns centres, radii and the elements it gave
    up on (cell budget spent; none on any mesh measured)."""
    centres = np.full((g.n, g.dim), np.nan)
    radius = np.zeros(g.n)
    evals = np.zeros(g.n, dtype=np.int64)
    elems = np.ascontiguousarray(elems, dtype=np.int64)
    prim = np.ascontiguousarray(g.prim, dtype=np.float64)
    ptr = np.ascontiguousarray(g.prim_ptr, dtype=np.int64)
    boxes = tuple(np.ascontiguousarray(a, dtype=np.float64) for a in (g.diameter, g.bbox_lo, g.bbox_hi))
    if g.dim == 3:
        fn, args = ext.inscribed, (prim, np.ascontiguousarray(g.tri_adj, dtype=np.int64), ptr)
        orient = ((g.signed_measure >= 0).astype(np.uint8),)
    else:
        fn, args, orient = ext.inscribed2d, (prim, ptr), ()
    rest = (*boxes, *orient, float(rel_tol), _EXT_MAX_CELLS, centres, radius, evals)
    nt = min(_threads(), max(1, elems.size // 16))
    if nt == 1:
        fn(*args, elems, *rest)
    else:  # interleaved shares (neighbouring elements cost alike); outputs are disjoint rows
        from concurrent.futures import ThreadPoolExecutor

        with ThreadPoolExecutor(nt) as pool:
            list(pool.map(lambda k: fn(*args, elems[k::nt].copy(), *rest), range(nt)))
    return centres, radius, elems[evals[elems] < 0]


def _inscribed(g: _Geometry, rel_tol: float, method: str = "auto"):
    if method not in _INSCRIBED_METHODS:
        raise ParameterError(f"unknown inscribed-ball method {method!r} ({', '.join(_INSCRIBED_METHODS)})")
    convex = g.convex if method == "auto" else np.zeros(g.n, dtype=bool)
    centres, radius = _inscribed_lp(g, np.flatnonzero(convex))
    # an element of zero measure (faces back to back) has no interior: radius 0, no centre
    flat = np.abs(g.signed_measure) <= 1e-12 * np.maximum(g.diameter, 1e-300) ** g.dim
    rest = np.flatnonzero(~convex & ~flat)
    ext = _compiled() if method != "bnb-numpy" else None
    if ext is not None and g.dim == 2 and not hasattr(ext, "inscribed2d"):
        ext = None  # a module built before the 2D search
    if rest.size and ext is not None:
        done = rest
        c2, r2, rest = _inscribed_compiled(ext, g, rest, rel_tol)
        centres[done], radius[done] = c2[done], r2[done]
    if rest.size:
        # elements in batches of about _BNB_BATCH_PRIMS boundary primitives: the search's per-level
        # arrays (cells x candidate nodes) stay bounded, so memory does not grow with the mesh; the
        # elements are independent, so the result is the same as one search over all of them
        bt = _build_ball_tree(g)
        nprim = (g.prim_ptr[rest + 1] - g.prim_ptr[rest]).astype(np.int64)
        batch = np.cumsum(nprim) // _BNB_BATCH_PRIMS
        for b in np.unique(batch):
            part = rest[batch == b]
            c2, r2 = _inscribed_bnb(g, part, rel_tol, bt)
            centres[part], radius[part] = c2[part], r2[part]
    return centres, radius


def largest_inscribed_ball(
    poly: PolyMesh, rel_tol: float = DEFAULT_REL_TOL, method: str = "auto"
) -> tuple[np.ndarray, np.ndarray]:
    """Centres (E, d) and radii (E,) of the largest balls inside each element.

    Convex elements (measure equal to the hull measure, one loop in 2D): exact Chebyshev centre
    from a linear program over the element's facet half-spaces (scipy linprog / HiGHS); the radius
    is re-measured from the returned centre, so it never exceeds the true one beyond rounding.

    Other elements (or all, with method="bnb"): the compiled best-first search of
    models/quality/_fastmetrics.c in 3D (same certificate, octree cells, bounds from the closest
    triangles and a small LP over each cell's corners; see that file) and of _fastcircle.c in 2D
    (quadtree cells, bounds from pairs of the closest segments); method="bnb-numpy", or where the
    module was not built (MAGNET_NO_COMPILED=1 switches it off): branch and bound on a quadtree
    (2D) / octree (3D) over the element's bounding cube, all elements at once, with exact point-to-segment /
    point-to-triangle distances (bounding-ball tree, candidate lists passed from parent to child
    cells) and exact inside tests (side of the closest facet, vertex wedge / edge pseudo-normal,
    else crossing number (2D) / winding number (3D)). best is the largest exact distance found at
    a certified interior point (0 before one is found; a greedy dive seeds it). A cell of
    half-diagonal rho is discarded when an upper bound U of the distance over the cell satisfies
    U <= best + eps: U = f + rho (f the signed centre distance; the distance is 1-Lipschitz), or a
    second-order bound from several nearby boundary points (see _cell_bounds). Every discarded
    cell holds no interior point farther than best + eps from the boundary, and the cells always
    cover the element, hence the guarantee, with eps = rel_tol * diameter (largest distance
    between the element's boundary vertices):

        r_true - eps <= r <= r_true

    (r is the exact distance from a certified interior point to the boundary). Elements with zero
    diameter, and slivers where no interior point was needed (then r_true <= eps), get radius 0
    and a NaN centre.
    """
    rel_tol = _check_tol(rel_tol)
    return _inscribed(_prepare(poly), rel_tol, method)
