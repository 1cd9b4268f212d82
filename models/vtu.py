"""VTU (VTK XML UnstructuredGrid) writer for agglomerated meshes.

2D elements are VTK_POLYGON (one loop each), 3D elements VTK_POLYHEDRON with their face
streams. Arrays are base64 binary with UInt64 headers; readable by VTK's vtkXMLUnstructuredGridReader
and ParaView.
"""

from __future__ import annotations

import base64
import os

import numpy as np

from .errors import MeshError
from .graph import sorted_unique
from .mesh import VTK_POLYGON, VTK_POLYHEDRON, PolyMesh

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


def write_vtu(
    path: str | os.PathLike,
    poly: PolyMesh,
    cell_data: dict[str, np.ndarray] | None = None,
    boundary=None,
    group_names: dict[str, tuple[int, int]] | None = None,
) -> None:
    """Write the agglomerated mesh; `cell_data` adds per-element arrays (e.g. metrics).

    boundary: None or (offsets, nodes, VTK types, tags) of tagged edges/faces (models.boundary.
    output_cells), written after the elements as their own cells with a `boundary_tag` array
    (-1 on elements; element arrays are -1 / NaN on them), which models.io reads back as groups.
    group_names: {name: (tag, dim)} written as FieldData the way meshio keeps gmsh's physical names.
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
        pts = _points3d(poly)
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
        f'<Piece NumberOfPoints="{pts.shape[0]}" NumberOfCells="{e + nb}">\n',
        "<Points>\n",
        _data_array("Points", np.asarray(pts, dtype=np.float64), 3),
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
    tmp = os.fspath(path) + ".tmp"
    with open(tmp, "w", encoding="ascii") as fh:
        fh.writelines(parts)
    os.replace(tmp, path)


def _field_data(names: dict[str, tuple[int, int]] | None) -> str:
    if not names:
        return ""
    from xml.sax.saxutils import quoteattr

    rows = [
        f'<DataArray type="Int64" Name={quoteattr(str(n))} NumberOfTuples="2" format="ascii">{int(t)} {int(d)}</DataArray>\n'
        for n, (t, d) in names.items()
    ]
    return "<FieldData>\n" + "".join(rows) + "</FieldData>\n"


def _points3d(poly: PolyMesh) -> np.ndarray:
    p = poly.points
    if poly.frame is None:
        return np.column_stack([p, np.zeros(len(p))])
    o, e1, e2 = poly.frame
    return o[None, :] + p[:, :1] * e1[None, :] + p[:, 1:2] * e2[None, :]


# meshio's VTU reader refuses polyhedra mixed with other cells, which is what write_vtu writes for
# a 3D result with boundary groups; this reads such files (inline ascii or uncompressed base64
# binary DataArrays, as write_vtu and VTK's own writer without compression produce).
_NP_TYPES = {
    "Float64": np.float64,
    "Float32": np.float32,
    "Int64": np.int64,
    "Int32": np.int32,
    "UInt64": np.uint64,
    "UInt32": np.uint32,
    "Int8": np.int8,
    "UInt8": np.uint8,
    "Int16": np.int16,
    "UInt16": np.uint16,
}
_MESHIO_NAMES = {
    3: "line",
    5: "triangle",
    7: "polygon",
    9: "quad",
    10: "tetra",
    12: "hexahedron",
    13: "wedge",
    14: "pyramid",
}


def _decode(el, header: type) -> np.ndarray:
    kind = _NP_TYPES.get(el.get("type", ""))
    if kind is None:
        raise MeshError(f"unsupported VTU data type {el.get('type')!r}")
    fmt = el.get("format", "ascii")
    text = (el.text or "").strip()
    if fmt == "ascii":
        return np.array(text.split(), dtype=np.float64).astype(kind) if text else np.zeros(0, kind)
    if fmt != "binary":
        raise MeshError(f"unsupported VTU data format {fmt!r} (inline ascii or binary only)")
    hsize = np.dtype(header).itemsize
    raw = base64.b64decode(text)
    n = int(np.frombuffer(raw[:hsize], dtype=header)[0])
    if len(raw) < hsize + n:  # header and data encoded separately
        hlen = 4 * ((hsize + 2) // 3)
        raw = base64.b64decode(text[:hlen])[:hsize] + base64.b64decode(text[hlen:])
    return np.frombuffer(raw[hsize : hsize + n], dtype=kind).copy()


def read_vtu_mixed(path: str | os.PathLike):
    """A VTU with VTK_POLYHEDRON cells next to other cells, as a meshio-like object
    (points, cells [.type, .data], cell_data {name: [array per block]}, field_data)."""
    import xml.etree.ElementTree as ET
    from types import SimpleNamespace

    root = ET.parse(os.fspath(path)).getroot()
    if root.get("compressor"):
        raise MeshError("compressed VTU files with polyhedra mixed with other cells are not supported")
    header = np.uint64 if root.get("header_type") == "UInt64" else np.uint32
    piece = root.find("UnstructuredGrid/Piece")
    if piece is None:
        raise MeshError("not a VTU UnstructuredGrid file")

    def arrays(section: str) -> dict:
        node = piece.find(section)
        return (
            {}
            if node is None
            else {
                el.get("Name"): (_decode(el, header), int(el.get("NumberOfComponents", 1)))
                for el in node.findall("DataArray")
            }
        )

    pts, ncomp = next(iter(arrays("Points").values()))
    cells = {k: v[0].astype(np.int64) for k, v in arrays("Cells").items()}
    conn, offs, types = cells["connectivity"], cells["offsets"], cells["types"]
    start = np.r_[0, offs[:-1]]
    cuts = np.flatnonzero(types[1:] != types[:-1]) + 1
    bounds = np.r_[0, cuts, types.size]
    blocks, sel = [], []
    for b0, b1 in zip(bounds[:-1], bounds[1:], strict=True):  # a loop over blocks of one type
        t = int(types[b0])
        if t == 42:
            fs, fo = cells["faces"], cells["faceoffsets"]
            # a cell's stream starts where the last earlier stream ended (faceoffsets = ends, -1 = none)
            begins = np.r_[0, np.maximum.accumulate(np.where(fo >= 0, fo, 0))[:-1]]
            data = []
            for c in range(b0, b1):  # polyhedra are parsed one by one (their faces are lists)
                begin = int(begins[c])
                n_faces = int(fs[begin])
                k, faces = begin + 1, []
                for _ in range(n_faces):
                    m = int(fs[k])
                    faces.append(fs[k + 1 : k + 1 + m])
                    k += m + 1
                data.append(faces)
            blocks.append(SimpleNamespace(type="polyhedron", data=data))
            sel.append(np.arange(b0, b1))
            continue
        if t not in _MESHIO_NAMES:
            raise MeshError(f"unsupported VTK cell type {t} in the VTU file")
        size = offs[b0:b1] - start[b0:b1]
        for s in np.unique(size):  # polygons of different sizes go to different blocks
            ids = np.arange(b0, b1)[size == s]
            data = conn[start[ids][:, None] + np.arange(s)[None, :]]
            name = _MESHIO_NAMES[t] if t != 7 else {3: "triangle", 4: "quad"}.get(int(s), "polygon")
            blocks.append(SimpleNamespace(type=name, data=data))
            sel.append(ids)
    cell_data = {
        name: [a.reshape(-1, nc)[ids].reshape(-1) if nc == 1 else a.reshape(-1, nc)[ids] for ids in sel]
        for name, (a, nc) in arrays("CellData").items()
    }
    fd = root.find("UnstructuredGrid/FieldData")
    field_data = {} if fd is None else {el.get("Name"): _decode(el, header) for el in fd.findall("DataArray")}
    return SimpleNamespace(
        points=pts.reshape(-1, ncomp).astype(np.float64),
        cells=blocks,
        cell_data=cell_data,
        field_data=field_data,
    )
