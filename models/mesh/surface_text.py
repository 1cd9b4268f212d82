"""OBJ and OFF surfaces as their writers write them: points and polygon faces.

meshio's readers refuse much of what these formats allow (outside sweep T): OFF faces that are not
triangles, or that carry a colour after their indices; OBJ faces written `v/vt/vn` where the file
has a different number of texture coordinates than of points (the usual case in exported files),
and OBJ's negative (relative) indices. Both formats are lines of whitespace-separated words; here
a file's lines are split once and the words of each kind of line are converted by numpy, per line
only the split (no numbers parsed in Python)."""

from __future__ import annotations

import re

import numpy as np

from models.errors import MeshError


def _lines(path: str, continued: bool = False) -> list[list[bytes]]:
    """Each line's words, comments dropped; continued: a line ending in a backslash goes on on the
    next (OBJ's rule: exporters break long `f` lines so)."""
    with open(path, "rb") as fh:
        data = fh.read()
    if continued and b"\\" in data:
        data = re.sub(rb"\\[ \t]*\r?\n", b" ", data)
    return [words for words in (line.split(b"#", 1)[0].split() for line in data.splitlines()) if words]


def _floats(rows: list[list[bytes]], what: str) -> np.ndarray:
    try:
        return np.array(rows, dtype=np.float64)
    except ValueError:
        raise MeshError(f"a {what} has a coordinate that is not a number") from None


def _faces(counts: np.ndarray, words: list[bytes]) -> tuple[np.ndarray, np.ndarray]:
    """(offsets, flat node words) of polygons from their sizes and their words in order."""
    offsets = np.zeros(counts.size + 1, dtype=np.int64)
    np.cumsum(counts, out=offsets[1:])
    return offsets, np.asarray(words)


def read_off(path: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(points (P, 3), face offsets (F + 1), face nodes) of an OFF file: the header OFF / COFF / NOFF / CNOFF (its
    counts on the same line or the next), then the points (extra words: colours, normals, ignored),
    then the faces, each its size, its indices (from 0) and optionally a colour."""
    lines = _lines(path)
    if not lines or not lines[0][0].upper().endswith(b"OFF"):
        raise MeshError("it does not start with an OFF header")
    head = lines[0][1:] or (lines[1] if len(lines) > 1 else [])
    rest = lines[1:] if lines[0][1:] else lines[2:]
    try:
        n_points, n_faces = int(head[0]), int(head[1])
    except (ValueError, IndexError):
        raise MeshError("its header does not give the number of points and faces") from None
    if n_points < 0 or n_faces < 0 or len(rest) < n_points + n_faces:
        raise MeshError(f"it announces {n_points:,} points and {n_faces:,} faces and holds fewer lines")
    if any(len(r) < 3 for r in rest[:n_points]):
        raise MeshError("a point has fewer than three coordinates")
    points = _floats([r[:3] for r in rest[:n_points]], "point")
    face_lines = rest[n_points : n_points + n_faces]
    try:
        counts = np.array([int(r[0]) for r in face_lines], dtype=np.int64)
    except ValueError:
        raise MeshError("a face's size is not a whole number") from None
    if (counts < 1).any() or any(len(r) <= c for r, c in zip(face_lines, counts.tolist(), strict=True)):
        raise MeshError("a face has fewer indices than its size says")
    words = [w for r, c in zip(face_lines, counts.tolist(), strict=True) for w in r[1 : c + 1]]
    offsets, flat = _faces(counts, words)
    try:
        nodes = flat.astype(np.int64)
    except ValueError:
        raise MeshError("a face index is not a whole number") from None
    return points, offsets, nodes


def read_obj(path: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(points (P, 3), face offsets (F + 1), face nodes) of a Wavefront OBJ file: `v` lines (x y z, extra words
    ignored) and `f` lines whose corners are `i`, `i/t`, `i//n` or `i/t/n` (the point index i, from 1;
    negative: counted back from the last point defined so far). Texture coordinates, normals, groups,
    materials, lines and the rest are ignored; a line ending in a backslash goes on on the next."""
    lines = _lines(path, continued=True)
    kind = [r[0] for r in lines]
    is_v = np.array([k == b"v" for k in kind], dtype=bool)
    is_f = np.array([k == b"f" for k in kind], dtype=bool)
    vlines = [lines[i] for i in np.flatnonzero(is_v)]
    if not vlines:  # (a binary file, or another format, under an .obj name)
        raise MeshError("it has no point lines ('v x y z'): is it an OBJ file?")
    if any(len(r) < 4 for r in vlines):
        raise MeshError("a point ('v' line) has fewer than three coordinates")
    points = _floats([r[1:4] for r in vlines], "point ('v' line)")
    flines = [lines[i] for i in np.flatnonzero(is_f)]
    counts = np.array([len(r) - 1 for r in flines], dtype=np.int64)
    words = [w.split(b"/", 1)[0] for r in flines for w in r[1:]]
    offsets, flat = _faces(counts, words)
    try:
        idx = flat.astype(np.int64)
    except ValueError:
        raise MeshError("a face ('f' line) has a corner that is not a point index") from None
    if (idx == 0).any():
        raise MeshError("a face ('f' line) refers to point 0 (OBJ counts points from 1)")
    before = np.cumsum(is_v)[is_f]  # the points defined before each face line
    seen = np.repeat(before, counts)
    nodes = np.where(idx < 0, seen + idx, idx - 1)
    return points, offsets, nodes


def as_meshio(points: np.ndarray, offsets: np.ndarray, nodes: np.ndarray):
    """A meshio-like object (points, cells [.type, .data], no data) of the faces by size: triangles,
    quads, and the larger polygons as meshio's polygon blocks (one per size)."""
    from types import SimpleNamespace

    sizes = np.diff(offsets)
    blocks = []
    for k in np.unique(sizes[sizes >= 3]):  # a loop over polygon sizes, not polygons
        rows = nodes[offsets[:-1][sizes == k][:, None] + np.arange(k)]
        name = {3: "triangle", 4: "quad"}.get(int(k), "polygon")
        blocks.append(SimpleNamespace(type=name, data=rows))
    return SimpleNamespace(points=points, cells=blocks, cell_data={}, field_data={})


READERS = {".obj": read_obj, ".off": read_off}  # extension -> (points, face offsets, face nodes)
