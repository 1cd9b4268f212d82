"""The reading child hands back the builders' arguments (models.mesh.deferred), the caller builds:
the same Mesh as an in-process read, fewer bytes across, and every argument a lying child could
send checked before any builder runs (refused as a crashed reader)."""

from __future__ import annotations

import copy
import gc
import os
from pathlib import Path

import numpy as np
import pytest
import vtk_corpus as vc
from test_read_raw_answer import same

from models.errors import MeshError
from models.mesh import deferred, zygote
from models.mesh.answer import _native
from models.mesh.build import build_deferred
from models.mesh.deferred import Deferred, Inconsistent
from models.mesh.read import read_mesh
from models.mesh.sandbox import (
    _built,
    _read_in_child,
    call_in_child,
    crash_sentence,
    memory_sentence,
    read_mesh_safe,
)

DATA = Path(__file__).parent / "data"


def _deferred(path, monkeypatch) -> Deferred:
    """What the reading child hands back for `path` (read here with the builders deferred)."""
    monkeypatch.setattr(deferred, "DEFER", True)
    try:
        got = read_mesh(path)
    finally:
        monkeypatch.setattr(deferred, "DEFER", False)
    assert isinstance(got, Deferred)
    return got


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("deferred")
    p, h = vc.grid(3, 3, 3)
    return {
        "image": Path(vc.write_xml(str(folder / "a.vti"), vc.image((6, 5, 4)))),
        "lattice": Path(vc.write_xml(str(folder / "a.vts"), vc.structured_grid())),
        "hexes": Path(vc.write_xml(str(folder / "h.vtu"), vc.unstructured(p, [(12, h)]))),
        "legacy": Path(vc.write_legacy(str(folder / "h.vtk"), vc.unstructured(p, [(12, h)]), 42, True)),
        "legacy51": Path(vc.write_legacy(str(folder / "h51.vtk"), vc.unstructured(p, [(12, h)]), 51, True)),
        "legacy_ascii": Path(vc.write_legacy(str(folder / "ha.vtk"), vc.unstructured(p, [(12, h)]), 42)),
        "poly": Path(vc.write_xml(str(folder / "poly.vtu"), vc.polyhedra(p, h))),
        "groups": DATA / "cube_faces.msh",  # boundary groups and names
        "plane": DATA / "square_sides.msh",
    }


def test_the_child_answers_with_arguments_and_the_caller_builds_the_same_mesh(files):
    assert zygote.wait_ready(120)
    try:
        for name, path in files.items():
            got = call_in_child(
                _read_in_child, (str(path), {}), path=str(path), timeout_s=60, memory_bytes=1 << 32
            )
            assert isinstance(got, Deferred), name
            if name == "image":  # a few numbers: the caller makes the points and the hexahedra
                assert got.builder == "image" and all(a.size <= 6 for a in got.args[0])
            if name == "lattice":  # the points and the dimensions: no connectivity crosses
                assert got.builder == "cells" and got.args[1] is None and got.args[2] is None
            if name == "hexes":
                assert got.builder == "cells" and got.args[2].size == 27 * 8
            if name.startswith("legacy"):  # the file's own arrays, in this machine's byte order once here
                points, cells, counted, t = got.args
                assert got.builder == "fixed" and t == 12 and cells.shape == (27, 8 + counted)
                assert counted == (name != "legacy51") and cells.dtype.isnative and points.dtype.isnative
            same(read_mesh(path), _built(got, str(path), None, 1 << 32), name)
    finally:
        zygote.shutdown()


def _lies(d: Deferred):
    """(what, a copy of d with that lie) for every argument of a "cells" build."""
    args = list(d.args)
    points, offsets, conn, types = args[:4]

    def with_(i, value):
        a = list(args)
        a[i] = value
        return Deferred(d.builder, tuple(a), dict(d.meta), d.dim)

    if conn is not None:
        c = conn.copy()
        c[-1] = len(points)
        yield "a point id past the end", with_(2, c)
        c = conn.copy()
        c[3] = -1
        yield "a negative point id", with_(2, c)
        o = offsets.copy()
        o[0] = 1
        yield "offsets not from 0", with_(1, o)
        o = offsets.copy()
        o[-1] += 1
        yield "offsets past the connectivity", with_(1, o)
        if len(o) > 2:
            o = offsets.copy()
            o[1], o[2] = o[2], o[1]
            yield "offsets going back", with_(1, o)
        t = types.copy()
        t[0] = 12 if t[0] != 12 else 10
        yield "a cell's node count against its type", with_(3, t)
        t = types.copy()
        t[-1] = 99
        yield "an unknown cell type", with_(3, t)
        yield "types of the wrong length", with_(3, types[:-1].copy())
        yield "offsets as floats", with_(1, offsets.astype(np.float64))
    yield "points as integers", with_(0, points.astype(np.int64))
    yield "tags of the wrong length", with_(4, np.zeros(len(types) + 1 if types is not None else 1, np.int64))
    yield "the wrong dimension", with_(9, 5 - d.dim)
    yield "a weld of NaN", with_(10, float("nan"))
    yield "an array in the metadata", with_(11, {"reader": np.zeros(3)})
    yield "lower cells as text", with_(8, {"line": "many"})
    if args[6]:  # polyhedra's faces
        ids, nf, fs, fn = args[6][0]
        bad = fn.copy()
        bad[0] = len(points) + 5
        yield "a face node past the end", with_(6, [(ids, nf, fs, bad)])
        yield (
            "a polyhedron without its faces",
            with_(6, [(ids[1:], nf[1:], fs[nf[0] :], fn[fs[: nf[0]].sum() :])]),
        )
        yield "too few faces", with_(6, [(ids, np.full_like(nf, 3), fs, fn)])
    if args[7] is not None:  # boundary cells
        b_off, b_conn, b_types, b_tags = args[7]
        bad = b_conn.copy()
        bad[0] = len(points)
        yield "a boundary id past the end", with_(7, (b_off, bad, b_types, b_tags))
        bt = b_types.copy()
        bt[0] = 10
        yield "a volume cell among the boundary cells", with_(7, (b_off, b_conn, bt, b_tags))
    if args[12] is not None:  # a lattice
        g = copy.deepcopy(args[12])
        g["dims"] = [g["dims"][0] + 1, *g["dims"][1:]]
        yield "lattice dimensions that are not the points'", with_(12, g)
        n = int(np.prod([v - 1 for v in args[12]["dims"]]))
        a = list(args)
        a[1:4] = [np.arange(0, 8 * n + 1, 8), np.zeros(8 * n, np.int64), np.full(n, 12, np.uint8)]
        yield "a lattice's hexahedra sent along", Deferred("cells", tuple(a), {}, 3)


def _refused_or_left_out(build, what: str) -> None:
    """A point id out of range in one cell: a MeshError, or (a few bad cells among many: the
    non-negotiable) the Mesh without that cell, which its meta says."""
    try:
        mesh = build()
    except MeshError:
        return
    left = mesh.meta.get("dropped_cells")
    assert left and len(left["ids_all"]) == 1, f"{what} was accepted"
    assert mesh.connectivity.min() >= 0 and mesh.connectivity.max() < len(mesh.points)


def test_every_lie_in_the_arguments_is_refused_before_a_builder_runs(files, monkeypatch):
    seen = 0
    for name in ("hexes", "poly", "groups", "plane", "lattice"):
        d = _deferred(files[name], monkeypatch)
        build_deferred(d)  # the genuine one builds
        for what, lie in _lies(d):
            seen += 1
            if "past the end" in what or "negative" in what:  # the builder's own check: refused in
                _refused_or_left_out(lambda lie=lie: build_deferred(lie), what)  # the words a bad
                continue  # file gets, or (one bad cell among 100 or more) that cell left out
            with pytest.raises(Inconsistent):
                build_deferred(lie)
                pytest.fail(f"{name}: {what} was accepted")
    assert seen > 60
    img = _deferred(files["image"], monkeypatch)
    axes, tags, tag_name, meta = img.args
    lies = [
        [[axes[0], axes[1]], tags, tag_name, meta],  # two axes
        [[axes[0], axes[1], np.array([0.0, np.inf])], tags, tag_name, meta],
        [[axes[0], axes[1], np.array([0.0])], tags, tag_name, meta],
        [axes, np.zeros(7, np.int64), tag_name, meta],
        [axes, tags, 3, meta],
        [axes, tags, tag_name, [1]],
    ]
    for lie in lies:
        with pytest.raises(Inconsistent):
            build_deferred(Deferred("image", tuple(lie), {}, 3))
    with pytest.raises(Inconsistent):
        build_deferred(Deferred("exec", (), {}, 3))
    with pytest.raises(Inconsistent):
        build_deferred(Deferred("image", img.args, {"group_names": object()}, 3))


def test_every_lie_in_a_fixed_answer_is_refused_before_a_builder_runs(files, monkeypatch):
    """The legacy reader's own arrays ("fixed": points, cells or counted rows, the cell type):
    each lie is refused (Inconsistent, or the builder's words for a point id out of range)."""
    for name in ("legacy", "legacy51", "legacy_ascii"):
        d = _deferred(files[name], monkeypatch)
        assert d.builder == "fixed"
        points, cells, counted, t = d.args
        # big-endian views of the file's bytes: in this machine's order, as the answer's loader gives them
        points, cells = _native(np.array(points)), _native(np.array(cells))
        genuine = Deferred("fixed", (points, cells, counted, t), d.meta, 3)
        same(read_mesh(files[name]), build_deferred(genuine), name)
        k = cells.shape[1] - counted

        base = {"points": points, "cells": cells, "counted": counted, "t": t, "dim": 3, "meta": d.meta}

        def lie(base=base, **kw):
            a = {**base, **kw}
            return Deferred(
                "fixed", (a["points"], a["cells"], a["counted"], a["t"]), dict(a["meta"]), a["dim"]
            )

        bad = cells.copy()
        bad[-1, -1] = len(points)
        past = lie(cells=bad)
        bad = cells.copy()
        bad[0, -1] = -1
        negative = lie(cells=bad)
        for builds in (past, negative):
            _refused_or_left_out(lambda builds=builds: build_deferred(builds), "an id out of range")
        lies = [
            lie(t=10),  # a tetrahedron of 8 nodes
            lie(t=5),  # a triangle in 3D
            lie(t=99),
            lie(t="12"),
            lie(dim=2),
            lie(counted=not counted),
            lie(counted=int(counted)),
            lie(points=points.astype(np.int64)),
            lie(points=points[:, :2].copy()),
            lie(points=points.reshape(-1)),
            lie(cells=cells.astype(np.float64)),
            lie(cells=cells.reshape(-1)),
            lie(cells=cells[:0]),
            lie(cells=cells[:, :k].copy()) if counted else lie(cells=np.column_stack([cells, cells[:, :1]])),
        ]
        if counted:
            bad = cells.copy()
            bad[3, 0] = 7  # a row that says it has 7 nodes
            lies.append(lie(cells=bad))
        for one in lies:
            with pytest.raises(Inconsistent):
                build_deferred(one)


def test_the_caller_words_a_lie_as_a_crash_and_a_huge_image_as_memory(files, monkeypatch):
    d = _deferred(files["hexes"], monkeypatch)
    c = d.args[2].copy()
    c[0] = 10**9
    lie = Deferred("cells", (*d.args[:2], c, *d.args[3:]), {}, 3)
    with pytest.raises(MeshError) as err:  # a point id out of range: the builder's words
        _built(lie, "h.vtk", None, 1 << 32)
    assert "cells refer to missing points" in str(err.value) and "h.vtk" in str(err.value)
    o = d.args[1].copy()
    o[0] = 1
    with pytest.raises(MeshError) as err:  # an inconsistent CSR: a crashed reader
        _built(Deferred("cells", (d.args[0], o, *d.args[2:]), {}, 3), "h.vtk", None, 1 << 32)
    assert str(err.value) == crash_sentence("h.vtk")
    img = _deferred(files["image"], monkeypatch)
    big = [np.arange(2001.0)] * 3  # 8e9 cells
    with pytest.raises(MeshError) as err:
        _built(Deferred("image", (big, None, None, img.args[3]), {}, 3), "a.vti", None, 1 << 32)
    assert str(err.value) == memory_sentence("a.vti", 1 << 32)
    # and a builder's own refusal is worded as read_mesh words it
    pts = d.args[0].copy()
    pts[:, 0] = 0.0  # every hexahedron flat
    flat = Deferred("cells", (pts, *d.args[1:]), {}, 3)
    with pytest.raises(MeshError) as err:
        _built(flat, str(files["hexes"]), None, 1 << 32)
    with pytest.raises(MeshError) as ref:
        read_mesh(_write_flat(files["hexes"].parent / "flat.vtk"))
    assert str(err.value).split(":", 1)[1] == str(ref.value).split(":", 1)[1]


def _write_flat(path: Path) -> str:
    p, h = vc.grid(3, 3, 3)
    p = p.copy()
    p[:, 0] = 0.0
    return vc.write_legacy(str(path), vc.unstructured(p, [(12, h)]), 42, True)


def test_a_held_child_is_released_after_the_build_and_no_descriptor_leaks(files):
    """read_mesh_safe holds the lending child until its Mesh is built (its exit and the zygote's
    next fork come after), then closes the pipe: as many open descriptors after reads as before."""
    assert zygote.wait_ready(120)
    try:
        path = str(files["hexes"])
        read_mesh_safe(path)
        gc.collect()  # earlier tests' garbage (sockets, files) closed now, not during the count
        before = len(os.listdir("/proc/self/fd"))
        for _ in range(5):
            read_mesh_safe(path)
        with pytest.raises(MeshError):
            read_mesh_safe(str(files["hexes"].parent / "missing.vtk"))
        gc.collect()
        assert len(os.listdir("/proc/self/fd")) == before
    finally:
        zygote.shutdown()


def test_the_probe_says_whether_arrays_can_be_borrowed():
    """answer.can_borrow: True where process_vm_readv reads the bytes expected at that address of
    that process; False for an address not mapped, other bytes, or a process that is not there
    (the zygote's children then answer through the memfd)."""
    import ctypes

    from models.mesh import answer

    buf = ctypes.create_string_buffer(b"probe", 5)
    at = ctypes.addressof(buf)
    assert answer.can_borrow(os.getpid(), at, b"probe")
    assert not answer.can_borrow(os.getpid(), at, b"other")
    assert not answer.can_borrow(os.getpid(), 4096, b"probe")  # the first page is never mapped
    assert not answer.can_borrow(2**22 + 12345, at, b"probe")  # past the default pid_max: no such process
