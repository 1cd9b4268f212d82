"""A file's bytes for our pure-Python readers (vtu, xml_grid, legacy), mapped instead of read.

Reading a file copies it into fresh memory, and on the virtual machines we run on every fresh 4 KiB
page costs a fault of about 2 microseconds: an 11 MB VTU took 6 ms to read that way, more than
VTK's whole read of it once warm. A mapping of the file costs a fault per 16 pages of the page cache
(0.4 ms for the same file), and the arrays are views of it until copied.

Arrays taken from a mapping must be copied before the read returns: a file cut short while it is
mapped ends the process on the next access of a page past its end (SIGBUS). So the readers copy
what the Mesh keeps (they did already: the connectivity is copied to be writable, points to
float64) and leave nothing else of the mapping in what they return; tests/test_read_mapped.py cuts
the file after the read and touches every array of the Mesh.
"""

from __future__ import annotations

import mmap
import os

import numpy as np


class Mapped(mmap.mmap):
    """A file mapped read-only, with the bytes methods the scanners use on it (find, rfind, slices,
    memoryview: those of mmap; index and startswith added)."""

    def startswith(self, prefix: bytes, start: int = 0) -> bool:
        return self[start : start + len(prefix)] == prefix

    def index(self, sub: bytes, start: int = 0, end: int | None = None) -> int:
        at = self.find(sub, start, len(self) if end is None else end)
        if at < 0:
            raise ValueError("subsection not found")
        return at


def file_bytes(path: str | os.PathLike) -> bytes | Mapped:
    """The file's bytes: mapped (Mapped) where the file can be mapped, else read (an empty file,
    a pipe: bytes)."""
    with open(os.fspath(path), "rb") as fh:
        try:
            if os.fstat(fh.fileno()).st_size > 0:
                return Mapped(fh.fileno(), 0, access=mmap.ACCESS_READ)
        except (OSError, ValueError):
            pass
        return fh.read()


def owned(a: np.ndarray) -> np.ndarray:
    """A copy of `a` where it is a view of a mapped file, else `a` itself: what may be such a view
    leaves the reader through here (the module's note)."""
    base = a
    while True:
        if isinstance(base, np.ndarray) and base.base is not None:
            base = base.base
        elif isinstance(base, memoryview):
            base = base.obj
        else:
            break
    return np.array(a) if isinstance(base, mmap.mmap) else a
