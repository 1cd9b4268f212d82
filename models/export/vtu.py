"""VTU (VTK XML UnstructuredGrid) writer for agglomerated meshes.

2D elements are VTK_POLYGON (one loop each), 3D elements VTK_POLYHEDRON with their face
streams. Arrays are base64 binary with UInt64 headers; readable by VTK's vtkXMLUnstructuredGridReader
and ParaView.
"""

from __future__ import annotations

import base64
import os

import numpy as np

from models.errors import MeshError
from models.export import atomic
from models.mesh.container import VTK_POLYGON, VTK_POLYHEDRON, PolyMesh
from models.mesh.dual import sorted_unique

_VTK_TYPES = {
    np.dtype(np.float64): "Float64",
    np.dtype(np.float32): "Float32",
    np.dtype(np.int64): "Int64",
    np.dtype(np.int32): "Int32",
    np.dtype(np.uint8): "UInt8",
}


def _data_array(name: str, arr: np.ndarray, ncomp: int = 1) -> str:
    arr = np.ascontiguousarray(arr)
    raw = arr.tobytes()
    payload = base64.b64encode(np.uint64(len(raw)).tobytes() + raw).decode("ascii")
    comps = f' NumberOfComponents="{ncomp}"' if ncomp > 1 else ""
    return f'<DataArray type="{_VTK_TYPES[arr.dtype]}" Name="{name}"{comps} format="binary">{payload}</DataArray>\n'


def group_names_of(mesh) -> dict[str, tuple[int, int]]:
    """{name: (tag, dim)} of the mesh's element and boundary groups that have names, for
    write_vtu's group_names."""
    out: dict[str, tuple[int, int]] = {}
    for key, dim in (("group_names", mesh.dim), ("boundary_names", mesh.dim - 1)):
        for tag, name in mesh.meta.get(key, {}).items():
            out.setdefault(name, (int(tag), dim))
    return out


def write_vtu(
    path: str | os.PathLike,
    poly: PolyMesh,
    cell_data: dict[str, np.ndarray] | None = None,
    boundary=None,
    group_names: dict[str, tuple[int, int]] | None = None,
    points_xml: str | None = None,
) -> None:
    """Write the agglomerated mesh; `cell_data` adds per-element arrays (e.g. metrics).

    boundary: None or (offsets, nodes, VTK types, tags) of tagged edges/faces (models.mesh.boundary.
    output_cells), written after the elements as their own cells with a `boundary_tag` array
    (-1 on elements; element arrays are -1 / NaN on them), which models.mesh.read reads back as groups.
    group_names: {name: (tag, dim)} written as FieldData the way meshio keeps gmsh's physical names.
    points_xml: points_xml(poly), when the caller already has it (levels of one mesh share their points).
    """
    e = poly.n_elements
    if poly.dim == 2:
        lo = poly.loop_offsets
        n_loops = np.diff(poly.elem_offsets)
        if np.any(n_loops != 1):
            raise MeshError(
                "cannot write elements with holes as VTK polygons; split them first (hole_policy='split')"
            )
        conn = poly.loop_nodes.astype(np.int64)
        offsets = lo[1:].astype(np.int64)
        types = np.full(e, VTK_POLYGON, dtype=np.uint8)
        faces_xml = ""
        pts = None if points_xml is not None else _points3d(poly)
    else:
        fo = poly.loop_offsets
        fsz = np.diff(fo)
        nface = np.diff(poly.elem_offsets)
        face_elem = np.repeat(np.arange(e), nface)
        # connectivity: the distinct points of each element
        node_elem = np.repeat(face_elem, fsz)
        pairs = sorted_unique(node_elem * np.int64(poly.points.shape[0]) + poly.loop_nodes)
        conn = pairs % poly.points.shape[0]
        pe = pairs // poly.points.shape[0]
        offsets = np.cumsum(np.bincount(pe, minlength=e)).astype(np.int64)
        types = np.full(e, VTK_POLYHEDRON, dtype=np.uint8)
        # face stream per element: nfaces, (n, ids...) per face
        stream_len = 1 + nface + np.bincount(face_elem, weights=fsz, minlength=e).astype(np.int64)
        soff = np.zeros(e + 1, dtype=np.int64)
        np.cumsum(stream_len, out=soff[1:])
        stream = np.empty(int(soff[-1]), dtype=np.int64)
        stream[soff[:-1]] = nface
        # position of each face header inside the stream
        face_rank = np.arange(face_elem.size) - poly.elem_offsets[:-1][face_elem]
        nodes_before = fo[:-1] - fo[poly.elem_offsets[:-1]][face_elem]
        head = soff[:-1][face_elem] + 1 + face_rank + nodes_before
        stream[head] = fsz
        node_pos = np.repeat(head + 1, fsz) + (np.arange(fo[-1]) - np.repeat(fo[:-1], fsz))
        stream[node_pos] = poly.loop_nodes
        faces_xml = (stream, soff[1:])
        pts = poly.points
    nb = 0
    if boundary is not None:
        b_off, b_nodes, b_types, b_tags = boundary
        nb = b_types.size
        offsets = np.concatenate([offsets, offsets[-1] + b_off[1:]]) if e else b_off[1:].astype(np.int64)
        conn = np.concatenate([conn, b_nodes]).astype(np.int64)
        types = np.concatenate([types, b_types]).astype(np.uint8)
    if faces_xml:
        stream, foff = faces_xml
        faces_xml = _data_array("faces", stream) + _data_array(
            "faceoffsets", np.concatenate([foff, np.full(nb, -1, np.int64)])
        )
    parts = [
        '<?xml version="1.0"?>\n',
        '<VTKFile type="UnstructuredGrid" version="1.0" byte_order="LittleEndian" header_type="UInt64">\n',
        "<UnstructuredGrid>\n",
        _field_data(group_names),
        f'<Piece NumberOfPoints="{poly.points.shape[0]}" NumberOfCells="{e + nb}">\n',
        "<Points>\n",
        points_xml if points_xml is not None else _data_array("Points", np.asarray(pts, dtype=np.float64), 3),
        "</Points>\n<Cells>\n",
        _data_array("connectivity", conn),
        _data_array("offsets", offsets),
        _data_array("types", types),
        faces_xml,
        "</Cells>\n<CellData>\n",
    ]
    data = {"element_id": np.arange(e, dtype=np.int64), "n_fine_cells": poly.n_fine.astype(np.int64)}
    if poly.tags is not None:
        data["physical_group"] = poly.tags.astype(np.int64)
    data["measure"] = poly.measure.astype(np.float64)
    for k, v in (cell_data or {}).items():
        data[k] = np.asarray(v)
    for name, arr in data.items():
        if arr.dtype not in _VTK_TYPES:
            arr = arr.astype(np.float64)
        if nb:
            fill = np.nan if arr.dtype.kind == "f" else -1 if arr.dtype.kind == "i" else 0
            arr = np.concatenate([arr, np.full(nb, fill, dtype=arr.dtype)])
        parts.append(_data_array(name, arr))
    if nb:
        parts.append(
            _data_array(
                "boundary_tag", np.concatenate([np.full(e, -1, np.int64), np.asarray(b_tags, np.int64)])
            )
        )
    parts.append("</CellData>\n</Piece>\n</UnstructuredGrid>\n</VTKFile>\n")
    atomic.write_lines(path, parts)


def _field_data(names: dict[str, tuple[int, int]] | None) -> str:
    if not names:
        return ""
    from xml.sax.saxutils import quoteattr

    rows = [
        f'<DataArray type="Int64" Name={quoteattr(str(n))} NumberOfTuples="2" format="ascii">{int(t)} {int(d)}</DataArray>\n'
        for n, (t, d) in names.items()
    ]
    return "<FieldData>\n" + "".join(rows) + "</FieldData>\n"


def points_xml(poly: PolyMesh) -> str:
    """The Points DataArray write_vtu writes for `poly` (pass it back as write_vtu's points_xml)."""
    pts = _points3d(poly) if poly.dim == 2 else poly.points
    return _data_array("Points", np.asarray(pts, dtype=np.float64), 3)


def _points3d(poly: PolyMesh) -> np.ndarray:
    p = poly.points
    if poly.frame is None:
        return np.column_stack([p, np.zeros(len(p))])
    o, e1, e2 = poly.frame
    return o[None, :] + p[:, :1] * e1[None, :] + p[:, 1:2] * e2[None, :]
