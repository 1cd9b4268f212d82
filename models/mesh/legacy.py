"""A fast path for legacy VTK files of the common layout: an unstructured grid of one cell type
(triangles, quads, tetrahedra or hexahedra) and nothing else, as VTK's vtkDataSetWriter writes it
(file versions up to 4.2: CELLS as counts and ids; 5.x: OFFSETS and CONNECTIVITY). BINARY: numpy
reads the big-endian arrays straight from the file's bytes; ASCII: the compiled
models/mesh/_fastmesh.c ascii_values parses each section's numbers (plain decimals only, correctly
rounded: the values VTK's reader gets). VTK's reader parses them through a stream: most of the read
stage's time on such a file. Any other file, any doubt (a word that is not a plain number, too few
numbers, the compiled module not built): None, and VTK's reader reads it
(models/mesh/vtk_readers.py), errors and all.
"""

from __future__ import annotations

import mmap
import os
import re
from types import SimpleNamespace

import numpy as np

# VTK cell type -> (meshio name, nodes)
_CELLS = {5: ("triangle", 3), 9: ("quad", 4), 10: ("tetra", 4), 12: ("hexahedron", 8)}
_FLOATS = {b"float": ">f4", b"double": ">f8"}
_INTS = {b"int": ">i4", b"vtktypeint64": ">i8"}


class _Decline(Exception):
    """Not the common layout: VTK's reader reads the file."""


class _Cursor:
    def __init__(self, data: bytes):
        self.data, self.pos, self.ascii = data, 0, None

    def line(self) -> list[bytes]:
        """The next non-blank line's words."""
        d = self.data
        while True:
            end = d.find(b"\n", self.pos)
            if end < 0:
                end = len(d)
            words = d[self.pos : end].split()
            self.pos = end + 1
            if words:
                return words
            if end >= len(d):
                raise _Decline

    def array(self, dtype: str, count: int, components: int = 1) -> np.ndarray:
        """`count` big-endian values here (then the line break VTK writes after them); in an ASCII
        file, `count` numbers of that type (int64 or the file's float type). Then past a METADATA
        block (of an array of `components` components)."""
        if self.ascii is not None:
            return self._text(dtype, count, components)
        n = np.dtype(dtype).itemsize * count
        if count < 0 or self.pos + n > len(self.data):
            raise _Decline
        out = np.frombuffer(self.data, dtype=dtype, count=count, offset=self.pos)
        self.pos += n
        self.metadata(components)
        return out

    def metadata(self, components: int) -> None:
        """Past the METADATA block VTK's writers put after an array whose information holds keys
        (the ranges an XML writer computed) or whose components are named, as vtkDataReader reads
        it: COMPONENT_NAMES and one line per component (a line may be empty), INFORMATION and its
        lines; a blank line ends the block. Nothing where the next line is not METADATA."""
        at = self.pos
        try:
            if self.line() != [b"METADATA"]:
                self.pos = at
                return
        except _Decline:
            self.pos = at
            return
        while True:
            line = self._raw_line().strip()
            if not line:
                return
            if line == b"COMPONENT_NAMES":
                for _ in range(components):
                    self._raw_line()
            elif line.split()[0] == b"INFORMATION":
                while self._raw_line().strip():  # its keys, to the blank line that ends the block
                    pass
                return
            else:
                raise _Decline

    def _raw_line(self) -> bytes:
        end = self.data.find(b"\n", self.pos)
        if end < 0:
            raise _Decline
        line, self.pos = self.data[self.pos : end], end + 1
        return line

    def _text(self, dtype: str, count: int, components: int) -> np.ndarray:
        kind = {">f4": 2, ">f8": 1}.get(dtype, 0)
        if count < 0 or count > len(self.data) // 2 + 1:  # a number and a separator at least
            raise _Decline
        out = np.empty(count, dtype=(np.int64, np.float64, np.float32)[kind])
        pos = self.ascii.ascii_values(self.data, self.pos, out, kind)
        if pos < 0:
            raise _Decline
        if dtype == ">i4" and count and (out.min() < -(2**31) or out.max() >= 2**31):
            raise _Decline  # VTK's reader would not take it as an int
        self.pos = pos
        self.metadata(components)
        return out


def read_legacy_simple(path: str | os.PathLike):
    """A meshio-like object (points, cells [.type, .data], cell_data {}, field_data {}) for a legacy
    VTK file of the layout above, or None for any other file."""
    raw = read_legacy_raw(path, mapped=True)  # widen copies every array (models.mesh.mapped)
    if raw is None:
        return None
    points, cells, counted, t = raw
    points, cells = widen(points, cells, counted)
    return SimpleNamespace(
        points=points,
        cells=[SimpleNamespace(type=_CELLS[t][0], data=cells)],
        cell_data={},
        field_data={},
    )


def widen(points: np.ndarray, cells: np.ndarray, counted: bool) -> tuple[np.ndarray, np.ndarray]:
    """read_legacy_raw's arrays as float64 points and int64 (C, k) cells, the count column of
    counted rows dropped (in this process's reader and, for the sandbox's reading child's answer,
    in the caller: models.mesh.deferred.fixed_args; the same values both ways)."""
    if counted:  # byte order first, whole rows (one pass, contiguous), then the ids
        cells = cells.astype(np.int32, copy=False)[:, 1:]
    return points.astype(np.float64), cells.astype(np.int64)


def read_legacy_raw(path: str | os.PathLike, mapped: bool = False):
    """The arrays of a legacy VTK file of the layout above as the file holds them (views of its
    bytes: big-endian in a binary file), or None for any other file: (points (n, 3) float32 or
    float64, cells (C, k) of k node ids each, or (C, k + 1) rows of the count k and the ids when
    `counted` (file versions up to 4.2), counted, the cells' VTK type). mapped: the bytes are the
    file mapped, not read (no copy): the arrays are views of the mapping, to be copied before the
    read returns (widen does; models.mesh.mapped). A file cut short while mapped ends the process:
    in the sandbox's reading child, a crashed reader."""
    try:
        fd = os.open(os.fspath(path), os.O_RDONLY | getattr(os, "O_CLOEXEC", 0))
        try:
            head = os.pread(fd, 256, 0)
            if not head.startswith(b"# vtk DataFile Version") or (
                b"BINARY" not in head and b"ASCII" not in head
            ):
                return None
            data = mmap.mmap(fd, 0, access=mmap.ACCESS_READ) if mapped else _whole(fd)
        finally:
            os.close(fd)
        return _simple(data)
    except (_Decline, ValueError, KeyError, IndexError, OSError):
        return None


def _whole(fd: int) -> bytes:
    """The file's bytes in one read where it can (one copy from the page cache, no buffer joined)."""
    size = os.fstat(fd).st_size
    data = os.pread(fd, size + 1, 0)  # (+1: a file grown since fstat is read on, below)
    if len(data) <= size:
        return data
    parts, at = [data], len(data)
    while True:
        more = os.pread(fd, 1 << 24, at)
        if not more:
            return b"".join(parts)
        parts.append(more)
        at += len(more)


def _count(word: bytes) -> int:
    if not word.isdigit():
        raise _Decline
    return int(word)


def _simple(data: bytes):
    cur = _Cursor(data)
    version = cur.line()
    if version[:4] != [b"#", b"vtk", b"DataFile", b"Version"] or len(version) != 5:
        return None
    cur.pos = data.find(b"\n", cur.pos) + 1  # the title line, whatever it says
    if cur.pos == 0:
        return None
    mode = cur.line()
    if mode == [b"ASCII"]:
        from models.native import compiled

        cur.ascii = compiled("mesh._fastmesh")
        if cur.ascii is None:
            return None
    elif mode != [b"BINARY"]:
        return None
    if cur.line() != [b"DATASET", b"UNSTRUCTURED_GRID"]:
        return None
    words = cur.line()
    if len(words) != 3 or words[0] != b"POINTS" or words[2] not in _FLOATS:
        return None
    n_points = _count(words[1])
    points = cur.array(_FLOATS[words[2]], 3 * n_points, 3)
    words = cur.line()
    if len(words) != 3 or words[0] != b"CELLS":
        return None
    a, b = _count(words[1]), _count(words[2])
    if version[4].split(b".")[0] >= b"5":  # OFFSETS and CONNECTIVITY arrays
        words = cur.line()
        if len(words) != 2 or words[0] != b"OFFSETS" or words[1] not in _INTS:
            return None
        offsets = cur.array(_INTS[words[1]], a)
        words = cur.line()
        if len(words) != 2 or words[0] != b"CONNECTIVITY" or words[1] not in _INTS:
            return None
        conn = cur.array(_INTS[words[1]], b)
        n_cells = a - 1
        k = b // n_cells if n_cells > 0 else 0
        if n_cells < 1 or k * n_cells != b or not np.array_equal(offsets, np.arange(0, b + 1, k)):
            return None
        cells, counted = conn.reshape(n_cells, k), False
    else:  # counts and ids: n, id_1 .. id_n per cell
        n_cells = a
        flat = cur.array(">i4", b)
        k = b // n_cells - 1 if n_cells > 0 else 0
        if n_cells < 1 or (k + 1) * n_cells != b:
            return None
        cells, counted = flat.reshape(n_cells, k + 1), True
        if not np.all(cells[:, 0] == k):
            return None
    words = cur.line()
    if words != [b"CELL_TYPES", words[1] if len(words) == 2 else b""] or _count(words[1]) != n_cells:
        return None
    types = cur.array(">i4", n_cells)
    t = int(types[0])
    if _CELLS.get(t, (None, -1))[1] != k or not np.all(types == t):
        return None
    if data[cur.pos :].strip():  # cell or point data, field data, another section: VTK's reader
        return None
    return points.reshape(n_points, 3), cells, counted, t


_HDR_CELLS = re.compile(rb"(?im)^[ \t]*CELLS[ \t]+(\d+)[ \t]+(\d+)")
_HDR_POINTS = re.compile(rb"(?im)^[ \t]*POINTS[ \t]+(\d+)[ \t]+(\w+)[ \t]*\r?$")
_HDR_VERSION = re.compile(rb"#\s*vtk DataFile Version\s+(\d+)", re.I)
_NEXT_SECTION = re.compile(
    rb"(?im)^[ \t]*(CELLS|CELL_TYPES|POINT_DATA|CELL_DATA|METADATA|FIELD|POLYGONS|LINES|VERTICES|"
    rb"TRIANGLE_STRIPS|OFFSETS|CONNECTIVITY)\b"
)


_POINT_BYTES = {b"float": 4, b"double": 8}


def _binary_cells(fh, head: bytes):
    """The CELLS header of a binary legacy file, found right after its points (POINTS n float|double:
    3 n values, big-endian), or None (another layout: the caller scans)."""
    pts = _HDR_POINTS.search(head)
    if pts is None or pts.group(2).lower() not in _POINT_BYTES or head[pts.end() : pts.end() + 1] != b"\n":
        return None
    at = pts.end() + 1 + 3 * int(pts.group(1)) * _POINT_BYTES[pts.group(2).lower()]
    fh.seek(at)
    window = fh.read(512)
    found = _HDR_CELLS.search(window)
    if found is None or window[: found.start()].strip():  # (only blank bytes before it)
        return None
    return found


def legacy_shortfall(path: str, n_cells_read: int | None) -> str | None:
    """What a legacy VTK file declares that VTK's reader did not find, which it reads without a word:
    fewer cells than CELLS declares (a cell's damaged node count swallows the cells after it), or in
    an ASCII file (up to 16 MiB) fewer point coordinates than POINTS declares (VTK fills the rest with
    zeros). n_cells_read: the unstructured grid's cells as read (None: not one)."""
    try:
        size = os.path.getsize(path)
        with open(path, "rb") as fh:
            head = fh.read(min(size, 4096))
            lines = head[:1024].splitlines()
            ascii_ = len(lines) > 2 and lines[2].strip().upper() == b"ASCII"
            found = None if ascii_ else _binary_cells(fh, head)  # (a seek past the points: no scan)
            if found is None:
                fh.seek(0)
                head = fh.read(min(size, 16 << 20))
                found = _HDR_CELLS.search(head)
    except OSError:
        return None
    if found is not None and n_cells_read is not None:
        declared = int(found.group(1))
        version = _HDR_VERSION.search(head[:256])
        if version is not None and int(version.group(1)) >= 5:
            declared -= 1  # (5.x: the offsets' count)
        if 0 <= n_cells_read < declared:
            return (
                f"it declares {declared:,} cells (CELLS) but its cell list holds {n_cells_read:,}: the file "
                "is corrupted (a cell's node count is wrong, and the cells after it were read as its nodes)"
            )
    if size <= (16 << 20) and ascii_:
        pts = _HDR_POINTS.search(head)
        if pts is not None:
            n = int(pts.group(1))
            rest = head[pts.end() :]
            nxt = _NEXT_SECTION.search(rest)
            got = len((rest[: nxt.start()] if nxt else rest).split())
            if got < 3 * n:
                return (
                    f"it declares {n:,} points (POINTS) but holds coordinates for {got // 3:,}: the file is "
                    "truncated"
                )
    return None


_UNKNOWN_KEYWORD = re.compile(r"Unrecognized keyword: (\S+)")
_MESH_SECTIONS = re.compile(
    rb"^[ \t]*(CELL_TYPES|POLYGONS|TRIANGLE_STRIPS|LINES|VERTICES)[ \t]+\d+", re.MULTILINE | re.IGNORECASE
)


def legacy_tail(path: str, text: str, out) -> str | None:
    """A legacy file whose one fault is what follows its mesh (a hand-written file's trailing
    comment or bytes; VTK's reader reads the mesh, says "Unrecognized keyword" and stops): the
    sentence saying what was ignored and where; None for any other fault, or where the unknown word
    is not after the file's last cell section, or the cells or points fall short of what it
    declares (legacy_shortfall)."""
    blocks = [b for b in re.split(r"(?=ERROR)", text) if b.startswith("ERROR")]
    words = [_UNKNOWN_KEYWORD.search(b) for b in blocks]
    if (
        not blocks
        or not all(words)
        or out is None
        or not (out.IsA("vtkUnstructuredGrid") or out.IsA("vtkPolyData"))
    ):
        return None
    if out.GetNumberOfCells() == 0 or legacy_shortfall(
        path, out.GetNumberOfCells() if out.IsA("vtkUnstructuredGrid") else None
    ):
        return None
    with open(path, "rb") as fh, mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as data:
        found = list(_MESH_SECTIONS.finditer(data))  # (mapped: no copy of a large file)
        last = found[-1] if found else None
        word = re.escape(words[0].group(1).encode("latin-1", "replace"))
        hit = re.compile(word, re.IGNORECASE).search(data, last.end()) if last is not None else None
        if hit is None:
            return None
        at = hit.start()
        line = data[:at].count(b"\n") + 1
        shown = "".join(
            c if c.isprintable() else "?" for c in data[at : at + 24].split(b"\n")[0].decode("latin-1")
        )
    return (
        f"the file goes on after its mesh with what is no legacy VTK section ('{shown}' at line {line:,}): "
        "ignored, as VTK's reader ignores it"
    )
