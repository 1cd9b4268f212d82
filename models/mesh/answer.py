"""The reading child's answer in its memfd: raw arrays and a JSON header, never a pickle.

Lent arrays (`dump(..., lend=True)`, where the zygote's probe found process_vm_readv allowed:
models.mesh.zygote): the memfd holds the header only, each array named by its address and length
in the child, which waits until the caller has copied them (`load(fd, pid=...)`: one
process_vm_readv into new arrays of the caller; the child's pid is the zygote's word, never the
child's). No shared-memory pages are written or mapped: the memfd's 4 KiB shmem pages made a
10 MB answer cost about 6 ms, a copy from the child's heap (2 MiB pages) costs about 1 ms. A child
can name only its own memory; an address it does not map fails the copy; the sizes are bounded by
the read's memory limit before anything is allocated.

The caller trusts nothing the child wrote: a child taken over by a reader exploit could write any
bytes, and unpickling them would run its code in the caller. So the answer is data only:

    b"MAGNETR1", the header's length (little-endian uint64), the header (UTF-8 JSON), then every
    numpy array raw, each at a 64-byte aligned offset, in the order of the header's table.

The header: {"kind": "ok", "arrays": [[dtype, shape, offset, nbytes], ...], "value": tree} or
{"kind": "error", "class": one of _ERRORS' names, "message": str} or {"kind": "memory"}. In the
tree, str, int, float, bool and None are themselves; everything else is a list led by a tag:
["a", i] the i-th array (an array met twice is one entry: the same object comes back), ["l", ...]
a list, ["t", ...] a tuple, ["d", [key, value], ...] a dict (any keys the tree can hold), ["s",
dtype, value] a numpy scalar, ["Mesh", {field: tree}], ["Faces", {field: tree}] and ["Deferred",
{field: tree}] the dataclasses a read returns (a Deferred: a builder's arguments, which the caller
checks and builds: models.mesh.deferred).

`load` checks everything before building anything: the magic, the header's bounds, JSON, every
array's dtype (a whitelist of plain numbers: no objects), shape, offset and length inside the
memfd without overlap, the tree's tags, depth and field names, and a Mesh's invariants (dtypes and
shapes of its fields, CSR offsets from 0 to the end, point ids in range, the cached faces' ids in
range). Any inconsistency raises Corrupt, which the caller words as a crashed reader. First of all
the memfd is sealed (no write, no resize, by anyone: the bytes checked stay the bytes used; a
writable mapping still open elsewhere is refused). The arrays are np.frombuffer views of the
caller's private mapping of the memfd (populated read-only, then made writable: copy-on-write per
page an edit touches, never a write to the memfd): no copy.
"""

from __future__ import annotations

import ctypes
import dataclasses
import json
import mmap
import os

import numpy as np

from models.mesh.invariants import csr_sizes, ids, in_range

MAGIC = b"MAGNETR1"
ALIGN = 64
_DTYPES = frozenset(
    "bool int8 int16 int32 int64 uint8 uint16 uint32 uint64 float16 float32 float64 complex64 complex128".split()
)
# an array's dtype in the table: its code with the byte order ("<i8", ">f4", "|u1"); a reader may
# hand back a file's big-endian values as they are, and the caller swaps them in place (_native)
_CODES = frozenset(np.dtype(n).newbyteorder(o).str for n in _DTYPES for o in "<>")
_MAX_HEADER = 64 << 20
_MAX_DEPTH = 32
_MAX_NDIM = 8


class Corrupt(Exception):
    """The memfd does not hold a well-formed answer (the child crashed mid-write, or lies)."""


# ---------------------------------------------------------------- the child's side


def dump(answer: tuple, fd: int, lend: bool = False) -> list:
    """("ok", value) | ("error", class name, message) | ("memory",) into the memfd `fd`.
    lend: the header only, each array named by its address in this process (the caller copies
    them out with process_vm_readv: `load(fd, pid=...)`); the arrays returned must stay alive
    until it has (the child waits for its word)."""
    arrays: list[np.ndarray] = []
    if answer[0] == "ok":
        seen: dict[int, int] = {}
        head = {"kind": "ok", "value": _encode(answer[1], arrays, seen, 0)}
    elif answer[0] == "error":
        head = {"kind": "error", "class": str(answer[1]), "message": str(answer[2])}
    else:
        head = {"kind": "memory"}
    if lend and arrays:
        head["lent"] = True
        table = [[a.dtype.str, list(a.shape), a.ctypes.data, a.nbytes] for a in arrays]
        body = json.dumps({**head, "arrays": table}).encode()
        _pwrite(fd, MAGIC + len(body).to_bytes(8, "little") + body, 0)  # (the memfd grows to it)
        return arrays
    table = []
    # the table's offsets depend on the header's length, which depends on the offsets: lay the
    # arrays out after a header size bound, padded (JSON allows trailing whitespace)
    sizes = [a.nbytes for a in arrays]
    body = json.dumps({**head, "arrays": [[a.dtype.str, list(a.shape), 0, 0] for a in arrays]}).encode()
    start = _up(16 + len(body) + 24 * len(arrays) + 64)
    pos = start
    for a, n in zip(arrays, sizes, strict=True):
        table.append([a.dtype.str, list(a.shape), pos, n])
        pos = _up(pos + n)
    body = json.dumps({**head, "arrays": table}).encode()
    if 16 + len(body) > start:  # cannot happen (the bound above is generous): refuse rather than overlap
        raise ValueError("answer header overflow")
    os.ftruncate(fd, max(pos, 16 + len(body)))
    _pwrite(fd, MAGIC + len(body).to_bytes(8, "little") + body, 0)
    for a, (_, _, at, n) in zip(arrays, table, strict=True):
        if n:
            _pwrite(fd, memoryview(a).cast("B"), at)
    return []


def _up(n: int) -> int:
    return n + (-n % ALIGN)


def _pwrite(fd: int, data, at: int) -> None:
    view = memoryview(data)
    while view.nbytes:
        n = os.pwrite(fd, view, at)
        view, at = view[n:], at + n


def _encode(x, arrays: list, seen: dict, depth: int):
    if depth > _MAX_DEPTH:
        raise ValueError("answer nested too deep")
    if x is None or isinstance(x, (bool, str)):
        return x
    if isinstance(x, (int, float)) and type(x) in (int, float):
        return x
    if isinstance(x, np.ndarray):
        i = seen.get(id(x))
        if i is None:
            if x.dtype.str not in _CODES:
                raise ValueError("answer array of an unsupported dtype")
            i = seen[id(x)] = len(arrays)
            arrays.append(np.ascontiguousarray(x))
            seen[id(arrays[-1])] = i  # (a copy made contiguous stays alive in `arrays`)
        return ["a", i]
    if isinstance(x, np.generic):
        if x.dtype.name not in _DTYPES:
            raise ValueError("answer scalar of an unsupported dtype")
        return ["s", x.dtype.name, x.item() if x.dtype.kind not in "c" else [x.real.item(), x.imag.item()]]
    if type(x) is list:
        return ["l", *(_encode(v, arrays, seen, depth + 1) for v in x)]
    if type(x) is tuple:
        return ["t", *(_encode(v, arrays, seen, depth + 1) for v in x)]
    if type(x) is dict:
        return [
            "d",
            *(
                [_encode(k, arrays, seen, depth + 1), _encode(v, arrays, seen, depth + 1)]
                for k, v in x.items()
            ),
        ]
    name = type(x).__name__
    if name in _classes() and type(x) is _classes()[name]:
        return [
            name,
            {f.name: _encode(getattr(x, f.name), arrays, seen, depth + 1) for f in dataclasses.fields(x)},
        ]
    raise ValueError("answer of an unsupported type")


def _classes() -> dict:
    from models.mesh.container import Mesh
    from models.mesh.deferred import Deferred
    from models.mesh.geometry import Faces

    return {"Mesh": Mesh, "Faces": Faces, "Deferred": Deferred}


# ---------------------------------------------------------------- the caller's side


def load(fd: int, pid: int | None = None, limit: int | None = None):
    """The answer in the memfd `fd` as dump wrote it: ("ok", value) | ("error", class name,
    message) | ("memory",); Corrupt when anything in it is inconsistent. pid: the child that wrote
    it, alive and waiting, whose lent arrays (dump's lend) are copied from its memory here, at most
    `limit` bytes in all; without it a lent answer is refused."""
    try:
        return _load(fd, pid, limit)
    except Corrupt:
        raise
    except Exception:  # noqa: BLE001  (whatever the bytes made fail: the same refusal)
        raise Corrupt("malformed answer") from None


def _load(fd: int, pid: int | None, limit: int | None):
    _seal(fd)  # from here on nobody, the child included, can change a byte of it
    size = os.fstat(fd).st_size
    if size < 16:
        raise Corrupt("short answer")
    head = os.pread(fd, 16, 0)
    if head[:8] != MAGIC:
        raise Corrupt("bad magic")
    n = int.from_bytes(head[8:16], "little")
    if n > _MAX_HEADER or 16 + n > size:
        raise Corrupt("header out of bounds")
    header = json.loads(os.pread(fd, n, 16).decode("utf-8"))
    _need(type(header) is dict)
    kind = header.get("kind")
    if kind == "memory":
        return ("memory",)
    if kind == "error":
        cls, message = header.get("class"), header.get("message")
        _need(cls in ("MeshError", "ParameterError", "ModelError") and type(message) is str)
        return ("error", cls, message)
    _need(kind == "ok")
    table = header.get("arrays")
    _need(type(table) is list)
    if header.get("lent", False) is not False:
        _need(header["lent"] is True and pid is not None)
        arrays = _borrow(table, pid, limit)
        return ("ok", _decode(header.get("value"), arrays, 0))
    end = 16 + n
    specs = []
    for entry in table:
        dt, shape, at, nbytes, count = _spec(entry)
        _need(at % ALIGN == 0 and at >= end and at + nbytes <= size)
        end = at + nbytes
        specs.append((dt, shape, at, count))
    mem = _map(fd, size) if specs else None
    arrays = [_native(np.frombuffer(mem, dt, count, at).reshape(shape)) for dt, shape, at, count in specs]
    value = _decode(header.get("value"), arrays, 0)
    return ("ok", value)


def _spec(entry) -> tuple:
    """(dtype, shape, where, nbytes, count) of one array of the header's table ([dtype name, shape,
    where, nbytes]): a whitelisted dtype, at most _MAX_NDIM dimensions, nbytes the shape's."""
    _need(type(entry) is list and len(entry) == 4)
    dtype, shape, at, nbytes = entry
    _need(type(dtype) is str and dtype in _CODES)
    _need(type(shape) is list and len(shape) <= _MAX_NDIM)
    _need(all(type(s) is int and s >= 0 for s in shape))
    _need(type(at) is int and type(nbytes) is int)
    count = 1
    for s in shape:
        count *= s
    dt = np.dtype(dtype)
    _need(nbytes == count * dt.itemsize)
    return dt, tuple(shape), at, nbytes, count


def _borrow(table: list, pid: int, limit: int | None) -> list:
    """The lent arrays of `table` ([dtype, shape, address, nbytes] each), copied from the memory of
    the child `pid` into new arrays of this process: process_vm_readv, one call for all (1024
    pieces at most per call). The child can name any address of its own, no other process's: an
    address it does not map fails the copy (Corrupt)."""
    specs, total = [], 0
    for entry in table:
        dt, shape, at, nbytes, _ = _spec(entry)
        _need(0 <= at < 1 << 64)
        total += nbytes
        _need(limit is None or total <= limit)
        specs.append((dt, shape, at, nbytes))
    arrays = [np.empty(shape, dt) for dt, shape, _, _ in specs]
    pieces = [
        (a.ctypes.data, at, nbytes) for a, (_, _, at, nbytes) in zip(arrays, specs, strict=True) if nbytes
    ]
    for i in range(0, len(pieces), 1024):
        _copy_from(pid, pieces[i : i + 1024])
    return [_native(a) for a in arrays]


def _native(a: np.ndarray) -> np.ndarray:
    """`a` in this machine's byte order: swapped in place where it came in the other (a file's
    big-endian values a reader handed back as they are), so nothing past the loader meets one."""
    if a.dtype.isnative:
        return a
    native = a.dtype.newbyteorder("=")
    return a.byteswap(inplace=True).view(native) if a.flags.writeable else a.astype(native)


def _copy_from(pid: int, pieces: list) -> None:
    import ctypes

    libc = _libc()
    n = len(pieces)
    local, remote = (_IOVEC * n)(), (_IOVEC * n)()
    want = 0
    for i, (here, there, nbytes) in enumerate(pieces):
        local[i].base, local[i].len = here, nbytes
        remote[i].base, remote[i].len = there, nbytes
        want += nbytes
    got = libc.process_vm_readv(pid, local, n, remote, n, 0)
    if got != want:  # an address the child does not map, the child gone, or not allowed
        raise Corrupt(f"lent arrays not copied ({os.strerror(ctypes.get_errno()) if got < 0 else 'short'})")


def can_borrow(pid: int, address: int, expect: bytes) -> bool:
    """True when process_vm_readv reads `expect` at `address` of process `pid` (a zygote's probe:
    seccomp, Yama or a container can forbid it; then answers come whole through the memfd)."""
    import ctypes

    try:
        buf = ctypes.create_string_buffer(len(expect))
        _copy_from(pid, [(ctypes.addressof(buf), address, len(expect))])
        return buf.raw == expect
    except (Corrupt, OSError, AttributeError):
        return False


def _seal(fd: int) -> None:
    """No more writes to the memfd, by anyone, nor a change of its size: checked and then used,
    its bytes stay the ones checked (a child that lies could otherwise rewrite an array after the
    checks, from a mapping kept by it or by a process it forked). A writable shared mapping still
    open somewhere makes sealing fail (EBUSY): refused. The memfd must allow sealing
    (MFD_ALLOW_SEALING)."""
    import fcntl

    try:
        fcntl.fcntl(
            fd,
            fcntl.F_ADD_SEALS,
            fcntl.F_SEAL_WRITE | fcntl.F_SEAL_SHRINK | fcntl.F_SEAL_GROW | fcntl.F_SEAL_SEAL,
        )
    except OSError:
        raise Corrupt("the answer could not be sealed") from None
    seals = fcntl.fcntl(fd, fcntl.F_GET_SEALS)
    _need(seals & fcntl.F_SEAL_WRITE and seals & fcntl.F_SEAL_SHRINK)


class _Mapping:
    """A private mapping of a sealed memfd, populated read-only and then made writable: the pages
    are the memfd's (no copy, no page fault on first read); an array edited in place copies the
    pages it writes (copy-on-write), never the memfd's. Unmapped when the last array goes."""

    def __init__(self, fd: int, size: int) -> None:
        import ctypes
        import weakref

        libc = _libc()
        addr = libc.mmap(
            None, size, mmap.PROT_READ, mmap.MAP_PRIVATE | getattr(mmap, "MAP_POPULATE", 0), fd, 0
        )
        if addr in (None, ctypes.c_void_p(-1).value):
            raise OSError("mmap failed")
        if libc.mprotect(addr, size, mmap.PROT_READ | mmap.PROT_WRITE) != 0:
            libc.munmap(addr, size)
            raise OSError("mprotect failed")
        self.buffer = (ctypes.c_char * size).from_address(addr)
        weakref.finalize(self.buffer, libc.munmap, addr, size)


_LIBC = None


class _IOVEC(ctypes.Structure):
    _fields_ = [("base", ctypes.c_void_p), ("len", ctypes.c_size_t)]


def _libc():
    global _LIBC
    if _LIBC is None:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        libc.mmap.restype = ctypes.c_void_p
        libc.mmap.argtypes = [
            ctypes.c_void_p,
            ctypes.c_size_t,
            ctypes.c_int,
            ctypes.c_int,
            ctypes.c_int,
            ctypes.c_long,
        ]
        libc.mprotect.argtypes = [ctypes.c_void_p, ctypes.c_size_t, ctypes.c_int]
        libc.munmap.argtypes = [ctypes.c_void_p, ctypes.c_size_t]
        try:  # (a libc without it: answers are never lent, can_borrow says so)
            libc.process_vm_readv.restype = ctypes.c_ssize_t
            libc.process_vm_readv.argtypes = [
                ctypes.c_int,
                ctypes.POINTER(_IOVEC),
                ctypes.c_ulong,
                ctypes.POINTER(_IOVEC),
                ctypes.c_ulong,
                ctypes.c_ulong,
            ]
        except AttributeError:
            pass
        _LIBC = libc
    return _LIBC


def _map(fd: int, size: int):
    """The sealed memfd's bytes, writable by this process only (see _Mapping); where libc's mmap
    cannot be called, Python's private mapping (populated: every page copied once)."""
    try:
        return _Mapping(fd, size).buffer
    except (OSError, AttributeError):
        flags = mmap.MAP_PRIVATE | getattr(mmap, "MAP_POPULATE", 0)
        return mmap.mmap(fd, size, flags=flags, prot=mmap.PROT_READ | mmap.PROT_WRITE)


def _need(ok: bool) -> None:
    if not ok:
        raise Corrupt("inconsistent answer")


def _decode(x, arrays: list, depth: int):
    _need(depth <= _MAX_DEPTH)
    if x is None or type(x) in (bool, str, int, float):
        return x
    _need(type(x) is list and len(x) >= 1 and type(x[0]) is str)
    tag, rest = x[0], x[1:]
    if tag == "a":
        _need(len(rest) == 1 and type(rest[0]) is int and 0 <= rest[0] < len(arrays))
        return arrays[rest[0]]
    if tag == "s":
        _need(len(rest) == 2 and rest[0] in _DTYPES)
        dt, v = np.dtype(rest[0]), rest[1]
        if dt.kind == "c":
            _need(type(v) is list and len(v) == 2 and all(type(p) in (int, float) for p in v))
            v = complex(*v)
        else:
            _need(type(v) in (bool, int, float))
        return dt.type(v)
    if tag == "l":
        return [_decode(v, arrays, depth + 1) for v in rest]
    if tag == "t":
        return tuple(_decode(v, arrays, depth + 1) for v in rest)
    if tag == "d":
        out = {}
        for pair in rest:
            _need(type(pair) is list and len(pair) == 2)
            key = _decode(pair[0], arrays, depth + 1)
            _need(key is None or type(key) in (bool, str, int, float, tuple))
            out[key] = _decode(pair[1], arrays, depth + 1)
        return out
    classes = _classes()
    _need(tag in classes and len(rest) == 1 and type(rest[0]) is dict)
    cls = classes[tag]
    names = {f.name for f in dataclasses.fields(cls)}
    _need(set(rest[0]) <= names)
    obj = cls(**{k: _decode(v, arrays, depth + 1) for k, v in rest[0].items()})
    if tag == "Mesh":
        check_mesh(obj)
    elif tag == "Deferred":
        pass  # a builder's arguments: build.build_deferred checks them all before building
    else:
        _check_csr(obj.offsets, obj.nodes, None)
        _need(ids(obj.cell) and obj.cell.shape == (len(obj.offsets) - 1,))
    return obj


# ---------------------------------------------------------------- a Mesh's invariants


def _check_csr(offsets, values, n_ids: int | None) -> None:
    """offsets from 0, never decreasing, to len(values); values (ids below n_ids when given)."""
    _need(csr_sizes(offsets, values) is not None)
    if n_ids is not None:
        _need(in_range(values, n_ids))


def check_mesh(mesh) -> None:
    """The invariants every consumer of a Mesh relies on (dtypes, shapes, CSR bounds, ids in range),
    checked vectorized; Corrupt at the first one broken. The cells' geometry (orientation, measures)
    is the reader's to check; it cannot make an index go out of bounds."""
    from models.mesh.container import Mesh

    _need(type(mesh) is Mesh)
    p = mesh.points
    _need(isinstance(p, np.ndarray) and p.dtype.kind == "f" and p.ndim == 2 and p.shape[1] in (2, 3))
    n_points = p.shape[0]
    types = mesh.cell_types
    _need(isinstance(types, np.ndarray) and types.dtype == np.uint8 and types.ndim == 1)
    n_cells = types.shape[0]
    _need(ids(mesh.offsets) and mesh.offsets.shape == (n_cells + 1,))
    _check_csr(mesh.offsets, mesh.connectivity, n_points)
    _need(mesh.tags is None or (ids(mesh.tags) and mesh.tags.shape == (n_cells,)))
    _need(mesh.tag_name is None or type(mesh.tag_name) is str)
    f = mesh.frame
    _need(f is None or (isinstance(f, np.ndarray) and f.dtype.kind == "f" and f.shape == (3, 3)))
    poly = (mesh.poly_cells, mesh.poly_cell_faces, mesh.poly_face_offsets, mesh.poly_face_nodes)
    _need(all(a is None for a in poly) or all(a is not None for a in poly))
    if poly[0] is not None:
        _need(ids(poly[0]) and in_range(poly[0], n_cells))
        _need(poly[1].shape == (poly[0].size + 1,))
        _check_csr(poly[1], poly[2][:-1] if ids(poly[2]) and poly[2].size else poly[2], None)
        _check_csr(poly[2], poly[3], n_points)
    bnd = (mesh.boundary_offsets, mesh.boundary_connectivity, mesh.boundary_types)
    _need(all(a is None for a in bnd) or all(a is not None for a in bnd))
    if bnd[0] is not None:
        _check_csr(bnd[0], bnd[1], n_points)
        _need(
            isinstance(bnd[2], np.ndarray) and bnd[2].dtype == np.uint8 and bnd[2].shape == (bnd[0].size - 1,)
        )
        bt = mesh.boundary_tags
        _need(bt is None or (ids(bt) and bt.shape == bnd[2].shape))
    else:
        _need(mesh.boundary_tags is None)
    _need(type(mesh.meta) is dict)
    for key in ("measures", "centroids", "signed_measures"):
        a = mesh.meta.get(key)
        _need(a is None or (isinstance(a, np.ndarray) and a.dtype.kind == "f" and a.shape[:1] == (n_cells,)))
    cached = mesh.meta.get("cell_faces")
    if cached is not None:
        _check_cached_faces(cached, mesh, n_points, n_cells)


def _check_cached_faces(c, mesh, n_points: int, n_cells: int) -> None:
    """meta["cell_faces"] (models.mesh.build._keep_faces): the faces' ids, the pairing's face ids
    and the areas, in range and of the faces' length."""
    from models.mesh.geometry import Faces

    _need(type(c) is dict and set(c) <= {"connectivity", "faces", "order", "same", "pairs", "areas"})
    faces = c.get("faces")
    _need(type(faces) is Faces and in_range(faces.nodes, n_points) and in_range(faces.cell, n_cells))
    n_faces = faces.cell.size
    _need(c.get("connectivity") is None or isinstance(c["connectivity"], np.ndarray))
    order, same, pairs, areas = (c.get(k) for k in ("order", "same", "pairs", "areas"))
    _need(order is None or (ids(order) and order.size == n_faces and in_range(order, n_faces)))
    _need(
        same is None
        or (isinstance(same, np.ndarray) and same.dtype == bool and same.shape == (max(n_faces - 1, 0),))
    )
    if pairs is not None:
        _need(type(pairs) is tuple and len(pairs) == 2)
        _need(all(ids(q) and q.shape == pairs[0].shape and in_range(q, n_faces) for q in pairs))
    _need(
        areas is None or (isinstance(areas, np.ndarray) and areas.dtype.kind == "f" and areas.size == n_faces)
    )
