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

Also here: `exodus_fault` / `exodus_fault_hdf5` (an Exodus II header's element blocks, netCDF
classic in pure Python, netCDF-4 with h5py) and `hdf5_damage` (the first HDF5 object whose metadata
h5py cannot read, with its byte address: after a native reader failed, crashed, or read an HDF5
container, since VTK's CGNS reader leaves a zone it cannot read out without a word).
"""

from __future__ import annotations

import os
import struct

import numpy as np

HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"


def is_hdf5(path: str) -> bool:
    """The file starts with HDF5's signature (False where it cannot be opened)."""
    try:
        with open(path, "rb") as fh:
            return fh.read(8) == HDF5_SIGNATURE
    except OSError:
        return False


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
    if need > 16 * size + (1 << 20):  # a damaged header, more likely than a file cut to a sliver
        return (
            f"its header declares {need:,} bytes, far more than the {size:,} it holds: the header is "
            "damaged, or the file was cut short (copy or upload it again)"
        )
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
    crash or say nothing useful (_blocks_fault); None where nothing is found (or the file is
    netCDF-4 / HDF5: exodus_fault_hdf5, in the reading child). Pure Python: safe in any process."""
    try:
        size = os.path.getsize(path)
        with open(path, "rb") as fh:
            if fh.read(4)[:3] != b"CDF":
                return None
            fh.seek(0)
            head = _netcdf_header(fh, size)
    except (OSError, struct.error, ValueError, IndexError, KeyError):
        return None
    variables = {
        name: (attrs, vsize // _TYPE_SIZE[kind] if kind in _TYPE_SIZE else None)
        for name, _, attrs, vsize, _, kind in head["vars"]
    }
    where = {name: (begin, vsize, kind) for name, _, _, vsize, begin, kind in head["vars"]}
    return _blocks_fault(dict(head["dims"]), variables, lambda name: _int_values(path, *where[name]))


def exodus_fault_hdf5(path: str) -> str | None:
    """exodus_fault for a netCDF-4 (HDF5) Exodus II file, read with h5py: its dimensions are the
    root's dimension scales, its variables the other datasets. Call it in the reading child: the
    HDF5 library reads the file. None where nothing is found or h5py cannot open it (VTK's reader
    then speaks)."""
    try:
        import h5py

        with h5py.File(path, "r") as f:
            dims, variables, found = {}, {}, {}
            for name in f.keys():
                try:
                    item = f[name]
                    item.attrs.get("CLASS")
                except Exception:  # noqa: BLE001  (an object whose header is damaged: VTK's reader
                    return None  # may not need it; where it fails, hdf5_damage names the object)
                if not isinstance(item, h5py.Dataset) or not item.shape:
                    continue
                if item.attrs.get("CLASS") == b"DIMENSION_SCALE":
                    dims[name] = int(item.shape[0])
                    if not str(item.attrs.get("NAME", b"").decode("latin-1")).startswith("This is a netCDF"):
                        variables[name] = ({}, int(item.size))
                    continue
                elem = item.attrs.get("elem_type")
                if isinstance(elem, bytes | np.bytes_):
                    elem = bytes(elem).decode("utf-8", "replace")
                attrs = {"elem_type": elem.rstrip("\0 ")} if isinstance(elem, str) else {}
                variables[name] = (attrs, int(item.size))
                found[name] = item
            return _blocks_fault(dims, variables, lambda name: _dataset_values(found[name]))
    except Exception:  # noqa: BLE001  (a file h5py cannot read: VTK's reader words it)
        return None


def _dataset_values(item) -> np.ndarray | None:
    """The values of an integer HDF5 dataset of at most 8 M values, or None."""
    if item.dtype.kind not in "iu" or item.size > (8 << 20):
        return None
    return np.asarray(item[()]).reshape(-1)  # (its own integer type: no copy)


def zero_based(n_nodes: int) -> str:
    """What is wrong with an Exodus II file whose connectivity numbers the nodes from 0."""
    return (
        f"its element connectivity numbers the nodes from 0, but Exodus II numbers them from 1 "
        f"(1..{n_nodes:,}): the file was written 0-based (add 1 to every node id of its connect arrays)"
    )


def _blocks_fault(dims: dict, variables: dict, int_values) -> str | None:
    """An Exodus II header's element blocks checked: a block whose connectivity variable is missing,
    whose element type Exodus II does not have, whose nodes per element do not fit its type, whose
    connectivity holds fewer ids than its elements need, or (NSIDED) whose nodes per element add up
    to another count than its connectivity's, or whose node ids lie outside 1..num_nodes (VTK's
    reader indexes its points with them: a 0 read past the array and crashed it, or not, as the
    heap lay); None where nothing is wrong. dims {name: length}; variables {name: (attributes
    {name: text}, number of values or None)}; int_values(name): an integer variable's values, or
    None."""
    for i in range(1, dims.get("num_el_blk", 0) + 1):
        n_el = dims.get(f"num_el_in_blk{i}", 0)
        if n_el == 0 or f"facconn{i}" in variables:
            continue  # (an empty block need not have a connectivity; an NFACED block lists faces)
        if f"connect{i}" not in variables:
            return f"element block {i} ({n_el:,} elements) has no connectivity (no variable connect{i})"
        attrs, held = variables[f"connect{i}"]
        elem = (attrs.get("elem_type") or "").strip()
        nodes = _EXODUS_NODES.get(elem[:3].upper(), "unknown")
        if nodes == "unknown":
            return f"element block {i} has element type {elem[:32]!r}, which is not an Exodus II element type"
        per = dims.get(f"num_nod_per_el{i}")
        if elem[:3].upper() == "NSI" and f"ebepecnt{i}" in variables and per is not None:
            counts = int_values(f"ebepecnt{i}")  # nodes per element
            total = None if counts is None else int(counts.sum())
            if total is not None and total != per:
                return (
                    f"element block {i} (NSIDED) gives its elements {total:,} nodes in all (ebepecnt{i}), "
                    f"but its connectivity holds {per:,}"
                )
        if nodes is not None and per and held is not None and held < n_el * per:
            return (
                f"element block {i}'s connectivity (connect{i}) holds {held:,} node "
                f"ids, fewer than its {n_el:,} elements of {per} nodes need ({n_el * per:,})"
            )
        if nodes is not None and per is not None and per not in nodes:
            return (
                f"element block {i} is of type {elem[:32]!r} with {per} nodes per element, which that type "
                f"does not have ({', '.join(map(str, sorted(nodes)))})"
            )
    return _ids_fault(dims, variables, int_values)


def _ids_fault(dims: dict, variables: dict, int_values) -> str | None:
    """_blocks_fault's node ids: every block's connectivity within 1..num_nodes."""
    n = dims.get("num_nodes")
    if not n:
        return None
    blocks = []
    for i in range(1, dims.get("num_el_blk", 0) + 1):  # a loop over element blocks
        if f"connect{i}" in variables and f"facconn{i}" not in variables:
            ids = int_values(f"connect{i}")
            if ids is None:
                return None  # (too large, or not integers: VTK's reader and the checks after it speak)
            blocks.append((i, ids))
    if not blocks:
        return None
    lo = [int(ids.min(initial=1)) for _, ids in blocks]
    hi = [int(ids.max(initial=1)) for _, ids in blocks]
    if min(lo) >= 1 and max(hi) <= n:
        return None
    zeros = sum(int(np.count_nonzero(ids == 0)) for _, ids in blocks) if min(lo) == 0 else 0
    if min(lo) == 0 and max(hi) == n - 1 and zeros <= 64:
        return zero_based(n)  # (a block of zeros, unwritten data, is no numbering)
    for i, ids in blocks:  # a loop over element blocks
        bad = (ids < 1) | (ids > n)
        if bad.any():
            return (
                f"element block {i}'s connectivity (connect{i}) holds node id {int(ids[bad][0]):,}, outside "
                f"1..{n:,} (the nodes the file defines)"
            )
    return None


def _int_values(path: str, begin: int, vsize: int, kind: int) -> np.ndarray | None:
    """The values of a netCDF classic integer variable (NC_INT or NC_INT64, big-endian) of at most
    64 MiB, or None."""
    dtype = {4: ">i4", 10: ">i8"}.get(kind)
    if dtype is None or vsize > (64 << 20):
        return None
    with open(path, "rb") as fh:
        fh.seek(begin)
        raw = fh.read(vsize)
    n = len(raw) // np.dtype(dtype).itemsize
    return np.frombuffer(raw[: n * np.dtype(dtype).itemsize], dtype=dtype).astype(np.int64)


# h5py's error text -> what is wrong with an object's metadata, in our words
_HDF5_FAULTS = (
    ("checksum", "its metadata fails its checksum"),
    ("bad object header", "its object header is not valid"),
    ("signature", "its metadata is not valid (a wrong signature)"),
    ("dataset size", "its size is not valid"),
    ("exponent", "its data type is not valid"),
    ("datatype", "its data type is not valid"),
    ("dataspace", "its shape is not valid"),
    ("bad", "its metadata is not valid"),
    ("address", "it points outside the file"),
    ("eof", "it points past the end of the file"),
    ("truncat", "it points past the end of the file"),
)


def _hdf5_reason(exc: BaseException) -> str:
    low = str(exc).lower()
    return next((said for key, said in _HDF5_FAULTS if key in low), "its metadata cannot be read")


def hdf5_damage(path: str, limit: int = 20_000) -> str | None:
    """Where an HDF5 file's metadata is damaged (a byte flipped in a header, a checksum that fails),
    in words: the first object (a netCDF variable or dimension, a CGNS node, a group) whose header,
    attributes or list of members h5py cannot read, with its byte address; None where the metadata
    of every object (up to `limit`) reads, or h5py is missing. Data are not read. Call it in the
    reading child, after a native reader failed on the file: the HDF5 library reads it."""
    try:
        import h5py
    except ImportError:
        return None
    try:
        f = h5py.File(path, "r")
    except Exception as exc:  # noqa: BLE001  (h5py's text is never shown: _hdf5_reason words it)
        return f"its HDF5 superblock or root group cannot be read: {_hdf5_reason(exc)}"
    with f:
        queue, seen = [("/", f)], 0
        while queue and seen < limit:
            where, group = queue.pop(0)
            try:
                names = list(group.keys())
            except Exception as exc:  # noqa: BLE001
                what = "root group" if where == "/" else f"group {where!r}"
                return f"the HDF5 {what}'s list of members is damaged: {_hdf5_reason(exc)}"
            for name in names:
                seen += 1
                full = where.rstrip("/") + "/" + name
                try:
                    item = group[name]
                    dict(item.attrs)
                    if isinstance(item, h5py.Dataset):
                        item.shape, item.dtype  # noqa: B018  (their headers read)
                except Exception as exc:  # noqa: BLE001
                    return f"the HDF5 object {full[:80]!r}{_address(group, name)} is damaged: {_hdf5_reason(exc)}"
                if isinstance(item, h5py.Group):
                    queue.append((full, item))
    return None


def _address(group, name: str) -> str:
    """' (at byte N)': where a hard link points, or '' where that cannot be told."""
    try:
        info = group.id.links.get_info(name.encode())
        return f" (at byte {int(info.u):,})" if info.type == 0 else ""
    except Exception:  # noqa: BLE001
        return ""
