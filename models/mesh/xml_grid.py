"""VTK XML structured files read with numpy: .vts (structured grid), .vtr (rectilinear grid) and
.vti (image data), before VTK's XML readers, which spend most of such a read decoding (issue 23).

The common layout only: one Piece covering the whole extent, little-endian, UInt32 or UInt64
headers, no compressor or zlib, the arrays we read inline binary (base64) or appended (base64 or
raw bytes), a 3D lattice (every axis of 2 points or more) or a 2D one (one axis of 1 point: quads),
image data not rotated. Anything else (several pieces, ascii data, another compressor, blanking: a
vtkGhostType array, a rotated image, a value not written as a plain number) gives None: VTK's
reader reads the file, and words any refusal.

The arrays are those the VTK path makes of the file (vtk_readers: _structured, _lattice,
_image_mesh), handed to the same builders with the same arguments (vtk_readers.mesh_of_cells,
mesh_of_image): the same Mesh, field by field and bit for bit, but for meta["reader"]. Of the cell
data only the tag array the VTK path would pick is decoded; point data is not read, as the VTK path
ignores it (but for a vtkGhostType array); field data gives the group names, as there.
"""

from __future__ import annotations

import math
import os
import re
import sys
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from models.errors import MeshError
from models.mesh.cells import find_tag_key
from models.mesh.container import Mesh
from models.mesh.formats import extension
from models.mesh.lattice import check_image_geometry, grid_points, image_axes, image_points, structured_cells
from models.mesh.mapped import file_bytes, owned
from models.mesh.vtk_readers import READERS, _int_tags, _lattice_cells, mesh_of_cells, mesh_of_image
from models.mesh.vtu import (
    _NP_TYPES,
    _appended,
    array_reader,
    layout,
    more_than_held,
    plain_number,
    room,
    scan_xml,
)

READER = "numpy (models/mesh/xml_grid.py)"
_DATASETS = {".vts": "StructuredGrid", ".vtr": "RectilinearGrid", ".vti": "ImageData"}
_GEOMETRY = {".vts": b"Points", ".vtr": b"Coordinates", ".vti": None}  # the Piece's section of points
# an extent bound as VTK reads one (an int): plain digits; anything else is left to VTK
_INT = re.compile(rb"[+-]?\d{1,9}")
_INTEGER_TYPES = {"Int8", "UInt8", "Int16", "UInt16", "Int32", "UInt32", "Int64", "UInt64"}
_GHOST = b"vtkGhostType"


@dataclass
class _Grid:
    """What the file says, checked and decoded: its extent (x0 x1 y0 y1 z0 z1), point counts per
    axis and numbers of points and cells; its points (.vts, as the file stores them), axes (.vtr: x,
    y, z coordinates, float64) or origin and spacing (.vti); its 1-component cell arrays by name
    (attrs, text), decoded on demand by `array` (vtu.array_reader's); its field data's integer
    arrays {name: values} (`groups`: the group names)."""

    kind: str
    extent: list
    dims: list
    n_points: int
    n_cells: int
    points: np.ndarray | None = None
    axes: list | None = None
    origin: tuple = (0.0, 0.0, 0.0)
    spacing: tuple = (1.0, 1.0, 1.0)
    cells: dict = field(default_factory=dict)
    groups: dict = field(default_factory=dict)
    array: Callable | None = None


def read_xml_grid(
    path: str | os.PathLike, physical_tag: str | None = None, weld: float | None = None, memory_bytes=None
) -> Mesh | None:
    """The Mesh of a .vts, .vtr or .vti file of the common layout (see the module's note), the one
    vtk_readers.read_vtk makes of it; None for any other file (VTK's reader then reads it).
    memory_bytes: None, or the most a lattice whose points the file does not store (image data,
    rectilinear grids) may take once built: a larger one gives None (read_mesh(native=False): the
    sandbox reads it under its memory limit). MeshError where the extent announces more points or
    cells than the file can hold (VTK's reader would believe it); the builders' refusals otherwise."""
    path = os.fspath(path)
    kind = extension(path)
    if kind not in _DATASETS or sys.byteorder != "little":
        return None
    try:
        grid = _scan(file_bytes(path), kind)  # mapped: what the Mesh keeps is copied (models.mesh.mapped)
    except MeshError:
        raise
    except Exception:  # noqa: BLE001  (anything unexpected: VTK's reader reads it, and says what is wrong)
        return None
    if grid is None:
        return None
    if memory_bytes is not None and kind != ".vts":
        from models.mesh.deferred import image_bytes

        if image_bytes(grid.n_points, grid.n_cells) > memory_bytes:
            return None
    return _build(grid, physical_tag, weld)


def _build(grid: _Grid, physical_tag, weld) -> Mesh | None:
    """vtk_readers.read_vtk's steps after VTK's reader, on our arrays."""
    meta = {"reader": READER, "format": READERS[grid.kind][0]}
    live = [a for a in range(3) if grid.dims[a] > 1]
    image = grid.kind == ".vti"
    if image and weld is None:  # _image_mesh: the header's origin and spacing are VTK's (plain numbers)
        check_image_geometry(grid.origin, grid.spacing, live)
    tag_key = find_tag_key(grid.cells, physical_tag)
    tags = None
    if tag_key is not None:
        try:
            values = grid.array(*grid.cells[tag_key]).reshape(-1)
        except Exception:  # noqa: BLE001  (a broken array: VTK's reader says what is wrong)
            return None
        if values.size != grid.n_cells:
            return None
        tags = _int_tags(values, grid.n_cells)
    if image and weld is None and len(live) == 3:
        mesh = mesh_of_image(grid.origin, grid.spacing, grid.extent, tags, tag_key, meta, grid.groups)
        if mesh is not None:
            return mesh
    if image:
        pts = image_points(grid.origin, grid.spacing, grid.extent)
        axes = image_axes(grid.origin, grid.spacing, grid.extent)
    elif grid.axes is not None:
        pts, axes = grid_points(grid.axes), grid.axes
    else:
        pts, axes = grid.points, None
    lattice = {"dims": grid.dims, "axes": axes} if len(live) == 3 else None  # vtk_readers._lattice
    norm = _lattice_cells(len(live), *structured_cells(grid.dims), tags)
    return mesh_of_cells(pts, norm, tag_key, weld, meta, lattice, grid.groups)


def _scan(data: bytes, kind: str) -> _Grid | None:
    """The file's layout and arrays checked (None: not ours to read); MeshError for counts beyond
    what the file can hold. Any other exception: the caller declines the file."""
    dataset = _DATASETS[kind]
    scanned = scan_xml(data, dataset.encode())
    if scanned is None:
        return None
    root, attrs, piece, sections = scanned
    file_layout = layout(root, dataset)
    if file_layout is None:
        return None
    compressor, header = file_layout
    extent = _numbers(attrs.get(b"WholeExtent"), 6, _int)
    if extent is None or _numbers(piece.get(b"Extent"), 6, _int) != extent:
        return None  # the Piece is not the whole extent
    dims = [extent[2 * a + 1] - extent[2 * a] + 1 for a in range(3)]
    if min(dims) < 1 or sum(d > 1 for d in dims) < 2:
        return None  # an empty extent, a line or a point: VTK's reader and its refusals
    geometry = _GEOMETRY[kind]
    appended = _appended(sections.pop(b"appended", None), sections)
    if set(sections) - {b"PointData", b"CellData", b"FieldData", geometry}:
        return None
    for section in (b"PointData", b"CellData"):
        if any(a.get(b"Name") == _GHOST for a, _ in sections.get(section, ())):
            return None  # blanking: VTK's path hides cells
    n_points, n_cells = math.prod(dims), math.prod(d - 1 for d in dims if d > 1)
    size = len(data)
    for what, n, held in (
        ("points", n_points, sections.get(b"PointData") or (kind == ".vts" and sections.get(b"Points"))),
        ("cells", n_cells, sections.get(b"CellData")),
    ):
        if held and n > room(size, compressor is not None):  # VTK's reader would allocate them
            raise MeshError(f"the file is corrupted: {more_than_held(n, what, size)}")
    array = array_reader(compressor, header, appended)
    grid = _Grid(kind, extent, dims, n_points, n_cells, array=array)
    if kind == ".vti":
        direction = _numbers(attrs.get(b"Direction"), 9, plain_number, (1, 0, 0, 0, 1, 0, 0, 0, 1))
        if direction != [1, 0, 0, 0, 1, 0, 0, 0, 1]:
            return None  # rotated (or unreadable): VTK's path
        grid.origin = _numbers(attrs.get(b"Origin"), 3, plain_number, (0.0, 0.0, 0.0))
        grid.spacing = _numbers(attrs.get(b"Spacing"), 3, plain_number, (1.0, 1.0, 1.0))
        if grid.origin is None or grid.spacing is None:
            return None
        grid.origin, grid.spacing = tuple(grid.origin), tuple(grid.spacing)
    elif kind == ".vts":
        (p_attrs, p_text), *more = sections.get(b"Points") or [(None, None)]
        if more or p_attrs is None or p_attrs.get(b"type") not in (b"Float32", b"Float64"):
            return None
        if p_attrs.get(b"NumberOfComponents") != b"3":
            return None
        points = array(p_attrs, p_text)  # float64 and our own (not a view of the mapped file)
        grid.points = owned(points) if points.dtype == np.float64 else points.astype(np.float64)
        if grid.points.shape != (n_points, 3):
            return None
    else:
        coords = sections.get(b"Coordinates", ())
        if len(coords) != 3 or any(a.get(b"NumberOfComponents", b"1") != b"1" for a, _ in coords):
            return None
        grid.axes = [owned(np.asarray(array(a, t).reshape(-1), np.float64)) for a, t in coords]
        if [x.size for x in grid.axes] != dims:
            return None
    grid.cells = _named(sections.get(b"CellData", ()), lambda a: a.get(b"NumberOfComponents", b"1") == b"1")
    if grid.cells is None:
        return None
    fields = _named(sections.get(b"FieldData", ()), lambda a: a[b"type"].decode() in _INTEGER_TYPES)
    if fields is None:
        return None
    for name, (a, t) in fields.items():  # vtk_readers._field_data: the integer arrays (group names)
        values = array(a, t).reshape(-1)
        tuples = int(a.get(b"NumberOfTuples", b"-1"))
        if values.size != tuples * int(a.get(b"NumberOfComponents", b"1")):
            return None
        grid.groups[name] = owned(values)
    return grid


def _named(items, keep) -> dict | None:
    """{name: (attrs, text)} of a section's DataArrays that VTK holds as numeric arrays (its
    GetArray: strings are not) and `keep` keeps (their attributes), or None where a name is missing
    or repeated, or a type is one we do not know."""
    out = {}
    names = set()
    for attrs, text in items:
        name = attrs.get(b"Name", b"").decode()
        kind = attrs.get(b"type", b"").decode()
        if not name or name in names or (kind not in _NP_TYPES and kind != "String"):
            return None
        names.add(name)
        if kind != "String" and keep(attrs):
            out[name] = (attrs, text)
    return out


def _numbers(text: bytes | None, n: int, number, default=None) -> list | None:
    """The n numbers of an attribute (`default` where it is absent), each read by `number` (None:
    a value VTK's parser may read otherwise, the caller declines), or None."""
    if text is None:
        return None if default is None else list(default)
    out = [number(t) for t in text.split()]
    return out if len(out) == n and None not in out else None


def _int(token: bytes) -> int | None:
    """An extent bound as VTK reads it (an int): plain digits, at most 9."""
    return int(token) if _INT.fullmatch(token) else None
