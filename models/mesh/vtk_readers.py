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

from models.errors import MeshError
from models.mesh.cells import (
    BOUNDARY_TAG_NAME,
    Normalized,
    find_tag_key,
    normalize,
    with_boundary_faces,
)
from models.mesh.convex_sets import VTK_CONVEX_POINT_SET, as_polyhedra
from models.mesh.vtk_arrays import _arrays, _cell_data, _field_data, _np, _openfoam, hidden_cells
from models.mesh.vtk_setup import (
    _exodus_names,
    _fluent_cell_zones_only,
    _foam_place,
    _names_of_tags,
    _openfoam_mesh_only,
    _part_names,
    _plot3d_layout,
)

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
    ".pvtk": ("VTK parallel legacy", "vtkDataSetReader", "vtkmodules.vtkIOLegacy"),
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
    "tecplot": ("Tecplot", "vtkTecplotReader", "vtkmodules.vtkIOGeometry"),
    "ply": ("PLY", "vtkPLYReader", "vtkmodules.vtkIOPLY"),
}
# parallel files whose pieces are separate point sets: read piece by piece (_pieces), joined as a
# composite's blocks are (points on the cuts between pieces, written once per piece, merged)
PIECEWISE = (".pvtu", ".pvtp")
# files whose blocks are pieces of one mesh, not physical groups
PIECES = (*PIECEWISE, ".vtpd", ".pvd", ".pvtk")
EXODUS_EXTENSIONS = (".exo", ".e", ".ex2", ".exii", ".g", ".gen")


def read_vtk(
    path: str, kind: str, physical_tag: str | None = None, weld: float | None = None, fmt: str | None = None
):
    """Read `path` with VTK's reader for `kind` (a key of READERS) and build our `Mesh`. fmt: the
    format's name as users know it (formats.format_name), in every refusal; the reader's own by default.
    A refusal names the file, the format and, when VTK says it, the place; never VTK's class names."""
    what, cls, _ = READERS[kind]
    fmt = fmt or what
    if kind == "cgns":  # its layout first: VTK's reader crashes or says nothing on a broken one
        from models.mesh.cgns_groups import cgns_fault

        why = cgns_fault(path)
        if why:
            raise MeshError(f"cannot read {os.path.basename(path)} as {fmt}: {why}")
    if kind == "exodus":  # netCDF-4 (HDF5): its blocks, read with h5py here in the reading child
        # (netCDF classic: pick_reader checked them, in pure Python)
        from models.mesh.containers import exodus_fault_hdf5, is_hdf5

        why = exodus_fault_hdf5(path) if is_hdf5(path) else None
        if why:
            raise MeshError(f"cannot read {os.path.basename(path)} as {fmt}: {why}")
    fluent_note = None
    if kind == "fluent":  # its sections first: VTK's reader crashes, or runs until the read's time
        from models.mesh.locate import LIMIT  # limit, on a broken one (a '(' among a section's numbers)

        if os.path.getsize(path) <= LIMIT:
            from models.mesh.fluent_sections import faults

            with open(path, "rb") as fh:
                why, fluent_note = faults(fh.read())
            if why:
                raise MeshError(f"cannot read {os.path.basename(path)} as {fmt}: {why}")
    foam_note = None
    if kind == "openfoam":  # its owner and neighbour lists, which VTK's reader believes
        from models.mesh.foam_lists import addressing_fault

        folder = os.path.dirname(os.path.abspath(path))
        fault, foam_note = addressing_fault(
            os.path.dirname(folder) if os.path.basename(path) == "controlDict" else folder
        )
        if fault:
            raise MeshError(f"cannot read {os.path.basename(path)} as {fmt}: {fault}")
    notes: dict = {}
    if kind == "gambit":
        from models.mesh.gambit import vtk_copy

        with vtk_copy(path) as (clean, raw):
            data = _run(clean, kind, fmt)
    else:
        data = _run(path, kind, fmt, notes)
    meta = {"reader": f"VTK {cls}", "format": what, **notes}
    if foam_note:
        meta["openfoam_order"] = {"count": 1, "message": foam_note}
    if fluent_note:  # read (VTK builds a cell from some of its faces), but a face's ids are wrong
        meta["fluent_faces"] = {
            "count": 1,
            "message": f"{fluent_note}: the cells beside it may be read wrong",
        }
    dup, hid, total = hidden_cells(data)
    if total and dup + hid == total:  # nothing left to read (VTK's reader read every cell)
        what_all = (
            "a ghost cell (marked in its ghost-type array as a copy of another piece's cell); read the "
            "parallel file (.pvtu, .pvtp) it is a piece of"
            if dup
            else "hidden (blanked in its ghost-type array)"
        )
        raise MeshError(
            f"cannot read {os.path.basename(path)} as {fmt}: every one of its {total:,} cells is {what_all}"
        )
    said = (
        [f"{dup:,} ghost cells (copies of a neighbouring piece's cells, as a parallel writer writes them)"]
        if dup
        else []
    )
    said += [f"{hid:,} blanked cells (hidden)"] if hid else []
    if said:  # vtkGhostType's cells that ParaView does not draw: left out, as there
        meta["ghost_cells"] = {
            "count": dup + hid,
            "message": f"{' and '.join(said)} left out, as marked in vtkGhostType (ParaView does not draw them either)",
        }
    if weld is None:
        mesh = _image_mesh(data, physical_tag, meta, path)
        if mesh is not None:
            return mesh
    if kind.startswith("openfoam"):
        pts, offsets, conn, types, cell_data, poly, field = _openfoam(
            data, path, what, fmt, kind == "openfoam-decomposed"
        )
    else:
        repeats: list = []  # (a VTKHDF of one partitioned dataset: one mesh's pieces, no groups)
        groups = kind not in PIECES and data.GetClassName() != "vtkPartitionedDataSet"
        pts, offsets, conn, types, cell_data, poly = _arrays(data, path, what, fmt, groups, repeats)
        if repeats and kind in PIECEWISE:  # (a time series' grids repeat
            blocks, cells = repeats[0]  # its mesh by design: said only of a parallel file's pieces)
            meta["repeated_pieces"] = {
                "count": cells,
                "message": f"{blocks:,} of the file's pieces repeat an earlier piece (the same points and "
                f"cells): read once, {cells:,} repeated cells left out",
            }
        field = _field_data(data)
        if kind == "exodus":
            field.update(_exodus_names(data))
        elif kind in ("ensight", "tecplot"):  # parts, zones: named blocks (their T="...")
            field.update(_names_of_tags(_part_names(data), cell_data, physical_tag))
        elif kind in (".vtm", "vtkhdf") and "block" in cell_data and not repeats:  # its blocks' names
            field.update(_names_of_tags(_part_names(data), cell_data, physical_tag))
    if kind == "cgns":  # its families (gmsh's physical groups), which VTK's reading does not show
        from models.mesh.cgns_groups import family_groups

        fams = family_groups(path, conn, len(types), offsets)
        if fams is not None:
            tags_top, names, lower = fams
            cell_data = {"block": tags_top}
            if lower is not None:  # the boundary conditions' faces: after the cells, tagged
                offsets, conn, types, cell_data = with_boundary_faces(offsets, conn, types, tags_top, *lower)
            field = {**field, **names}
    if kind == "gambit":  # its node order, element groups and boundary conditions (models.mesh.gambit)
        from models.mesh.gambit import gambit_cells

        offsets, conn, types, cell_data, field = gambit_cells(
            raw, pts, offsets, conn, types, cell_data, field, meta
        )
    elif (
        kind == "exodus"
        and conn.size
        and conn.min() == -1
        and conn.max() == len(pts) - 2
        and np.count_nonzero(conn == -1) <= 64
    ):  # (VTK subtracts 1 from the file's ids: a file numbered 0..N-1 gives -1..N-2, node 0 in a
        # few cells; a block of zeros, unwritten data, is no numbering)
        from models.mesh.containers import zero_based

        raise MeshError(f"cannot read {os.path.basename(path)} as {fmt}: {zero_based(len(pts))}")
    grid = _lattice(data, len(types))
    live = _whole_live(data, len(types))
    del data
    if len(types) == 0:
        if _declares_no_cells(path):  # (as the service's upload check says it)
            raise MeshError(
                f"cannot read {os.path.basename(path)} as {fmt}: the mesh has no cells (every piece "
                "declares NumberOfCells=0)"
            )
        raise MeshError(
            f"cannot read {os.path.basename(path)} as {fmt}: it holds no cells "
            f"(is it truncated, or not {article(what)} file?)"
        )
    tag_key = find_tag_key(cell_data, physical_tag)
    tags = None if tag_key is None else _int_tags(cell_data[tag_key], len(types))
    btags = cell_data.get(BOUNDARY_TAG_NAME)
    btags = None if btags is None else _int_tags(btags, len(types))
    norm = _lattice_cells(live, offsets, conn, types, tags)
    if norm is None:
        try:
            if np.any(np.asarray(types) == VTK_CONVEX_POINT_SET):  # (VTK's own writers: as polyhedra)
                offsets, conn, types, poly = as_polyhedra(pts, offsets, conn, types, poly)
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


_NUMBER_OF_CELLS = re.compile(rb"<Piece\b[^>]*?\bNumberOfCells\s*=\s*[\"']\s*(\d+)")


def _declares_no_cells(path: str) -> bool:
    """A VTK XML unstructured grid whose every piece declares NumberOfCells="0" (its header, the
    first MiB)."""
    if not path.lower().endswith((".vtu", ".pvtu")):
        return False
    try:
        with open(path, "rb") as fh:
            found = _NUMBER_OF_CELLS.findall(fh.read(1 << 20))
    except OSError:
        return False
    return bool(found) and all(int(n) == 0 for n in found)


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

    _on_error.CallDataType = (
        13  # VTK_STRING: the message comes as call data (8, VTK_LONG, gave its first 8 bytes)
    )

    def __exit__(self, *exc):
        from vtkmodules.vtkCommonCore import vtkLogger, vtkOutputWindow

        text = self.win.GetOutput() or ""
        if isinstance(text, bytes):
            text = text.decode("utf-8", "replace")
        vtkOutputWindow.SetInstance(self.prev)
        vtkLogger.SetStderrVerbosity(self.verbosity)
        self.text = "\n".join([*self.errors, text])
        blocks = [*self.errors, *(b for b in re.split(r"(?=ERROR)", text) if b.startswith("ERROR"))]
        self.lost_data = any(_DATA_ONLY.search(b) for b in blocks)
        self.failed = any(not _HARMLESS.search(b) and not _DATA_ONLY.search(b) for b in blocks)
        return False


# errors after which VTK's reader still gives the whole mesh: Exodus QA and information records
# declared and missing (the file's history, not its mesh); an XML data array's information key
# VTK cannot parse back (its own writer writes L2_NORM_RANGE "inf" or "-nan" for a vector array
# holding an infinity or only NaNs: metadata of the data, not of the mesh)
_HARMLESS = re.compile(
    r"Unable to read (?:QA|info(?:rmation)?) records|Error reading InformationKey element", re.IGNORECASE
)
# errors after which the mesh is whole but some of its data arrays are not read: an XDMF attribute
# whose HDF5 dataset is missing (VTK's own XDMF writer leaves such files); said, never silent, since
# physical groups may be among them
_DATA_ONLY = re.compile(r"Failed to read attribute data", re.IGNORECASE)


def _run(path: str, kind: str, fmt: str | None = None, notes: dict | None = None):
    """The reader's output data object; notes: where given, what was read past (trailing_bytes)."""
    import importlib

    what, cls, module = READERS[kind]
    fmt = fmt or what
    if kind in (".pvd", ".pvtk"):  # (a reader per data set it lists)
        return _collection(path, fmt, legacy=kind == ".pvtk")
    reader = getattr(importlib.import_module(module), cls)()
    name = os.path.basename(path)
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
        elif kind == "xdmf":  # a time series: its earliest time, where ParaView opens it (VTK's
            out = _earliest(reader)  # reader gives the file's first grid, in whatever order)
        else:
            reader.Update()
            out = reader.GetOutputDataObject(0)
    from models.mesh.containers import hdf5_damage, is_hdf5

    tail = None
    if cap.failed and kind == "legacy":
        from models.mesh.legacy import legacy_tail

        tail = legacy_tail(path, cap.text, out)
    if cap.lost_data and not cap.failed and notes is not None:
        notes["lost_data"] = {
            "count": 1,
            "message": f"some of its cell or point data arrays could not be read (the {what} reader "
            "found their data missing): the mesh is read without them, so physical groups held in them "
            "are not seen",
        }
    if tail:  # (only bytes after the mesh VTK's reader could not read: read as VTK reads it)
        if notes is not None:
            notes["trailing_bytes"] = {"count": 1, "message": tail}
    elif cap.failed:
        why = _foam_place(cap.text) if kind.startswith("openfoam") else None
        said = why or explain(cap.text, what)
        if not why and is_hdf5(path):  # an HDF5 container (Exodus, CGNS, Fluent .cas.h5, ...):
            said = hdf5_damage(path) or said  # its damaged object, where one is
        if kind == "legacy":  # a truncated ASCII file: say so
            from models.mesh.legacy import legacy_shortfall

            said = legacy_shortfall(path, None) or said
        if kind == "tecplot":  # a zone type its rows do not fit (meshio's writer, tetrahedra beside
            said = _tecplot_rows(path) or said  # triangles: FEQUADRILATERAL of 8-node rows)
        if kind in _XML_KINDS:  # the XML's own fault where VTK said no place; another kind of XML always
            found = xml_fault(path, "Xdmf" if kind == "xdmf" else "VTKFile")
            if found and (" (at " not in said or not found.startswith("its XML is malformed")):
                said = found
        raise MeshError(f"cannot read {name} as {fmt}: {said}")
    if out is None:
        raise MeshError(f"cannot read {name} as {fmt}: the reader produced no data")
    if kind == "legacy":  # short data VTK reads without a word: a swallowed cell list, a truncation
        from models.mesh.legacy import legacy_shortfall

        why = legacy_shortfall(path, out.GetNumberOfCells() if out.IsA("vtkUnstructuredGrid") else None)
        if why:
            raise MeshError(f"cannot read {name} as {fmt}: {why}")
    if is_hdf5(path):  # read, but a damaged object may have been left out without a word (a CGNS
        why = hdf5_damage(path)  # zone whose ZoneType header fails its checksum)
        if why:
            raise MeshError(f"cannot read {name} as {fmt}: {why}")
    return out


_PVD_DATASET = re.compile(rb"<DataSet\b([^>]*)>")
_PVD_ATTR = re.compile(rb"""\b(timestep|part|file)\s*=\s*["']([^"']*)["']""")


def _collection(path: str, fmt: str, legacy: bool = False):
    """A ParaView data collection (.pvd, a time series as FEniCS and many solvers write it): the
    mesh of its first time step, that step's parts (a part per process) read by VTK's XML readers
    and joined as a parallel file's pieces. legacy: a .pvtk (vtkPDataSetWriter: <Piece
    fileName=...> of legacy .vtk files, read by VTK's legacy reader, joined the same way).
    case_files.pieces_present has checked that the files are there, inside the file's folder."""
    from vtkmodules.vtkCommonDataModel import vtkMultiBlockDataSet
    from vtkmodules.vtkIOLegacy import vtkDataSetReader
    from vtkmodules.vtkIOXML import vtkXMLGenericDataObjectReader

    from models.mesh.case_files import legacy_pieces
    from models.mesh.xml_refs import collection

    name = os.path.basename(path)
    with open(path, "rb") as fh:
        text = fh.read()
    steps = [(0.0, f) for f in legacy_pieces(path, text)] if legacy else []
    listed = None if legacy else collection(path)  # (as XML: comments skipped, entities decoded)
    if listed is None and not legacy:  # not well-formed XML: by patterns (VTK's reader says what is wrong)
        listed = []
        for m in _PVD_DATASET.finditer(text):
            attrs = {k.decode(): v.decode("utf-8", "replace") for k, v in _PVD_ATTR.findall(m.group(1))}
            if "file" in attrs:
                listed.append((attrs.get("timestep", ""), attrs.get("part", ""), attrs["file"]))
    for timestep, _, file in listed or []:
        try:
            t = float(timestep or 0)
        except ValueError:
            t = 0.0
        steps.append((t, file))
    if not steps:
        tag = "<Piece fileName=...>" if legacy else "<DataSet file=...>"
        raise MeshError(f"cannot read {name} as {fmt}: it lists no data set (no {tag})")
    first = min(t for t, _ in steps)
    files = [f for t, f in steps if t == first]
    folder = os.path.dirname(os.path.abspath(path))
    out = vtkMultiBlockDataSet()
    with _Captured() as cap:
        for i, f in enumerate(files):
            reader = vtkDataSetReader() if legacy else vtkXMLGenericDataObjectReader()
            reader.AddObserver("ErrorEvent", cap._on_error)
            reader.SetFileName(f if legacy else os.path.join(folder, f))
            reader.Update()
            data = reader.GetOutputDataObject(0)
            if data is not None:
                out.SetBlock(i, data)
    if cap.failed:
        raise MeshError(
            f"cannot read {name} as {fmt}: its data set {files[0]}: "
            f"{explain(cap.text, 'legacy VTK' if legacy else 'VTK XML')}"
        )
    return out


def _earliest(reader):
    """The reader's output at its earliest time step (the file's only one where it has none)."""
    from vtkmodules.vtkCommonExecutionModel import vtkStreamingDemandDrivenPipeline as sddp

    reader.UpdateInformation()
    info = reader.GetOutputInformation(0)
    times = info.Get(sddp.TIME_STEPS()) if info is not None and info.Has(sddp.TIME_STEPS()) else None
    if times:
        reader.UpdateTimeStep(min(times))
    else:
        reader.Update()
    return reader.GetOutputDataObject(0)


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


_WHERE = re.compile(r"\b(line|column|byte index|offset|position|piece)\s*[:=]?\s*(\d+)", re.IGNORECASE)
_KINDS = (
    (
        ("faces array", '"faces" array', "faceoffsets", "face offsets"),
        "its polyhedra's faces and face offsets do not match",
    ),
    (("xml", "parsing"), "its XML cannot be parsed"),
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


def article(what: str) -> str:
    """'an Exodus II', 'a legacy VTK', 'an XDMF': the indefinite article by the first sound (a vowel,
    or an X said as a letter)."""
    return ("an " if what[:1].lower() in "aeiou" or what[:2] in ("XD", "XM") else "a ") + what


_XML_KINDS = ("xdmf", "xml", *(k for k in READERS if k.startswith(".")))


def xml_fault(path: str, root: str | None = None) -> str | None:
    """Where an XML file is not well-formed, in our words with its line and column (expat, the
    parser of Python's standard library, streaming over the file); with root ('VTKFile', 'Xdmf'),
    a file whose first element is another says so (an HTML page saved under a mesh's name, well-formed
    or not); None where neither is wrong."""
    from xml.parsers import expat

    parser = expat.ParserCreate()
    first: list[str] = []
    odd: list[str] = []  # a data array of no components (VTK reads on, then fails)

    def start(name, attrs):
        if not first:
            first.append(name.rsplit(":", 1)[-1])
        n = attrs.get("NumberOfComponents") if name == "DataArray" else None
        if n is not None and not odd and n.strip().lstrip("+-").isdigit() and int(n) <= 0:
            label = str(attrs.get("Name", ""))[:40]
            where = f" (at line {parser.CurrentLineNumber:,})"
            odd.append(
                f"its data array {label or 'without a name'} declares {int(n)} components per value{where}"
            )

    parser.StartElementHandler = start
    fault = None
    try:
        with open(path, "rb") as fh:
            parser.ParseFile(fh)
    except expat.ExpatError as exc:
        codes = expat.errors.codes
        what = {
            codes[expat.errors.XML_ERROR_TAG_MISMATCH]: "a closing tag does not match the tag it closes",
            codes[expat.errors.XML_ERROR_NO_ELEMENTS]: "the file ends before its XML does (truncated?)",
            codes[expat.errors.XML_ERROR_UNCLOSED_TOKEN]: "the file ends inside a tag (truncated?)",
            codes[expat.errors.XML_ERROR_INVALID_TOKEN]: "a character that XML does not allow",
            codes[expat.errors.XML_ERROR_SYNTAX]: "a character that XML does not allow",
            codes[expat.errors.XML_ERROR_JUNK_AFTER_DOC_ELEMENT]: "text after the end of the document",
            codes[expat.errors.XML_ERROR_UNDEFINED_ENTITY]: "an entity (&name;) that is not declared",
        }.get(exc.code, "a fault of its XML")
        fault = f"its XML is malformed: {what} (at line {exc.lineno:,}, column {exc.offset + 1:,})"
    except (OSError, ValueError):
        return None
    if root is None or not first or first[0].lower() == root.lower():
        return fault or (odd[0] if odd else None)
    what = article({"vtkfile": "VTK XML"}.get(root.lower(), root.upper()))
    if first[0].lower() == "html":  # (HTML need not be well-formed XML: this says more than its fault)
        return f"it is a web page (HTML), not {what} file: was a download page saved instead of the mesh?"
    return f"its root element is <{first[0][:40]}>, not <{root}>: it is not {what} file"


_TECPLOT_NODES = {"FETRIANGLE": 3, "FEQUADRILATERAL": 4, "FETETRAHEDRON": 4, "FEBRICK": 8}
_TECPLOT_TYPE = {"TRIANGLE": 3, "QUADRILATERAL": 4, "TETRAHEDRON": 4, "BRICK": 8}


def _tecplot_rows(path: str) -> str | None:
    """Where VTK's Tecplot reader failed on a file of one finite-element zone: its declared element
    type against the node ids the file's last row holds (a zone's connectivity comes last, one
    element a line as writers write it), or None."""
    try:
        with open(path, "rb") as fh:
            text = fh.read(1 << 24).decode("latin-1")
    except OSError:
        return None
    zones = re.findall(r"(?im)^\s*ZONE\b(.*(?:\n(?!\s*[-+.\d]).*)*)", text)
    if len(zones) != 1:
        return None
    head = zones[0].upper()
    m = re.search(r"ZONETYPE\s*=\s*(FE[A-Z]+)", head)
    declared = _TECPLOT_NODES.get(m.group(1)) if m else None
    if m is None:
        m = re.search(r"\bET\s*=\s*([A-Z]+)", head)
        declared = _TECPLOT_TYPE.get(m.group(1)) if m else None
    rows = [line.split() for line in text.strip().splitlines()[-3:]]
    counts = {len(r) for r in rows}
    if declared is None or len(counts) != 1 or not all(w.isdigit() for r in rows for w in r):
        return None
    held = counts.pop()
    if held == declared:
        return None
    kind = m.group(1)
    return (
        f"its zone is {kind} ({declared} nodes an element), but its connectivity rows hold {held} node ids: "
        "the header does not fit the data (meshio's Tecplot writer writes tetrahedra so beside triangles: "
        "write the volume cells alone, or another format)"
    )


def explain(text: str, what: str) -> str:
    """VTK's error text -> what was wrong, in our words (and where, when VTK says where)."""
    text = re.sub(r"In [^\n,]*\.(cxx|h|txx|hxx), line \d+", "", text)  # VTK's own source lines
    text = re.sub(r"\b\S+\.(cxx|h|txx|hxx):\d+", "", text)
    text = re.sub(r"\bvtk\w+ \(0x[0-9a-fA-F]+\)", "", text)  # the class and address speaking
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
    if said == "its XML cannot be parsed" and not any(w in what for w in ("XML", "XDMF")):
        said = "its text cannot be parsed"  # (a parser's words in a format that is no XML: Fluent's)
    said = said.format(a_what=article(what))
    return f"{said} (at {', '.join(where[:3])})" if where else said


# ---- VTK data -> arrays -------------------------------------------------------------------------


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
    tag_key = find_tag_key(cell_data, physical_tag)
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
