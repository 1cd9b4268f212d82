"""PLY files: our check of the header before any reader opens the file (the read itself:
models.mesh.read._read_ply, meshio's reader then VTK's vtkPLYReader for the files meshio refuses)."""

from __future__ import annotations

import contextlib
import os
import re

import numpy as np

from models.errors import MeshError

_PLY_FORMATS = (b"ascii", b"binary_little_endian", b"binary_big_endian")
# other formats' first words: a file of that format under a .ply name
_OTHERS = (
    (b"OFF", "an OFF"),
    (b"solid", "an ASCII STL"),
    (b"<?xml", "an XML (VTK XML?)"),
    (b"<VTKFile", "a VTK XML"),
    (b"# vtk DataFile", "a legacy VTK"),
    (b"$MeshFormat", "a gmsh"),
)


def check_header(path: str, name: str, head: bytes) -> None:
    """Refuses, in our words, a PLY file whose header VTK's reader would only call unopenable: one
    that does not start with 'ply', names no known format, or ends (or runs past 64 KiB) before its
    end_header line."""
    if not head.startswith(b"ply"):
        shown = "".join(c if c.isprintable() else "?" for c in head[:8].decode("latin-1"))
        got = "a byte-order mark" if head.startswith(b"\xef\xbb\xbf") else f"'{shown}'"
        other = next((f for sig, f in _OTHERS if head.lstrip().startswith(sig)), None)
        hint = f": it looks like {other} file (give it that format's extension)" if other else ""
        raise MeshError(
            f"cannot read {name} as PLY: a PLY file starts with 'ply', this one with {got} (byte 0){hint}"
        )
    window = head if len(head) >= 65536 else _head_bytes(path, 65536)
    end = window.find(b"end_header")
    if end < 0:
        where = "the file ends" if len(window) < 65536 else "its first 64 KiB end"
        raise MeshError(f"cannot read {name} as PLY: {where} before its header does (no end_header line)")
    fmt = next(
        (w.split()[1] for w in window[:end].splitlines() if w.startswith(b"format") and len(w.split()) > 1),
        b"",
    )
    if fmt not in _PLY_FORMATS:
        raise MeshError(
            f"cannot read {name} as PLY: its format line names "
            + (f"'{fmt.decode('latin-1')}'" if fmt else "no format")
            + ", not ascii, binary_little_endian or binary_big_endian"
        )


# PLY's scalar types as numpy's
_SCALARS = {
    b"char": "i1", b"int8": "i1", b"uchar": "u1", b"uint8": "u1", b"short": "i2", b"int16": "i2",
    b"ushort": "u2", b"uint16": "u2", b"int": "i4", b"int32": "i4", b"uint": "u4", b"uint32": "u4",
    b"float": "f4", b"float32": "f4", b"double": "f8", b"float64": "f8",
}  # fmt: skip
_ELEMENT = re.compile(rb"^element\s+(\S+)\s+(\d+)\s*$")
_PROPERTY = re.compile(rb"^property\s+(\S+)\s+(\S+)\s*$")


@contextlib.contextmanager
def planar_copy(path: str):
    """A PLY whose vertices have x and y but no z (meshio's writer given 2D points; meshio's reader
    and VTK's refuse it): yields a copy (in a temporary folder, under its own name) with a z
    property of 0 after y, which the readers read as a planar mesh; None for any other file. Refuses
    such a file whose layout the copy cannot be made of (the vertices not the first element, or
    not of scalar properties only; in ASCII, x and y not their first two)."""
    name = os.path.basename(path)
    raw = _head_bytes(path, 65536)  # (the whole file only where it is such a file)
    end = raw.find(b"end_header")
    body = raw.find(b"\n", end) + 1 if end >= 0 else 0
    lines = [ln.strip() for ln in raw[:end].splitlines()] if end >= 0 else []
    elements = [i for i, ln in enumerate(lines) if ln.startswith(b"element")]
    first = next((i for i in elements if lines[i].split()[1:2] == [b"vertex"]), None)
    fmt = next((ln.split()[1] for ln in lines if ln.startswith(b"format") and len(ln.split()) > 1), b"")
    if first is None:
        yield None
        return
    vertex = _ELEMENT.match(lines[first])
    if vertex is None:
        yield None
        return
    props = []
    for ln in lines[first + 1 :]:  # (the vertex element's property lines: a few)
        if not ln.startswith(b"property"):
            break
        props.append(_PROPERTY.match(ln))
    names = [p.group(2) if p else None for p in props]
    if not body or b"z" in names or b"x" not in names or b"y" not in names:
        yield None
        return
    ascii_ok = fmt == b"ascii" and names[:2] == [b"x", b"y"]
    simple = first == elements[0] and all(p and p.group(1) in _SCALARS for p in props)
    if not simple or (fmt == b"ascii" and not ascii_ok):
        raise MeshError(
            f"cannot read {name} as PLY: its vertices have no z property (a PLY needs x, y and z): "
            "write its points with a z coordinate (0 for a planar mesh)"
        )
    with open(path, "rb") as fh:
        raw = fh.read()
    n, at_y = int(vertex.group(2)), first + 1 + names.index(b"y")
    header = b"\n".join(
        [*raw[:end].splitlines()[: at_y + 1], b"property " + props[at_y - first - 1].group(1) + b" z"]
    )
    header += b"\n" + b"\n".join(raw[:end].splitlines()[at_y + 1 :]) + b"\n" + raw[end:body]
    if fmt == b"ascii":
        ends = np.flatnonzero(np.frombuffer(raw, np.uint8, offset=body) == 10)
        stop = body + (int(ends[n - 1]) + 1 if n and len(ends) >= n else len(raw) - body)
        rows = re.sub(rb"(?m)^([ \t]*\S+[ \t]+\S+)", rb"\1 0", raw[body:stop])
        data = rows + raw[stop:]
    else:
        order = "<" if fmt == b"binary_little_endian" else ">"
        dtype = np.dtype([(f"p{i}", order + _SCALARS[p.group(1)]) for i, p in enumerate(props)])
        if len(raw) - body < n * dtype.itemsize:
            yield None  # (cut short: the readers say so)
            return
        old = np.frombuffer(raw, dtype, count=n, offset=body)
        k = names.index(b"y") + 1
        fields = [*dtype.descr[:k], ("z", dtype.descr[k - 1][1]), *dtype.descr[k:]]
        new = np.zeros(n, np.dtype(fields))
        for field in dtype.names:  # (the vertex properties: a few)
            new[field] = old[field]
        data = new.tobytes() + raw[body + n * dtype.itemsize :]
    import shutil
    import tempfile

    folder = tempfile.mkdtemp(prefix="magnet-ply-")
    try:
        copy = os.path.join(folder, name)
        with open(copy, "wb") as out:
            out.write(header + data)
        yield copy
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def _head_bytes(path: str, n: int) -> bytes:
    with open(path, "rb") as fh:
        return fh.read(n)
