"""Export a 2D agglomerated mesh to the `region` / `neighbor` structs of lymph (Matlab PolyDG).

Layout (MISSION.md section 7), everything 1-based like Matlab:
  region: coord (Nv, 2) only the vertices used by element loops, renumbered compactly;
    connectivity{i} (row, counter-clockwise), ne, nedges, coords_element{i} (n_i, 2),
    id (physical group per element), tag = 'P', connectivity_bc (Nb, 2) and bc_tag (Nb,),
    BBox (ne, 4: xmin xmax ymin ymax), area (ne,), max_kb{i} (one value per edge).
  neighbor: nedges, neigh{i}(j) element across edge j of element i (-1 on the boundary),
    neighedges{i}(j) index of that edge in the neighbour's edge list (-1 on the boundary).
Edge j of element i joins connectivity{i}(j) and connectivity{i}(j+1) (cyclically).

max_kb{i}(j) is the largest area of a triangle made of edge j = (a, b) and a third vertex c of
the element that lies inside the element. "Inside" is decided exactly (up to a round-off
tolerance of 1e-10 * diam^2 on doubled areas), see `_separated`:
  1. c lies strictly to the left of a->b (positive area; the element is counter-clockwise), and
  2. no boundary edge (p, q) of the element meets the open triangle. A segment and the open
     triangle are disjoint iff one of four lines separates them (separating axis theorem):
     the segment lies on the outer closed side of one of the lines ab, bc, ca, or the three
     corners a, b, c lie on one closed side of the line pq.
Condition 2 rules out polygon vertices strictly inside the triangle, polygon edges crossing the
sides bc or ca, and chords between vertices that merely touch the triangle's sides; together
with 1 it is equivalent to "triangle contained in the polygon" for simple polygons (the open
triangle is connected, meets no boundary point and lies locally inside next to the edge ab).
Cheap necessary tests (c inside the interior angle at a, at b, and a, b inside the interior
angle at c) prune candidates first; survivors are tried in decreasing area order and the first
one passing the full test is the answer. For convex elements the largest triangle is taken
directly. Every edge of a simple polygon has a valid triangle; if round-off leaves none, the
largest positive triangle is used and a warning is issued.
"""

from __future__ import annotations

import json
import warnings

import numpy as np

from models.errors import MeshError, ParameterError, id_list
from models.export import atomic
from models.mesh.boundary import edge_tags
from models.mesh.container import PolyMesh
from models.mesh.dual import sorted_unique

# Work budget of the max_kb kernel: entries of the (elements x edges x vertices) blocks.
_BLOCK = 1 << 20
_REL_TOL = 1e-10


def _ragged_arange(counts: np.ndarray) -> np.ndarray:
    """0..n_i-1 for every segment, concatenated."""
    counts = np.asarray(counts, dtype=np.int64)
    total = int(counts.sum())
    starts = np.cumsum(counts) - counts
    return np.arange(total, dtype=np.int64) - np.repeat(starts, counts)


def _element_loops(poly: PolyMesh) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Concatenated outer loops (point ids), segment starts and counts; CCW, no repeated nodes."""
    if poly.dim != 2:
        raise ParameterError(f"lymph export needs a 2D mesh; this one is {poly.dim}D")
    elem_offsets = np.asarray(poly.elem_offsets, dtype=np.int64)
    loop_offsets = np.asarray(poly.loop_offsets, dtype=np.int64)
    n_elem = elem_offsets.shape[0] - 1
    if n_elem < 1:
        raise ParameterError("lymph export needs at least one element")
    n_loops = np.diff(elem_offsets)
    bad = np.flatnonzero(n_loops != 1)
    if bad.size:
        raise ParameterError(
            "lymph export needs exactly one boundary loop per element; elements "
            f"{id_list(bad, 10)} have {id_list(n_loops[bad], 10)} loops (apply the hole policy)"
        )
    lo = loop_offsets[elem_offsets[:-1]]
    counts = loop_offsets[elem_offsets[:-1] + 1] - lo
    if np.any(counts < 1):
        raise MeshError("an element has an empty boundary loop")
    nodes = np.asarray(poly.loop_nodes, dtype=np.int64)[np.repeat(lo, counts) + _ragged_arange(counts)]

    # Drop nodes equal to their cyclic successor (a closing repeat of the first node, or
    # zero-length edges).
    starts = np.cumsum(counts) - counts
    nxt = np.arange(nodes.shape[0], dtype=np.int64) + 1
    nxt[starts + counts - 1] = starts
    keep = nodes != nodes[nxt]
    if not keep.all():
        elem_of = np.repeat(np.arange(n_elem), counts)
        counts = np.bincount(elem_of[keep], minlength=n_elem).astype(np.int64)
        nodes = nodes[keep]
        starts = np.cumsum(counts) - counts
    if np.any(counts < 3):
        raise MeshError(f"element(s) {id_list(np.flatnonzero(counts < 3), 10)} have fewer than 3 vertices")
    if nodes.min() < 0 or nodes.max() >= poly.points.shape[0]:
        raise MeshError("loop node ids out of range of the points")

    # Orientation: reverse loops with negative signed area so that every element is CCW.
    signed = _shoelace(np.asarray(poly.points, dtype=np.float64)[nodes], starts, counts)
    flip = signed < 0
    if flip.any():
        local = _ragged_arange(counts)
        c_rep = np.repeat(counts, counts)
        rev = np.repeat(starts, counts) + (c_rep - 1 - local)
        idx = np.where(np.repeat(flip, counts), rev, np.arange(nodes.shape[0]))
        nodes = nodes[idx]
    if np.any(signed == 0):
        raise MeshError(f"element(s) {id_list(np.flatnonzero(signed == 0), 10)} have zero area")
    return nodes, starts, counts


def _shoelace(xy: np.ndarray, starts: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Signed area of every closed loop (CCW positive); coordinates taken relative to the
    loop's first vertex to limit cancellation."""
    n = xy.shape[0]
    nxt = np.arange(n, dtype=np.int64) + 1
    nxt[starts + counts - 1] = starts
    rel = xy - np.repeat(xy[starts], counts, axis=0)
    cross = rel[:, 0] * rel[nxt, 1] - rel[nxt, 0] * rel[:, 1]
    return 0.5 * np.add.reduceat(cross, starts)


def lymph_structs(poly: PolyMesh, boundary_tag: int = 1) -> tuple[dict, dict]:
    """Build lymph's `region` and `neighbor` structs (as dicts, 1-based ids) of a 2D PolyMesh.

    Every element must have exactly one (outer) loop. `bc_tag` of a boundary edge is its boundary
    group (poly.facet_tags, see models.mesh.boundary), `boundary_tag` where it has none.
    Two elements are neighbours across an edge when both loops contain the same vertex pair
    (loops are made of fine-mesh vertices, so shared interfaces consist of whole fine edges).
    """
    nodes, starts, counts = _element_loops(poly)
    n_elem = counts.shape[0]
    n_nodes = nodes.shape[0]

    used, compact = sorted_unique(nodes, return_inverse=True)
    compact = compact.astype(np.int64).reshape(-1)
    coord = np.asarray(poly.points, dtype=np.float64)[used]
    n_vert = coord.shape[0]
    xy = coord[compact]

    elem_of = np.repeat(np.arange(n_elem, dtype=np.int64), counts)
    local = _ragged_arange(counts)
    nxt = np.arange(n_nodes, dtype=np.int64) + 1
    nxt[starts + counts - 1] = starts
    v0, v1 = compact, compact[nxt]

    # Pair up edges by their unordered vertex pair.
    key = np.minimum(v0, v1) * n_vert + np.maximum(v0, v1)
    order = np.argsort(key, kind="stable")
    ks = key[order]
    head = np.r_[True, ks[1:] != ks[:-1]]
    first = np.flatnonzero(head)
    mult = np.diff(np.append(first, ks.size))
    if np.any(mult > 2):
        raise MeshError("an edge is shared by more than two elements (non-manifold agglomeration)")
    ea = order[first[mult == 2]]
    eb = order[first[mult == 2] + 1]
    neigh = np.full(n_nodes, -1, dtype=np.int64)
    neighedges = np.full(n_nodes, -1, dtype=np.int64)
    neigh[ea], neigh[eb] = elem_of[eb] + 1, elem_of[ea] + 1
    neighedges[ea], neighedges[eb] = local[eb] + 1, local[ea] + 1
    bnd = np.sort(order[first[mult == 1]])
    connectivity_bc = np.column_stack([v0[bnd], v1[bnd]]) + 1
    bc_tag = edge_tags(poly, used[v0[bnd]], used[v1[bnd]], default=boundary_tag)

    area = _shoelace(xy, starts, counts)
    bbox = np.column_stack(
        [
            np.minimum.reduceat(xy[:, 0], starts),
            np.maximum.reduceat(xy[:, 0], starts),
            np.minimum.reduceat(xy[:, 1], starts),
            np.maximum.reduceat(xy[:, 1], starts),
        ]
    )
    kb = max_kb(xy, starts, counts)

    if poly.tags is not None:
        ids = np.asarray(poly.tags, dtype=np.int64).reshape(-1)
        if ids.shape[0] != n_elem:
            raise MeshError(f"poly.tags has {ids.shape[0]} entries for {n_elem} elements")
    else:
        ids = np.ones(n_elem, dtype=np.int64)

    cuts = starts[1:]
    region = {
        "coord": coord,
        "connectivity": np.split(compact + 1, cuts),
        "ne": int(n_elem),
        "nedges": counts.copy(),
        "coords_element": np.split(xy, cuts),
        "id": ids,
        "tag": "P",
        "connectivity_bc": connectivity_bc.astype(np.int64).reshape(-1, 2),
        "bc_tag": bc_tag,
        "BBox": bbox,
        "area": area,
        "max_kb": np.split(kb, cuts),
    }
    neighbor = {
        "nedges": counts.copy(),
        "neigh": np.split(neigh, cuts),
        "neighedges": np.split(neighedges, cuts),
    }
    return region, neighbor


# ---------------------------------------------------------------------------------------------
# max_kb


def _line(p: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Coefficients (A, B, C) with A*x + B*y + C = orient(p, q, (x, y)) = (q-p) x ((x,y)-p)."""
    dx = q[..., 0] - p[..., 0]
    dy = q[..., 1] - p[..., 1]
    return -dy, dx, dy * p[..., 0] - dx * p[..., 1]


def max_kb(xy: np.ndarray, starts: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Per edge of every CCW loop (concatenated in `xy`), the area of the largest triangle made
    of the edge and a vertex of the loop that lies inside the loop (see the module docstring)."""
    xy = np.asarray(xy, dtype=np.float64)
    starts = np.asarray(starts, dtype=np.int64)
    counts = np.asarray(counts, dtype=np.int64)
    out = np.zeros(xy.shape[0], dtype=np.float64)
    order = np.argsort(counts, kind="stable")
    c_sorted = counts[order]
    n_elem = order.shape[0]
    fallbacks = 0
    i = 0
    while i < n_elem:  # chunks of elements of similar size, bounded work per chunk
        j = min(n_elem, i + max(1, _BLOCK // int(c_sorted[i]) ** 2))
        while j > i + 1 and (j - i) * int(c_sorted[j - 1]) ** 2 > _BLOCK:
            j = i + max(1, _BLOCK // int(c_sorted[j - 1]) ** 2)
        ids = order[i:j]
        vals, nfb = _max_kb_block(xy, starts[ids], counts[ids])
        fallbacks += nfb
        pos = np.repeat(starts[ids], counts[ids]) + _ragged_arange(counts[ids])
        rows = np.repeat(np.arange(ids.shape[0]), counts[ids])
        out[pos] = vals[rows, _ragged_arange(counts[ids])]
        i = j
    if fallbacks:
        warnings.warn(
            f"max_kb: {fallbacks} edge(s) found no triangle inside their element (degenerate or "
            "self-touching loop); used the largest positive triangle instead",
            RuntimeWarning,
            stacklevel=2,
        )
    return out


def _prev_rows(a: np.ndarray, cnt: np.ndarray, axis: int) -> np.ndarray:
    """out[..., j, ...] = a[..., j-1 (cyclically within the first cnt entries), ...] along axis
    1 or 2 of an (m, n, n) array."""
    out = np.empty_like(a)
    r = np.arange(a.shape[0])
    if axis == 1:
        out[:, 1:] = a[:, :-1]
        out[:, 0] = a[r, cnt - 1]
    else:
        out[:, :, 1:] = a[:, :, :-1]
        out[:, :, 0] = a[r, :, cnt - 1]
    return out


def _next_rows(a: np.ndarray, cnt: np.ndarray) -> np.ndarray:
    """out[:, j] = a[:, j+1 (cyclically within the first cnt rows)] of an (m, n, ...) array;
    rows past cnt (padding) are left as garbage."""
    out = np.empty_like(a)
    out[:, :-1] = a[:, 1:]
    out[np.arange(a.shape[0]), cnt - 1] = a[:, 0]
    return out


def _separated(s1, s2, s3, a_ge, b_ge, c_ge, a_le, b_le, c_le) -> np.ndarray:
    """Separating-axis test of triangles (a, b, c) against the loop edges (w, w+1), w = 0..n-1
    (padded cyclic), from boolean sign tables along the last axis (all within tolerance t):
    s1/s2/s3[w]: orient(a, b, v_w) / orient(b, c, v_w) / orient(c, a, v_w) <= t (v_w on the
    outer closed side of the triangle's side); a_ge/b_ge/c_ge[w]: orient(v_w, v_w+1, corner) >= -t,
    a_le/b_le/c_le[w]: ... <= t. True where every loop edge is separated from the open triangle."""
    sep = s1 & np.roll(s1, -1, axis=-1)
    sep |= s2 & np.roll(s2, -1, axis=-1)
    sep |= s3 & np.roll(s3, -1, axis=-1)
    sep |= a_ge & b_ge & c_ge
    sep |= a_le & b_le & c_le
    return sep.all(axis=-1)


def _lines(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """(..., 3) coefficients of orient(p, q, .) (see `_line`)."""
    return np.stack(_line(p, q), axis=-1)


def _max_kb_block(xy: np.ndarray, starts: np.ndarray, counts: np.ndarray) -> tuple[np.ndarray, int]:
    """max_kb (doubled areas, (m, n) padded) of m loops of at most n vertices; the padding
    repeats the last vertex, so the padded cyclic edge list is the real edges plus zero-length
    edges. Returns (values, number of edges that needed the fallback)."""
    m, n = counts.shape[0], int(counts.max())
    ar = np.arange(n)
    r = np.arange(m)[:, None]
    v = xy[starts[:, None] + np.minimum(ar[None, :], counts[:, None] - 1)]
    v = v - 0.5 * (v.min(axis=1) + v.max(axis=1))[:, None, :]
    t1 = _REL_TOL * np.sum((v.max(axis=1) - v.min(axis=1)) ** 2, axis=1)  # (m,) on doubled areas
    t2, t3 = t1[:, None], t1[:, None, None]
    x, y = v[..., 0], v[..., 1]
    hom = np.stack([x, y, np.ones_like(x)], axis=1)  # (m, 3, n) homogeneous coordinates
    jn = np.where(ar[None, :] + 1 < counts[:, None], ar[None, :] + 1, 0)
    jp = np.where(ar[None, :] == 0, counts[:, None] - 1, ar[None, :] - 1)
    vmask = ar[None, :] < counts[:, None]

    # M[e, j, w] = orient(v_j, v_j+1, v_w): doubled area of the triangle (edge j, vertex w).
    # Row n-1 and the padding rows are the closing edge (v_cnt-1, v_0), so M's rows are also the
    # lines of the padded cyclic edges (for the zero-length ones a harmless stricter stand-in).
    M = _lines(v, v[r, jn]) @ hom
    ge, le = M >= -t3, M <= t3
    ge_t = np.ascontiguousarray(ge.transpose(0, 2, 1))  # ge_t[e, w, k] = ge[e, k, w]
    le_t = np.ascontiguousarray(le.transpose(0, 2, 1))
    ge_tn = _next_rows(ge_t, counts)  # [e, j, k]: orient(edge k, v_j+1) >= -t

    cand = vmask[:, None, :] & vmask[:, :, None] & ~le
    cand &= (ar[None, None, :] != ar[None, :, None]) & (ar[None, None, :] != jn[:, :, None])
    # Necessary local tests. convex[e, w]: interior angle at v_w below pi.
    turn = np.stack(_line(v[r, jp], v), axis=-1)
    turn = turn[..., 0] * v[r, jn][..., 0] + turn[..., 1] * v[r, jn][..., 1] + turn[..., 2]
    convex = turn > t2
    cand &= ~convex[:, :, None] | _prev_rows(ge, counts, 1)  # c inside the angle at a
    cand &= ~_next_rows(convex, counts)[:, :, None] | _next_rows(ge, counts)  # ... and at b
    conv_c = convex[:, None, :]
    for lw in (ge_t, ge_tn):  # a (then b) inside the angle at c
        lp = _prev_rows(lw, counts, 2)
        cand &= (lw & lp) | (~conv_c & (lw | lp))
    del lp

    score = np.where(cand, M, -np.inf)
    del cand
    best_k = np.argmax(score, axis=2)
    best = np.take_along_axis(score, best_k[:, :, None], 2)[:, :, 0]
    found = vmask & np.isfinite(best)
    result = np.where(found, best, 0.0)

    # Convex loops: the largest triangle is inside. Others: full test of the best candidate.
    e = np.flatnonzero(np.any(vmask & (turn < -t2), axis=1))
    if e.size:
        ke = best_k[e]
        ec = e[:, None]
        tb = t3[e]
        b, c = v[ec, jn[e]], v[ec, ke]
        ok = _separated(
            le[e],
            (_lines(b, c) @ hom[e]) <= tb,
            (_lines(c, v[e]) @ hom[e]) <= tb,
            ge_t[e],
            ge_tn[e],
            ge_t[ec, ke],
            le_t[e],
            _next_rows(le_t[e], counts[e]),
            le_t[ec, ke],
        )
        fail = found[e] & ~ok
        fail_r, fail_j = e[np.nonzero(fail)[0]], np.nonzero(fail)[1]
    else:
        fail_r = fail_j = np.zeros(0, dtype=np.int64)

    if fail_r.size:  # next candidates, by decreasing area, in batches of growing width
        found[fail_r, fail_j] = False
        sub = score[fail_r, fail_j]
        sub[np.arange(fail_r.size), best_k[fail_r, fail_j]] = -np.inf
        srt = np.argsort(-sub, axis=1)
        nval = np.isfinite(sub).sum(axis=1)
        rows = np.arange(fail_r.size)
        pos, width = 0, 2
        step = max(1, _BLOCK // n)
        while rows.size:
            kk = srt[rows, pos : pos + width]
            w = kk.shape[1]
            rr, cc = np.nonzero((pos + np.arange(w))[None, :] < nval[rows][:, None])
            inside = np.zeros((rows.size, w), dtype=bool)
            for s0 in range(0, rr.size, step):
                q, qc = rr[s0 : s0 + step], cc[s0 : s0 + step]
                er, ej, ek = fail_r[rows[q]], fail_j[rows[q]], kk[q, qc]
                en = jn[er, ej]
                a, b, c = v[er, ej], v[er, en], v[er, ek]
                tq = t2[er]
                hq = hom[er]
                inside[q, qc] = _separated(
                    le[er, ej],
                    np.einsum("pk,pkn->pn", _lines(b, c), hq) <= tq,
                    np.einsum("pk,pkn->pn", _lines(c, a), hq) <= tq,
                    ge_t[er, ej],
                    ge_t[er, en],
                    ge_t[er, ek],
                    le_t[er, ej],
                    le_t[er, en],
                    le_t[er, ek],
                )
            hit = inside.any(axis=1)
            first = np.argmax(inside, axis=1)
            hr = rows[hit]
            result[fail_r[hr], fail_j[hr]] = sub[hr, kk[hit, first[hit]]]
            found[fail_r[hr], fail_j[hr]] = True
            pos += width
            width *= 2
            rows = rows[~hit & (nval[rows] > pos)]

    missing = vmask & ~found
    n_fallback = int(missing.sum())
    if n_fallback:
        anypos = np.where(vmask[:, None, :] & (M > 0), M, 0.0).max(axis=2)
        result = np.where(missing, anypos, result)
    return 0.5 * result, n_fallback


# ---------------------------------------------------------------------------------------------
# Writers / reader


def _cell(items, column: bool = False) -> np.ndarray:
    """A 1 x n Matlab cell array (numpy object array) of double vectors (rows, or columns)."""
    cell = np.empty((1, len(items)), dtype=object)
    for i, it in enumerate(items):
        arr = np.asarray(it, dtype=np.float64)
        if arr.ndim == 1:
            arr = arr.reshape(-1, 1) if column else arr.reshape(1, -1)
        cell[0, i] = arr
    return cell


def write_lymph_mat(path, region: dict, neighbor: dict) -> str:
    """Write `region` and `neighbor` as Matlab structs in a .mat file (v5). Numbers are stored
    as doubles (Matlab's default class); per-element lists become 1 x ne cell arrays like lymph
    builds them: connectivity / neigh / neighedges rows, coords_element n_i x 2, max_kb columns."""
    from scipy.io import savemat

    reg = {
        "coord": np.asarray(region["coord"], dtype=np.float64),
        "connectivity": _cell(region["connectivity"]),
        "ne": float(region["ne"]),
        "nedges": np.asarray(region["nedges"], dtype=np.float64).reshape(1, -1),
        "coords_element": _cell(region["coords_element"]),
        "id": np.asarray(region["id"], dtype=np.float64).reshape(-1, 1),
        "tag": str(region["tag"]),
        "connectivity_bc": np.asarray(region["connectivity_bc"], dtype=np.float64).reshape(-1, 2),
        "bc_tag": np.asarray(region["bc_tag"], dtype=np.float64).reshape(1, -1),
        "BBox": np.asarray(region["BBox"], dtype=np.float64).reshape(-1, 4),
        "area": np.asarray(region["area"], dtype=np.float64).reshape(-1, 1),
        "max_kb": _cell(region["max_kb"], column=True),
    }
    nb = {
        "nedges": np.asarray(neighbor["nedges"], dtype=np.float64).reshape(1, -1),
        "neigh": _cell(neighbor["neigh"]),
        "neighedges": _cell(neighbor["neighedges"]),
    }
    with atomic.replacing(path) as fh:
        savemat(fh, {"region": reg, "neighbor": nb}, do_compression=True, oned_as="row")
    return str(path)


def _as_jsonable(region: dict, neighbor: dict) -> dict:
    def ints(a):
        return np.asarray(a, dtype=np.int64).tolist()

    def floats(a):
        return np.asarray(a, dtype=np.float64).tolist()

    reg = {
        "coord": floats(region["coord"]),
        "connectivity": [ints(c) for c in region["connectivity"]],
        "ne": int(region["ne"]),
        "nedges": ints(region["nedges"]),
        "coords_element": [floats(c) for c in region["coords_element"]],
        "id": ints(region["id"]),
        "tag": str(region["tag"]),
        "connectivity_bc": ints(np.asarray(region["connectivity_bc"]).reshape(-1, 2)),
        "bc_tag": ints(region["bc_tag"]),
        "BBox": floats(region["BBox"]),
        "area": floats(region["area"]),
        "max_kb": [floats(c) for c in region["max_kb"]],
    }
    nb = {
        "nedges": ints(neighbor["nedges"]),
        "neigh": [ints(c) for c in neighbor["neigh"]],
        "neighedges": [ints(c) for c in neighbor["neighedges"]],
    }
    return {"region": reg, "neighbor": nb}


def write_lymph_json(path, region: dict, neighbor: dict) -> str:
    """Write {"region": ..., "neighbor": ...} as JSON with plain lists (1-based ids)."""
    atomic.write_text(path, json.dumps(_as_jsonable(region, neighbor)))
    return str(path)


def _uncell(cell, dtype) -> list[np.ndarray]:
    """Matlab cell array of vectors -> list of flat numpy arrays."""
    return [np.asarray(c, dtype=dtype).reshape(-1) for c in np.asarray(cell, dtype=object).reshape(-1)]


def lymph_from_mat(path) -> tuple[dict, dict]:
    """Read a .mat written by `write_lymph_mat` back into (region, neighbor) dicts shaped like
    `lymph_structs` returns them (integer ids as int64)."""
    from scipy.io import loadmat

    data = loadmat(str(path), squeeze_me=False, struct_as_record=True)
    reg, nb = data["region"][0, 0], data["neighbor"][0, 0]
    coords = [
        np.asarray(c, dtype=np.float64).reshape(-1, 2) for c in np.asarray(reg["coords_element"]).reshape(-1)
    ]
    region = {
        "coord": np.asarray(reg["coord"], dtype=np.float64).reshape(-1, 2),
        "connectivity": _uncell(reg["connectivity"], np.int64),
        "ne": int(np.asarray(reg["ne"]).reshape(-1)[0]),
        "nedges": np.asarray(reg["nedges"], dtype=np.int64).reshape(-1),
        "coords_element": coords,
        "id": np.asarray(reg["id"], dtype=np.int64).reshape(-1),
        "tag": str(np.asarray(reg["tag"]).reshape(-1)[0]),
        "connectivity_bc": np.asarray(reg["connectivity_bc"], dtype=np.int64).reshape(-1, 2),
        "bc_tag": np.asarray(reg["bc_tag"], dtype=np.int64).reshape(-1),
        "BBox": np.asarray(reg["BBox"], dtype=np.float64).reshape(-1, 4),
        "area": np.asarray(reg["area"], dtype=np.float64).reshape(-1),
        "max_kb": _uncell(reg["max_kb"], np.float64),
    }
    neighbor = {
        "nedges": np.asarray(nb["nedges"], dtype=np.int64).reshape(-1),
        "neigh": _uncell(nb["neigh"], np.int64),
        "neighedges": _uncell(nb["neighedges"], np.int64),
    }
    return region, neighbor
