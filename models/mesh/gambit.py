"""Gambit neutral (.neu) files: what VTK's reader (vtkGAMBITReader) leaves out, gets wrong or dies on.
Our reading is VTK's (its points and cells), then `gambit_cells` on its arrays:

- Node order. Gambit numbers a brick's nodes and a pyramid's base lexicographically, (0,0) (1,0)
  (0,1) (1,1) (the GAMBIT neutral file's element conventions; OpenFOAM's gambitToFoam maps them so),
  VTK around the base; vtkGAMBITReader keeps the file's order, so that ParaView draws such cells
  twisted. They are put in VTK's order, decided per cell type by their bases (a file written in
  VTK's order is left as it is).
- Element groups as physical groups. A Gambit file puts every element in an ELEMENT GROUP (its
  zone: a material, a fluid or solid region; gmsh writes one per physical group), named on the
  line after the group's header. VTK's reader keeps only each group's MATERIAL number ("Material
  Type"), 0 in every group gmsh writes.
- Boundary conditions as boundary groups. A BOUNDARY CONDITIONS section of element faces (its
  type 1) lists (element, element type, face number) entries, the faces numbered by Gambit's face
  definitions; VTK's reader ignores them. Each face is checked to be a face of its element (its
  nodes those of one of the element's faces) before it is used.
- Repeated ENDOFSECTION lines. gmsh writes one or more ENDOFSECTION too many after the element
  groups of a file with boundary conditions; VTK's reader then frees memory twice and dies, so the
  file is read from a copy without them (`without_repeated_ends`).

Element ids: groups and boundary conditions list Gambit element ids; VTK's reader keeps the
elements in the file's order and ignores their ids, so the k-th element is taken to be id k (as
every writer we know numbers them: Gambit, gmsh, ICEM). A group or a condition that does not fit
(an id past the elements, a count that does not match its entries, a face that is not one of its
element's) is said in a note and not used, rather than guessed at.
"""

from __future__ import annotations

import contextlib
import os
import re

import numpy as np

# the header line of an element group: GROUP: g ELEMENTS: n MATERIAL: m NFLAGS: f, then its name
_GROUP = re.compile(
    rb"ELEMENT GROUP[^\n]*\n\s*GROUP:\s*(\d+)\s+ELEMENTS:\s*(\d+)\s+MATERIAL:\s*(\d+)\s+NFLAGS:\s*(\d+)[^\n]*\n"
    rb"([^\n]*)\n"
)
# a boundary condition's title and its header line (name, itype, entries, values, codes: _bc_header)
_BC = re.compile(rb"BOUNDARY CONDITIONS[^\n]*\n([^\n]*)\n")
_END = re.compile(rb"^[ \t]*ENDOFSECTION[ \t\r]*$", re.M)
REPEATED_END = re.compile(rb"(ENDOFSECTION[ \t\r]*\n)(?:[ \t\r]*ENDOFSECTION[ \t\r]*\n)+")
# an element group's or a boundary condition's whole section; the header's NGRPS and NBSETS
_SETS = re.compile(
    rb"^[ \t]*(?:ELEMENT GROUP|BOUNDARY CONDITIONS)[^\n]*\n.*?^[ \t]*ENDOFSECTION[ \t]*(?:\n|$)", re.M | re.S
)
# the header's count row: NUMNP NELEM NGRPS NBSETS NDFCD NDFVL, in any layout (meshpy writes a
# left-aligned table, "125   384   1     0      3     3", which VTK's reader does not parse)
_COUNTS = re.compile(
    rb"(NUMNP\s+NELEM\s+NGRPS\s+NBSETS[^\n]*\n)[ \t]*(\d+)\s+(\d+)\s+\d+\s+\d+((?:[ \t]+\d+)*)[ \t]*\n"
)
_FIRST_ID = re.compile(rb"ELEMENTS/CELLS[^\n]*\n\s*(\d+)")

# Gambit's face definitions per element (its node order, 0-based), by the element's VTK type as
# VTK's reader gives it: brick, wedge, tetrahedron, pyramid; quadrilateral and triangle edges
_FACES = {
    12: ((0, 1, 5, 4), (1, 3, 7, 5), (3, 2, 6, 7), (2, 0, 4, 6), (0, 2, 3, 1), (4, 5, 7, 6)),
    13: ((0, 1, 4, 3), (1, 2, 5, 4), (2, 0, 3, 5), (0, 2, 1), (3, 4, 5)),
    10: ((1, 0, 2), (0, 1, 3), (1, 2, 3), (2, 0, 3)),
    14: ((0, 2, 3, 1), (0, 1, 4), (1, 3, 4), (3, 2, 4), (2, 0, 4)),
    9: ((0, 1), (1, 2), (2, 3), (3, 0)),
    5: ((0, 1), (1, 2), (2, 0)),
}
_FACE_TYPE = np.array([0, 0, 3, 5, 9], np.uint8)  # a face's VTK type by its node count (line, triangle, quad)
_GAMBIT_ORDER = ((12, 8, (0, 1, 3, 2, 4, 5, 7, 6), "bricks"), (14, 5, (0, 1, 3, 2, 4), "pyramids"))


@contextlib.contextmanager
def vtk_copy(path: str):
    """The file to give VTK's reader: a copy (in a temporary folder, under its own name) with only
    what VTK reads of it, its nodes and elements: line ends and tabs as VTK's parser wants them
    (CRLF and tabs made it die), the element groups and boundary conditions left out (we read them
    from the file itself; a group or condition VTK's reader did not expect killed it: a count off
    by one, an empty name, values after the faces) and the header's count row rewritten in Gambit's
    fixed columns (10 characters each: meshpy's left-aligned table made VTK's reader die) with
    NGRPS and NBSETS 0,
    gmsh's repeated ENDOFSECTION lines made one. Yields (the copy's path, the file's own bytes):
    gambit_cells reads the groups from those, so the file is read once."""
    import shutil
    import tempfile

    folder = tempfile.mkdtemp(prefix="magnet-neu-")
    try:
        copy = os.path.join(folder, os.path.basename(path))
        with open(path, "rb") as fh:
            raw = fh.read()
        data = raw.replace(b"\r\n", b"\n").replace(b"\t", b" ")
        data = _SETS.sub(b"", REPEATED_END.sub(b"ENDOFSECTION\n", data))
        data = _COUNTS.sub(_fixed_counts, data, count=1)
        with open(copy, "wb") as out:
            out.write(data)
        yield copy, raw
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def _fixed_counts(m) -> bytes:
    """The count row in Gambit's own layout, each integer right-aligned in 10 characters (as VTK's
    reader reads it), NGRPS and NBSETS 0 (vtk_copy leaves the groups and conditions out)."""
    numbers = [m.group(2), m.group(3), b"0", b"0", *m.group(4).split()]
    return m.group(1) + b"".join(b"%10d" % int(n) for n in numbers) + b"\n"


def gambit_cells(data: bytes, pts, offsets, conn, types, cell_data: dict, field: dict, meta: dict):
    """VTK's arrays of a Gambit file (data: its bytes, vtk_copy's) with its node order, groups and
    boundary conditions (the module's note): (offsets, conn, types, cell_data, field), the boundary
    faces appended as cells of one dimension less with their group in cell_data's boundary tags;
    notes in meta."""
    from models.mesh.cells import DIM, with_boundary_faces

    offsets = np.asarray(offsets, dtype=np.int64)
    types = np.asarray(types, dtype=np.uint8)
    n, dim = len(types), int(DIM[types].max(initial=2))
    faces = boundary_conditions(data, offsets, np.asarray(conn), types)  # on the file's node order
    conn = _node_order(pts, offsets, conn, types, meta)
    notes = []
    groups = element_groups(data, n, dim)
    if groups is not None:
        tags, names, note = groups
        if note:
            notes.append(note)
        if tags is not None:
            cell_data, field = {**cell_data, "block": tags}, {**field, **names}
    sets: dict[str, list] = {}  # name -> the faces of every condition of that name (one group)
    if faces is not None:
        found, note = faces
        if note:
            notes.append(note)
        for name, parts in found:  # each face a face of its element, in VTK's order now
            if all(_is_face(offsets, conn, types, cells, f) for cells, f in parts):
                sets.setdefault(name, []).extend(f for _, f in parts)
            else:
                notes.append(
                    f"boundary condition '{name}' names faces that are not faces of their elements (the "
                    "file's elements are not in Gambit's node order, or its face numbers are not Gambit's): not used"
                )
    if sets:
        first = max([0, *(int(v[0]) for v in field.values() if len(v) == 2)]) + 1
        parts = [(first + i, f) for i, fs in enumerate(sets.values()) for f in _distinct_faces(fs)]
        sizes = np.concatenate([np.full(len(f), f.shape[1]) for _, f in parts])
        offsets, conn, types, cell_data = with_boundary_faces(  # (the reader's other cell arrays go)
            offsets,
            conn,
            types,
            cell_data.get("block"),
            sizes,
            np.concatenate([f.reshape(-1) for _, f in parts]),
            _FACE_TYPE[sizes],
            np.concatenate([np.full(len(f), g) for g, f in parts]),
        )
        for i, name in enumerate(sets):  # (a name an element group has too: told apart, as for CGNS)
            field = {**field, (name if name not in field else f"{name} ({dim - 1}D)"): [first + i, dim - 1]}
    if notes:
        meta["gambit_groups"] = {"count": 1, "message": "; ".join(notes)}
    return offsets, conn, types, cell_data, field


def _distinct_faces(faces: list) -> list:
    """A group's faces by node count, each face once (gmsh lists a face between two volumes once for
    each of them), in their first order."""
    out = []
    for k in sorted({f.shape[1] for f in faces}):
        f = np.concatenate([x for x in faces if x.shape[1] == k])
        _, first = np.unique(np.sort(f, axis=1), axis=0, return_index=True)
        out.append(f[np.sort(first)])
    return out


def _is_face(offsets, conn, types, cells, faces) -> bool:
    """Every faces[i] (its nodes, any order) is one of element cells[i]'s faces (FACE_TEMPLATES, or
    the element's edges in 2D)."""
    from models.mesh.geometry import FACE_TEMPLATES

    want = np.sort(faces, axis=1)
    for t in np.unique(types[cells]).tolist():  # (a loop over element types)
        sel = np.flatnonzero(types[cells] == t)
        k = int(offsets[cells[sel[0]] + 1] - offsets[cells[sel[0]]])
        nodes = np.asarray(conn)[offsets[cells[sel]][:, None] + np.arange(k)]
        table = FACE_TEMPLATES.get(int(t)) or [(j, (j + 1) % k) for j in range(k)]
        table = [f for f in table if len(f) == faces.shape[1]]
        if not table:
            return False
        theirs = np.sort(nodes[:, np.array(table)], axis=2)  # (m, faces, size)
        if not np.all((theirs == want[sel][:, None, :]).all(axis=2).any(axis=1)):
            return False
    return True


def element_groups(data: bytes, n_cells: int, dim: int) -> tuple[np.ndarray | None, dict, str | None] | None:
    """(tags (n_cells,) int64: each element's group number, 0 for none; {name: [number, dim]} as
    gmsh's field data; a note or None) from a Gambit file's bytes; None where it has no element
    group. Groups that cannot be trusted (a count that does not match its ids, an id past the
    elements, a word that is not an id) give (None, {}, a note saying so): no group is used. A group
    whose header miscounts its ids has all its ids used, and a note says so."""
    tags = np.zeros(n_cells, dtype=np.int64)
    sizes = np.zeros(n_cells, dtype=np.int64)  # the size of the group a cell is in (smallest wins)
    names: dict[str, list[int]] = {}
    twice = 0
    found = False
    first = _first_element_id(data) - 1  # ids from there (1 in every writer we know)
    miscounted = []
    for m in _GROUP.finditer(data):
        found = True
        number, count, nflags = int(m.group(1)), int(m.group(2)), int(m.group(4))
        body = _section(data, m.end()).split()
        words = body[nflags:]
        if not nflags and len(words) == count + 1 and words[0] == b"0" and first >= 0:
            words = words[1:]  # meshpy writes Gambit's flag line ("0") under NFLAGS 0: no element id 0
        ids = _ids(words)
        if ids is None or number < 1:
            return (
                None,
                {},
                f"element group {number} holds a word that is not an element id: the element groups are not used",
            )
        if ids.size != count:  # the ids are what counts (VTK's reader died on such a file)
            miscounted.append(
                f"element group {number} lists {ids.size:,} elements where its header says {count:,}"
            )
        ids -= first
        if ids.size and (ids.min() < 0 or ids.max() >= n_cells):
            bad = int(ids.max() if ids.max() >= n_cells else ids.min()) + 1 + first
            return (
                None,
                {},
                (
                    f"element group {number} lists element {bad:,}, not one of the file's {n_cells:,} elements "
                    f"(ids {first + 1:,} to {first + n_cells:,}): the element groups are not used"
                ),
            )
        name = m.group(5).decode("utf-8", "replace").strip() or f"group {number}"
        name = name if name not in names else f"{name} (group {number})"
        names[name] = [number, dim]
        taken = sizes[ids] > 0
        twice += int(np.count_nonzero(taken))
        better = ~taken | (sizes[ids] > ids.size)  # a cell in two groups: kept in the smaller one
        tags[ids[better]] = number
        sizes[ids[better]] = ids.size
    if not found:
        return None
    notes = [f"{'; '.join(miscounted)}: all of them used"] if miscounted else []
    if twice:
        notes.append(
            f"{twice:,} element{'s' if twice > 1 else ''} listed in two element groups: "
            f"{'each' if twice > 1 else 'it is'} kept in the smaller group"
        )
    loose = int(np.count_nonzero(sizes == 0))
    if loose:
        notes.append(f"{loose:,} element{'s' if loose > 1 else ''} in no element group: group 0")
    return tags, names, "; ".join(notes) or None


def boundary_conditions(data: bytes, offsets, conn, types) -> tuple[list, str | None] | None:
    """([(name, [(cells (m,), faces (m, k) node ids)] by the faces' node count)] of the file's
    boundary conditions on element faces, a note or None), the faces' nodes from the elements as the
    file orders them (before _node_order); None where it has no boundary condition. A condition on
    nodes (type 0) is left out and said; one that does not fit (the module's note) is not used and
    said. Values after each face (NVALUES) are read past."""
    sets, notes = [], []
    n = len(types)
    first = _first_element_id(data)
    for m in _BC.finditer(data):
        words = _section(data, m.end()).split()
        head = _bc_header(m.group(1), len(words))
        if head is None:
            line = m.group(1).decode("utf-8", "replace").strip()
            notes.append(
                f"a boundary condition's header '{line}' is not NAME ITYPE NENTRY NVALUES [IBCODE...]: not used"
            )
            continue
        name, itype, count, nvalues = head
        if itype != 1:
            notes.append(f"boundary condition '{name}' is on nodes, not faces: not used")
            continue
        rows = _ids(np.array(words, dtype=bytes).reshape(count, 3 + nvalues)[:, :3].reshape(-1))
        if rows is None:
            notes.append(f"boundary condition '{name}' holds a word that is not a number: not used")
            continue
        rows = rows.reshape(count, 3) + 1  # (_ids subtracts 1)
        cell, face = rows[:, 0] - first, rows[:, 2] - 1
        if count and (cell.min() < 0 or cell.max() >= n):
            notes.append(
                f"boundary condition '{name}' names element {int(rows[:, 0].max()):,}, past the {n:,} "
                "elements: not used"
            )
            continue
        got = _face_nodes(offsets, conn, types, cell, face)
        if got is None:
            notes.append(
                f"boundary condition '{name}' names faces that are not faces of their elements (an element "
                "type or face number Gambit does not define for it): not used"
            )
            continue
        sets.append((name, got))
    if not sets and not notes:
        return None
    return sets, "; ".join(notes) or None


def _bc_header(line: bytes, n_words: int) -> tuple[str, int, int, int] | None:
    """(name, itype, entries, values) of a boundary condition's header: NAME (Gambit's A32, gmsh's
    right-aligned; it may hold spaces), then ITYPE (0 nodes, 1 element faces), NENTRY, NVALUES and
    up to five IBCODEs (none in some writers'). The name ends where the numbers begin: the first
    split whose ITYPE is 0 or 1 and whose entries (NENTRY x (3 or 1 + NVALUES) words) are the
    section's n_words; None where no split is."""
    words = line.split()
    k = len(words)
    while k > 0 and words[k - 1].isdigit():
        k -= 1  # words[k:]: the trailing integers
    for at in range(max(k, 1), len(words) - 2):
        itype, count, nvalues = (int(w) for w in words[at : at + 3])
        if len(words) - at <= 8 and itype in (0, 1) and count * (nvalues + (3 if itype else 1)) == n_words:
            return b" ".join(words[:at]).decode("utf-8", "replace"), itype, count, nvalues
    return None


def _first_element_id(data: bytes) -> int:
    """The id of the file's first element (1 in every writer we know; a file cut out of a larger
    model may start later, its ids then consecutive from there)."""
    m = _FIRST_ID.search(data)
    return int(m.group(1)) if m else 1


def _face_nodes(offsets, conn, types, cell, face) -> list | None:
    """[(cells, faces (m, k))] by node count: the nodes of face `face` (0-based, Gambit's numbering)
    of each element `cell`, from Gambit's face definitions; None where a face number is past its
    element type's faces, or the type has none here."""
    out: dict[int, list] = {}
    for t in np.unique(types[cell]).tolist():  # (a loop over element types)
        table = _FACES.get(int(t))
        sel = np.flatnonzero(types[cell] == t)
        if table is None:
            return None
        k = max(max(f) for f in table) + 1
        f = face[sel]
        if f.min() < 0 or f.max() >= len(table) or np.any(np.diff(offsets)[cell[sel]] != k):
            return None
        nodes = np.asarray(conn)[offsets[cell[sel]][:, None] + np.arange(k)]
        for size in sorted({len(x) for x in table}):  # faces of one node count at a time
            here = np.flatnonzero(np.array([len(x) == size for x in table])[f])
            if here.size == 0:
                continue
            local = np.array([x if len(x) == size else (0,) * size for x in table])[f[here]]
            out.setdefault(size, []).append((cell[sel][here], np.take_along_axis(nodes[here], local, axis=1)))
    return [
        (np.concatenate([c for c, _ in v]), np.concatenate([x for _, x in v])) for _, v in sorted(out.items())
    ]


def _section(data: bytes, start: int) -> bytes:
    end = _END.search(data, start)
    return data[start : end.start() if end else len(data)]


def _ids(words) -> np.ndarray | None:
    """Integer words (a list, or an array of bytes) as 0-based ids (each minus 1), or None where one
    is not an integer."""
    try:
        return np.asarray(words).astype(np.int64) - 1 if len(words) else np.zeros(0, np.int64)
    except ValueError:
        return None


def _node_order(pts, offsets, conn, types, meta: dict):
    """conn with a Gambit file's bricks and pyramids in VTK's node order, where the file is in
    Gambit's: decided per cell type by the base quadrilaterals (a bow-tie in VTK's order, the points
    1 and 3 on the same side of the diagonal 0-2, in most of them), said in meta["reordered_cells"].
    A file written in VTK's order (not Gambit's) is left as it is."""
    done, count = [], 0
    for vtk_type, k, perm, name in _GAMBIT_ORDER:
        sel = np.flatnonzero((types == vtk_type) & (np.diff(offsets) == k))
        if sel.size == 0:
            continue
        idx = np.asarray(offsets[sel], dtype=np.int64)[:, None] + np.arange(k)
        nodes = np.asarray(conn)[idx]
        p = np.asarray(pts, dtype=np.float64)[nodes[:, :4]]
        diag = p[:, 2] - p[:, 0]
        side = np.einsum("ij,ij->i", np.cross(diag, p[:, 1] - p[:, 0]), np.cross(diag, p[:, 3] - p[:, 0]))
        if np.count_nonzero(side > 0) * 2 <= sel.size:
            continue
        conn = np.array(conn, copy=True) if not done else conn
        conn[idx] = nodes[:, list(perm)]
        done.append(f"{sel.size:,} {name}")
        count += int(sel.size)
    if done:
        meta["reordered_cells"] = {
            "count": count,
            "message": f"{' and '.join(done)} read in Gambit's node order (VTK's reader keeps the file's "
            "order and draws them twisted)",
        }
    return conn
