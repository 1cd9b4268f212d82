"""Polyhedra as refinement and other tools write them (outside sweep X).

1. Faces holding the midpoints of their edges (the faces of a refined or snappyHexMesh mesh): two
   faces sharing an edge and its midpoint share their three smallest nodes, which keyed them as one
   face; every such mesh was refused ("not a manifold" / "the same edge/face twice").
2. Faces stored once for both their cells (Exodus NFACED, Fluent polyhedra): VTK keeps the face's
   order in both, so it points inwards in one; such cells were refused as degenerate or inconsistent.

Each cube [i, i+1]^3 of a 2 x 2 x 2 block is a polyhedron whose six faces are octagons (four corners,
four edge midpoints); the volume is 8 whatever the face order, checked on our output read back by VTK.
"""

from __future__ import annotations

import numpy as np
import pytest
import vtk
import vtk_corpus as vc

from models.mesh.read import read_mesh

# a unit cube's faces, outward, each as (corner, midpoint, corner, ...) on the half-step lattice
_FACES = [
    [(0, 0, 0), (0, 1, 0), (0, 2, 0), (1, 2, 0), (2, 2, 0), (2, 1, 0), (2, 0, 0), (1, 0, 0)],  # z = 0
    [(0, 0, 2), (1, 0, 2), (2, 0, 2), (2, 1, 2), (2, 2, 2), (1, 2, 2), (0, 2, 2), (0, 1, 2)],  # z = 1
    [(0, 0, 0), (1, 0, 0), (2, 0, 0), (2, 0, 1), (2, 0, 2), (1, 0, 2), (0, 0, 2), (0, 0, 1)],  # y = 0
    [(0, 2, 0), (0, 2, 1), (0, 2, 2), (1, 2, 2), (2, 2, 2), (2, 2, 1), (2, 2, 0), (1, 2, 0)],  # y = 1
    [(0, 0, 0), (0, 0, 1), (0, 0, 2), (0, 1, 2), (0, 2, 2), (0, 2, 1), (0, 2, 0), (0, 1, 0)],  # x = 0
    [(2, 0, 0), (2, 1, 0), (2, 2, 0), (2, 2, 1), (2, 2, 2), (2, 1, 2), (2, 0, 2), (2, 0, 1)],  # x = 1
]


def _block(shared_faces_once: bool, repeat_nodes: bool = False) -> vtk.vtkUnstructuredGrid:
    """The 8 cubes; shared_faces_once: each interior face in the lower cube's direction in both cubes;
    repeat_nodes: every other face with its first node written twice (a collapsed edge)."""
    n = 5  # half-step lattice points per axis over [0, 2]
    pid = lambda i, j, k: (k * n + j) * n + i  # noqa: E731
    g = np.arange(n) * 0.5
    pts = np.array([(x, y, z) for z in g for y in g for x in g])
    ug = vtk.vtkUnstructuredGrid()
    p = vtk.vtkPoints()
    for q in pts:
        p.InsertNextPoint(*q)
    ug.SetPoints(p)
    seen: dict = {}
    for c in range(8):
        o = np.array([c & 1, (c >> 1) & 1, c >> 2]) * 2
        stream = [6]
        for face in _FACES:
            ids = [pid(*(o + np.array(v))) for v in face]
            key = frozenset(ids)
            if shared_faces_once and key in seen:
                ids = seen[key]  # the first cube's order: inward here
            seen.setdefault(key, ids)
            if repeat_nodes and (len(stream) // 9) % 2 == 0:
                ids = [ids[0], *ids]
            stream += [len(ids), *ids]
        lst = vtk.vtkIdList()
        for v in stream:
            lst.InsertNextId(int(v))
        ug.InsertNextCell(vtk.VTK_POLYHEDRON, lst)
    return ug


def _volume_back(path) -> float:
    """Our output's polyhedra read back by VTK: the divergence theorem over their faces."""
    r = vtk.vtkXMLUnstructuredGridReader()
    r.SetFileName(str(path))
    r.Update()
    o = r.GetOutput()
    total = 0.0
    for i in range(o.GetNumberOfCells()):
        cell = o.GetCell(i)
        if cell.GetCellDimension() != 3:
            continue
        for f in range(cell.GetNumberOfFaces()):
            face = cell.GetFace(f)
            q = np.array([o.GetPoint(face.GetPointId(j)) for j in range(face.GetNumberOfPoints())])
            total += sum(np.dot(q[0], np.cross(q[j], q[j + 1])) for j in range(1, len(q) - 1)) / 6
    return total


@pytest.mark.parametrize("once", [False, True])
def test_polyhedra_with_edge_midpoints_and_faces_stored_once(tmp_path, once):
    from models import agglomerate

    path = vc.write_xml(tmp_path / "block.vtu", _block(once))
    mesh = read_mesh(path)
    assert mesh.n_cells == 8
    assert float(np.abs(mesh.meta["measures"]).sum()) == pytest.approx(8.0, rel=1e-12)
    assert mesh.meta["orientation"]["folded"] == 0
    if once:
        assert "faces reversed to agree" in mesh.meta["reversed_faces"]["message"]
        assert mesh.meta["reversed_faces"]["count"] == 12  # the 12 interior faces, in their second cube
    else:
        assert "reversed_faces" not in mesh.meta
    out = tmp_path / "out.vtu"
    agglomerate(str(path), k=2).write(str(out))
    assert _volume_back(out) == pytest.approx(8.0, rel=1e-9)


def test_a_polyhedron_missing_a_face_is_said_to_be_open(tmp_path):
    """A face missing from a cell's list (a corrupted OpenFOAM owner list, outside sweep X): the cell
    is kept and said not to be closed (its measure is not that of a closed cell)."""
    ug = _block(False)
    out = vtk.vtkUnstructuredGrid()
    out.SetPoints(ug.GetPoints())
    for i in range(ug.GetNumberOfCells()):
        stream = vtk.vtkIdList()
        ug.GetFaceStream(i, stream)
        ids = [stream.GetId(j) for j in range(stream.GetNumberOfIds())]
        if i == 5:  # drop its last face
            faces, pos = [], 1
            for _ in range(ids[0]):
                faces.append(ids[pos : pos + 1 + ids[pos]])
                pos += 1 + ids[pos]
            ids = [len(faces) - 1] + [v for f in faces[:-1] for v in f]
        lst = vtk.vtkIdList()
        for v in ids:
            lst.InsertNextId(int(v))
        out.InsertNextCell(vtk.VTK_POLYHEDRON, lst)
    path = vc.write_xml(tmp_path / "open.vtu", out)
    mesh = read_mesh(path)
    assert mesh.meta["open_polyhedra"]["cells"] == [5], mesh.meta.get("open_polyhedra")
    assert "not closed" in mesh.meta["open_polyhedra"]["message"]


@pytest.mark.parametrize("nodes", [1, 2])
def test_a_polygon_of_one_or_two_nodes_among_many_is_left_out_in_the_sandbox_too(tmp_path, nodes):
    """The in-process read left it out (a degenerate cell among 200); the sandboxed read, whose
    caller checks the child's arrays, took a polygon of fewer than 3 nodes for a lie and said the
    reader crashed (outside sweep Y)."""
    from models.mesh.sandbox import read_mesh_safe

    n = 15
    g = np.arange(n + 1, dtype=float)
    pts = np.array([(x, y, 0.0) for y in g for x in g])
    ug = vtk.vtkUnstructuredGrid()
    p = vtk.vtkPoints()
    for q in pts:
        p.InsertNextPoint(*q)
    ug.SetPoints(p)
    for j in range(n):
        for i in range(n):
            a = j * (n + 1) + i
            ring = [a, a + 1, a + n + 2, a + n + 1]
            if j == 0 and i == 7:
                ring = ring[:nodes]  # the bad one
            lst = vtk.vtkIdList()
            for v in ring:
                lst.InsertNextId(v)
            ug.InsertNextCell(vtk.VTK_POLYGON, lst)
    path = vc.write_xml(tmp_path / "polys.vtu", ug)
    mesh = read_mesh_safe(str(path))
    assert mesh.n_cells == n * n - 1
    assert mesh.meta["dropped_cells"]["ids_all"] == [7]


def test_faces_with_a_node_repeated_are_read_closed(tmp_path):
    """Some writers repeat a node where an edge collapses (a b b c): the zero-length edge was walked
    by no other face, every such cell looked open ("not closed", wrong boundary faces), and our own
    output, fed back, could not be agglomerated again (outside sweep Y). Read as VTK draws them."""
    from models import agglomerate

    path = vc.write_xml(tmp_path / "rep.vtu", _block(False, repeat_nodes=True))
    mesh = read_mesh(path)
    assert "open_polyhedra" not in mesh.meta and mesh.n_cells == 8
    assert float(np.abs(mesh.meta["measures"]).sum()) == pytest.approx(8.0, rel=1e-12)
    out, again = tmp_path / "out.vtu", tmp_path / "again.vtu"
    agglomerate(str(path), k=4).write(str(out))
    agglomerate(str(out), k=2).write(str(again))
    assert _volume_back(again) == pytest.approx(8.0, rel=1e-9)


def _old_layout_vtu(ug: vtk.vtkUnstructuredGrid, shift_last: int = 0) -> str:
    """The polyhedra as VTK XML of the layout before VTK 9.4 (ascii `faces` and `faceoffsets`
    arrays, as older writers and hand-rolled scripts write them); shift_last: added to the last
    face offset."""
    conn, offs, faces, foffs = [], [], [], []
    for i in range(ug.GetNumberOfCells()):
        stream = vtk.vtkIdList()
        ug.GetFaceStream(i, stream)
        ids = [stream.GetId(j) for j in range(stream.GetNumberOfIds())]
        points, pos = set(), 1
        for _ in range(ids[0]):  # (the stream: nfaces, then each face's size and points)
            points.update(ids[pos + 1 : pos + 1 + ids[pos]])
            pos += 1 + ids[pos]
        conn += sorted(points)
        offs.append(len(conn))
        faces += ids
        foffs.append(len(faces))
    foffs[-1] += shift_last
    pts = " ".join(f"{v:.17g}" for i in range(ug.GetNumberOfPoints()) for v in ug.GetPoint(i))

    def arr(name, kind, values):
        return (
            f'<DataArray type="{kind}" Name="{name}" format="ascii">{" ".join(map(str, values))}</DataArray>'
        )

    n = ug.GetNumberOfCells()
    return (
        '<?xml version="1.0"?><VTKFile type="UnstructuredGrid" version="1.0" byte_order="LittleEndian">'
        f'<UnstructuredGrid><Piece NumberOfPoints="{ug.GetNumberOfPoints()}" NumberOfCells="{n}">'
        f'<Points><DataArray type="Float64" NumberOfComponents="3" format="ascii">{pts}</DataArray></Points>'
        "<Cells>"
        + arr("connectivity", "Int64", conn)
        + arr("offsets", "Int64", offs)
        + arr("types", "UInt8", [42] * n)
        + arr("faces", "Int64", faces)
        + arr("faceoffsets", "Int64", foffs)
        + "</Cells></Piece></UnstructuredGrid></VTKFile>"
    )


def test_a_vtu_whose_face_offsets_run_past_its_faces_says_so(tmp_path):
    """VTK's reader says 'the "faces" array is not long enough'; its error text never reached us
    (the observer took the message as a long: its first 8 bytes), so the refusal was 'corrupted'
    (outside sweep Y). The same file with its offsets right reads."""
    from models.errors import MeshError
    from models.mesh.sandbox import read_mesh_safe

    good, bad = tmp_path / "good.vtu", tmp_path / "bad.vtu"
    good.write_text(_old_layout_vtu(_block(False)))
    bad.write_text(_old_layout_vtu(_block(False), shift_last=50))
    assert float(np.abs(read_mesh_safe(str(good)).meta["measures"]).sum()) == pytest.approx(8.0, rel=1e-12)
    with pytest.raises(MeshError) as err:
        read_mesh_safe(str(bad))
    assert str(err.value) == (
        "cannot read bad.vtu as VTK XML (VTU): its polyhedra's faces and face offsets do not match"
    ), str(err.value)
