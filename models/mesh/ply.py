"""PLY files: our check of the header before any reader opens the file, and the read (meshio's
reader, which keeps a PLY's doubles; VTK's vtkPLYReader, ParaView's, for the files meshio refuses:
big-endian, extra face properties, colours in odd places)."""

from __future__ import annotations

import os
from typing import TYPE_CHECKING

from models.errors import MeshError

if TYPE_CHECKING:
    from models.mesh.container import Mesh

_PLY_FORMATS = (b"ascii", b"binary_little_endian", b"binary_big_endian")


def check_header(path: str, name: str, head: bytes) -> None:
    """Refuses, in our words, a PLY file whose header VTK's reader would only call unopenable: one
    that does not start with 'ply', names no known format, or ends (or runs past 64 KiB) before its
    end_header line."""
    if not head.startswith(b"ply"):
        shown = "".join(c if c.isprintable() else "?" for c in head[:8].decode("latin-1"))
        got = "a byte-order mark" if head.startswith(b"\xef\xbb\xbf") else f"'{shown}'"
        raise MeshError(
            f"cannot read {name} as PLY: a PLY file starts with 'ply', this one with {got} (byte 0)"
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


def _head_bytes(path: str, n: int) -> bytes:
    with open(path, "rb") as fh:
        return fh.read(n)


def read_ply(path: str, physical_tag, weld, native: bool, fmt: str) -> Mesh:
    """A PLY file by meshio's reader (its points as written: VTK's vtkPLYReader makes doubles
    float32); one that meshio refuses (big-endian, extra face properties, colours in odd places) by
    VTK's reader, ParaView's, which is native code: with native=False NativeReaderNeeded (the caller
    reads it in the sandbox). A file VTK cannot read either keeps meshio's refusal."""
    from models.mesh import read
    from models.mesh.meshio_files import read_meshio

    try:
        m = read_meshio(path, "ply")
    except MeshError as refused:
        if not native:
            raise read.NativeReaderNeeded(f"{os.path.basename(path)} needs VTK's PLY reader") from None
        from models.mesh.vtk_readers import read_vtk

        try:
            return read_vtk(path, "ply", physical_tag=physical_tag, weld=weld, fmt=fmt)
        except MeshError as exc:
            if "cannot be opened" in str(exc) or "corrupted" in str(exc):
                raise refused from None
            raise  # (VTK read it: what is wrong with the mesh, a curved surface say)
    return read.mesh_from_meshio(m, physical_tag=physical_tag, weld=weld, owned=True)
