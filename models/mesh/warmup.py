"""The reader zygote's warm-up (models.mesh.zygote): what it reads once before it says ready, and
what each spare child does while it waits for its request, so that neither the zygote's first read
nor a child's read pays first-call costs or fresh pages."""

from __future__ import annotations

import os
import pickle
import select
import socket

from models.mesh.answer import dump

# one tetrahedron, read once by the zygote before it says ready (with the files of _warm_up_files):
# the first call's costs (VTK's object factories, numpy's and the validation's first paths) are
# paid there, not by every child
_WARMUP = (
    b"# vtk DataFile Version 4.2\nwarm-up\nASCII\nDATASET UNSTRUCTURED_GRID\nPOINTS 4 double\n"
    b"0 0 0 1 0 0 0 1 0 0 0 1\nCELLS 1 5\n4 0 1 2 3\nCELL_TYPES 1\n10\n"
)
_HEAP = 1 << 30  # a spare's blocks up to this size come from its heap, kept when freed
_PREFAULT = 64 << 20  # heap a spare touches while it waits (its resident memory meanwhile)


def apply_environ(env: dict) -> None:
    """os.environ made `env`, setting only what differs (each change is a putenv)."""
    for key in [k for k in os.environ if k not in env]:
        del os.environ[key]
    for key, value in env.items():
        if os.environ.get(key) != value:
            os.environ[key] = value


def warm_up(folder: str) -> list[str]:
    """Write a small file of each kind the bench and the service meet most (legacy VTK binary and
    ASCII, VTU appended, VTI, VTS, Exodus II; VTK's and meshio's writers) into `folder` and read
    each: every module a reader imports lazily is imported here, and each reader's first-call
    costs are paid here, once, instead of by every child. The paths read (the spares read them again)."""
    from models.mesh.read import read_mesh

    path = os.path.join(folder, "warm-up.vtk")
    with open(path, "wb") as f:
        f.write(_WARMUP)
    paths = [path]
    try:
        paths += _warm_up_files(folder)
    except Exception:  # noqa: BLE001  (a warm-up only: the reads work without it)
        pass
    read = []
    for path in paths:
        try:
            read_mesh(path)
            read.append(path)
        except Exception:  # noqa: BLE001
            pass
    return read


def prewarm(conn: socket.socket, paths: list[str]) -> None:
    """A spare's warm-up while it waits, given up as soon as the request comes (checked between
    steps of a few milliseconds): the warm-up files read again, so the pages the readers write
    (reference counts, VTK's and numpy's state) are copied from the zygote's now, not during the
    read, each read as the request's will be (its builder deferred: sandbox._read_in_child) and
    its answer dumped as the request's will be (lent, into a scratch memfd), and a request's own
    steps once (unpickled, its environment applied); then heap memory touched once and kept (glibc:
    blocks up to 1 GiB from the heap, not given back when freed), so the read's arrays land on
    pages already mapped. Trusted files only (written by the zygote itself)."""
    from models.mesh import deferred
    from models.mesh.read import read_mesh

    deferred.DEFER = True  # as sandbox._read_in_child reads (and only for these reads)
    scratch = os.memfd_create("magnet-warm", os.MFD_CLOEXEC)
    try:
        for path in paths:
            if select.select([conn], [], [], 0)[0]:
                return
            try:
                dump(("ok", read_mesh(path)), scratch, lend=True)
                os.ftruncate(scratch, 0)
            except Exception:  # noqa: BLE001
                pass
        request = (read_mesh, ("x", {"weld": None}), 1 << 30, 60.0, dict(os.environ), os.getcwd())
        apply_environ(pickle.loads(pickle.dumps(request))[4])
    finally:
        deferred.DEFER = False
        os.close(scratch)
    try:
        import ctypes

        libc = ctypes.CDLL(None)
        libc.malloc.restype = ctypes.c_void_p
        libc.malloc.argtypes = [ctypes.c_size_t]
        libc.free.argtypes = [ctypes.c_void_p]
        if not (
            libc.mallopt(-3, _HEAP) and libc.mallopt(-1, 2 * _HEAP)
        ):  # M_MMAP_THRESHOLD, M_TRIM_THRESHOLD
            return
        block = libc.malloc(_PREFAULT)
    except Exception:  # noqa: BLE001  (not glibc: the read faults its pages in itself)
        return
    if block:
        try:
            step = 4 << 20
            for at in range(0, _PREFAULT, step):
                if select.select([conn], [], [], 0)[0]:
                    break
                ctypes.memset(block + at, 0, step)
        finally:
            libc.free(block)


def _warm_up_files(folder: str) -> list[str]:
    import numpy as np
    from vtkmodules.util.numpy_support import numpy_to_vtk, numpy_to_vtkIdTypeArray
    from vtkmodules.vtkCommonCore import VTK_UNSIGNED_CHAR, vtkPoints
    from vtkmodules.vtkCommonDataModel import (
        vtkCellArray,
        vtkImageData,
        vtkStructuredGrid,
        vtkUnstructuredGrid,
    )
    from vtkmodules.vtkIOLegacy import vtkDataSetWriter
    from vtkmodules.vtkIOXML import (
        vtkXMLImageDataWriter,
        vtkXMLStructuredGridWriter,
        vtkXMLUnstructuredGridWriter,
    )

    n = 2  # cells per side
    g = np.arange(n + 1, dtype=np.float64)
    z, y, x = np.meshgrid(g, g, g, indexing="ij")  # x fastest
    points = np.column_stack([x.ravel(), y.ravel(), z.ravel()])
    i, j, k = (a.ravel() for a in np.meshgrid(*(np.arange(n),) * 3, indexing="ij"))
    b = i + (n + 1) * (j + (n + 1) * k)
    sx, sy, sz = 1, n + 1, (n + 1) ** 2
    hexes = np.stack([b, b + sx, b + sx + sy, b + sy, b + sz, b + sz + sx, b + sz + sx + sy, b + sz + sy], 1)
    kuhn = [[0, 1, 2, 6], [0, 2, 3, 6], [0, 3, 7, 6], [0, 7, 4, 6], [0, 4, 5, 6], [0, 5, 1, 6]]
    tets = np.concatenate([hexes[:, q] for q in kuhn])

    def grid(cells, vtk_type):
        ug = vtkUnstructuredGrid()
        pts = vtkPoints()
        pts.SetData(numpy_to_vtk(points, deep=True))
        ug.SetPoints(pts)
        offsets = np.arange(len(cells) + 1, dtype=np.int64) * cells.shape[1]
        ca = vtkCellArray()
        ca.SetData(
            numpy_to_vtkIdTypeArray(offsets, deep=True),
            numpy_to_vtkIdTypeArray(cells.astype(np.int64).ravel(), deep=True),
        )
        types = np.full(len(cells), vtk_type, np.uint8)
        ug.SetCells(numpy_to_vtk(types, deep=True, array_type=VTK_UNSIGNED_CHAR), ca)
        return ug

    hex_grid, tet_grid = grid(hexes, 12), grid(tets, 10)
    image = vtkImageData()
    image.SetDimensions(n + 1, n + 1, n + 1)
    structured = vtkStructuredGrid()
    structured.SetDimensions(n + 1, n + 1, n + 1)
    pts = vtkPoints()
    pts.SetData(numpy_to_vtk(points, deep=True))
    structured.SetPoints(pts)
    out = []
    for name, writer, data, setup in (
        ("hex.vtk", vtkDataSetWriter, hex_grid, ("SetFileTypeToBinary",)),
        ("tet.vtk", vtkDataSetWriter, tet_grid, ()),
        ("tet.vtu", vtkXMLUnstructuredGridWriter, tet_grid, ("SetDataModeToAppended",)),
        (
            "hex.vtu",
            vtkXMLUnstructuredGridWriter,
            hex_grid,
            ("SetDataModeToAppended", "EncodeAppendedDataOff"),
        ),
        ("image.vti", vtkXMLImageDataWriter, image, ("SetDataModeToAppended",)),
        ("grid.vts", vtkXMLStructuredGridWriter, structured, ("SetDataModeToAppended",)),
    ):
        path = os.path.join(folder, name)
        w = writer()
        w.SetFileName(path)
        w.SetInputData(data)
        for call in setup:
            getattr(w, call)()
        if w.Write() == 1:
            out.append(path)
    try:
        import meshio

        path = os.path.join(folder, "hex.exo")
        meshio.write(path, meshio.Mesh(points, [("hexahedron", hexes)]), file_format="exodus")
        out.append(path)
    except Exception:  # noqa: BLE001  (no netCDF4: no Exodus II warm-up)
        pass
    return out
