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

    def name(self) -> str:
        n = self.count()
        return self.read((n + 3) // 4 * 4)[:n].decode("utf-8", "replace")


_TYPE_SIZE = {1: 1, 2: 1, 3: 2, 4: 4, 5: 4, 6: 8, 7: 1, 8: 2, 9: 4, 10: 8, 11: 8}


def _attributes(h: _Header) -> dict:
    """The attributes of a header list: {name: text} for text ones (NC_CHAR), {name: None} others."""
    out = {}
    tag, n = h.int32(), h.count()
    if tag == 0:
        return out
    for _ in range(n):
        name = h.name()
        kind = h.int32()
        values = h.count()
        raw = h.read((values * _TYPE_SIZE[kind] + 3) // 4 * 4)
        out[name] = raw[:values].decode("utf-8", "replace").rstrip("\0 ") if kind == 2 else None
    return out


def _netcdf_header(fh, size: int) -> dict:
    """A netCDF classic header: {"version", "numrecs", "dims": [(name, length)], "vars": [(name,
    dim ids, attributes, vsize, begin, type)]} (ValueError, struct.error where it cannot be read)."""
    version = fh.read(4)[3]
    h = _Header(fh, version, size)
    numrecs = struct.unpack(">q", h.read(8))[0] if version == 5 else struct.unpack(">I", h.read(4))[0]
    if numrecs in (0xFFFFFFFF, -1):  # streaming: the number of records is not in the header
        numrecs = 0
    tag, n = h.int32(), h.count()
    dims = [(h.name(), h.count()) for _ in range(n if tag else 0)]
    _attributes(h)
    tag, n = h.int32(), h.count()
    variables = []
    for _ in range(n if tag else 0):
        name = h.name()
        ids = [h.count() for _ in range(h.count())]
        attrs = _attributes(h)
        kind = h.int32()
        vsize = h.count() if version == 5 else struct.unpack(">I", h.read(4))[0]
        begin = struct.unpack(">q", h.read(8))[0] if version in (2, 5) else struct.unpack(">i", h.read(4))[0]
        variables.append((name, ids, attrs, vsize, begin, kind))
    return {"version": version, "numrecs": numrecs, "dims": dims, "vars": variables}


def _netcdf_end(fh, size: int) -> int | None:
    head = _netcdf_header(fh, size)
    lengths = [n for _, n in head["dims"]]
    end, record_begin, record_size, records = 0, None, 0, 0
    for _, dims, _, vsize, begin, _ in head["vars"]:
        if dims and dims[0] < len(lengths) and lengths[dims[0]] == 0:  # a record variable
            record_begin = begin if record_begin is None else min(record_begin, begin)
            record_size += vsize
            records += 1
        else:
            end = max(end, begin + vsize)
    if record_begin is not None and head["numrecs"] and records > 1:  # (one record variable: its
        # records are not padded to 4 bytes, and its vsize is)
        end = max(end, record_begin + head["numrecs"] * record_size)
    return end - 8 if end > 8 else None  # (slack: the last variable's padding may be left out)


# Exodus II element types by their first three letters (as VTK's reader tells them) -> the node
# counts a block of that type may have
_EXODUS_NODES = {
    "HEX": {8, 9, 20, 27},
    "TET": {4, 8, 10, 11, 14, 15},
    "WED": {6, 15, 18},
    "PYR": {5, 13, 14, 18, 19},
    "TRI": {3, 4, 6, 7},
    "QUA": {4, 5, 8, 9},
    "SHE": {2, 3, 4, 5, 8, 9},
    "BAR": {2, 3},
    "BEA": {2, 3},
    "TRU": {2, 3},
    "EDG": {2, 3},
    "SPH": {1},
    "CIR": {1},
    "POI": {1},
    "NSI": None,  # NSIDED, NFACED: nodes per element vary
    "NFA": None,
    "SUP": None,
}


def exodus_fault(path: str) -> str | None:
    """What is wrong in a netCDF classic Exodus II file's header, in words, where VTK's reader would
    crash or say nothing useful: an element block whose connectivity variable is missing, whose
    element type Exodus II does not have, or whose nodes per element do not fit its type; None
    where nothing is found (or the file is netCDF-4 / HDF5: not read here)."""
    try:
        size = os.path.getsize(path)
        with open(path, "rb") as fh:
            if fh.read(4)[:3] != b"CDF":
                return None
            fh.seek(0)
            head = _netcdf_header(fh, size)
    except (OSError, struct.error, ValueError, IndexError, KeyError):
        return None
    dims = dict(head["dims"])
    variables = {name: (attrs, begin, vsize, kind) for name, _, attrs, vsize, begin, kind in head["vars"]}
    for i in range(1, dims.get("num_el_blk", 0) + 1):
        n_el = dims.get(f"num_el_in_blk{i}", 0)
        if n_el == 0 or f"facconn{i}" in variables:
            continue  # (an empty block need not have a connectivity; an NFACED block lists faces)
        if f"connect{i}" not in variables:
            return f"element block {i} ({n_el:,} elements) has no connectivity (no variable connect{i})"
        attrs, _, vsize, vkind = variables[f"connect{i}"]
        elem = (attrs.get("elem_type") or "").strip()
        nodes = _EXODUS_NODES.get(elem[:3].upper(), "unknown")
        if nodes == "unknown":
            return f"element block {i} has element type {elem[:32]!r}, which is not an Exodus II element type"
        per = dims.get(f"num_nod_per_el{i}")
        if elem[:3].upper() == "NSI" and f"ebepecnt{i}" in variables and per is not None:
            total = _int_sum(path, *variables[f"ebepecnt{i}"][1:])  # nodes per element, summed
            if total is not None and total != per:
                return (
                    f"element block {i} (NSIDED) gives its elements {total:,} nodes in all (ebepecnt{i}), "
                    f"but its connectivity holds {per:,}"
                )
        if nodes is not None and per and vkind in _TYPE_SIZE and vsize // _TYPE_SIZE[vkind] < n_el * per:
            return (
                f"element block {i}'s connectivity (connect{i}) holds {vsize // _TYPE_SIZE[vkind]:,} node "
                f"ids, fewer than its {n_el:,} elements of {per} nodes need ({n_el * per:,})"
            )
        if nodes is not None and per is not None and per not in nodes:
            return (
                f"element block {i} is of type {elem[:32]!r} with {per} nodes per element, which that type "
                f"does not have ({', '.join(map(str, sorted(nodes)))})"
            )
    return None


def _int_sum(path: str, begin: int, vsize: int, kind: int) -> int | None:
    """The sum of a netCDF classic integer variable (NC_INT or NC_INT64, big-endian), or None."""
    dtype = {4: ">i4", 10: ">i8"}.get(kind)
    if dtype is None or vsize > (64 << 20):
        return None
    import numpy as np

    with open(path, "rb") as fh:
        fh.seek(begin)
        raw = fh.read(vsize)
    n = len(raw) // np.dtype(dtype).itemsize
    return int(np.frombuffer(raw[: n * np.dtype(dtype).itemsize], dtype=dtype).sum())
