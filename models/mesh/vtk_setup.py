"""How VTK's readers are set up for a format (models.mesh.vtk_readers runs them), and what their
outputs and messages say beyond the arrays: PLOT3D's ASCII layout, an OpenFOAM case's mesh only,
Fluent's cell zones only, Exodus blocks' and sets' and EnSight parts' names, an OpenFOAM file's
place in VTK's error text; block names given to the groups the cells carry. numpy, the standard
library and models.mesh.cells only (the reader objects come in)."""

from __future__ import annotations

import os
import re

import numpy as np

from models.errors import MeshError, ParameterError
from models.mesh.cells import find_tag_key


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
    """An EnSight case's part descriptions, a multiblock's block names, as the names of its blocks
    (_composite numbers the non-empty leaves 1, 2, ... in order): {name: [block, dim of its cells]}.
    A partitioned dataset collection (VTKHDF) names its partitioned datasets, not their partitions:
    each partition is a block, named by its dataset ("steel", or "steel (2)" for a second one)."""
    if data.IsA("vtkPartitionedDataSetCollection"):
        return _collection_names(data)
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


def _collection_names(data) -> dict:
    """_part_names of a vtkPartitionedDataSetCollection (the names on its partitioned datasets)."""
    out, block = {}, 0
    for i in range(data.GetNumberOfPartitionedDataSets()):
        pds = data.GetPartitionedDataSet(i)
        meta = data.GetMetaData(i) if data.HasMetaData(i) else None
        name = str(meta.Get(data.NAME())).strip() if meta is not None and meta.Has(data.NAME()) else ""
        parts = [] if pds is None else [pds.GetPartition(j) for j in range(pds.GetNumberOfPartitions())]
        parts = [ds for ds in parts if ds is not None and ds.IsA("vtkDataSet") and ds.GetNumberOfCells() > 0]
        for k, ds in enumerate(parts):
            block += 1
            if name:
                out[name if k == 0 else f"{name} ({k + 1})"] = np.array(
                    [block, ds.GetCell(0).GetCellDimension()]
                )
    return out


def _names_of_tags(names: dict, cell_data: dict, physical_tag: str | None) -> dict:
    """Block names ({name: [block number, dim]}) as names of the groups the mesh will have (its tag
    array: models.mesh.cells.find_tag_key): as they are where the blocks are the groups ("block");
    where another tag array is taken (a zone's cells tagged gmsh:physical), each name goes to the one
    tag its block's cells carry, and a name whose block holds several tags, or none, is left out
    (matched by position it named the wrong group). A physical_tag the mesh lacks: no names (the
    reader refuses it where it takes the tags)."""
    try:
        key = find_tag_key(cell_data, physical_tag)
    except ParameterError:
        return {}
    if key in (None, "block"):
        return names
    block, tags = cell_data.get("block"), cell_data.get(key)
    if block is None or tags is None or len(block) != len(tags):
        return {}
    block, tags = np.asarray(block).reshape(-1), np.asarray(tags).reshape(-1)
    out = {}
    for name, (b, dim) in names.items():  # (a loop over the named blocks: a few)
        held = np.unique(tags[block == b])
        if held.size == 1 and float(held[0]).is_integer():
            out[name] = np.array([int(held[0]), int(dim)])
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
    except ValueError:  # (VTK's ASCII reading of such a file says different things run to run)
        where = 2 if multi else 1
        bad = next((v for v in dims_line if not v.isdigit()), b"")
        raise MeshError(
            f"cannot read {os.path.basename(path)} as PLOT3D grid: line {where} holds "
            f"'{bad.decode('ascii', 'replace')[:20]}' where the grid's point counts (whole numbers) are "
            "expected; it is text but not a PLOT3D grid"
        ) from None
    points = int(sizes.prod(axis=1).sum())
    numbers = len(text.split()) - int(multi) - dim * grids
    reader.SetIBlanking(int(numbers == (dim + 1) * points))


def _openfoam_mesh_only(reader) -> None:
    """An OpenFOAM case's mesh at its first time (constant/polyMesh): the internal mesh and every
    boundary patch (our boundary groups), the zones (cellZones: our groups), no field arrays;
    polyhedra kept whole."""
    reader.UpdateInformation()
    reader.EnableAllPatchArrays()
    for off in ("DisableAllCellArrays", "DisableAllPointArrays", "DisableAllLagrangianArrays"):
        getattr(reader, off, lambda: None)()
    reader.SetReadZones(1)  # (cellZones: the groups; point and face zones are not read)
    reader.SetCreateCellToPoint(0)
    if hasattr(reader, "SetDecomposePolyhedra"):
        reader.SetDecomposePolyhedra(0)


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
