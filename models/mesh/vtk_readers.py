"""The formats VTK is the reference for, read by VTK's own readers (the `vtk` wheel, imported here
only, lazily: a file that needs no VTK never loads it).

Legacy VTK (every version and dataset), VTK XML (.vtu .vtp .vti .vts .vtr and their parallel
forms), Exodus II, XDMF, CGNS, Fluent (.cas, .msh, .cas.h5), Gambit (.neu), binary AVS UCD.
VTK's arrays become ours with vtk_to_numpy (offsets, connectivity, types: no loop over cells);
structured datasets (image data, structured and rectilinear grids) get their quads / hexahedra
from their dimensions. Composite outputs (element blocks, zones) are joined: blocks that share the
file's point set (Exodus with SqueezePoints off, Fluent zones) keep it, others have their
coincident points merged, as vtkAppendFilter's MergePoints does.

VTK's readers report errors on the output window, not as exceptions: they are captured and turned
into one sentence of ours (file, format, what was wrong and where, when VTK says where).
"""

from __future__ import annotations

import os
import re

import numpy as np

from models.errors import MeshError, ParameterError
from models.mesh.cells import BOUNDARY_TAG_NAME, TAG_NAMES, Normalized, normalize, ranges
from models.mesh.lattice import grid_points, image_points, structured_cells

# extension -> (what the file is, VTK reader class, its module)
_XML = "vtkmodules.vtkIOXML"
READERS: dict[str, tuple[str, str, str]] = {
    "legacy": ("legacy VTK", "vtkDataSetReader", "vtkmodules.vtkIOLegacy"),
    ".vtu": ("VTK XML unstructured grid", "vtkXMLUnstructuredGridReader", _XML),
    ".pvtu": ("VTK XML parallel unstructured grid", "vtkXMLPUnstructuredGridReader", _XML),
    ".vtp": ("VTK XML polydata", "vtkXMLPolyDataReader", _XML),
    ".pvtp": ("VTK XML parallel polydata", "vtkXMLPPolyDataReader", _XML),
    ".vti": ("VTK XML image data", "vtkXMLImageDataReader", _XML),
    ".pvti": ("VTK XML parallel image data", "vtkXMLPImageDataReader", _XML),
    ".vts": ("VTK XML structured grid", "vtkXMLStructuredGridReader", _XML),
    ".pvts": ("VTK XML parallel structured grid", "vtkXMLPStructuredGridReader", _XML),
    ".vtr": ("VTK XML rectilinear grid", "vtkXMLRectilinearGridReader", _XML),
    ".pvtr": ("VTK XML parallel rectilinear grid", "vtkXMLPRectilinearGridReader", _XML),
    ".vtm": ("VTK XML multiblock", "vtkXMLMultiBlockDataReader", _XML),
    ".vtpc": ("VTK XML partitioned dataset collection", "vtkXMLPartitionedDataSetCollectionReader", _XML),
    ".vtpd": ("VTK XML partitioned dataset", "vtkXMLPartitionedDataSetReader", _XML),
    ".pvd": ("ParaView data collection", "vtkXMLGenericDataObjectReader", _XML),
    "xml": ("VTK XML", "vtkXMLGenericDataObjectReader", _XML),
    "exodus": ("Exodus II", "vtkExodusIIReader", "vtkmodules.vtkIOExodus"),
    "xdmf": ("XDMF", "vtkXdmfReader", "vtkmodules.vtkIOXdmf2"),
    "cgns": ("CGNS", "vtkCGNSReader", "vtkmodules.vtkIOCGNSReader"),
    "fluent": ("Fluent case", "vtkFLUENTReader", "vtkmodules.vtkIOGeometry"),
    "fluent-h5": ("Fluent HDF5 case", "vtkFLUENTCFFReader", "vtkmodules.vtkIOFLUENTCFF"),
    "gambit": ("Gambit neutral", "vtkGAMBITReader", "vtkmodules.vtkIOGeometry"),
    "vtkhdf": ("VTKHDF", "vtkHDFReader", "vtkmodules.vtkIOHDF"),
    "avs-binary": ("binary AVS UCD", "vtkAVSucdReader", "vtkmodules.vtkIOGeometry"),
    "avs": ("AVS UCD", "vtkAVSucdReader", "vtkmodules.vtkIOGeometry"),
    "openfoam": ("OpenFOAM case", "vtkOpenFOAMReader", "vtkmodules.vtkIOGeometry"),
    "openfoam-decomposed": ("OpenFOAM case", "vtkPOpenFOAMReader", "vtkmodules.vtkIOParallel"),
    "plot3d": ("PLOT3D grid", "vtkMultiBlockPLOT3DReader", "vtkmodules.vtkIOParallel"),
    "ensight": ("EnSight case", "vtkGenericEnSightReader", "vtkmodules.vtkIOEnSight"),
}
# parallel files whose pieces are separate point sets: read piece by piece, joined as a composite's
# blocks are (points on the cuts between pieces, written once per piece, merged)
PIECEWISE = (".pvtu", ".pvtp", ".vtpd", ".pvd")
EXODUS_EXTENSIONS = (".exo", ".e", ".ex2", ".exii", ".g", ".gen")
HIDDEN_CELL, HIDDEN_POINT, DUPLICATE_CELL = 32, 2, 1  # vtkDataSetAttributes ghost bits


def read_vtk(
    path: str, kind: str, physical_tag: str | None = None, weld: float | None = None, fmt: str | None = None
):
    """Read `path` with VTK's reader for `kind` (a key of READERS) and build our `Mesh`. fmt: the
    format's name as users know it (formats.format_name), in every refusal; the reader's own by default.
    A refusal names the file, the format and, when VTK says it, the place; never VTK's class names."""
    what, cls, _ = READERS[kind]
    fmt = fmt or what
    data = _run(path, kind, fmt)
    meta = {"reader": f"VTK {cls}", "format": what}
    if weld is None:
        mesh = _image_mesh(data, physical_tag, meta, path)
        if mesh is not None:
            return mesh
    if kind.startswith("openfoam"):
        pts, offsets, conn, types, cell_data, poly, field = _openfoam(
            data, path, what, fmt, kind == "openfoam-decomposed"
        )
    else:
        pts, offsets, conn, types, cell_data, poly = _arrays(data, path, what, fmt, kind not in PIECEWISE)
        field = _field_data(data)
        if kind == "exodus":
            field.update(_exodus_names(data))
        elif kind == "ensight":
            field.update(_part_names(data))
    grid = _lattice(data, len(types))
    live = _whole_live(data, len(types))
    del data
    if len(types) == 0:
        raise MeshError(
            f"cannot read {os.path.basename(path)} as {fmt}: it holds no cells "
            f"(is it truncated, or not {article(what)} file?)"
        )
    tag_key = _tag_key(cell_data, physical_tag)
    tags = None if tag_key is None else _int_tags(cell_data[tag_key], len(types))
    btags = cell_data.get(BOUNDARY_TAG_NAME)
    btags = None if btags is None else _int_tags(btags, len(types))
    norm = _lattice_cells(live, offsets, conn, types, tags)
    if norm is None:
        try:
            norm = normalize(offsets, conn, types, tags=tags, bnd_tags=btags, poly=poly, n_points=len(pts))
        except MeshError as exc:
            raise MeshError(f"cannot read {os.path.basename(path)} as {fmt}: {exc}") from None
    if norm.notes:
        meta["higher_order"] = "; ".join(norm.notes)
        meta["higher_order_unused_points"] = norm.unused_higher
    if norm.overlong:
        meta["overlong_cells"] = norm.overlong
    grid = grid if norm.types.size == len(types) and norm.dim == 3 else None
    return mesh_of_cells(pts, norm, tag_key, weld, meta, grid, field)


def mesh_of_cells(pts, norm: Normalized, tag_key, weld, meta: dict, grid, field: dict):
    """build.mesh_from_cells of a reader's points and normalized cells, then the group names of its
    field data: the end of read_vtk (and of models/mesh/xml_grid.py, which makes the same arrays).
    grid: _lattice's hint, or None."""
    from models.mesh.boundary import group_names
    from models.mesh.build import mesh_from_cells

    mesh = mesh_from_cells(
        np.asarray(pts, dtype=np.float64),
        norm.offsets,
        norm.connectivity,
        norm.types,
        None if norm.tags is None else norm.tags.astype(np.int64),
        tag_key,
        norm.poly_faces,
        norm.bnd,
        norm.lower,
        norm.dim,
        weld=weld,
        meta=meta,
        grid=grid,
    )
    mesh.meta["group_names"], mesh.meta["boundary_names"] = group_names(field, mesh.dim)
    return mesh


def _exodus_names(data) -> dict:
    """Exodus element blocks' and side sets' names as meshio's field_data {name: [id, dim]} (the
    id their cells carry as ObjectId; dim: their cells' dimension), those the file names only."""
    out = {}
    it = data.NewIterator()
    it.InitTraversal()
    while not it.IsDoneWithTraversal():
        ds, meta = it.GetCurrentDataObject(), it.GetCurrentMetaData()
        name = meta.Get(data.NAME()) if meta is not None and meta.Has(data.NAME()) else None
        ids = ds.GetCellData().GetArray("ObjectId") if ds is not None and ds.IsA("vtkDataSet") else None
        if name and not name.startswith("Unnamed") and ids is not None and ds.GetNumberOfCells():
            out[str(name)] = np.array([int(ids.GetValue(0)), ds.GetCell(0).GetCellDimension()])
        it.GoToNextItem()
    return out


def _part_names(data) -> dict:
    """An EnSight case's part descriptions as the names of its blocks (_composite numbers the
    non-empty leaves 1, 2, ... in order): {name: [block, dim of its cells]}."""
    out = {}
    it = data.NewIterator()
    it.SkipEmptyNodesOn()
    it.InitTraversal()
    block = 0
    while not it.IsDoneWithTraversal():
        ds, meta = it.GetCurrentDataObject(), it.GetCurrentMetaData()
        if ds is not None and ds.IsA("vtkDataSet") and ds.GetNumberOfCells() > 0:
            block += 1
            name = meta.Get(data.NAME()) if meta is not None and meta.Has(data.NAME()) else None
            if name:
                out[str(name).strip()] = np.array([block, ds.GetCell(0).GetCellDimension()])
        it.GoToNextItem()
    return out


def _field_data(data) -> dict:
    """The dataset's field data {name: array} (group names as meshio's field_data: [tag, dim])."""
    fd = data.GetFieldData()
    out = {}
    for i in range(fd.GetNumberOfArrays() if fd is not None else 0):
        a = fd.GetArray(i)
        if a is not None and a.GetName():
            out[a.GetName()] = _np(a).reshape(-1)
    return out


def _tag_key(cell_data: dict, physical_tag: str | None) -> str | None:
    if physical_tag is not None:
        if physical_tag not in cell_data:
            raise ParameterError(
                f"physical tag {physical_tag!r} not found in the mesh cell data; available: {sorted(cell_data) or 'none'}"
            )
        return physical_tag
    return next((k for k in TAG_NAMES if k in cell_data), None)


def _int_tags(a: np.ndarray, n: int) -> np.ndarray | None:
    a = np.asarray(a)
    if a.ndim != 1 or len(a) != n or not np.issubdtype(a.dtype, np.number):
        return None
    return a.astype(np.int64)


# ---- running a reader, its errors captured ------------------------------------------------------


class _Captured:
    """VTK's output window replaced by a string window while a reader runs."""

    def __enter__(self):
        from vtkmodules.vtkCommonCore import vtkLogger, vtkOutputWindow, vtkStringOutputWindow

        self.verbosity = vtkLogger.GetCurrentVerbosityCutoff()
        vtkLogger.SetStderrVerbosity(vtkLogger.VERBOSITY_OFF)  # VTK's logger prints errors itself
        self.prev = vtkOutputWindow.GetInstance()
        self.win = vtkStringOutputWindow()
        vtkOutputWindow.SetInstance(self.win)
        self.errors: list[str] = []
        return self

    def _on_error(self, _obj, _event, data=None):
        if isinstance(data, bytes):  # a message quoting the file's bytes that are not UTF-8
            data = data.decode("utf-8", "replace")
        self.errors.append(str(data or "error"))

    _on_error.CallDataType = 8  # VTK_STRING: the message comes as call data

    def __exit__(self, *exc):
        from vtkmodules.vtkCommonCore import vtkLogger, vtkOutputWindow

        text = self.win.GetOutput() or ""
        if isinstance(text, bytes):
            text = text.decode("utf-8", "replace")
        vtkOutputWindow.SetInstance(self.prev)
        vtkLogger.SetStderrVerbosity(self.verbosity)
        self.text = "\n".join([*self.errors, text])
        self.failed = bool(self.errors) or "ERROR" in text
        return False


def _run(path: str, kind: str, fmt: str | None = None):
    import importlib

    what, cls, module = READERS[kind]
    fmt = fmt or what
    reader = getattr(importlib.import_module(module), cls)()
    name = os.path.basename(path)
    if kind == ".pvd":
        return _collection(path, fmt)
    with _Captured() as cap:
        reader.AddObserver("ErrorEvent", cap._on_error)
        if kind == "ensight":  # (its parts: our blocks; no variable read)
            reader.SetCaseFileName(path)
            reader.ReadAllVariablesOff()
        else:
            reader.SetFileName(path)
        if kind == "exodus":
            reader.UpdateInformation()
            reader.SetAllArrayStatus(reader.ELEM_BLOCK, 1)
            reader.SetSqueezePoints(False)  # every block keeps the file's node numbering
            for i in range(reader.GetNumberOfSideSetArrays()):  # side sets: boundary groups
                reader.SetSideSetArrayStatus(reader.GetSideSetArrayName(i), 1)
        elif kind == "cgns":
            reader.UpdateInformation()
            reader.EnableAllBases()
        elif kind in ("fluent", "fluent-h5"):
            reader.UpdateInformation()
            _fluent_cell_zones_only(reader)
        elif kind == "avs-binary":
            reader.SetBinaryFile(1)
        elif kind == "plot3d":
            _plot3d_layout(reader, path)
        elif kind.startswith("openfoam"):
            if kind == "openfoam-decomposed":
                reader.SetCaseType(0)  # processor*/ (vtkPOpenFOAMReader's DECOMPOSED_CASE)
            _openfoam_mesh_only(reader)
        elif kind == "legacy":
            reader.ReadAllScalarsOn()
            reader.ReadAllFieldsOn()
        if kind in PIECEWISE:
            out = _pieces(reader)
        else:
            reader.Update()
            out = reader.GetOutputDataObject(0)
    if cap.failed:
        why = _foam_place(cap.text) if kind.startswith("openfoam") else None
        raise MeshError(f"cannot read {name} as {fmt}: {why or explain(cap.text, what)}")
    if out is None:
        raise MeshError(f"cannot read {name} as {fmt}: the reader produced no data")
    return out


_PVD_DATASET = re.compile(rb"<DataSet\b([^>]*)>")
_PVD_ATTR = re.compile(rb"""\b(timestep|part|file)\s*=\s*["']([^"']*)["']""")


def _collection(path: str, fmt: str):
    """A ParaView data collection (.pvd, a time series as FEniCS and many solvers write it): the
    mesh of its first time step, that step's parts (a part per process) read by VTK's XML readers
    and joined as a parallel file's pieces. read._pieces_present has checked that the files are
    there, inside the file's folder."""
    from vtkmodules.vtkCommonDataModel import vtkMultiBlockDataSet
    from vtkmodules.vtkIOXML import vtkXMLGenericDataObjectReader

    name = os.path.basename(path)
    with open(path, "rb") as fh:
        text = fh.read()
    steps = []
    for m in _PVD_DATASET.finditer(text):
        attrs = {k.decode(): v.decode("utf-8", "replace") for k, v in _PVD_ATTR.findall(m.group(1))}
        if "file" in attrs:
            try:
                t = float(attrs.get("timestep", "0") or 0)
            except ValueError:
                t = 0.0
            steps.append((t, attrs["file"]))
    if not steps:
        raise MeshError(f"cannot read {name} as {fmt}: it lists no data set (no <DataSet file=...>)")
    first = min(t for t, _ in steps)
    files = [f for t, f in steps if t == first]
    folder = os.path.dirname(os.path.abspath(path))
    out = vtkMultiBlockDataSet()
    with _Captured() as cap:
        for i, f in enumerate(files):
            reader = vtkXMLGenericDataObjectReader()
            reader.AddObserver("ErrorEvent", cap._on_error)
            reader.SetFileName(os.path.join(folder, f))
            reader.Update()
            data = reader.GetOutputDataObject(0)
            if data is not None:
                out.SetBlock(i, data)
    if cap.failed:
        raise MeshError(
            f"cannot read {name} as {fmt}: its data set {files[0]}: {explain(cap.text, 'VTK XML')}"
        )
    return out


def _pieces(reader):
    """A parallel reader's pieces, each read on its own, as the blocks of a multiblock dataset
    (VTK's own reading appends them with every cut point twice, so that the pieces do not touch)."""
    from vtkmodules.vtkCommonDataModel import vtkMultiBlockDataSet

    reader.UpdateInformation()
    n = reader.GetNumberOfPieces()
    if n < 2:
        reader.Update()
        return reader.GetOutputDataObject(0)
    out = vtkMultiBlockDataSet()
    for i in range(n):
        reader.UpdatePiece(i, n, 0)
        piece = reader.GetOutputDataObject(0)
        block = piece.NewInstance()
        block.ShallowCopy(piece)
        out.SetBlock(i, block)
    return out


def _plot3d_layout(reader, path: str) -> None:
    """A PLOT3D grid file's layout for VTK's reader: a binary one (C or Fortran records, either byte
    order, single or double precision, iblanks) its own detection finds; an ASCII one it does not,
    so the layout is read off its numbers: one grid or several (a first line of one number), 2D or
    3D (numbers of its dimension line), iblanks or not (the count of the numbers after them)."""
    with open(path, "rb") as fh:
        head = fh.read(4096)
    if not head or any(b > 127 or (b < 32 and b not in b"\t\r\n") for b in head):
        reader.AutoDetectFormatOn()
        return
    with open(path, "rb") as fh:
        text = fh.read()
    lines = text.split(b"\n", 2)
    first = lines[0].split()
    multi = len(first) == 1
    grids = int(first[0]) if multi and first[0].isdigit() else 1
    dims_line = (lines[1] if multi and len(lines) > 1 else lines[0]).split()
    dim = 2 if len(dims_line) == 2 * grids else 3
    reader.SetBinaryFile(0)
    reader.SetDoublePrecision(1)  # (an ASCII file's decimals read as doubles, not floats)
    reader.SetMultiGrid(int(multi))
    reader.SetTwoDimensionalGeometry(int(dim == 2))
    try:
        sizes = np.array([int(v) for v in dims_line[: dim * grids]], dtype=np.int64).reshape(grids, dim)
    except ValueError:
        return  # (VTK's reader says what is wrong)
    points = int(sizes.prod(axis=1).sum())
    numbers = len(text.split()) - int(multi) - dim * grids
    reader.SetIBlanking(int(numbers == (dim + 1) * points))


def _openfoam_mesh_only(reader) -> None:
    """An OpenFOAM case's mesh at its first time (constant/polyMesh): the internal mesh and every
    boundary patch (our boundary groups), no zones, no field arrays; polyhedra kept whole."""
    reader.UpdateInformation()
    reader.EnableAllPatchArrays()
    for off in ("DisableAllCellArrays", "DisableAllPointArrays", "DisableAllLagrangianArrays"):
        getattr(reader, off, lambda: None)()
    reader.SetReadZones(0)
    reader.SetCreateCellToPoint(0)
    if hasattr(reader, "SetDecomposePolyhedra"):
        reader.SetDecomposePolyhedra(0)


def _openfoam(data, path, what, fmt, decomposed: bool = False):
    """The internal mesh's cells (no group) and the boundary patches' faces as boundary cells
    tagged 1, 2, ... in the case's patch order, their names in the field data (as meshio's
    field_data: name -> [tag, 2]). The patches' points are found among the internal mesh's by their
    coordinates (the reader gives every patch its own copy); internal points that coincide (a
    baffle's two sides) stay apart, except in a decomposed case, whose processors' meshes the
    reader appends with the points on their cuts once per processor: there coincident points
    are merged (the processors' patches are not boundary groups: VTK's reader leaves them out)."""
    internal, patches = None, []
    for i in range(data.GetNumberOfBlocks()):
        name = data.GetMetaData(i).Get(data.NAME()) if data.HasMetaData(i) else ""
        block = data.GetBlock(i)
        if block is None:
            continue
        if name == "internalMesh":
            internal = block
        elif name == "boundary" and block.IsA("vtkMultiBlockDataSet"):
            for j in range(block.GetNumberOfBlocks()):
                patch = block.GetBlock(j)
                if patch is not None and patch.GetNumberOfCells() > 0:
                    patches.append((block.GetMetaData(j).Get(data.NAME()), patch))
    if internal is None or internal.GetNumberOfCells() == 0:
        raise MeshError(
            f"cannot read {os.path.basename(path)} as {fmt}: its internal mesh has no cells "
            "(constant/polyMesh: points, faces, owner, neighbour, boundary, are empty or cannot be read)"
        )
    pts, offsets, conn, types, _, poly = _dataset(internal, path, what, fmt)
    pts = np.asarray(pts, np.float64)
    if decomposed:
        pts, inverse = np.unique(pts, axis=0, return_inverse=True)
        inverse = inverse.reshape(-1)
        conn = inverse[np.asarray(conn, np.int64)]
        if poly is not None:
            poly = (poly[0], poly[1], inverse[poly[2]])
    field = {}
    if patches:
        parts = [_dataset(p, path, what, fmt) for _, p in patches]
        ppts = np.concatenate([np.asarray(p[0], np.float64) for p in parts])
        _, first, inverse = np.unique(
            np.concatenate([pts, ppts]), axis=0, return_index=True, return_inverse=True
        )
        at = first[inverse.reshape(-1)[len(pts) :]]  # each patch point's first copy
        new = at >= len(pts)  # (a patch point the internal mesh lacks: kept, at the end)
        if new.any():
            keep, where = np.unique(at[new], return_inverse=True)
            at[new] = len(pts) + where
            pts = np.concatenate([pts, np.concatenate([pts, ppts])[keep]])
        base, offs, conns, tps, tags = (
            0,
            [np.asarray(offsets, np.int64)],
            [np.asarray(conn, np.int64)],
            [types],
            [],
        )
        end = int(offsets[-1])
        for t, ((name, _), part) in enumerate(zip(patches, parts, strict=True), start=1):
            _, o, c, ty = part[:4]
            offs.append(np.asarray(o[1:], np.int64) + end)
            conns.append(at[np.asarray(c, np.int64) + base])
            tps.append(ty)
            tags.append(np.full(len(ty), t, np.int64))
            end += int(o[-1])
            base += len(part[0])
            field[str(name).rsplit("/", 1)[-1]] = np.array([t, 2])
        offsets, conn, types = np.concatenate(offs), np.concatenate(conns), np.concatenate(tps)
        cell_data = {
            BOUNDARY_TAG_NAME: np.concatenate([np.zeros(internal.GetNumberOfCells(), np.int64), *tags])
        }
    else:
        cell_data = {}
    return pts, offsets, conn, types, cell_data, poly, field


# Fluent zone types of cell zones (section 45 "(45 (id type name)())"); the rest are face zones
FLUENT_CELL_ZONES = ("fluid", "solid")


def _fluent_cell_zones_only(reader) -> None:
    """Read a Fluent case's cell zones only: VTK's reader (9.7) also outputs every face zone as a
    block, and for an ASCII mesh of hexahedra those blocks repeat a volume cell per face. Zones are
    named 'name:type'; when no zone is a known cell zone type, every zone stays selected."""
    sel = getattr(reader, "GetZoneSectionSelection", lambda: None)()
    if sel is None:
        return
    names = [sel.GetArrayName(i) for i in range(sel.GetNumberOfArrays())]
    cells = [n for n in names if n.rsplit(":", 1)[-1].lower() in FLUENT_CELL_ZONES]
    if cells:
        for n in names:
            (sel.EnableArray if n in cells else sel.DisableArray)(n)


_WHERE = re.compile(r"\b(line|column|byte index|offset|position|piece)\s*[:=]?\s*(\d+)", re.IGNORECASE)
_KINDS = (
    (("xml", "parsing"), "its XML is not well-formed"),
    (
        ("unrecognized file type", "unsupported data type", "not a vtk", "unrecognized keyword"),
        "its header or a section keyword is not one VTK knows",
    ),
    (
        ("premature", "end of file", "eof", "too short", "truncat", "unexpected end"),
        "the file ends before its data does (truncated?)",
    ),
    (("decompress", "compress", "zlib", "lz4", "lzma"), "its compressed data cannot be decompressed"),
    (("appended",), "its appended data section is broken"),
    (("base64",), "its base64 data is broken"),
    (("points",), "its point coordinates cannot be read"),
    (("cell types", "cell_types", "types"), "its cell types cannot be read"),
    (("offsets", "connectivity", "cells", "cell"), "its cells cannot be read"),
    (
        (
            "unable to open",
            "cannot open",
            "could not open",
            "failed to open",
            "can't open",
            "not a valid",
            "open file",
        ),
        "it cannot be opened as {a_what} file",
    ),
    (("netcdf", "hdf5", "h5"), "its binary container (netCDF / HDF5) is corrupted"),
)


_FOAM_FILE = re.compile(r"(constant/polyMesh/\w+|system/\w+)")
_FOAM_LINE = re.compile(r"line (\d+) of")
_FOAM_EXPECTED = re.compile(
    r"Expected ((?:integer|a number|string \"FoamFile\"|integer or '\('|'[^']{1,3}'|[a-z ]{1,30}?)), found"
)


def _foam_place(text: str) -> str | None:
    """An OpenFOAM case's failing file, line and what was expected there, from VTK's reader's text:
    "its constant/polyMesh/faces cannot be read at line 43, where an integer or '(' was expected";
    None where VTK names no file of the case."""
    f = _FOAM_FILE.search(text)
    if f is None:
        return None
    said = f"its {f.group(1)} cannot be read"
    line = _FOAM_LINE.search(text)
    if line:
        said += f" at line {int(line.group(1)):,}"
    e = _FOAM_EXPECTED.search(text)
    if e:
        want = e.group(1).replace('string "FoamFile"', "its FoamFile header")
        want = {"integer": "an integer", "integer or '('": "an integer or '('"}.get(want, want)
        said += f"{',' if line else ':'} where {want} was expected" if line else f": {want} was expected"
    return said


def article(what: str) -> str:
    """'an Exodus II', 'a legacy VTK': the indefinite article by the first letter."""
    return ("an " if what[:1].lower() in "aeiou" else "a ") + what


def explain(text: str, what: str) -> str:
    """VTK's error text -> what was wrong, in our words (and where, when VTK says where)."""
    text = re.sub(r"In [^\n,]*\.(cxx|h|txx|hxx), line \d+", "", text)  # VTK's own source lines
    text = re.sub(r"\b\S+\.(cxx|h|txx|hxx):\d+", "", text)
    low = text.lower()
    said = next(
        (msg for keys, msg in _KINDS if any(k in low for k in keys)), "it is corrupted or not {a_what} file"
    )
    where = []
    seen = set()
    for m in _WHERE.finditer(text):
        key = m.group(1).lower()
        if key not in seen and key != "piece":
            seen.add(key)
            where.append(f"{key} {int(m.group(2)):,}")
    said = said.format(a_what=article(what))
    return f"{said} (at {', '.join(where[:3])})" if where else said


# ---- VTK data -> arrays -------------------------------------------------------------------------


def _np(a) -> np.ndarray:
    from vtkmodules.util.numpy_support import vtk_to_numpy

    return vtk_to_numpy(a)


def _cell_data(ds) -> dict:
    cd = ds.GetCellData()
    out = {}
    for i in range(cd.GetNumberOfArrays()):
        a = cd.GetArray(i)
        if a is not None and a.GetName() and a.GetNumberOfComponents() == 1:
            out[a.GetName()] = _np(a)
    return out


def _arrays(data, path: str, what: str, fmt: str, groups: bool = True):
    """(points, offsets, connectivity, types, cell data {name: array}, polyhedron faces or None).
    groups: a composite's blocks are physical groups (Exodus element blocks, CGNS zones); not a
    parallel file's pieces, which are one mesh cut for the processes that wrote it."""
    if data.IsA("vtkCompositeDataSet"):
        return _composite(data, path, what, fmt, groups)
    return _dataset(data, path, what, fmt)


def _dataset(ds, path, what, fmt, piece: bool = False):
    if ds.IsA("vtkUnstructuredGrid"):
        out = _unstructured(ds)
    elif ds.IsA("vtkPolyData"):
        out = _polydata(ds)
    elif ds.IsA("vtkImageData") or ds.IsA("vtkStructuredGrid") or ds.IsA("vtkRectilinearGrid"):
        out = _structured(ds)
    else:
        raise MeshError(
            f"cannot read {os.path.basename(path)} as {fmt}: it holds a {ds.GetClassName()[3:]}, not a mesh"
        )
    return _hide_blanked(ds, *out, piece=piece)


def _unstructured(ug):
    n = ug.GetNumberOfPoints()
    pts = _np(ug.GetPoints().GetData()) if n else np.zeros((0, 3))
    cells = ug.GetCells()
    if ug.GetNumberOfCells() == 0:
        return pts, np.zeros(1, np.int64), np.zeros(0, np.int64), np.zeros(0, np.uint8), {}, None
    offsets = _np(cells.GetOffsetsArray())
    conn = _np(cells.GetConnectivityArray())
    ct = ug.GetCellTypes()  # VTK >= 9.6: the type array (before: a vtkCellTypes)
    types = _np(ct if ct.IsA("vtkDataArray") else ug.GetCellTypesArray()).astype(np.uint8, copy=False)
    poly = None
    if np.any(types == 42):
        poly = _polyhedron_faces(ug, types)
    return pts, offsets, conn, types, _cell_data(ug), poly


def _polyhedron_faces(ug, types):
    """The polyhedra's faces, per polyhedron in cell order: (face offsets per polyhedron, face
    offsets, face nodes)."""
    faces, locs = ug.GetPolyhedronFaces(), ug.GetPolyhedronFaceLocations()
    if faces is None or locs is None:
        return None
    f_off, f_conn = _np(faces.GetOffsetsArray()).astype(np.int64), _np(faces.GetConnectivityArray())
    l_off, l_conn = _np(locs.GetOffsetsArray()).astype(np.int64), _np(locs.GetConnectivityArray())
    q = np.flatnonzero(types == 42)
    count = l_off[q + 1] - l_off[q]
    fids = np.asarray(l_conn[ranges(l_off[q], count)], dtype=np.int64)
    if fids.size and (fids.min() < 0 or fids.max() >= f_off.size - 1):
        raise MeshError("a polyhedron refers to a face that the file does not have")
    fsz = f_off[fids + 1] - f_off[fids]
    nodes = np.asarray(f_conn[ranges(f_off[fids], fsz)], dtype=np.int64)
    cell_face_off = np.zeros(q.size + 1, np.int64)
    np.cumsum(count, out=cell_face_off[1:])
    face_off = np.zeros(fsz.size + 1, np.int64)
    np.cumsum(fsz, out=face_off[1:])
    return cell_face_off, face_off, nodes


def _polydata(pd):
    """Verts, lines, polygons, strips (VTK's cell order for polydata) in one CSR."""
    n = pd.GetNumberOfPoints()
    pts = _np(pd.GetPoints().GetData()) if n else np.zeros((0, 3))
    offs, conns, types = [], [], []
    base = 0
    for arr, one, many in (
        (pd.GetVerts(), 1, 2),
        (pd.GetLines(), 3, 4),
        (pd.GetPolys(), 7, 7),
        (pd.GetStrips(), 6, 6),
    ):
        if arr is None or arr.GetNumberOfCells() == 0:
            continue
        o = _np(arr.GetOffsetsArray()).astype(np.int64)
        c = _np(arr.GetConnectivityArray())
        sizes = np.diff(o)
        offs.append(o[1:] + base)
        conns.append(c)
        types.append(np.where(sizes == (1 if one == 1 else 2), one, many).astype(np.uint8))
        base += int(o[-1])
    if not types:
        return pts, np.zeros(1, np.int64), np.zeros(0, np.int64), np.zeros(0, np.uint8), {}, None
    offsets = np.concatenate([np.zeros(1, np.int64), *offs])
    conn = conns[0] if len(conns) == 1 else np.concatenate([np.asarray(c, np.int64) for c in conns])
    return pts, offsets, conn, np.concatenate(types), _cell_data(pd), None


def _structured(ds):
    """Image data, structured and rectilinear grids: hexahedra (3D), quads (2D) or lines from the
    point dimensions, VTK's cell numbering (i fastest): lattice.structured_cells."""
    ext = ds.GetExtent()
    dims = [int(ext[2 * a + 1] - ext[2 * a] + 1) for a in range(3)]
    if ds.IsA("vtkImageData"):
        m = ds.GetDirectionMatrix()
        d = np.array([[m.GetElement(i, j) for j in range(3)] for i in range(3)])
        pts = image_points(ds.GetOrigin(), ds.GetSpacing(), ext, d)
    elif ds.IsA("vtkRectilinearGrid"):
        axes = [
            np.asarray(_np(c), np.float64) if c is not None else np.zeros(1)
            for c in (ds.GetXCoordinates(), ds.GetYCoordinates(), ds.GetZCoordinates())
        ]
        pts = grid_points(axes)
    else:
        pts = _np(ds.GetPoints().GetData()) if ds.GetNumberOfPoints() else np.zeros((0, 3))
    offsets, conn, types = structured_cells(dims)
    return pts, offsets, conn, types, _cell_data(ds) if types.size else {}, None


def _lattice(data, n_cells: int) -> dict | None:
    """For a 3D image, rectilinear or structured grid read whole (no blanked cell): the hint that
    lets the read stage skip the orientation machinery (build._orient_and_check: its hexahedra are
    consistently oriented by construction). "axes": the x, y, z coordinates of an axis-aligned grid
    (image data without rotation, rectilinear grids), for measures and centroids in closed form."""
    if data.IsA("vtkCompositeDataSet") or not (
        data.IsA("vtkImageData") or data.IsA("vtkStructuredGrid") or data.IsA("vtkRectilinearGrid")
    ):
        return None
    ext = data.GetExtent()
    dims = [int(ext[2 * a + 1] - ext[2 * a] + 1) for a in range(3)]
    if min(dims) < 2 or n_cells != (dims[0] - 1) * (dims[1] - 1) * (dims[2] - 1):
        return None  # 2D, or cells were hidden (blanking): the general path
    axes = None
    if data.IsA("vtkImageData"):
        m = data.GetDirectionMatrix()
        if all(m.GetElement(i, j) == (i == j) for i in range(3) for j in range(3)):
            o, h = data.GetOrigin(), data.GetSpacing()
            axes = [o[a] + (ext[2 * a] + np.arange(dims[a])) * h[a] for a in range(3)]
    elif data.IsA("vtkRectilinearGrid"):
        axes = [
            np.asarray(_np(c), np.float64)
            for c in (data.GetXCoordinates(), data.GetYCoordinates(), data.GetZCoordinates())
        ]
    return {"dims": dims, "axes": axes}


def _whole_live(data, n_cells: int) -> int:
    """The number of live axes (2: quads, 3: hexahedra) of an image, rectilinear or structured grid
    read whole (no blanked cell); 0 for anything else."""
    if data.IsA("vtkCompositeDataSet") or not (
        data.IsA("vtkImageData") or data.IsA("vtkStructuredGrid") or data.IsA("vtkRectilinearGrid")
    ):
        return 0
    ext = data.GetExtent()
    cdims = [int(ext[2 * a + 1] - ext[2 * a]) for a in range(3)]
    live = [c for c in cdims if c > 0]
    if len(live) < 2 or n_cells != int(np.prod(live)):
        return 0
    return len(live)


def _lattice_cells(live: int, offsets, conn, types, tags) -> Normalized | None:
    """What normalize makes of a whole structured grid's cells (_structured: quads or hexahedra of
    one fixed size, our node order already, no lower-dimensional cell), without its checks; None
    where the grid is not whole (live 0: normalize)."""
    if not live:
        return None
    out = Normalized()
    out.dim = live
    out.offsets = np.asarray(offsets, dtype=np.int64)
    out.connectivity = np.asarray(conn, dtype=np.int64)
    out.types = np.asarray(types, dtype=np.uint8)
    out.tags = tags
    return out


_IMAGE_TAG = re.compile(rb"<ImageData\b[^>]*>")


def _xml_image_geometry(path: str):
    """(origin, spacing) as an XML image file's header writes them, floats (nan, inf kept), or None
    where the file is not XML image data or the header says neither. VTK's XML reader takes a
    value it cannot parse (nan, inf) for its default (origin 0, spacing 1) without a word."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(4096)
    except OSError:
        return None
    tag = _IMAGE_TAG.search(head)
    if tag is None:
        return None
    out = []
    for name, default in ((rb"Origin", 0.0), (rb"Spacing", 1.0)):
        m = re.search(rb"\s" + name + rb'="([^"]*)"', tag.group(0))
        vals = [default] * 3
        if m is not None:
            try:
                got = [float(t) for t in m.group(1).split()]
            except ValueError:
                got = [float("nan")] * 3
            vals = (got + vals)[:3]
        out.append(vals)
    return out[0], out[1]


def _image_mesh(data, physical_tag, meta: dict, path: str | None = None):
    """The whole Mesh of image data (legacy STRUCTURED_POINTS too) straight from its origin, spacing
    and extent (build.mesh_from_image), or None where the general path reads it: not image data, a
    rotated or 2D image, blanked points or cells. Its origin and spacing are checked first (one
    sentence: a lattice with a zero, NaN or infinite step has no volume or no place)."""
    if data.IsA("vtkCompositeDataSet") or not data.IsA("vtkImageData"):
        return None
    from models.mesh.lattice import check_image_geometry

    ext = data.GetExtent()
    live = [a for a in range(3) if ext[2 * a + 1] > ext[2 * a]]
    if len(live) >= 2:
        check_image_geometry(data.GetOrigin(), data.GetSpacing(), live)
        head = _xml_image_geometry(path) if path else None
        if head is not None:
            check_image_geometry(*head, live)
    if len(live) < 3:
        return None
    m = data.GetDirectionMatrix()
    if not all(m.GetElement(i, j) == (i == j) for i in range(3) for j in range(3)):
        return None
    if data.GetCellData().GetArray("vtkGhostType") is not None:
        return None
    if data.GetPointData().GetArray("vtkGhostType") is not None:
        return None
    cell_data = _cell_data(data)
    n = (ext[1] - ext[0]) * (ext[3] - ext[2]) * (ext[5] - ext[4])
    tag_key = _tag_key(cell_data, physical_tag)
    tags = None if tag_key is None else _int_tags(cell_data[tag_key], n)
    return mesh_of_image(data.GetOrigin(), data.GetSpacing(), ext, tags, tag_key, meta, _field_data(data))


def mesh_of_image(origin, spacing, extent, tags, tag_key, meta: dict, field: dict):
    """build.mesh_from_image of a whole 3D axis-aligned image, then the group names of its field
    data; None where the builder leaves it to the general path (coordinates that overflow). The end
    of _image_mesh (and of models/mesh/xml_grid.py's image data)."""
    from models.mesh.boundary import group_names
    from models.mesh.build import mesh_from_image
    from models.mesh.lattice import image_axes

    mesh = mesh_from_image(image_axes(origin, spacing, extent), tags, tag_key, meta)
    if mesh is None:
        return None
    mesh.meta["group_names"], mesh.meta["boundary_names"] = group_names(field, 3)
    return mesh


def _hide_blanked(ds, pts, offsets, conn, types, cell_data, poly, piece: bool = False):
    """Drop blanked (hidden) cells, and cells on hidden points, as VTK does when it draws them;
    in a parallel file's piece, its ghost cells too (copies of another piece's cells)."""
    ghost = ds.GetCellData().GetArray("vtkGhostType")
    pghost = ds.GetPointData().GetArray("vtkGhostType")
    hide = None
    if ghost is not None:
        hide = (_np(ghost) & (HIDDEN_CELL | (DUPLICATE_CELL if piece else 0))) != 0
    if pghost is not None and types.size:
        hp = (_np(pghost) & HIDDEN_POINT) != 0
        if hp.any():
            cell = np.repeat(np.arange(types.size), np.diff(offsets))
            on = np.bincount(cell, weights=hp[np.asarray(conn, np.int64)], minlength=types.size) > 0
            hide = on if hide is None else hide | on
    cell_data.pop("vtkGhostType", None)
    if hide is None or not hide.any() or poly is not None:
        return pts, offsets, conn, types, cell_data, poly
    keep = np.flatnonzero(~hide)
    sizes = np.diff(offsets)[keep]
    conn = np.asarray(conn)[ranges(offsets[keep], sizes)]
    offsets = np.zeros(keep.size + 1, np.int64)
    np.cumsum(sizes, out=offsets[1:])
    cell_data = {k: v[keep] for k, v in cell_data.items() if len(v) == hide.size}
    return pts, offsets, conn, types[keep], cell_data, poly


def _leaves(data) -> list:
    it = data.NewIterator()
    it.SkipEmptyNodesOn()
    it.InitTraversal()
    out = []
    while not it.IsDoneWithTraversal():
        ds = it.GetCurrentDataObject()
        if ds is not None and ds.IsA("vtkDataSet") and ds.GetNumberOfCells() > 0:
            out.append(ds)
        it.GoToNextItem()
    return out


def _composite(data, path, what, fmt, groups: bool = True):
    """Element blocks / zones joined in one cell set; a `block` tag (1, 2, ...) where the blocks
    carry no tag of their own and are groups (not a parallel file's pieces)."""
    leaves = _leaves(data)
    if not leaves:
        raise MeshError(f"cannot read {os.path.basename(path)} as {fmt}: the file has no cells")
    parts = _distinct([_dataset(ds, path, what, fmt, piece=not groups) for ds in leaves])
    if len(parts) == 1:
        pts, off, conn, types, cd, poly = parts[0]
        if groups and not any(k in cd for k in TAG_NAMES):
            cd = {**cd, "block": np.ones(len(types), np.int64)}
        return pts, off, conn, types, cd, poly
    shared = all(len(p[0]) == len(parts[0][0]) for p in parts) and all(
        p[0] is parts[0][0] or np.array_equal(p[0], parts[0][0]) for p in parts[1:]
    )
    offs, conns, types, polys = [np.zeros(1, np.int64)], [], [], []
    base_c = base_p = 0
    for pts, off, conn, t, _, poly in parts:
        offs.append(np.asarray(off[1:], np.int64) + base_c)
        conns.append(np.asarray(conn, np.int64) + (0 if shared else base_p))
        types.append(t)
        polys.append(poly)
        base_c += int(off[-1])
        base_p += len(pts)
    keys = set(parts[0][4]).intersection(*(p[4] for p in parts[1:]))
    cd = {k: np.concatenate([p[4][k] for p in parts]) for k in keys}
    own = [next((k for k in TAG_NAMES if k in p[4] and len(p[4][k]) == len(p[3])), None) for p in parts]
    if not any(k in cd for k in TAG_NAMES) and all(own):  # each block tagged under its own name
        # (an XDMF of dolfinx: its cells' "cell_tags", its facets' "facet_tags"): one tag array
        cd[own[0]] = np.concatenate(
            [np.asarray(p[4][k]).reshape(-1) for p, k in zip(parts, own, strict=True)]
        )
    elif groups:
        cd["block"] = np.repeat(np.arange(1, len(parts) + 1), [len(p[3]) for p in parts])
    poly = _join_polys(polys, [p[0] for p in parts], shared) if any(p is not None for p in polys) else None
    conn = np.concatenate(conns)
    if shared:
        pts = parts[0][0]
    else:
        pts = np.concatenate([np.asarray(p[0], np.float64) for p in parts])
        pts, inverse = np.unique(pts, axis=0, return_inverse=True)  # coincident points merged
        inverse = inverse.reshape(-1)
        conn = inverse[conn]
        if poly is not None:
            poly = (poly[0], poly[1], inverse[poly[2]])
    return pts, np.concatenate(offs), conn, np.concatenate(types), cd, poly


def _distinct(parts: list) -> list:
    """The blocks, each one repeating an earlier block (same points and cells) dropped, its cell
    data given to that block where it lacks them: an XDMF time series holds its mesh once as a grid
    and once per time step, all of them the same mesh; dolfinx's XDMF holds its cells once more as
    the grid of their tags."""
    kept: list = []
    for part in parts:
        pts, off, conn, types = part[:4]
        same = next(
            (
                k
                for k in kept
                if len(k[3]) == len(types)
                and len(k[2]) == len(conn)
                and np.array_equal(k[3], types)
                and np.array_equal(k[2], conn)
                and np.array_equal(k[1], off)
                and (k[0] is pts or np.array_equal(k[0], pts))
            ),
            None,
        )
        if same is None:
            kept.append(part)
        else:
            for key, values in part[4].items():
                same[4].setdefault(key, values)
    return kept


def _join_polys(polys, pts_list, shared):
    cf, fo, fn = [np.zeros(1, np.int64)], [np.zeros(1, np.int64)], []
    base_f = base_n = base_p = 0
    for poly, pts in zip(polys, pts_list, strict=True):
        if poly is not None:
            cf.append(poly[0][1:] + base_f)
            fo.append(poly[1][1:] + base_n)
            fn.append(poly[2] + (0 if shared else base_p))
            base_f += int(poly[0][-1])
            base_n += int(poly[1][-1])
        base_p += len(pts)
    return np.concatenate(cf), np.concatenate(fo), np.concatenate(fn)
