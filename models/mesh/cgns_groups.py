"""CGNS families as physical groups.

CGNS names a mesh's regions by families: an element section carries a FamilyName, or a boundary
condition at the cell centres (a BC_t with GridLocation CellCenter) lists the elements of a family,
as gmsh's export and most mesh generators write them; the family's own FamilyName child holds the
name the user gave (gmsh's physical group name). VTK's reader (and so ParaView) shows the zone as
one grid without them. Here, for an HDF5 CGNS file of one unstructured zone, the cells VTK read are
matched to the zone's element sections (the same cells in the same order, their connectivity
compared) and tagged by their family; anything else keeps VTK's reading as it is.
"""

from __future__ import annotations

import numpy as np

# CGNS ElementType_t codes of fixed-size elements -> (dimension, nodes, VTK type of the linear ones)
_TYPES = {
    2: (0, 1, None), 3: (1, 2, 3), 4: (1, 3, None), 24: (1, 4, None),
    5: (2, 3, 5), 6: (2, 6, None), 7: (2, 4, 9), 8: (2, 8, None), 9: (2, 9, None),
    10: (3, 4, 10), 11: (3, 10, None), 12: (3, 5, 14), 13: (3, 14, None), 21: (3, 13, None),
    14: (3, 6, 13), 15: (3, 15, None), 16: (3, 18, None), 17: (3, 8, 12), 18: (3, 20, None), 19: (3, 27, None),
}  # fmt: skip


# higher-order CGNS codes -> the linear element on their corners (their first nodes, as in VTK)
_CORNERS_OF = {4: 3, 24: 3, 6: 5, 8: 7, 9: 7, 11: 10, 13: 12, 21: 12, 15: 14, 16: 14, 18: 17, 19: 17}


def _corners(code: int) -> int | None:
    """The linear CGNS code of an element's corners (itself where linear), or None."""
    return code if _TYPES.get(code, (0, 0, None))[2] is not None else _CORNERS_OF.get(code)


def _linear(code: int, dim: int | None = None) -> bool:
    """An element with a linear VTK type on its corners, of the given dimension or of a cell's (2 or
    3): linear, or quadratic (agglomerated on its corners, its faces matched by theirs)."""
    t = _TYPES.get(code)
    return t is not None and _corners(code) is not None and (t[0] == dim if dim is not None else t[0] >= 2)


def _corner_table(sec, code: int) -> np.ndarray:
    """(elements, corners) 0-based node ids of a section's elements."""
    conn = np.asarray(sec["ElementConnectivity"][" data"][()], dtype=np.int64).reshape(-1) - 1
    return conn.reshape(-1, _TYPES[code][1])[:, : _TYPES[_corners(code)][1]]


def _label(node) -> bytes:
    v = node.attrs.get("label", b"")
    return bytes(v).rstrip(b"\0") if not isinstance(v, bytes) else v.rstrip(b"\0")


def _text(node) -> str | None:
    d = node.get(" data")
    if d is None:
        return None
    return bytes(np.asarray(d[()], dtype=np.uint8).reshape(-1)).decode("utf-8", "replace").strip("\0 ")


def _children(node, label: bytes) -> list:
    return [node[k] for k in node if k != " data" and _label(node[k]) == label]


def family_groups(path: str, conn: np.ndarray, n_cells: int, offsets: np.ndarray | None = None):
    """(tags per VTK cell, field data {name: [id, dim]}, faces) of the zone's families, or None (not
    an HDF5 CGNS file of one unstructured zone whose sections are the cells VTK read, or no family).
    faces: (sizes, connectivity, VTK types, tags) of the sections one dimension below the cells (the
    boundary conditions' faces, which VTK's reader leaves out; quadratic ones on their corners), or
    None. offsets: VTK's cell offsets (then quadratic cells are matched on their corners)."""
    return _with_hdf5(path, lambda f: _groups(f, conn, n_cells, offsets))


def meshio_layout(path: str) -> bool:
    """An HDF5 .cgns file as meshio's writer makes it: groups Base/Zone1/GridCoordinates without
    CGNS's labels (no CGNSBase_t), which VTK's reader refuses ("not enough bases") and meshio reads.
    Run where the file is read (the sandbox's child): h5py parses it."""

    def look(f) -> bool:
        return "Base" in f and "Zone1" in f["Base"] and not any(_label(f[k]) == b"CGNSBase_t" for k in f)

    return bool(_with_hdf5(path, look))


# what meshio's CGNS reader takes of its own layout, each a group holding a " data" dataset
_MESHIO_NEEDS = tuple(
    f"Base/Zone1/{p}"
    for p in (
        "GridCoordinates/CoordinateX",
        "GridCoordinates/CoordinateY",
        "GridCoordinates/CoordinateZ",
        "GridElements/ElementRange",
        "GridElements/ElementConnectivity",
    )
)


def meshio_layout_fault(path: str) -> str | None:
    """Where meshio's reader of its own CGNS layout failed: the first of the nodes it reads that the
    file lacks, or holds no data ("Base/Zone1/GridCoordinates/CoordinateX has no data"), or None."""

    def look(f):
        for node in _MESHIO_NEEDS:
            if node not in f:
                return f"it has no {node} node, which meshio's CGNS layout holds"
            if " data" not in f[node]:
                return f"its {node} node has no data"
        return None

    return _with_hdf5(path, look)


def _with_hdf5(path: str, look):
    """look(the open h5py file) for an HDF5 file, None for any other, or where h5py is missing, or
    where the file's layout is not what look expects."""
    try:
        import h5py
    except ImportError:
        return None
    try:
        from models.mesh.containers import is_hdf5

        if not is_hdf5(path):
            return None
        with h5py.File(path, "r") as f:
            return look(f)
    except Exception:  # noqa: BLE001  (h5py's errors on a damaged file: hdf5_damage words them)
        return None


def _groups(f, conn: np.ndarray, n_cells: int, offsets: np.ndarray | None = None):
    bases = _children(f, b"CGNSBase_t")
    if len(bases) != 1:
        return None
    base = bases[0]
    zones = _children(base, b"Zone_t")
    if len(zones) != 1 or (_text(_children(zones[0], b"ZoneType_t")[0]) or "") != "Unstructured":
        return None
    zone = zones[0]
    names = {}  # family -> the name users gave it
    for fam in _children(base, b"Family_t"):
        given = _children(fam, b"FamilyName_t")
        names[fam.name.rsplit("/", 1)[-1]] = (_text(given[0]) if given else None) or fam.name.rsplit("/", 1)[
            -1
        ]
    sections = []
    for sec in _children(zone, b"Elements_t"):
        code = int(np.asarray(sec[" data"][()]).reshape(-1)[0])
        lo, hi = (int(v) for v in np.asarray(sec["ElementRange"][" data"][()]).reshape(-1)[:2])
        fam = _children(sec, b"FamilyName_t")
        sections.append((lo, hi, code, sec, _text(fam[0]) if fam else None))
    if not sections:
        return None
    dims = [_TYPES[c][0] if c in _TYPES else None for _, _, c, _, _ in sections]
    if any(d is None for d in dims):
        return None  # (MIXED, NGON: not followed here)
    top = max(dims)
    cells = sorted((s for s, d in zip(sections, dims, strict=True) if d == top), key=lambda s: s[0])
    if sum(hi - lo + 1 for lo, hi, *_ in cells) != n_cells or any(not _linear(c) for _, _, c, _, _ in cells):
        return None
    if not _same_cells(cells, conn, offsets):
        return None  # (not the cells VTK read, in its order)
    bnd = sorted(
        (s for s, d in zip(sections, dims, strict=True) if d == top - 1 and _linear(s[2], top - 1)),
        key=lambda s: s[0],
    )
    both = cells + bnd  # the zone's cells, then its faces (boundary conditions' sections)
    ids = np.concatenate([np.arange(lo, hi + 1) for lo, hi, *_ in both])  # element id of each
    kinds: dict[str, int] = {}  # family -> its number (1, 2, ...); 0: no family
    family = np.zeros(ids.size, dtype=np.int64)
    start = 0
    for lo, hi, _, _, fam in both:  # (a loop over sections)
        if fam:
            family[start : start + hi - lo + 1] = kinds.setdefault(fam, len(kinds) + 1)
        start += hi - lo + 1
    for bcs in _children(zone, b"ZoneBC_t"):  # boundary conditions on elements: their family
        for bc in _children(bcs, b"BC_t"):
            loc = _children(bc, b"GridLocation_t")
            fam = _children(bc, b"FamilyName_t")
            if not loc or not fam or _text(loc[0]) not in ("CellCenter", "FaceCenter", "EdgeCenter"):
                continue
            if "PointRange" in bc:
                a, b = (int(v) for v in np.asarray(bc["PointRange"][" data"][()]).reshape(-1)[:2])
                hit = (ids >= a) & (ids <= b)
            elif "PointList" in bc:
                hit = np.isin(ids, np.asarray(bc["PointList"][" data"][()]).reshape(-1))
            else:
                continue
            family[hit] = kinds.setdefault(_text(fam[0]), len(kinds) + 1)
    shown = [""] + [names.get(fam, fam) for fam in kinds]  # each family's name as users gave it
    n_top = n_cells
    field, tags = {}, np.zeros(ids.size, dtype=np.int64)
    for part, dim in ((slice(0, n_top), top), (slice(n_top, ids.size), top - 1)):
        here = np.unique(family[part])
        used = list(dict.fromkeys(shown[k] for k in here.tolist() if k))  # (families sharing a name: one)
        base_id = max(len(field), 1 if dim != top else 0)
        code = {name: base_id + i + 1 for i, name in enumerate(used)}
        for name, gid in code.items():
            field[name if name not in field else f"{name} ({dim}D)"] = [gid, dim]
        lookup = np.array([code.get(name, 0) for name in shown], dtype=np.int64)  # family -> group
        tags[part] = lookup[family[part]] if used else 1 if dim == top else 0
    if not field:
        return None
    lower = None
    if bnd:  # (quadratic faces on their corners: the cells' faces are matched by theirs)
        conn_b = np.concatenate([_corner_table(sec, c).reshape(-1) for _, _, c, sec, _ in bnd])
        sizes = np.concatenate([np.full(hi - lo + 1, _TYPES[_corners(c)][1]) for lo, hi, c, _, _ in bnd])
        vtk_types = np.concatenate(
            [np.full(hi - lo + 1, _TYPES[_corners(c)][2], np.uint8) for lo, hi, c, _, _ in bnd]
        )
        if conn_b.size != sizes.sum() or conn_b.min(initial=0) < 0:
            return tags[:n_top], {k: v for k, v in field.items() if v[1] == top} or None, None
        lower = (sizes, conn_b, vtk_types, tags[n_top:])
    return tags[:n_top], field, lower


def _same_cells(cells, conn: np.ndarray, offsets: np.ndarray | None) -> bool:
    """The sections' cells are the cells VTK read, in its order: every node where all are linear, the
    corners (each cell's first nodes in both numberings) where VTK's offsets are known."""
    conn = np.asarray(conn, dtype=np.int64)
    if all(_TYPES[c][2] is not None for _, _, c, _, _ in cells):  # (linear: their corners are all)
        expected = np.concatenate([_corner_table(sec, c).reshape(-1) for _, _, c, sec, _ in cells])
        return expected.size == conn.size and np.array_equal(expected, conn)
    if offsets is None:
        return False
    offsets = np.asarray(offsets, dtype=np.int64)
    start = 0
    for _, _, c, sec, _ in cells:  # a loop over sections
        want = _corner_table(sec, c)
        n, k = want.shape
        if start + n > offsets.size - 1 or np.any(
            offsets[start + 1 : start + n + 1] - offsets[start : start + n] < k
        ):
            return False
        got = conn[offsets[start : start + n, None] + np.arange(k)]
        if not np.array_equal(got, want):
            return False
        start += n
    return start == offsets.size - 1


def cgns_fault(path: str) -> str | None:
    """What is wrong in an HDF5 CGNS file's unstructured zones, in words, where VTK's reader says
    nothing useful or crashes: a zone without GridCoordinates, coordinate arrays shorter than the
    zone's vertex count, an element section without ElementRange or ElementConnectivity, or one
    whose connectivity is shorter than its range's elements need. None where nothing is found (ADF
    files, structured zones and MIXED/NGON sections are not looked into). Run where the file is read
    (the sandbox's child): h5py parses the untrusted file."""
    return _with_hdf5(path, _fault)


def _fault(f) -> str | None:
    for base in _children(f, b"CGNSBase_t"):
        for zone in _children(base, b"Zone_t"):
            said = _zone_fault(zone)
            if said:
                return f"zone {zone.name.rsplit('/', 1)[-1][:40]!r}: {said}"
    return None


def _zone_fault(zone) -> str | None:
    kind = _children(zone, b"ZoneType_t")
    text = (_text(kind[0]) or "") if kind else "Unstructured"
    if text not in ("Structured", "Unstructured"):  # (VTK's reader leaves such a zone out, saying nothing)
        return f"its zone type is {text[:32]!r}, which CGNS does not have (Structured or Unstructured)"
    if not kind or text != "Unstructured":
        return None
    size = np.asarray(zone[" data"][()]).reshape(-1)
    n_vertices = int(size[0])
    coords = _children(zone, b"GridCoordinates_t")
    if not coords:
        return "it has no GridCoordinates (no point coordinates)"
    for arr in _children(coords[0], b"DataArray_t"):
        held = int(np.prod(arr[" data"].shape)) if " data" in arr else 0
        if held < n_vertices:
            name = arr.name.rsplit("/", 1)[-1]
            return f"its {name} holds {held:,} values for the {n_vertices:,} vertices the zone declares"
    for sec in _children(zone, b"Elements_t"):
        name = sec.name.rsplit("/", 1)[-1][:40]
        if "ElementRange" not in sec:
            return f"its element section {name!r} has no ElementRange"
        if "ElementConnectivity" not in sec:
            return f"its element section {name!r} has no ElementConnectivity"
        code = int(np.asarray(sec[" data"][()]).reshape(-1)[0])
        lo, hi = (int(v) for v in np.asarray(sec["ElementRange"][" data"][()]).reshape(-1)[:2])
        if code in _TYPES:
            need = (hi - lo + 1) * _TYPES[code][1]
            held = int(np.prod(sec["ElementConnectivity"][" data"].shape))
            if held < need:
                return (
                    f"its element section {name!r} holds {held:,} node ids for the {hi - lo + 1:,} "
                    f"elements of its ElementRange ({need:,} needed)"
                )
    return None
