"""PLY files: our check of the header before any reader opens the file (the read itself:
models.mesh.read._read_ply, meshio's reader then VTK's vtkPLYReader for the files meshio refuses)."""

from __future__ import annotations

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


def _head_bytes(path: str, n: int) -> bytes:
    with open(path, "rb") as fh:
        return fh.read(n)
