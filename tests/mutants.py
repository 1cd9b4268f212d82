"""A seeded, deterministic file mutator and a small corpus of every format family, written at test
time by the tools that write them in practice (meshio's writers, VTK's writers, gmsh's format).

Mutations: byte flips, truncation, swapped lines, duplicated lines, bad numbers (a number replaced
by a huge, negative, NaN or non-numeric token), zeroed blocks. `mutants(data, seed, n)` gives n
mutated copies of `data`, the same ones for the same seed on every machine.
"""

from __future__ import annotations

import random
import re
from pathlib import Path

import numpy as np

NUMBER = re.compile(rb"-?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?")
BAD_NUMBERS = [b"-1", b"999999999", b"nan", b"1e308", b"x", b"", b"0", b"-2147483649", b"3.5"]


def flip_bytes(data: bytes, rnd: random.Random) -> bytes:
    b = bytearray(data)
    for _ in range(rnd.randint(1, 8)):
        i = rnd.randrange(len(b))
        b[i] ^= 1 << rnd.randrange(8)
    return bytes(b)


def truncate(data: bytes, rnd: random.Random) -> bytes:
    return data[: rnd.randrange(1, max(2, len(data) - 1))]


def _lines(data: bytes) -> list[bytes]:
    return data.split(b"\n")


def swap_lines(data: bytes, rnd: random.Random) -> bytes:
    lines = _lines(data)
    if len(lines) < 3:
        return flip_bytes(data, rnd)
    i, j = rnd.sample(range(len(lines)), 2)
    lines[i], lines[j] = lines[j], lines[i]
    return b"\n".join(lines)


def duplicate_line(data: bytes, rnd: random.Random) -> bytes:
    lines = _lines(data)
    i = rnd.randrange(len(lines))
    lines.insert(i, lines[i])
    return b"\n".join(lines)


def bad_number(data: bytes, rnd: random.Random) -> bytes:
    found = list(NUMBER.finditer(data[:200_000]))
    if not found:
        return flip_bytes(data, rnd)
    out = data
    for m in sorted(rnd.sample(found, min(len(found), rnd.randint(1, 3))), key=lambda m: -m.start()):
        out = out[: m.start()] + rnd.choice(BAD_NUMBERS) + out[m.end() :]
    return out


def zero_block(data: bytes, rnd: random.Random) -> bytes:
    i = rnd.randrange(len(data))
    n = rnd.randint(1, 64)
    return data[:i] + b"\0" * min(n, len(data) - i) + data[i + n :]


def random_block(data: bytes, rnd: random.Random) -> bytes:
    i = rnd.randrange(len(data))
    n = rnd.randint(1, 32)
    return data[:i] + bytes(rnd.randrange(256) for _ in range(n)) + data[i + n :]


MUTATORS = (flip_bytes, truncate, swap_lines, duplicate_line, bad_number, zero_block, random_block)


def mutants(data: bytes, seed: int, n: int) -> list[tuple[str, bytes]]:
    """n mutants of `data` as (what was done, bytes); each mutant a seeded choice of mutator."""
    rnd = random.Random(seed)
    out = []
    for _ in range(n):
        fn = rnd.choice(MUTATORS)
        out.append((fn.__name__, fn(data, rnd)))
    return out


# ---------------------------------------------------------------- the corpus (small files)


def _grid(n: int = 3):
    """A tetrahedral cube (6 tets per hex), n^3 hexes: points, tets, and a triangulated square."""
    xs = np.linspace(0.0, 1.0, n + 1)
    x, y, z = np.meshgrid(xs, xs, xs, indexing="ij")
    pts = np.c_[x.ravel(), y.ravel(), z.ravel()]
    idx = np.arange((n + 1) ** 3).reshape(n + 1, n + 1, n + 1)
    c = [idx[:-1, :-1, :-1], idx[1:, :-1, :-1], idx[1:, 1:, :-1], idx[:-1, 1:, :-1]]
    c += [idx[:-1, :-1, 1:], idx[1:, :-1, 1:], idx[1:, 1:, 1:], idx[:-1, 1:, 1:]]
    h = np.stack([a.ravel() for a in c], axis=1)
    tets = np.concatenate(
        [h[:, [0, 1, 3, 4]], h[:, [1, 2, 3, 6]], h[:, [1, 3, 4, 6]], h[:, [3, 4, 6, 7]], h[:, [1, 4, 5, 6]]]
    )
    return pts, tets, h


def _square(n: int = 4):
    xs = np.linspace(0.0, 1.0, n + 1)
    x, y = np.meshgrid(xs, xs)
    pts = np.c_[x.ravel(), y.ravel(), np.zeros(x.size)]
    a = (np.arange(n)[None, :] + (n + 1) * np.arange(n)[:, None]).ravel()
    tri = np.r_[np.c_[a, a + 1, a + n + 2], np.c_[a, a + n + 2, a + n + 1]]
    return pts, tri


def _vtk_grid(pts, cells, vtk_type):
    import vtk
    from vtk.util.numpy_support import numpy_to_vtk, numpy_to_vtkIdTypeArray

    g = vtk.vtkUnstructuredGrid()
    p = vtk.vtkPoints()
    p.SetData(numpy_to_vtk(np.ascontiguousarray(pts, dtype=np.float64), deep=True))
    g.SetPoints(p)
    n, w = cells.shape
    flat = np.c_[np.full(n, w), cells].astype(np.int64).ravel()
    ca = vtk.vtkCellArray()
    ca.ImportLegacyFormat(numpy_to_vtkIdTypeArray(flat, deep=True))
    g.SetCells(vtk_type, ca)
    return g


def write_corpus(folder: Path) -> dict[str, Path]:
    """One small valid file per format family and variant: name -> path."""
    import meshio
    import vtk

    folder.mkdir(parents=True, exist_ok=True)
    pts, tets, hexes = _grid()
    sq, tri = _square()
    vol = meshio.Mesh(pts, [("tetra", tets)], cell_data={"gmsh:physical": [np.ones(len(tets), int)]})
    files: dict[str, Path] = {}

    def out(name: str) -> Path:
        files[name] = folder / name
        return files[name]

    meshio.write(out("gmsh22.msh"), vol, file_format="gmsh22", binary=False)
    meshio.write(out("gmsh41.msh"), vol, file_format="gmsh", binary=False)
    meshio.write(out("gmsh41_bin.msh"), vol, file_format="gmsh", binary=True)
    meshio.write(out("inline.vtu"), vol, binary=False)
    plain = meshio.Mesh(pts, [("tetra", tets)])
    meshio.write(out("appended.vtu"), plain, binary=True, compression=None)
    meshio.write(out("compressed.vtu"), plain, binary=True, compression="zlib")
    meshio.write(out("ascii.vtk"), plain, binary=False)
    meshio.write(out("binary.vtk"), plain, binary=True)
    meshio.write(out("mesh.ucd"), meshio.Mesh(pts, [("tetra", tets)]), file_format="avsucd")
    surf = meshio.Mesh(sq, [("triangle", tri)])
    meshio.write(out("square.obj"), surf)
    meshio.write(out("square.ply"), surf, binary=False)
    meshio.write(out("square_bin.ply"), surf, binary=True)
    meshio.write(out("square.stl"), surf, binary=False)
    meshio.write(out("square.off"), surf)
    meshio.write(out("mesh.xdmf"), plain, data_format="XML")
    # VTK's own writers: legacy binary (4.2 layout), XML appended raw, and Exodus II
    grid = _vtk_grid(pts, hexes, vtk.VTK_HEXAHEDRON)
    w = vtk.vtkUnstructuredGridWriter()
    w.SetFileName(str(out("vtk_binary.vtk")))
    w.SetFileTypeToBinary()
    w.SetFileVersion(42)
    w.SetInputData(grid)
    w.Write()
    w = vtk.vtkXMLUnstructuredGridWriter()
    w.SetFileName(str(out("vtk_raw.vtu")))
    w.SetDataModeToAppended()
    w.EncodeAppendedDataOff()
    w.SetInputData(grid)
    w.Write()
    # Exodus II through IOSS (vtkExodusIIWriter itself segfaults on a plain grid in VTK 9.5)
    coll = vtk.vtkPartitionedDataSetCollection()
    part = vtk.vtkPartitionedDataSet()
    part.SetPartition(0, grid)
    coll.SetPartitionedDataSet(0, part)
    coll.GetMetaData(0).Set(vtk.vtkCompositeDataSet.NAME(), "block_1")
    w = vtk.vtkIOSSWriter()
    w.SetFileName(str(out("mesh.exo")))
    w.SetInputData(coll)
    w.Write()
    # the families VTK's writers do not cover here (tests/format_writers.py): meshio's Exodus II and
    # XDMF + HDF5 writers, and CGNS, Gambit, binary AVS UCD and Fluent written by their specs
    import format_writers as fw

    bp, bblocks = fw.blocks(2, 2, 2)
    fw.write_exodus(out("blocks.e"), bp, bblocks)
    fw.write_xdmf(out("mesh_h5.xdmf"), bp, bblocks)  # its heavy data: mesh_h5.h5 beside it
    fw.write_cgns(
        out("zones.cgns"), [(zp, [("hexahedron", zc)]) for zp, zc in fw.split_zones(*fw.grid(2, 2, 1))]
    )
    fw.write_gambit(out("mesh.neu"), bp, bblocks)
    fw.write_avs_binary(out("mesh_bin.inp"), bp, bblocks)
    fw.write_fluent(out("fluent.msh"), *fw.grid(2, 2, 1))
    fp, fh = fw.grid(2, 2, 1)
    fw.write_fluent_h5(out("zones_fluent.cas.h5"), fp, [("hexahedron", fh)])  # Fluent CFF (HDF5)
    if fw.cgns_library() is not None:  # CGNS/ADF by the CGNS library of the vtk wheel
        fw.write_cgns_lib(
            out("zones_adf.cgns"), [(zp, [("hexahedron", zc)]) for zp, zc in fw.split_zones(fp, fh)]
        )
    return files


def vtk_read(path: str) -> int:
    """Read `path` with VTK's own reader for its extension (the C++ code that crashes on some mutants);
    the number of cells read."""
    import vtk

    vtk.vtkObject.GlobalWarningDisplayOff()
    if path.endswith((".exo", ".e")):
        r = vtk.vtkExodusIIReader()
        r.SetFileName(path)
        r.UpdateInformation()
        for i in range(r.GetNumberOfObjects(vtk.vtkExodusIIReader.ELEM_BLOCK)):
            r.SetObjectStatus(vtk.vtkExodusIIReader.ELEM_BLOCK, i, 1)
        r.Update()
        out = r.GetOutput()
        it = out.NewIterator()
        it.InitTraversal()
        n = 0
        while not it.IsDoneWithTraversal():
            n += it.GetCurrentDataObject().GetNumberOfCells()
            it.GoToNextItem()
        return n
    r = vtk.vtkXMLUnstructuredGridReader() if path.endswith(".vtu") else vtk.vtkUnstructuredGridReader()
    r.SetFileName(path)
    r.Update()
    return r.GetOutput().GetNumberOfCells()


def read_mutants(folder: Path, data: bytes, stem: str, suffix: str, fmt: str, seed: int, n: int) -> dict:
    """n mutants of `data` written as folder/{stem}{i}{suffix}, each read in the sandbox as the
    service reads: a Mesh, or one sentence naming the file and `fmt` with no library text (a crash or
    a hang of a native reader is a sentence too). Returns {"mesh": count, "refused": count}."""
    from test_read_fuzz import RAW_RE

    from models.errors import MeshError, ParameterError
    from models.mesh.container import Mesh
    from models.mesh.sandbox import read_mesh_safe

    out = {"mesh": 0, "refused": 0}
    for i, (how, bad) in enumerate(mutants(data, seed=seed, n=n)):
        path = folder / f"{stem}{i}{suffix}"
        path.write_bytes(bad)
        try:
            mesh = read_mesh_safe(str(path), timeout_s=20, memory_bytes=2 << 30)
        except (MeshError, ParameterError) as exc:
            msg = str(exc)
            out["refused"] += 1
            assert path.name in msg and fmt in msg, (how, msg)
            assert not RAW_RE.search(msg) and "\n" not in msg, (how, msg)
        else:
            assert isinstance(mesh, Mesh) and mesh.n_cells > 0
            out["mesh"] += 1
    return out
