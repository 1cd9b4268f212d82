"""Truncated container files, told before a native reader opens them.

Exodus II, CGNS, VTKHDF, MED, Fluent's .cas.h5 and XDMF's heavy data are HDF5 or netCDF files.
Cut short (an upload that stopped, a copy off a full disk), their readers fail with "cannot be
opened" or crash. Both containers say in their header how long the file is:
- HDF5: the superblock's end-of-file address (versions 0 to 3);
- netCDF classic (CDF-1, CDF-2 64-bit offsets, CDF-5): each variable's begin offset and size, and
  the number of records.
`truncated(path, head)` compares that with the file's size and returns a sentence, or None for a
file that is whole or that it cannot judge (another container, an unusual header: the reader then
speaks). Only the header is read.
"""

from __future__ import annotations

import os
import struct

HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"


def truncated(path: str, head: bytes) -> str | None:
    try:
        size = os.path.getsize(path)
        if head.startswith(HDF5_SIGNATURE):
            need = _hdf5_end(head)
        elif head[:3] == b"CDF" and head[3:4] in (b"\x01", b"\x02", b"\x05"):
            with open(path, "rb") as fh:
                need = _netcdf_end(fh, size)
        else:
            return None
    except (OSError, struct.error, ValueError, IndexError):
        return None
    if need is None or size >= need:
        return None
    return (
        f"the file is truncated: it holds {size:,} bytes of the {need:,} its header declares "
        "(copy or upload it again)"
    )


def _hdf5_end(head: bytes) -> int | None:
    version = head[8]
    if version in (0, 1):
        offsets = head[13]
        at = 24 + (4 if version == 1 else 0)  # base, free-space, end of file (after the K values)
        at += 2 * offsets
    elif version in (2, 3):
        offsets = head[9]
        at = 12 + 2 * offsets  # base, superblock extension, end of file
    else:
        return None
    if offsets not in (4, 8):
        return None
    base = int.from_bytes(head[at - 2 * offsets : at - offsets], "little") if version in (0, 1) else 0
    end = int.from_bytes(head[at : at + offsets], "little")
    if end == (1 << (8 * offsets)) - 1:  # "undefined address"
        return None
    return (base if base != (1 << (8 * offsets)) - 1 else 0) + end


class _Header:
    def __init__(self, fh, version: int, size: int):
        self.fh, self.big = fh, version == 5
        self.limit = min(size, 64 << 20)  # (a header is small; a count beyond the file is a lie)

    def read(self, n: int) -> bytes:
        b = self.fh.read(n)
        if len(b) < n:
            raise ValueError("short header")
        return b

    def int32(self) -> int:
        return struct.unpack(">i", self.read(4))[0]

    def count(self) -> int:
        n = struct.unpack(">q", self.read(8))[0] if self.big else struct.unpack(">i", self.read(4))[0]
        if n < 0 or n > self.limit:
            raise ValueError("count out of range")
        return n

    def name(self) -> None:
        n = self.count()
        self.read((n + 3) // 4 * 4)


_TYPE_SIZE = {1: 1, 2: 1, 3: 2, 4: 4, 5: 4, 6: 8, 7: 1, 8: 2, 9: 4, 10: 8, 11: 8}


def _attributes(h: _Header) -> None:
    tag, n = h.int32(), h.count()
    if tag == 0:
        return
    for _ in range(n):
        h.name()
        kind = h.int32()
        values = h.count()
        h.read((values * _TYPE_SIZE[kind] + 3) // 4 * 4)


def _netcdf_end(fh, size: int) -> int | None:
    version = fh.read(4)[3]
    h = _Header(fh, version, size)
    numrecs = struct.unpack(">q", h.read(8))[0] if version == 5 else struct.unpack(">I", h.read(4))[0]
    if numrecs in (0xFFFFFFFF, -1):  # streaming: the number of records is not in the header
        numrecs = 0
    tag, n = h.int32(), h.count()
    lengths = []
    for _ in range(n if tag else 0):
        h.name()
        lengths.append(h.count())
    _attributes(h)
    tag, n = h.int32(), h.count()
    end, record_begin, record_size, records = 0, None, 0, 0
    for _ in range(n if tag else 0):
        h.name()
        dims = [h.count() for _ in range(h.count())]
        _attributes(h)
        h.int32()  # its type
        vsize = h.count() if version == 5 else struct.unpack(">I", h.read(4))[0]
        begin = struct.unpack(">q", h.read(8))[0] if version in (2, 5) else struct.unpack(">i", h.read(4))[0]
        if dims and dims[0] < len(lengths) and lengths[dims[0]] == 0:  # a record variable
            record_begin = begin if record_begin is None else min(record_begin, begin)
            record_size += vsize
            records += 1
        else:
            end = max(end, begin + vsize)
    if record_begin is not None and numrecs and records > 1:  # (one record variable: its records
        # are not padded to 4 bytes, and its vsize is)
        end = max(end, record_begin + numrecs * record_size)
    return end - 8 if end > 8 else None  # (slack: the last variable's padding may be left out)
