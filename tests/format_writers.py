"""Writers for the format families that VTK's own writers do not cover here, at test time: by the
tool that writes them in practice where this machine has it (meshio's Exodus II and XDMF writers,
meshio's XDMF TimeSeriesWriter), else by hand from the format's specification (CGNS/HDF5 by the
SIDS file mapping with h5py, Gambit neutral, binary AVS UCD, Fluent ASCII mesh).

meshio's own CGNS writer is not used: its files lack the CGNSBase_t/Zone_t labels and VTK's CGNS
reader refuses them ("Not enough bases in the file"). vtkExodusIIWriter segfaults in the vtk 9.7
wheel, so Exodus comes from meshio (netCDF4).

Geometry: vtk_corpus.grid (an affine image of a unit grid: planar faces), several blocks / zones.
"""

from __future__ import annotations

import os
import struct
from pathlib import Path

import numpy as np

HEX_FACES = [[0, 3, 2, 1], [4, 5, 6, 7], [0, 1, 5, 4], [1, 2, 6, 5], [2, 3, 7, 6], [3, 0, 4, 7]]


def wedges(hexes: np.ndarray) -> np.ndarray:
    """Each hexahedron as two wedges (prism axis along the hexahedron's 0-3 edge): conforming with
    hexahedra below and above, and with each other."""
    return np.concatenate([hexes[:, [0, 1, 5, 3, 2, 6]], hexes[:, [0, 5, 4, 3, 6, 7]]])


# an affine map with dyadic entries: the grid's points are exact in float32 too (binary AVS UCD and
# VTK's Fluent reader keep float32 points), so every face stays planar in either precision
D = np.array([[1.0, 0.25, 0.125], [0.125, 1.25, 0.0], [0.0, 0.25, 0.875]])


def grid(nx: int, ny: int, nz: int) -> tuple[np.ndarray, np.ndarray]:
    """vtk_corpus.grid's hexahedra, its points mapped by D instead."""
    import vtk_corpus as vc

    p, h = vc.grid(nx, ny, nz)
    return np.rint(p @ np.linalg.inv(vc.A).T) @ D.T, h


def blocks(nx: int = 3, ny: int = 2, nz: int = 2):
    """Points and two element blocks of an nx x ny x nz grid: hexahedra (bottom layers) and wedges
    (the top layer)."""
    p, h = grid(nx, ny, nz)
    top = np.arange(len(h)) >= nx * ny * (nz - 1)
    return p, [("hexahedron", h[~top]), ("wedge", wedges(h[top]))]


def write_exodus(path, points, cell_blocks) -> str:
    """Exodus II by meshio's writer (netCDF4): one element block per cell block."""
    import meshio

    meshio.write(str(path), meshio.Mesh(points, cell_blocks), file_format="exodus")
    return str(path)


def add_exodus_sets(path, side_sets=(), block_names=()) -> str:
    """Side sets and element block names added to an Exodus II file (netCDF4, the Exodus II
    schema: ss_prop1 ids, elem_ssN / side_ssN 1-based, ss_names, eb_names), as Cubit and MOOSE
    write them: side_sets = [(name, id, element indices (0-based), local side numbers (1-based,
    Exodus' numbering))]."""
    import netCDF4

    with netCDF4.Dataset(str(path), "a") as ds:
        if "len_name" not in ds.dimensions:
            ds.createDimension("len_name", 33)
        if side_sets:
            ds.createDimension("num_side_sets", len(side_sets))
            ds.createVariable("ss_status", "i4", ("num_side_sets",))[:] = np.ones(len(side_sets), np.int32)
            prop = ds.createVariable("ss_prop1", "i4", ("num_side_sets",))
            prop.setncattr("name", "ID")
            prop[:] = [sid for _, sid, _, _ in side_sets]
            for k, (_, _, elems, sides) in enumerate(side_sets, start=1):
                ds.createDimension(f"num_side_ss{k}", len(elems))
                ds.createVariable(f"elem_ss{k}", "i4", (f"num_side_ss{k}",))[:] = np.asarray(elems) + 1
                ds.createVariable(f"side_ss{k}", "i4", (f"num_side_ss{k}",))[:] = np.broadcast_to(
                    sides, len(elems)
                )
            names = np.array([n for n, _, _, _ in side_sets], dtype="S33")
            ds.createVariable("ss_names", "S1", ("num_side_sets", "len_name"))[:] = netCDF4.stringtochar(
                names
            )
        if block_names:
            names = np.array(list(block_names), dtype="S33")
            ds.createVariable("eb_names", "S1", ("num_el_blk", "len_name"))[:] = netCDF4.stringtochar(names)
    return str(path)


def write_xdmf(path, points, cell_blocks) -> str:
    """XDMF 3 with its heavy data in an HDF5 file beside it (meshio's writer)."""
    import meshio

    meshio.write(str(path), meshio.Mesh(points, cell_blocks), file_format="xdmf", data_format="HDF")
    return str(path)


def write_xdmf_dolfinx(path, points, tets, cell_tags, facets, facet_tags) -> str:
    """An XDMF file as dolfinx's XDMFFile writes a mesh and its MeshTags: the mesh's grid, then a
    grid per tag set (the tagged entities' topology, the mesh's geometry by xi:include, the values
    as a cell attribute); heavy data in an .h5 beside it (h5py, dolfinx's layout). 2D (points of
    two coordinates, triangles): geometry XY, the facets as dolfinx writes them, PolyLine of 2."""
    import h5py

    path = Path(path)
    h5 = path.with_suffix(".h5")
    with h5py.File(h5, "w") as f:
        f["Mesh/mesh/geometry"] = np.asarray(points, np.float64)
        f["Mesh/mesh/topology"] = np.asarray(tets, np.int64)
        f["MeshTags/cells/topology"] = np.asarray(tets, np.int64)
        f["MeshTags/cells/values"] = np.asarray(cell_tags, np.int32)
        f["MeshTags/facets/topology"] = np.asarray(facets, np.int64)
        f["MeshTags/facets/values"] = np.asarray(facet_tags, np.int32)
    nt, nf, npts, hn = len(tets), len(facets), len(points), h5.name
    flat = np.asarray(points).shape[1] == 2
    cell_kind, per_cell = ("Triangle", 3) if flat else ("Tetrahedron", 4)
    facet_kind, per_facet = ("PolyLine", 2) if flat else ("Triangle", 3)

    def tags(name, kind, n, per, group):
        return f"""    <Grid Name="{name}" GridType="Uniform">
      <xi:include xpointer="xpointer(/Xdmf/Domain/Grid[@GridType='Uniform'][1]/Geometry)" />
      <Topology TopologyType="{kind}" NumberOfElements="{n}" NodesPerElement="{per}">
        <DataItem Dimensions="{n} {per}" NumberType="Int" Format="HDF">{hn}:/MeshTags/{group}/topology</DataItem>
      </Topology>
      <Attribute Name="{name}" AttributeType="Scalar" Center="Cell">
        <DataItem Dimensions="{n} 1" NumberType="Int" Format="HDF">{hn}:/MeshTags/{group}/values</DataItem>
      </Attribute>
    </Grid>
"""

    path.write_text(
        f"""<?xml version="1.0"?>
<!DOCTYPE Xdmf SYSTEM "Xdmf.dtd" []>
<Xdmf Version="3.0" xmlns:xi="http://www.w3.org/2001/XInclude">
  <Domain>
    <Grid Name="mesh" GridType="Uniform">
      <Topology TopologyType="{cell_kind}" NumberOfElements="{nt}" NodesPerElement="{per_cell}">
        <DataItem Dimensions="{nt} {per_cell}" NumberType="Int" Format="HDF">{hn}:/Mesh/mesh/topology</DataItem>
      </Topology>
      <Geometry GeometryType="{"XY" if flat else "XYZ"}">
        <DataItem Dimensions="{npts} {2 if flat else 3}" NumberType="Float" Precision="8" Format="HDF">{hn}:/Mesh/mesh/geometry</DataItem>
      </Geometry>
    </Grid>
"""
        + tags("cell_tags", cell_kind, nt, per_cell, "cells")
        + tags("facet_tags", facet_kind, nf, per_facet, "facets")
        + "  </Domain>\n</Xdmf>\n"
    )
    return str(path)


def write_xdmf_series(path, points, cell_blocks, steps: int = 3) -> str:
    """An XDMF time series (meshio.xdmf.TimeSeriesWriter): the mesh once, point data per step.
    The writer puts its .h5 in the working directory: it is run from the file's folder."""
    import meshio

    path = Path(path)
    cwd = os.getcwd()
    os.chdir(path.parent)
    try:
        with meshio.xdmf.TimeSeriesWriter(path.name) as w:
            w.write_points_cells(points, cell_blocks)
            for t in range(steps):
                w.write_data(float(t), point_data={"u": points[:, 0] * t})
    finally:
        os.chdir(cwd)
    return str(path)


# ---- CGNS (HDF5) by the SIDS-to-HDF5 file mapping -------------------------------------------------

CGNS_TYPES = {"tetra": 10, "pyramid": 12, "wedge": 14, "hexahedron": 17, "triangle": 5, "quad": 7}


def _node(parent, name: str, label: str, dtype: str, data=None):
    g = parent.create_group(name, track_order=True)
    g.attrs.create("name", np.bytes_(name), dtype="S33")
    g.attrs.create("label", np.bytes_(label), dtype="S33")
    g.attrs.create("type", np.bytes_(dtype), dtype="S3")
    g.attrs.create("flags", np.array([1], np.int32))
    if data is not None:
        if dtype == "C1":
            data = np.frombuffer(data.encode(), np.int8)
        data = np.asarray(data)
        g.create_dataset(" data", data=data.T if data.ndim > 1 else data)  # CGNS arrays are Fortran-ordered
    return g


def _cgns_base(f):
    """A CGNS/HDF5 file's root (its HDF5 mother node, format, library version) and its 3D base."""
    f.attrs.create("name", np.bytes_("HDF5 MotherNode"), dtype="S33")
    f.attrs.create("label", np.bytes_("Root Node of HDF5 File"), dtype="S33")
    f.attrs.create("type", np.bytes_("MT"), dtype="S3")
    f.create_dataset(" format", data=np.frombuffer(b"IEEE_LITTLE_32\0", np.int8))
    f.create_dataset(" hdf5version", data=np.frombuffer(b"HDF5 Version 1.12.2".ljust(33, b"\0"), np.int8))
    _node(f, "CGNSLibraryVersion", "CGNSLibraryVersion_t", "R4", np.array([4.2], np.float32))
    return _node(f, "Base", "CGNSBase_t", "I4", np.array([3, 3], np.int32))


def write_cgns(path, zones) -> str:
    """A CGNS/HDF5 file of unstructured zones: zones = [(points, [(meshio type, cells)])], one
    Elements_t node per block, 1-based connectivity, each zone with its own points."""
    import h5py

    with h5py.File(str(path), "w", track_order=True) as f:
        base = _cgns_base(f)
        for zi, (pts, cell_blocks) in enumerate(zones, 1):
            ncell = sum(len(c) for _, c in cell_blocks)
            zone = _node(base, f"Zone{zi}", "Zone_t", "I4", np.array([[len(pts), ncell, 0]], np.int32))
            _node(zone, "ZoneType", "ZoneType_t", "C1", "Unstructured")
            coords = _node(zone, "GridCoordinates", "GridCoordinates_t", "MT")
            for axis, nm in enumerate("XYZ"):
                _node(coords, "Coordinate" + nm, "DataArray_t", "R8", np.ascontiguousarray(pts[:, axis]))
            start = 1
            for bi, (kind, cells) in enumerate(cell_blocks):
                e = _node(
                    zone, f"Elements{bi}", "Elements_t", "I4", np.array([CGNS_TYPES[kind], 0], np.int32)
                )
                _node(
                    e,
                    "ElementRange",
                    "IndexRange_t",
                    "I4",
                    np.array([start, start + len(cells) - 1], np.int32),
                )
                _node(e, "ElementConnectivity", "DataArray_t", "I4", (cells + 1).astype(np.int32).ravel())
                start += len(cells)
    return str(path)


def write_cgns_structured(path, zones) -> str:
    """A CGNS/HDF5 file of structured zones (as Pointwise and ICEM write multi-block grids):
    zones = [(X, Y, Z)], each (ni, nj, nk), the zones' touching faces repeating their points."""
    import h5py

    with h5py.File(str(path), "w", track_order=True) as f:
        base = _cgns_base(f)
        for zi, (X, Y, Z) in enumerate(zones, 1):
            vertices = np.array(X.shape, np.int32)
            size = np.stack(
                [vertices, vertices - 1, np.zeros(3, np.int32)]
            )  # (vertex, cell, boundary vertex) sizes
            zone = _node(base, f"Zone{zi}", "Zone_t", "I4", size.T)
            _node(zone, "ZoneType", "ZoneType_t", "C1", "Structured")
            coords = _node(zone, "GridCoordinates", "GridCoordinates_t", "MT")
            for nm, a in zip("XYZ", (X, Y, Z), strict=True):
                _node(coords, "Coordinate" + nm, "DataArray_t", "R8", np.asarray(a, np.float64))
    return str(path)


def write_plot3d(path, grids, mode: str = "fortran", iblank=None, dtype="<f8") -> str:
    """A PLOT3D grid file (the NASA whole-format layout): the number of grids, their dimensions,
    then per grid x, y (, z) in Fortran order (and its iblank, where given: 0 blanks a point).
    grids: [(X, Y) or (X, Y, Z)] arrays of one shape; mode "ascii", "c" (raw binary) or "fortran"
    (unformatted records with their 4-byte lengths, as Fortran codes write it)."""
    order = np.dtype(dtype).byteorder.replace("=", "<").replace("|", "<")
    ints = order + "i4"  # (a file's integers and reals in one byte order)
    dims = np.array([g[0].shape for g in grids], ints)
    data = [np.concatenate([np.asarray(a, np.float64).ravel("F") for a in g]).astype(dtype) for g in grids]
    blanks = [None] * len(grids) if iblank is None else [np.asarray(b, ints).ravel("F") for b in iblank]
    if mode == "ascii":
        lines = [str(len(grids)), " ".join(map(str, dims.ravel()))]
        for d, b in zip(data, blanks, strict=True):
            lines.append(" ".join(f"{v:.17g}" for v in d))
            if b is not None:
                lines.append(" ".join(map(str, b)))
        Path(path).write_text("\n".join(lines) + "\n")
        return str(path)
    with open(path, "wb") as f:

        def record(*arrays):
            raw = b"".join(a.tobytes() for a in arrays)
            if mode == "fortran":
                f.write(np.array([len(raw)], ints).tobytes())
            f.write(raw)
            if mode == "fortran":
                f.write(np.array([len(raw)], ints).tobytes())

        record(np.array([len(grids)], ints))
        record(dims.ravel())
        for d, b in zip(data, blanks, strict=True):
            record(d, *([] if b is None else [b]))
    return str(path)


def write_ensight(folder, name, points, parts) -> str:
    """An EnSight Gold case in ASCII, as CFD codes export it: name.case and name.geo, one part per
    entry of parts = [(description, EnSight element type ("hexa8", "quad4", ...), cells as point
    ids into `points`)], each part with its own coordinates (1-based, the spec's fixed widths)."""
    folder = Path(folder)
    lines = ["EnSight Gold geometry", "written at test time", "node id off", "element id off"]
    for k, (desc, kind, cells) in enumerate(parts, start=1):
        cells = np.asarray(cells)
        used, local = np.unique(cells, return_inverse=True)
        xyz = np.asarray(points, np.float64)[used]
        lines += ["part", f"{k:10d}", desc, "coordinates", f"{len(used):10d}"]
        for axis in range(3):
            lines += [f"{v:12.5e}" for v in xyz[:, axis]]
        lines += [kind, f"{len(cells):10d}"]
        lines += ["".join(f"{i + 1:10d}" for i in row) for row in local.reshape(cells.shape)]
    (folder / f"{name}.geo").write_text("\n".join(lines) + "\n")
    case = folder / f"{name}.case"
    case.write_text(f"FORMAT\ntype: ensight gold\n\nGEOMETRY\nmodel: {name}.geo\n")
    return str(case)


def split_zones(points, cells, axis: int = 0):
    """Cells split in two zones by their centres along `axis`, each zone with its own points (the
    interface points repeated, as multi-zone CGNS files have them)."""
    c = points[cells].mean(axis=1)[:, axis]
    out = []
    for part in (cells[c < np.median(c)], cells[c >= np.median(c)]):
        used, inv = np.unique(part, return_inverse=True)
        out.append((points[used], inv.reshape(part.shape)))
    return out


# ---- Gambit neutral (by the GAMBIT neutral file specification) -----------------------------------

GAMBIT_TYPES = {"quad": 2, "triangle": 3, "hexahedron": 4, "wedge": 5, "tetra": 6, "pyramid": 7}


def write_gambit(path, points, cell_blocks) -> str:
    """A Gambit neutral file: header, NODAL COORDINATES, ELEMENTS/CELLS (7 nodes a line), one
    ELEMENT GROUP per block."""
    ncells = sum(len(c) for _, c in cell_blocks)
    out = [
        "        CONTROL INFO 2.4.6",
        "** GAMBIT NEUTRAL FILE",
        "hand-written test mesh",
        "PROGRAM:                Gambit     VERSION:  2.4.6",
        " 4 Dec 2026    12:00:00",
        "     NUMNP     NELEM     NGRPS    NBSETS     NDFCD     NDFVL",
        f"{len(points):10d}{ncells:10d}{len(cell_blocks):10d}{0:10d}{3:10d}{3:10d}",
        "ENDOFSECTION",
        "   NODAL COORDINATES 2.4.6",
    ]
    out += [f"{i + 1:10d}{x:20.11e}{y:20.11e}{z:20.11e}" for i, (x, y, z) in enumerate(points)]
    out += ["ENDOFSECTION", "      ELEMENTS/CELLS 2.4.6"]
    eid = 0
    ids = []
    for kind, cells in cell_blocks:
        ids.append(np.arange(eid + 1, eid + len(cells) + 1))
        for c in cells + 1:
            eid += 1
            head = f"{eid:8d} {GAMBIT_TYPES[kind]:2d} {len(c):2d} "
            nodes = [f"{n:8d}" for n in c]
            out.append(head + "".join(nodes[:7]))
            for k in range(7, len(nodes), 7):
                out.append(" " * 15 + "".join(nodes[k : k + 7]))
    out.append("ENDOFSECTION")
    for g, ((kind, cells), gid) in enumerate(zip(cell_blocks, ids, strict=True), 1):
        out += [
            "       ELEMENT GROUP 2.4.6",
            f"GROUP:{g:11d} ELEMENTS:{len(cells):11d} MATERIAL:{2:11d} NFLAGS:{1:11d}",
            f"{kind:>32s}",
            "       0",
        ]
        out += ["".join(f"{i:8d}" for i in gid[k : k + 10]) for k in range(0, len(gid), 10)]
        out.append("ENDOFSECTION")
    Path(path).write_text("\n".join(out) + "\n")
    return str(path)


# ---- binary AVS UCD (the layout vtkAVSucdReader reads) -------------------------------------------

AVS_TYPES = {"triangle": 2, "quad": 3, "tetra": 4, "pyramid": 5, "wedge": 6, "hexahedron": 7}


def write_avs_binary(path, points, cell_blocks, node_data: bool = True) -> str:
    """Binary AVS UCD, little-endian: magic byte 7; six int32 (nodes, cells, node fields, cell
    fields, model fields, length of the node list); per cell (id, material, nodes, type); the node
    list (1-based); x, y and z as float32 blocks; then one scalar node field (labels, units, counts,
    min, max, values, active flags), which a reader of the mesh ignores."""
    ncells = sum(len(c) for _, c in cell_blocks)
    nlist = sum(c.size for _, c in cell_blocks)
    parts = [b"\x07", struct.pack("<6i", len(points), ncells, 1 if node_data else 0, 0, 0, nlist)]
    desc, conn, cid = [], [], 0
    for mat, (kind, cells) in enumerate(cell_blocks, 1):
        for c in cells:
            cid += 1
            desc.append((cid, mat, len(c), AVS_TYPES[kind]))
        conn.append((cells + 1).ravel())
    parts.append(np.asarray(desc, "<i4").tobytes())
    parts.append(np.concatenate(conn).astype("<i4").tobytes())
    pts = np.asarray(points, "<f4")
    parts += [np.ascontiguousarray(pts[:, a]).tobytes() for a in range(3)]
    if node_data:
        value = pts[:, 0].astype("<f4")
        parts += [
            b"temperature.".ljust(1024, b"\0"),
            b"kelvin.".ljust(1024, b"\0"),
            struct.pack("<i", 1),  # components
            struct.pack("<i", 1),  # veclen of each
            struct.pack("<f", float(value.min())),
            struct.pack("<f", float(value.max())),
            value.tobytes(),
            struct.pack("<i", 1),  # active
        ]
    Path(path).write_bytes(b"".join(parts))
    return str(path)


# ---- Fluent ASCII mesh (sections 10 nodes, 12 cells, 13 faces, 45 zone names) --------------------


def write_fluent(path, points, hexes, binary: bool = False) -> str:
    """A Fluent mesh of hexahedra, by faces: each face's nodes (hexadecimal, 1-based) with the
    right-hand normal pointing into its first cell c0, then c0 and c1 (0 on the boundary).
    binary: the node and face sections in Fluent's binary form, as Fluent writes a .msh/.cas by
    default (3010: float64 coordinates; 2013: int32 rows of 4 nodes, c0, c1; each section closed by
    ")\\nEnd of Binary Section   NNNN)": vtkFLUENTReader needs that line break)."""
    faces: dict[tuple, list] = {}
    for c, h in enumerate(hexes, 1):
        for f in HEX_FACES:
            key = tuple(sorted(h[f].tolist()))
            if key in faces:
                faces[key][2] = c
            else:
                faces[key] = [h[f][::-1], c, 0]  # outward of c reversed: the normal points into c
    interior = [v for v in faces.values() if v[2]]
    boundary = [v for v in faces.values() if not v[2]]

    def row(v):
        return " ".join(f"{n + 1:x}" for n in v[0]) + f" {v[1]:x} {v[2]:x}"

    def rows(vs):
        return np.array([[*(np.asarray(v[0]) + 1), v[1], v[2]] for v in vs], dtype="<i4").tobytes()

    n, m, k = len(points), len(hexes), len(faces)
    head = ['(0 "hand-written Fluent mesh")', "(2 3)", f"(10 (0 1 {n:x} 0 3))", f"(12 (0 1 {m:x} 0))"]
    head += [f"(13 (0 1 {k:x} 0))"]
    if binary:
        out = ("\n".join(head) + f"\n(3010 (1 1 {n:x} 1 3)(").encode()
        out += np.asarray(points, dtype="<f8").tobytes() + b")\nEnd of Binary Section   3010)\n"
        out += f"(12 (2 1 {m:x} 1 4))\n(2013 (3 1 {len(interior):x} 2 4)(".encode()
        out += rows(interior) + b")\nEnd of Binary Section   2013)\n"
        out += f"(2013 (4 {len(interior) + 1:x} {k:x} 3 4)(".encode()
        out += rows(boundary) + b")\nEnd of Binary Section   2013)\n"
        out += b"(45 (2 fluid fluid)())\n(45 (3 interior default-interior)())\n(45 (4 wall walls)())\n"
        Path(path).write_bytes(out)
        return str(path)
    out = head + [f"(10 (1 1 {n:x} 1 3)("]
    out += [f"{x:.17g} {y:.17g} {z:.17g}" for x, y, z in points]
    out += ["))", f"(12 (2 1 {m:x} 1 4))", f"(13 (3 1 {len(interior):x} 2 4)("]
    out += [row(v) for v in interior] + ["))", f"(13 (4 {len(interior) + 1:x} {k:x} 3 4)("]
    out += [row(v) for v in boundary] + ["))"]
    out += ["(45 (2 fluid fluid)())", "(45 (3 interior default-interior)())", "(45 (4 wall walls)())"]
    Path(path).write_text("\n".join(out) + "\n")
    return str(path)


# ---- Fluent CFF case (.cas.h5): the HDF5 layout VTK's vtkFLUENTCFFReader reads -------------------
# /meshes/1 (attributes dimension, node/cell/face Offset and Count), nodes (zoneTopology, coords/<zone>),
# cells (zoneTopology; ctype/<section> for a mixed zone, cellType 0), faces (zoneTopology,
# nodes/<section> with nnodes and the flat 1-based node list, c0/<section> and c1/<section>), and
# a /settings group (the reader's test for a CFF file). Fluent's element types: 1 triangle,
# 2 tetrahedron, 3 quadrilateral, 4 hexahedron, 5 pyramid, 6 wedge; face types 2 line, 3 triangle,
# 4 quadrilateral, 0 mixed.

FLUENT_TYPES = {"triangle": 1, "tetra": 2, "quad": 3, "hexahedron": 4, "pyramid": 5, "wedge": 6}
CELL_FACES = {  # each cell type's faces (edges in 2D), by local node
    "triangle": [[0, 1], [1, 2], [2, 0]],
    "quad": [[0, 1], [1, 2], [2, 3], [3, 0]],
    "tetra": [[0, 1, 2], [0, 1, 3], [1, 2, 3], [0, 2, 3]],
    "hexahedron": HEX_FACES,
    "wedge": [[0, 1, 2], [3, 4, 5], [0, 1, 4, 3], [1, 2, 5, 4], [2, 0, 3, 5]],
    "pyramid": [[0, 1, 2, 3], [0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]],
}


def _fluent_faces(points, cell_blocks):
    """Every face once: (faces as node lists, c0, c1), interior faces first; cells numbered from 1
    in block order. A face's nodes are ordered for its first cell c0: in 3D its right-hand normal
    points into c0 (Fluent's rule), in 2D along c0's counter-clockwise boundary."""
    dim = points.shape[1]
    rows, owner = [], []
    base = 0
    for kind, cells in cell_blocks:
        for f in CELL_FACES[kind]:
            rows += [list(r) for r in cells[:, f]]
            owner += list(base + 1 + np.arange(len(cells)))
        base += len(cells)
    owner = np.asarray(owner)
    centre = np.concatenate([points[c].mean(axis=1) for _, c in cell_blocks])
    keys = [tuple(sorted(r)) for r in rows]
    first: dict = {}
    faces, c0, c1 = [], [], []
    for r, key, cell in zip(rows, keys, owner, strict=True):
        if key in first:
            c1[first[key]] = cell
            continue
        q = points[r]
        out = q.mean(axis=0) - centre[cell - 1]
        if dim == 3:
            normal = sum(np.cross(q[i], q[(i + 1) % len(q)]) for i in range(len(q)))  # Newell
            outward = float(normal @ out) > 0
            r = r[::-1] if outward else r  # the right-hand normal into c0
        else:
            d = q[1] - q[0]
            ccw = float(d[1] * out[0] - d[0] * out[1]) > 0  # the outward normal (dy, -dx): c0 on the left
            r = r if ccw else r[::-1]
        first[key] = len(faces)
        faces.append(r)
        c0.append(cell)
        c1.append(0)
    order = sorted(range(len(faces)), key=lambda i: c1[i] == 0)  # interior faces first
    return [faces[i] for i in order], np.asarray(c0)[order], np.asarray(c1)[order]


def write_fluent_h5(path, points, cell_blocks, mixed_zone: bool = False) -> str:
    """A Fluent CFF case file: one cell zone per block (or, mixed_zone, one zone of cellType 0 whose
    types come from a ctype section), one interior and one wall face zone; 2D when points are (n, 2)."""
    import h5py

    points = np.asarray(points, np.float64)
    dim = points.shape[1]
    faces, c0, c1 = _fluent_faces(points, cell_blocks)
    n_cells = sum(len(c) for _, c in cell_blocks)
    n_int = int((c1 > 0).sum())
    u8, i4 = np.uint64, np.int32

    def zone_topology(g, ids, mins, maxs, **extra):
        t = g.create_group("zoneTopology")
        t.attrs["nZones"] = u8(len(ids))
        t["id"] = np.asarray(ids, i4)
        t["minId"] = np.asarray(mins, u8)
        t["maxId"] = np.asarray(maxs, u8)
        t["dimension"] = np.full(len(ids), dim, u8)
        for k, v in extra.items():
            t[k] = np.asarray(v, i4)

    def section(g, name, data, lo, hi):
        d = g.create_dataset(name, data=data)
        d.attrs["minId"], d.attrs["maxId"] = u8(lo), u8(hi)
        return d

    with h5py.File(str(path), "w") as f:
        f.create_group("settings")
        m = f.create_group("meshes").create_group("1")
        m.attrs["dimension"] = i4(dim)
        for what, count in (("node", len(points)), ("cell", n_cells), ("face", len(faces))):
            m.attrs[what + "Offset"], m.attrs[what + "Count"] = u8(0), u8(count)
        nodes = m.create_group("nodes")
        zone_topology(nodes, [1], [1], [len(points)])
        section(nodes.create_group("coords"), "1", points, 1, len(points))
        cells = m.create_group("cells")
        if mixed_zone:
            types = np.concatenate([np.full(len(c), FLUENT_TYPES[k], np.int16) for k, c in cell_blocks])
            zone_topology(cells, [2], [1], [n_cells], cellType=[0], childZoneId=[0])
            ct = cells.create_group("ctype")
            ct.attrs["nSections"] = u8(1)
            s = ct.create_group("1")
            s.attrs["elementType"], s.attrs["minId"], s.attrs["maxId"] = np.int16(0), u8(1), u8(n_cells)
            s["cell-types"] = types
        else:
            hi = np.cumsum([len(c) for _, c in cell_blocks])
            zone_topology(
                cells,
                list(range(2, 2 + len(cell_blocks))),
                hi - [len(c) for _, c in cell_blocks] + 1,
                hi,
                cellType=[FLUENT_TYPES[k] for k, _ in cell_blocks],
                childZoneId=[0] * len(cell_blocks),
            )
        fz = m.create_group("faces")
        nb = len(cell_blocks) if not mixed_zone else 1
        sizes = {len(r) for r in faces}
        ftype = sizes.pop() if len(sizes) == 1 else 0
        zone_topology(
            fz,
            [2 + nb, 3 + nb],
            [1, n_int + 1],
            [n_int, len(faces)],
            zoneType=[2, 3],  # interior, wall
            faceType=[ftype, ftype],
            childZoneId=[0, 0],
            shadowZoneId=[0, 0],
            flags=[0, 0],
        )
        fn = fz.create_group("nodes")
        fn.attrs["nSections"] = u8(1)
        s = fn.create_group("1")
        s.attrs["minId"], s.attrs["maxId"] = u8(1), u8(len(faces))
        s["nnodes"] = np.array([len(r) for r in faces], np.int16)
        s["nodes"] = (np.concatenate(faces) + 1).astype(np.uint32)
        for name, cell, lo, hi in (("c0", c0, 1, len(faces)), ("c1", c1[:n_int], 1, n_int)):
            g = fz.create_group(name)
            g.attrs["nSections"] = u8(1)
            section(g, "1", np.asarray(cell, np.uint32), lo, hi)
    return str(path)


# ---- CGNS through the CGNS library itself (ADF or HDF5): the one bundled in the vtk wheel ---------
# libvtkcgns.so exports the mid-level library with a vtkcgns_ prefix (cg_open, cg_base_write,
# cg_zone_write, cg_coord_write, cg_section_write, cg_poly_section_write, ...), ADF compiled in,
# cgsize_t 64-bit. CGNS enums used: CG_MODE_WRITE 1; CG_FILE_ADF 1, CG_FILE_HDF5 2; ZoneType
# Unstructured 3; DataType RealDouble 4; ElementType TRI_3 5, QUAD_4 7, TETRA_4 10, PYRA_5 12,
# PENTA_6 14, HEXA_8 17, MIXED 20.

CGNS_FILE_TYPES = {"adf": 1, "hdf5": 2}
CGNS_MIXED = 20


def cgns_library():
    """The CGNS library of the vtk wheel (ctypes), or None when it is not there or lacks a writer."""
    import ctypes

    import vtkmodules

    path = os.path.join(os.path.dirname(vtkmodules.__file__), "libvtkcgns.so")
    if not os.path.exists(path):
        return None
    lib = ctypes.CDLL(path)
    need = ("cg_set_file_type", "cg_open", "cg_base_write", "cg_zone_write", "cg_coord_write")
    need += ("cg_section_write", "cg_poly_section_write", "cg_close", "cg_get_error", "cg_get_file_type")
    if not all(hasattr(lib, "vtkcgns_" + n) for n in need):
        return None
    return lib


def write_cgns_lib(path, zones, file_type: str = "adf", mixed: bool = False, cell_dim: int = 3) -> str:
    """A CGNS file written by the CGNS library (ADF or HDF5 container): zones = [(points,
    [(meshio type, cells)])], one Elements_t section per block, or (mixed) one MIXED section per
    zone; 2D zones (cell_dim 2) get CoordinateX and CoordinateY only."""
    import ctypes

    lib = cgns_library()
    i, i64, ref = ctypes.c_int, ctypes.c_int64, ctypes.byref

    def call(name, *args):
        if getattr(lib, "vtkcgns_" + name)(*args) != 0:
            err = lib.vtkcgns_cg_get_error
            err.restype = ctypes.c_char_p
            raise RuntimeError(f"{name}: {err().decode()}")

    def ptr(a):
        return a.ctypes.data_as(ctypes.c_void_p)

    fn, b, z, c, s = i(), i(), i(), i(), i()
    call("cg_set_file_type", i(CGNS_FILE_TYPES[file_type]))
    call("cg_open", str(path).encode(), i(1), ref(fn))
    try:
        call("cg_base_write", fn, b"Base", i(cell_dim), i(cell_dim), ref(b))
        for zi, (pts, cell_blocks) in enumerate(zones, 1):
            ncell = sum(len(cells) for _, cells in cell_blocks)
            size = np.array([len(pts), ncell, 0], np.int64)
            call("cg_zone_write", fn, b, f"Zone{zi}".encode(), ptr(size), i(3), ref(z))
            for axis in range(cell_dim):
                x = np.ascontiguousarray(pts[:, axis], np.float64)
                call("cg_coord_write", fn, b, z, i(4), f"Coordinate{'XYZ'[axis]}".encode(), ptr(x), ref(c))
            if mixed:
                rows = [
                    np.column_stack([np.full(len(cells), CGNS_TYPES[k]), cells + 1])
                    for k, cells in cell_blocks
                ]
                conn = np.concatenate([r.ravel() for r in rows]).astype(np.int64)
                widths = np.concatenate([np.full(len(r), r.shape[1]) for r in rows])
                offsets = np.concatenate([[0], np.cumsum(widths)]).astype(np.int64)
                call(
                    "cg_poly_section_write", fn, b, z, b"Mixed", i(CGNS_MIXED), i64(1), i64(ncell),
                    i(0), ptr(conn), ptr(offsets), ref(s),
                )  # fmt: skip
                continue
            start = 1
            for bi, (kind, cells) in enumerate(cell_blocks):
                conn = np.ascontiguousarray(cells + 1, np.int64).ravel()
                call(
                    "cg_section_write", fn, b, z, f"Elements{bi}".encode(), i(CGNS_TYPES[kind]),
                    i64(start), i64(start + len(cells) - 1), i(0), ptr(conn), ref(s),
                )  # fmt: skip
                start += len(cells)
    finally:
        call("cg_close", fn)
    return str(path)
