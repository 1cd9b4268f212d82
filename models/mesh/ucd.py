"""deal.II's AVS UCD ASCII meshes (.inp / .ucd), read and written without a loop over lines.

Layout (what deal.II's GridOut::write_ucd writes and GridIn::read_ucd reads):

    # comment lines
    n_points n_cells n_node_data n_cell_data 0
    id x y z                        (n_points lines; ids need not be 0.. or contiguous)
    id material type v1 v2 ...      (n_cells lines; type: pt line tri quad tet pyr prism hex)
    node and cell data              (where the counts are not 0: ignored)

Quads and hexahedra list their vertices as VTK does (a hexahedron: one face cyclically, then the
opposite face in the same order), so only the pyramid (apex first in AVS) is permuted. The
material id of the top-dimensional cells is the physical group; lower-dimensional cells (lines
in 2D, faces in 3D) carry boundary ids: they become the mesh's boundary groups.

meshio takes `.inp` for Abaqus, so `read_mesh` looks at the content first (`is_ucd`).
The writer writes the fine cells with a material id per cell (magnet: the agglomerated element
each belongs to), then the boundary groups as line / face cells with their tag as material id:
UCD has no polygon or polyhedron cell, so agglomerates cannot be written as cells.
"""

from __future__ import annotations

import os

import numpy as np

from models.errors import MeshError

# type token -> (meshio name, number of vertices); AVS's pyramid lists the apex first
UCD_TYPES = {
    "pt": ("vertex", 1),
    "line": ("line", 2),
    "tri": ("triangle", 3),
    "quad": ("quad", 4),
    "tet": ("tetra", 4),
    "pyr": ("pyramid", 5),
    "prism": ("wedge", 6),
    "hex": ("hexahedron", 8),
}
_PYR_FROM_UCD = np.array([1, 2, 3, 4, 0])
_PYR_TO_UCD = np.array([4, 0, 1, 2, 3])
UCD_NAME_OF = {v[0]: k for k, v in UCD_TYPES.items()}


def _header_line(text: bytes) -> tuple[int, list[bytes]]:
    """Offset just past the header line and its tokens (comment lines start with '#')."""
    pos = 0
    while pos < len(text):
        end = text.find(b"\n", pos)
        end = len(text) if end < 0 else end
        line = text[pos:end].strip()
        if line and not line.startswith(b"#"):
            return end + 1, line.split()
        pos = end + 1
    return len(text), []


def is_ucd(path: str | os.PathLike) -> bool:
    """True when the file starts (after '#' comments) with the UCD header of five integers
    followed by a point line `id x y z`."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(1 << 16)
    except OSError:
        return False
    pos, tokens = _header_line(head)
    if len(tokens) != 5 or not all(t.lstrip(b"-").isdigit() for t in tokens):
        return False
    nxt = head[pos:].split(b"\n", 1)[0].split()
    if int(tokens[0]) == 0:
        return True
    try:
        return len(nxt) == 4 and all(np.isfinite(float(t)) for t in nxt)
    except ValueError:
        return False


def read_ucd(path: str | os.PathLike):
    """The file as a meshio.Mesh (cell_data 'avsucd:material' per block). MeshError if malformed."""
    import meshio

    name = os.path.basename(os.fspath(path))
    with open(path, "rb") as fh:
        text = fh.read()
    pos, tokens = _header_line(text)
    try:
        n_pts, n_cells = int(tokens[0]), int(tokens[1])
        n_node_data, n_cell_data = int(tokens[2]), int(tokens[3])
    except (IndexError, ValueError):
        raise MeshError(
            f"{name}: not an AVS UCD file (the header line must be 'n_points n_cells 0 0 0')"
        ) from None
    if n_pts < 0 or n_cells < 0:
        raise MeshError(f"{name}: negative counts in the UCD header")
    if n_node_data < 0 or n_cell_data < 0:
        raise MeshError(f"{name}: negative data counts in the UCD header")
    # node or cell data (n_node_data, n_cell_data > 0) follow the cells: ignored (the mesh is read)
    body = np.frombuffer(text, dtype=np.uint8, offset=pos) if pos < len(text) else np.zeros(0, np.uint8)
    nl = np.flatnonzero(body == ord("\n"))
    ends = np.r_[nl, body.size]
    starts = np.r_[0, nl + 1]
    nonblank = _nonblank_lines(body, starts, ends)
    starts, ends = starts[nonblank], ends[nonblank]
    if starts.size < n_pts + n_cells:
        raise MeshError(
            f"{name}: the header announces {n_pts} points and {n_cells} cells, the file has {starts.size} lines"
        )
    # points: one flat parse of the block
    p_end = ends[n_pts - 1] if n_pts else (starts[0] if starts.size else 0)
    flat = _numbers(body[:p_end], name)
    if flat.size != 4 * n_pts:
        raise MeshError(f"{name}: point lines must be 'id x y z' ({n_pts} expected)")
    pt = flat.reshape(-1, 4)
    ids = pt[:, 0].astype(np.int64)
    points = pt[:, 1:]
    # cells: find the tokens at the byte level; the type word is the only alphabetic token of a line
    c0 = starts[n_pts] if n_cells else p_end
    c1 = ends[n_pts + n_cells - 1] if n_cells else p_end
    b = body[c0:c1].copy()
    solid = b > 32
    tok_start = np.flatnonzero(solid & ~np.r_[False, solid[:-1]])
    tok_end = np.flatnonzero(solid & ~np.r_[solid[1:], False]) + 1
    alpha = ((b >= ord("a")) & (b <= ord("z"))) | ((b >= ord("A")) & (b <= ord("Z")))
    is_word = alpha[tok_start]
    type_pos = np.flatnonzero(is_word)
    if type_pos.size != n_cells:
        raise MeshError(f"{name}: {n_cells} cells announced, {type_pos.size} cell lines found")
    ws, we = tok_start[type_pos], tok_end[type_pos]
    # a key per word: its length and first two letters; the distinct words are few
    second = b[np.minimum(ws + 1, b.size - 1)]
    key = (we - ws).astype(np.int64) * 65536 + b[ws].astype(np.int64) * 256 + second
    ukey, first_at, inv = np.unique(key, return_index=True, return_inverse=True)
    kinds = [b[ws[f] : we[f]].tobytes().decode("ascii", "replace").lower() for f in first_at]
    unknown = [k for k in kinds if k not in UCD_TYPES]
    if unknown:
        raise MeshError(f"{name}: unknown UCD cell type {unknown[0]!r} (known: {', '.join(UCD_TYPES)})")
    nv_of_kind = np.array([UCD_TYPES[k][1] for k in kinds], dtype=np.int64)
    nv = nv_of_kind[inv]
    expected_next = type_pos + nv + 3  # id material type v*nv -> the next line's type token
    if not np.array_equal(expected_next[:-1], type_pos[1:]) or (
        n_cells and expected_next[-1] - 2 != tok_start.size
    ):
        raise MeshError(
            f"{name}: cell lines must be 'id material type v1 v2 ...' with as many vertices as the type has"
        )
    b[alpha] = ord(" ")
    nums = _numbers(b, name)
    if nums.size != tok_start.size - n_cells:
        raise MeshError(f"{name}: non-numeric values in the cell lines")
    # numeric tokens per line: id, material, then nv vertex ids
    width = nv + 2
    off = np.zeros(n_cells + 1, dtype=np.int64)
    np.cumsum(width, out=off[1:])
    material = nums[off[:-1] + 1].astype(np.int64)
    order = np.argsort(ids, kind="stable")
    sid = ids[order]
    if sid.size and np.any(sid[1:] == sid[:-1]):
        raise MeshError(f"{name}: repeated point ids")
    blocks, tags = [], []
    for j, kind in enumerate(kinds):  # a loop over cell types, not cells
        rows = np.flatnonzero(inv == j)
        k = nv_of_kind[j]
        vid = nums[(off[rows] + 2)[:, None] + np.arange(k)].astype(np.int64)
        at = np.searchsorted(sid, vid)
        at = np.minimum(at, max(sid.size - 1, 0))
        if sid.size == 0 or np.any(sid[at] != vid):
            raise MeshError(f"{name}: {kind} cells refer to point ids that are not in the file")
        conn = order[at]
        if kind == "pyr":
            conn = conn[:, _PYR_FROM_UCD]
        blocks.append((UCD_TYPES[kind][0], conn))
        tags.append(material[rows])
    return meshio.Mesh(points, blocks, cell_data={"avsucd:material": tags})


def _numbers(b: np.ndarray, name: str) -> np.ndarray:
    """All whitespace-separated numbers of a byte block (one C-level parse)."""
    if b.size == 0:
        return np.zeros(0)
    text = b.tobytes().decode("ascii", "replace")
    try:
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("error")
            return np.fromstring(text, sep=" ")
    except (ValueError, DeprecationWarning):
        raise MeshError(f"{name}: non-numeric values where numbers are expected") from None


def _nonblank_lines(body: np.ndarray, starts: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """Lines holding something other than whitespace (comment lines inside the body are not allowed)."""
    if body.size == 0:
        return np.zeros(starts.size, dtype=bool)
    sp = np.flatnonzero(body > 32)  # printable, non-space bytes
    return np.searchsorted(sp, ends) > np.searchsorted(sp, starts)
