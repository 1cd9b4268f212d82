"""The sandboxed read's raw answer (models.mesh.answer): the same Mesh as an in-process read, field
by field, on every format family; anything malformed (or a pickle) refused as a crashed reader,
never unpickled."""

from __future__ import annotations

import dataclasses
import json
import os
import time
from pathlib import Path

import numpy as np
import pytest
from mutants import write_corpus
from vtkmodules.util.numpy_support import numpy_to_vtk

from models.errors import MeshError
from models.mesh import answer, zygote
from models.mesh.container import Mesh
from models.mesh.read import read_mesh
from models.mesh.sandbox import call_in_child, crash_sentence, read_mesh_safe

DATA = Path(__file__).parent / "data"
MARKER = "/tmp/magnet-raw-answer-test-unpickled"


def same(a, b, where="mesh"):
    """a and b equal in type, value, dtype and shape, all the way down."""
    assert type(a) is type(b), where
    if isinstance(a, np.ndarray):
        assert a.dtype == b.dtype and a.shape == b.shape, where
        assert np.array_equal(a, b, equal_nan=a.dtype.kind in "fc"), where
    elif dataclasses.is_dataclass(a):
        for f in dataclasses.fields(a):
            same(getattr(a, f.name), getattr(b, f.name), f"{where}.{f.name}")
    elif isinstance(a, dict):
        assert list(a) == list(b), where
        for k in a:
            same(a[k], b[k], f"{where}[{k!r}]")
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            same(x, y, f"{where}[{i}]")
    else:
        assert a == b or (a != a and b != b), where


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    import vtk_corpus as vc

    folder = tmp_path_factory.mktemp("corpus")
    corpus = write_corpus(folder)
    p, h = vc.grid(3, 3, 3)
    tagged = vc.image((6, 5, 4))  # image data with a material array (tags) and a rotated one
    mat = numpy_to_vtk(np.arange(5 * 4 * 3, dtype=np.int32) % 3, deep=True)
    mat.SetName("gmsh:physical")
    tagged.GetCellData().AddArray(mat)
    rotated = vc.image()
    rotated.SetDirectionMatrix(0, -1, 0, 1, 0, 0, 0, 0, 1)
    extra = [  # VTK polyhedra (the poly_* fields) and a wedge/pyramid mix
        vc.write_xml(str(folder / "poly.vtu"), vc.polyhedra(p, h)),
        vc.write_legacy(str(folder / "prisms.vtk"), vc.prisms(), 51, True),
        # structured data: built by the caller from origin, spacing and extent (image data) or from
        # the points and the lattice's dimensions (models.mesh.deferred)
        vc.write_xml(str(folder / "image.vti"), tagged),
        vc.write_xml(str(folder / "rotated.vti"), rotated),
        vc.write_xml(str(folder / "grid.vts"), vc.structured_grid()),
        vc.write_xml(str(folder / "grid.vtr"), vc.rectilinear()),
        vc.write_legacy(str(folder / "points.vtk"), vc.image(), 42, True),
        vc.write_xml(str(folder / "flat.vti"), vc.image((5, 4, 1))),
        vc.write_xml(str(folder / "strips.vtp"), vc.plane("strips")),
    ]
    return [*corpus.values(), *map(Path, extra), *sorted(DATA.glob("*.msh")), DATA / "MeshEmilia.vtk"]


@pytest.mark.parametrize("use_zygote", [True, False, "no-lend"])
def test_the_sandboxed_mesh_is_the_in_process_one_field_by_field(files, use_zygote, monkeypatch):
    """Through the zygote (its children lend their arrays where process_vm_readv works, else the
    memfd carries them: "no-lend"), and through a direct fork (the memfd)."""
    monkeypatch.setenv("MAGNET_READ_ZYGOTE", "1")
    monkeypatch.setenv("MAGNET_READ_LEND", "0" if use_zygote == "no-lend" else "1")
    zygote.shutdown()
    if use_zygote:
        assert zygote.wait_ready(120)
        lends = zygote.acquire(start=False)
        assert lends is not None
        zygote.release(lends)
        assert lends.lend == (use_zygote is True and answer.can_borrow(os.getpid(), *_here()))
    checked = set()
    try:
        for path in files:
            ours = read_mesh(path)
            theirs = read_mesh_safe(path, zygote=use_zygote)
            same(ours, theirs, path.name)
            checked |= set(ours.meta)
            if ours.poly_cells is not None:
                checked.add("poly_cells")
            if ours.dim == 2:
                checked.add("2D")
            if ours.tags is not None:
                checked.add("tags")
            if ours.boundary_tags is not None:
                checked.add("boundary_tags")
            assert theirs.connectivity.flags.writeable and theirs.points.flags.writeable
            theirs.points[:1] += 1.0  # edited in place: this mapping's page only (copy-on-write)
            c = theirs.meta.get("cell_faces")
            if c is not None:  # the cache still belongs to the mesh: the same array object
                assert c["connectivity"] is theirs.connectivity
    finally:
        zygote.shutdown()
    # the corpus covers what a Mesh carries: tags, boundary groups, names, measures, the cached faces
    assert {"tags", "boundary_tags", "group_names", "boundary_names", "measures", "cell_faces"} <= checked
    assert {"poly_cells", "2D"} <= checked


def _here():
    """(address, bytes) of a buffer of this process (for can_borrow on itself)."""
    import ctypes

    global _HERE
    _HERE = ctypes.create_string_buffer(b"here", 4)
    return ctypes.addressof(_HERE), b"here"


# ---------------------------------------------------------------- a child that lies


def _memfd(data: bytes) -> int:
    fd = os.memfd_create("test-answer", os.MFD_CLOEXEC | os.MFD_ALLOW_SEALING)
    os.write(fd, data)
    return fd


def _raw(header: dict, arrays=()) -> bytes:
    """An answer laid out as dump does, from a header whose table offsets the caller chose."""
    body = json.dumps(header).encode()
    out = bytearray(answer.MAGIC + len(body).to_bytes(8, "little") + body)
    for at, a in arrays:
        out += b"\0" * (at - len(out))
        out += a.tobytes()
    return bytes(out)


def _ok_mesh(conn_max: int = 3):
    """A one-tetrahedron Mesh answer with its last point id `conn_max`."""
    arrays = [
        np.zeros((4, 3)),
        np.array([0, 4], np.int64),
        np.array([0, 1, 2, conn_max], np.int64),
        np.array([10], np.uint8),
    ]
    table, at = [], 1024
    for a in arrays:
        table.append([a.dtype.str, list(a.shape), at, a.nbytes])
        at += 64 * (-(-a.nbytes // 64))
    fields = {"points": ["a", 0], "offsets": ["a", 1], "connectivity": ["a", 2], "cell_types": ["a", 3]}
    header = {"kind": "ok", "arrays": table, "value": ["Mesh", fields]}
    return header, [(t[2], a) for t, a in zip(table, arrays, strict=True)]


def test_a_well_formed_answer_loads_and_every_malformed_one_is_refused():
    header, arrays = _ok_mesh()
    fd = _memfd(_raw(header, arrays))
    try:
        kind, mesh = answer.load(fd)
    finally:
        os.close(fd)
    assert kind == "ok" and isinstance(mesh, Mesh) and mesh.n_cells == 1 and mesh.connectivity[-1] == 3

    def bad(h, a=arrays, raw=None):
        fd = _memfd(raw if raw is not None else _raw(h, a))
        try:
            with pytest.raises(answer.Corrupt):
                answer.load(fd)
        finally:
            os.close(fd)

    bad(*_ok_mesh(conn_max=4))  # a point id past the points
    bad(None, raw=b"")
    bad(None, raw=b"MAGNETR1" + (1 << 40).to_bytes(8, "little"))  # header past the end
    bad(None, raw=b"MAGNETR1" + (5).to_bytes(8, "little") + b"{oops")
    for edit in (
        lambda h: h["arrays"][0].__setitem__(0, "object"),
        lambda h: h["arrays"][0].__setitem__(1, [4, 4]),  # nbytes no longer the shape's
        lambda h: h["arrays"][1].__setitem__(2, 1056),  # overlaps the points
        lambda h: h["arrays"][3].__setitem__(2, 1 << 30),  # past the end of the memfd
        lambda h: h["arrays"][2].__setitem__(2, 1025),  # not aligned
        lambda h: h["value"][1].__setitem__("points", ["a", 9]),
        lambda h: h["value"][1].__setitem__("__class__", None),
        lambda h: h.__setitem__("value", ["os.system", {}]),
        lambda h: h.__setitem__("kind", "error") or h.__setitem__("class", "SystemExit"),
        lambda h: h["value"][1].__setitem__("offsets", ["a", 2]),  # CSR offsets not ending at len
    ):
        h = json.loads(json.dumps(header))
        edit(h)
        bad(h)


class _Evil:
    def __reduce__(self):
        return (os.mkdir, (MARKER,))


def _pickle_dump(value, shm, lend=False):
    """What a taken-over child could write: the former answer, a pickle, with code in it."""
    import pickle

    os.ftruncate(shm, 0)
    os.write(shm, pickle.dumps(("ok", _Evil())))
    return []


def _out_of_range_dump(value, shm, lend=False):
    header, arrays = _ok_mesh(conn_max=1 << 40)
    os.ftruncate(shm, 0)
    os.write(shm, _raw(header, arrays))
    return []


def _lent(edit):
    """A lent answer (the header only: each array named by an address of this child) with `edit`
    applied to its table: what a taken-over child could name instead of its own arrays."""

    def write(value, shm, lend=False):
        header, arrays = _ok_mesh()
        keep = [a for _, a in arrays]
        header["lent"] = True
        header["arrays"] = [[a.dtype.str, list(a.shape), a.ctypes.data, a.nbytes] for a in keep]
        edit(header["arrays"])
        os.ftruncate(shm, 0)
        os.write(shm, _raw(header))
        return keep

    return write


def _mapping_kept_dump(value, shm, lend=False):
    """A well-formed answer, and a process of the child's own keeping a writable mapping of it (to
    rewrite an array once the caller has checked it)."""
    import mmap

    header, arrays = _ok_mesh()
    os.ftruncate(shm, 0)
    os.write(shm, _raw(header, arrays))
    mem = mmap.mmap(shm, os.fstat(shm).st_size)
    if os.fork() == 0:
        time.sleep(3)
        mem[0] = 0
        os._exit(0)
    return []


def take_over(how: str):
    """Run in the child: from now on its answer is what `how` writes (a reader exploit's doing)."""
    import models.mesh.zygote as z

    z.dump = {
        "pickle": _pickle_dump,
        "range": _out_of_range_dump,
        "mapping": _mapping_kept_dump,
        # lent arrays: an address it does not map, a size past the read's memory limit, a size
        # past the array (the copy would read on into other memory of the child: still its own)
        "unmapped": _lent(lambda t: t[0].__setitem__(2, 4096)),
        "huge": _lent(lambda t: t[2].__setitem__(1, [1 << 40]) or t[2].__setitem__(3, 8 << 40)),
        "shape": _lent(lambda t: t[0].__setitem__(1, [4, 4]) or t[0].__setitem__(3, 128)),
    }[how]
    return 1


@pytest.mark.parametrize("use_zygote", [True, False])
def test_a_taken_over_child_cannot_run_code_in_the_caller(use_zygote, monkeypatch):
    monkeypatch.setenv("MAGNET_READ_ZYGOTE", "1")
    if use_zygote:
        assert zygote.wait_ready(120)
    if os.path.isdir(MARKER):
        os.rmdir(MARKER)
    try:
        for how in ("pickle", "range", "mapping", "unmapped", "huge", "shape"):
            with pytest.raises(MeshError) as err:
                call_in_child(
                    take_over, (how,), path="x.vtk", timeout_s=30, memory_bytes=1 << 30, zygote=use_zygote
                )
            assert str(err.value) == crash_sentence("x.vtk")
        assert not os.path.exists(MARKER)
        assert call_in_child(os.getpid, path="x.vtk", timeout_s=30, memory_bytes=1 << 30) > 0  # reads go on
    finally:
        zygote.shutdown()


def test_big_endian_arrays_arrive_in_this_machines_byte_order():
    """A reader may hand back a file's big-endian values as they are (models/mesh/legacy.py's raw
    arrays); the loader swaps them in place: every array past it is native, with the same values."""
    sent = {
        "i4": np.arange(-3, 7, dtype=">i4").reshape(2, 5),
        "f8": np.linspace(-1.0, 2.0, 7).astype(">f8"),
        "f4": np.array([1.5, -2.25], dtype=">f4"),
        "u1": np.arange(4, dtype=np.uint8),
    }
    fd = os.memfd_create("answer-test", os.MFD_ALLOW_SEALING)
    try:
        answer.dump(("ok", sent), fd)
        kind, got = answer.load(fd)
    finally:
        os.close(fd)
    assert kind == "ok" and set(got) == set(sent)
    for key, a in sent.items():
        assert got[key].dtype.isnative and got[key].dtype.kind == a.dtype.kind
        assert got[key].dtype.itemsize == a.dtype.itemsize and got[key].shape == a.shape
        assert np.array_equal(got[key], a)
