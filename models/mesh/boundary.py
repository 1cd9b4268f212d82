"""Boundary groups: tagged edges (2D) / faces (3D) read with the mesh, carried through
agglomeration, written with the result (vectorized; no Python loop over cells or faces).

A *facet* is an edge in 2D and a face in 3D. A mesh file may hold lower-dimensional cells with a
physical tag (gmsh physical curves in 2D and surfaces in 3D, line/triangle/quad cells with tag
data in VTU/VTK): these are boundary groups. `fine_boundary` matches them to the facets of the
fine cells by the same face key the dual graph uses (graph.face_keys), so a group cell is found
whatever its node order. Facets on the domain boundary without a group are "untagged" (they get
the `boundary_tag` default, 1, when written for lymph); tagged facets between two cells are
interfaces (kept and reported, e.g. a material interface carrying a physical curve).

Agglomeration keeps every fine vertex on element boundaries (merge.py chains fine facets, it never
straightens a run of edges), so every agglomerated boundary edge/face *is* one fine facet and keeps
its tag exactly: a polygon has a vertex wherever the tag changes, and no agglomerated edge ever has
two tags. `annotate` looks the element facets up by key; `NO_TAG` marks untagged ones.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from models.mesh.container import VTK_LINE, VTK_POLYGON, VTK_QUAD, VTK_TRIANGLE, Mesh, PolyMesh
from models.mesh.dual import face_keys, sort_keys, sorted_unique
from models.mesh.geometry import Faces, cell_faces, face_measures, next_in_cycle

NO_TAG = np.iinfo(np.int64).min  # "this facet has no boundary group"


@dataclass
class FineBoundary:
    """The fine mesh's facets that lie on the domain boundary or carry a group, each once.

    keys (B,) or (B, 4): face keys (graph.face_keys); tags (B,): group or NO_TAG;
    on_boundary (B,): True on the domain boundary, False for tagged interior facets (interfaces);
    measure (B,): length / area. names: tag -> group name (gmsh physical names), when known.
    unmatched: group cells that are no facet of any cell; conflicts: facets given two different tags
    (the first one in file order is kept).
    """

    keys: np.ndarray
    tags: np.ndarray
    on_boundary: np.ndarray
    measure: np.ndarray
    names: dict = field(default_factory=dict)
    unmatched: int = 0
    conflicts: int = 0

    @property
    def groups(self) -> list[int]:
        t = self.tags[self.tags != NO_TAG]
        return [int(x) for x in sorted_unique(t)] if t.size else []


def _as_ids(*key_sets: np.ndarray) -> list[np.ndarray]:
    """1D int64 ids standing for face keys (rows of a (n, 4) key table become ranks)."""
    if key_sets[0].ndim == 1:
        return list(key_sets)
    allk = np.concatenate(key_sets)
    _, inv = np.unique(allk, axis=0, return_inverse=True)
    inv = inv.reshape(-1).astype(np.int64)
    cuts = np.cumsum([len(k) for k in key_sets])[:-1]
    return np.split(inv, cuts)


def _match(query: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """Index into `ref` of the key equal to each `query` key (-1 when none); ref keys distinct."""
    q, r = _as_ids(query, ref)
    if r.size == 0:
        return np.full(q.size, -1, dtype=np.int64)
    order = np.argsort(r, kind="stable")
    rs = r[order]
    pos = np.minimum(np.searchsorted(rs, q), rs.size - 1)
    return np.where(rs[pos] == q, order[pos], -1)


def _group_faces(mesh: Mesh) -> Faces:
    return Faces(
        cell=np.arange(len(mesh.boundary_types)),
        offsets=mesh.boundary_offsets,
        nodes=mesh.boundary_connectivity,
    )


def has_groups(mesh: Mesh) -> bool:
    """True when the mesh holds lower-dimensional cells with tags (boundary groups)."""
    return mesh.boundary_tags is not None and mesh.boundary_tags.size > 0


def fine_boundary(mesh: Mesh, faces: Faces | None = None, partner: np.ndarray | None = None) -> FineBoundary:
    """Boundary and tagged facets of the fine mesh (partner: graph.partner, -1 on the boundary)."""
    faces = faces if faces is not None else cell_faces(mesh)
    keys = face_keys(faces, mesh.n_points)
    n = faces.n
    if partner is None:  # each key once (boundary) or twice (interior)
        order, same = sort_keys(keys)
        partner = np.full(n, -1, dtype=np.int64)
        i = np.flatnonzero(same)
        partner[order[i]], partner[order[i + 1]] = order[i + 1], order[i]
    rep = np.flatnonzero((partner < 0) | (np.arange(n) < partner))  # every facet once
    rkeys = keys[rep]
    tags = np.full(rep.size, NO_TAG, dtype=np.int64)
    unmatched = conflicts = 0
    if has_groups(mesh):
        gkeys = face_keys(_group_faces(mesh), mesh.n_points)
        idx = _match(gkeys, rkeys)
        ok = np.flatnonzero(idx >= 0)
        unmatched = int(idx.size - ok.size)
        gt = mesh.boundary_tags[ok]
        hit = idx[ok]
        order = np.lexsort((ok, hit))  # by facet, then file order
        hs, ts = hit[order], gt[order]
        first = np.r_[hs.size > 0, hs[1:] != hs[:-1]][: hs.size]  # (no facet matched: none first)
        tags[hs[first]] = ts[first]
        conflicts = int(np.unique(hs[~first & (ts != tags[hs])]).size)
    on_boundary = partner[rep] < 0
    keep = on_boundary | (tags != NO_TAG)
    sel = rep[keep]
    return FineBoundary(
        keys=rkeys[keep],
        tags=tags[keep],
        on_boundary=on_boundary[keep],
        measure=face_measures(mesh.points, faces, sel),
        names=dict(mesh.meta.get("boundary_names", {})),
        unmatched=unmatched,
        conflicts=conflicts,
    )


def _poly_faces(poly: PolyMesh) -> Faces:
    """The facets of the agglomerated elements (2D: loop edges, 3D: faces) as a Faces object."""
    if poly.dim == 2:
        nxt = next_in_cycle(poly.loop_offsets)
        nodes = np.column_stack([poly.loop_nodes, poly.loop_nodes[nxt]]).reshape(-1)
        return Faces(
            cell=np.zeros(poly.loop_nodes.size, np.int64),
            offsets=np.arange(0, nodes.size + 1, 2, dtype=np.int64),
            nodes=nodes,
        )
    return Faces(
        cell=np.zeros(poly.loop_offsets.size - 1, np.int64), offsets=poly.loop_offsets, nodes=poly.loop_nodes
    )


def annotate(poly: PolyMesh, fb: FineBoundary) -> PolyMesh:
    """Set poly.facet_tags / poly.facet_on_boundary (one entry per loop edge in 2D, aligned with
    loop_nodes: edge i runs from loop_nodes[i] to the next node of its loop; per face in 3D)."""
    idx = _match(face_keys(_poly_faces(poly), poly.points.shape[0]), fb.keys)
    found = idx >= 0
    poly.facet_tags = np.where(found, fb.tags[np.maximum(idx, 0)], NO_TAG)
    poly.facet_on_boundary = found & fb.on_boundary[np.maximum(idx, 0)]
    return poly


def edge_tags(poly: PolyMesh, u: np.ndarray, v: np.ndarray, default: int = 1) -> np.ndarray:
    """Tag of the element edges (u[i], v[i]) (point ids of poly.points); `default` where untagged."""
    out = np.full(np.asarray(u).size, int(default), dtype=np.int64)
    if poly.facet_tags is None or out.size == 0:
        return out
    tagged = np.flatnonzero(poly.facet_tags != NO_TAG)
    f = _poly_faces(poly)
    P = np.int64(poly.points.shape[0])
    a, b = f.nodes[2 * tagged], f.nodes[2 * tagged + 1]
    ref, inv = sorted_unique(np.minimum(a, b) * P + np.maximum(a, b), return_inverse=True)
    ref_tag = np.empty(ref.size, dtype=np.int64)
    ref_tag[inv] = poly.facet_tags[tagged]
    u, v = np.asarray(u, dtype=np.int64), np.asarray(v, dtype=np.int64)
    idx = _match(np.minimum(u, v) * P + np.maximum(u, v), ref)
    hit = idx >= 0
    out[hit] = ref_tag[idx[hit]]
    return out


def output_cells(poly: PolyMesh) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """The tagged facets of the result, each once (an interface is a facet of two elements), as
    cells to write next to the elements: (offsets, nodes, VTK types, tags); None without tags."""
    if poly.facet_tags is None:
        return None
    tagged = np.flatnonzero(poly.facet_tags != NO_TAG)
    if tagged.size == 0:
        return None
    f = _poly_faces(poly)
    (ids,) = _as_ids(face_keys(f, poly.points.shape[0])[tagged])
    _, first = np.unique(ids, return_index=True)
    keep = tagged[np.sort(first)]
    sizes = np.diff(f.offsets)[keep]
    offsets = np.zeros(keep.size + 1, dtype=np.int64)
    np.cumsum(sizes, out=offsets[1:])
    src = np.repeat(f.offsets[keep] - offsets[:-1], sizes) + np.arange(offsets[-1])
    types = np.select(
        [sizes == 2, sizes == 3, sizes == 4], [VTK_LINE, VTK_TRIANGLE, VTK_QUAD], VTK_POLYGON
    ).astype(np.uint8)
    return offsets, f.nodes[src], types, poly.facet_tags[keep]


def _per_tag(tags: np.ndarray, weights: np.ndarray) -> dict[int, tuple[int, float]]:
    if tags.size == 0:
        return {}
    u, inv = sorted_unique(tags, return_inverse=True)
    cnt = np.bincount(inv, minlength=u.size)
    m = np.bincount(inv, weights=weights, minlength=u.size)
    return {int(t): (int(c), float(x)) for t, c, x in zip(u, cnt, m, strict=True)}


def measure_report(fb: FineBoundary, poly: PolyMesh) -> dict:
    """Boundary length (2D) / area (3D) per group before and after agglomeration (equal, since
    element boundary facets are fine facets), plus tagged interfaces (an interface inside an
    element is gone after agglomeration unless the mode keeps materials apart)."""
    f = _poly_faces(poly)
    pm = face_measures(poly.points, f)
    tb = poly.facet_tags
    on = poly.facet_on_boundary
    name = lambda t: fb.names.get(t)  # noqa: E731
    out = {"kind": "length" if poly.dim == 2 else "area", "groups": {}, "untagged": {}, "interfaces": {}}
    before = _per_tag(fb.tags[fb.on_boundary], fb.measure[fb.on_boundary])
    after = _per_tag(tb[on], pm[on])
    for t in sorted(set(before) | set(after)):
        n0, m0 = before.get(t, (0, 0.0))
        n1, m1 = after.get(t, (0, 0.0))
        entry = {"facets_before": n0, "facets_after": n1, "measure_before": m0, "measure_after": m1}
        if t == NO_TAG:
            out["untagged"] = entry
        else:
            out["groups"][str(t)] = {"name": name(t), **entry}
    inner = ~fb.on_boundary
    ib = _per_tag(fb.tags[inner], fb.measure[inner])
    ia = _per_tag(tb[~on & (tb != NO_TAG)], pm[~on & (tb != NO_TAG)])
    for t, (n0, m0) in ib.items():
        n1, m1 = ia.get(t, (0, 0.0))  # each interface facet of the result belongs to two elements
        out["interfaces"][str(t)] = {
            "name": name(t),
            "facets_before": n0,
            "facets_after": n1 // 2,
            "measure_before": m0,
            "measure_after": m1 / 2,
        }
    return out


def summary(mesh: Mesh, faces: Faces | None = None, partner: np.ndarray | None = None) -> dict:
    """The boundary part of the mesh summary: groups with their facet counts on the boundary and
    inside (interfaces), boundary facets left untagged, group cells that match no facet.
    faces, partner: the dual graph's, when already built (see fine_boundary)."""
    if not has_groups(mesh):
        return {"groups": []}
    fb = fine_boundary(mesh, faces, partner)
    groups = []
    for t in fb.groups:
        sel = fb.tags == t
        groups.append(
            {
                "tag": t,
                "name": fb.names.get(t),
                "on_boundary": int(np.count_nonzero(sel & fb.on_boundary)),
                "interior": int(np.count_nonzero(sel & ~fb.on_boundary)),
                "measure": float(fb.measure[sel].sum()),
            }
        )
    untagged = fb.on_boundary & (fb.tags == NO_TAG)
    return {
        "facet": "edge" if mesh.dim == 2 else "face",
        "groups": groups,
        "boundary_facets": int(np.count_nonzero(fb.on_boundary)),
        "untagged_boundary_facets": int(np.count_nonzero(untagged)),
        "interior_tagged_facets": int(np.count_nonzero(~fb.on_boundary)),
        "unmatched_cells": fb.unmatched,
        "conflicting_facets": fb.conflicts,
    }


def check_lines(s: dict | Mesh) -> list[str]:
    """The boundary groups in words, one line (for `magnet check`); `s`: a `summary` or the mesh."""
    s = summary(s) if isinstance(s, Mesh) else s
    if not s["groups"]:
        return ["boundary groups: none (every boundary facet gets the --boundary-tag default)"]
    f = s["facet"]
    return [
        "boundary groups: "
        + ", ".join(
            f"{g['tag']}{' ' + repr(g['name']) if g['name'] else ''} ({g['on_boundary']} boundary {f}s"
            + (f", {g['interior']} interior" if g["interior"] else "")
            + ")"
            for g in s["groups"]
        )
    ]


def check_issues(s: dict) -> list[dict]:
    """Findings about the boundary groups as `magnet check` issues {kind, severity, count, ids,
    message}: boundary left untagged and tagged interfaces (info), facets in two groups (warning).
    Group cells that are no facet of any cell are reported by the check itself (mixed-dimension)."""
    if not s["groups"]:
        return []
    f = s["facet"]
    out = []

    def issue(kind: str, severity: str, count: int, message: str) -> None:
        out.append({"kind": kind, "severity": severity, "count": int(count), "ids": [], "message": message})

    if s["untagged_boundary_facets"]:
        issue(
            "untagged-boundary",
            "info",
            s["untagged_boundary_facets"],
            f"{s['untagged_boundary_facets']} of {s['boundary_facets']} boundary {f}s are in no boundary group "
            "(they get the --boundary-tag default, 1)",
        )
    if s["interior_tagged_facets"]:
        tags = [g["tag"] for g in s["groups"] if g["interior"]]
        issue(
            "interface-groups",
            "info",
            s["interior_tagged_facets"],
            f"{s['interior_tagged_facets']} tagged {f}s lie inside the domain (interfaces, groups {tags}); "
            "--mode segregated keeps them as element boundaries where they separate materials",
        )
    if s["conflicting_facets"]:
        issue(
            "group-conflict",
            "warning",
            s["conflicting_facets"],
            f"{s['conflicting_facets']} {f}s are in two boundary groups; the first one in the file is kept",
        )
    return out


def group_names(field_data: dict | None, dim: int) -> tuple[dict[int, str], dict[int, str]]:
    """(element group names, boundary group names) from meshio's field_data {name: [tag, dim]}."""
    elem, bnd = {}, {}
    for name, val in (field_data or {}).items():
        v = np.asarray(val).reshape(-1)
        if v.size >= 2 and np.issubdtype(v.dtype, np.integer):
            if int(v[1]) == dim:
                elem[int(v[0])] = str(name)
            elif int(v[1]) == dim - 1:
                bnd[int(v[0])] = str(name)
    return elem, bnd
