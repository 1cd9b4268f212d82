"""What an outside format sweep (session 44: 288 files) found: collection files whose references a
pattern misread (a commented-out time step read, a '>' in another attribute, entities, apostrophes,
spaces), an XDMF time series read at its first grid instead of its earliest time, VTK's own files
refused for an information key it cannot read back, NaN points no cell uses, a vector named
vtkGhostType, and coordinates too large or too small refused for a wrong reason."""

from __future__ import annotations

import os
import shutil

import numpy as np
import pytest

vtk = pytest.importorskip("vtk")
import vtk_corpus as vc  # noqa: E402
from vtkmodules.util.numpy_support import numpy_to_vtk  # noqa: E402

from models.errors import MeshError  # noqa: E402
from models.mesh.read import read_mesh  # noqa: E402


def _block(tmp_path, name, x0=0.0, n=2, scale=1.0):
    """A n x n x n block of hexahedra at x0 (x0 .. x0 + scale), written by VTK's XML writer."""
    p, h = vc.grid(n, n, n)
    p = np.asarray(p, dtype=float)
    p = (p - p.min(axis=0)) / np.ptp(p, axis=0) * scale
    p[:, 0] += x0
    return vc.write_xml(tmp_path / name, vc.unstructured(p, [(12, h)]))


def _pvd(path, rows, head=""):
    lines = [f"<DataSet {r}/>" for r in rows]
    text = '<?xml version="1.0"?>\n<VTKFile type="Collection" version="0.1">\n<Collection>\n'
    path.write_text(text + head + "\n".join(lines) + "\n</Collection>\n</VTKFile>\n", encoding="utf-8")
    return str(path)


def test_a_commented_out_time_step_and_a_greater_than_in_an_attribute_are_read_as_xml(tmp_path):
    _block(tmp_path, "a.vtu")
    _block(tmp_path, "b.vtu", x0=1.0)
    _block(tmp_path, "old.vtu", x0=5.0, n=3)
    comment = '<!-- <DataSet timestep="-1" part="0" file="old.vtu"/> -->\n'
    rows = ['timestep="0" part="0" file="a.vtu"', 'timestep="0" part="1" file="b.vtu"']
    mesh = read_mesh(_pvd(tmp_path / "c.pvd", rows, comment))
    assert mesh.n_cells == 16  # the two parts at time 0, not the commented-out 27 cells
    rows[1] = 'timestep="0" group="x&gt;y" part="1" file="b.vtu"'
    assert read_mesh(_pvd(tmp_path / "g.pvd", rows)).n_cells == 16  # both parts
    rows[1] = 'timestep="0" group="x>y" part="1" file="b.vtu"'  # (legal XML: '>' in an attribute)
    assert read_mesh(_pvd(tmp_path / "h.pvd", rows)).n_cells == 16


@pytest.mark.parametrize("name", ["p&0.vtu", "it's a.vtu", "dir é/p 1.vtu"])
def test_piece_names_with_entities_apostrophes_and_spaces_are_found(tmp_path, name):
    os.makedirs(tmp_path / os.path.dirname(name) if os.path.dirname(name) else tmp_path, exist_ok=True)
    _block(tmp_path, name)
    _block(tmp_path, "q.vtu", x0=1.0)
    esc = name.replace("&", "&amp;")
    assert (
        read_mesh(_pvd(tmp_path / "s.pvd", [f'part="0" file="{esc}"', 'part="1" file="q.vtu"'])).n_cells == 16
    )
    vtm = tmp_path / "m.vtm"
    vtm.write_text(
        '<?xml version="1.0"?>\n<VTKFile type="vtkMultiBlockDataSet" version="1.0">\n<vtkMultiBlockDataSet>\n'
        f'<!-- <DataSet index="9" file="gone.vtu"/> -->\n<DataSet index="0" file="{esc}"/>\n'
        '<DataSet index="1" file="q.vtu"/>\n</vtkMultiBlockDataSet>\n</VTKFile>\n',
        encoding="utf-8",
    )
    assert read_mesh(str(vtm)).n_cells == 16


def _xdmf_grid(t, x0, n=2):
    p, h = vc.grid(n, n, n)
    p = np.asarray(p, dtype=float)
    p = (p - p.min(axis=0)) / np.ptp(p, axis=0)
    p[:, 0] += x0
    conn = "\n".join(" ".join(map(str, r)) for r in h)
    pts = "\n".join(" ".join(f"{v:.17g}" for v in r) for r in p)
    return (
        f'<Grid Name="t{t}" GridType="Uniform"><Time Value="{t}"/>\n'
        f'<Topology TopologyType="Hexahedron" NumberOfElements="{len(h)}">'
        f'<DataItem Dimensions="{len(h)} 8" NumberType="Int" Format="XML">{conn}</DataItem></Topology>\n'
        f'<Geometry GeometryType="XYZ"><DataItem Dimensions="{len(p)} 3" NumberType="Float" Precision="8" '
        f'Format="XML">{pts}</DataItem></Geometry></Grid>\n'
    )


def test_an_xdmf_time_series_is_read_at_its_earliest_time_and_comments_name_no_file(tmp_path):
    """ParaView opens a time series at its earliest time; VTK's reader gave the file's first grid
    (here t = 2, 27 cells at x 5..6). A comment naming a missing .h5 is not a data file."""
    path = tmp_path / "ts.xdmf"
    path.write_text(
        '<?xml version="1.0"?>\n<Xdmf Version="3.0"><Domain>\n'
        '<!-- <DataItem Format="HDF">old_run.h5:/mesh</DataItem> -->\n'
        '<Grid Name="TS" GridType="Collection" CollectionType="Temporal">\n'
        + _xdmf_grid(2.0, 5.0, n=3)
        + _xdmf_grid(0.0, 0.0)
        + _xdmf_grid(1.0, 2.0)
        + "</Grid></Domain></Xdmf>\n"
    )
    mesh = read_mesh(str(path))
    assert mesh.n_cells == 8 and mesh.points[:, 0].max() <= 1.0 + 1e-12


def test_an_hdf5_data_file_with_a_space_in_its_name_is_found(tmp_path):
    h5py = pytest.importorskip("h5py")
    p, h = vc.grid(2, 2, 2)
    with h5py.File(tmp_path / "my data.h5", "w") as f:
        f["p"] = np.asarray(p, dtype=float)
        f["c"] = np.asarray(h, dtype=np.int64)
    path = tmp_path / "m.xdmf"
    path.write_text(
        '<?xml version="1.0"?>\n<Xdmf Version="3.0"><Domain><Grid Name="g">\n'
        f'<Topology TopologyType="Hexahedron" NumberOfElements="8"><DataItem Dimensions="8 8" '
        f'NumberType="Int" Precision="8" Format="HDF">my data.h5:/c</DataItem></Topology>\n'
        f'<Geometry GeometryType="XYZ"><DataItem Dimensions="{len(p)} 3" NumberType="Float" Precision="8" '
        'Format="HDF">my data.h5:/p</DataItem></Geometry>\n</Grid></Domain></Xdmf>\n'
    )
    assert read_mesh(str(path)).n_cells == 8
    os.remove(tmp_path / "my data.h5")
    with pytest.raises(MeshError, match="its data file my data.h5 is missing"):
        read_mesh(str(path))


@pytest.mark.parametrize("mode", ["ascii", "binary", "appended"])
@pytest.mark.parametrize("value", [np.inf, np.nan])
def test_vtk_files_whose_vector_data_hold_an_infinity_or_only_nans_are_read(tmp_path, mode, value):
    """VTK's writer records a vector array's norm range as an information key; with an infinity (or
    NaNs only) it writes 'inf' or '-nan', which its reader logs as an error and reads on."""
    p, h = vc.grid(3, 3, 3)
    ug = vc.unstructured(p, [(12, h)])
    vec = np.ones((len(p), 3)) if value == np.inf else np.full((len(p), 3), np.nan)
    vec[0] = value
    arr = numpy_to_vtk(vec, deep=True)
    arr.SetName("velocity")
    ug.GetPointData().AddArray(arr)
    arr.GetRange(-1)  # (the L2 norm range: the key the writer writes)
    mesh = read_mesh(vc.write_xml(tmp_path / "v.vtu", ug, mode))
    assert mesh.n_cells == 27


def test_nan_points_no_cell_uses_are_left_out_and_said(tmp_path):
    p, h = vc.grid(2, 2, 2)
    p = np.vstack([p, [[np.nan, 0, 0], [np.inf, 1, 1]]])
    mesh = read_mesh(vc.write_xml(tmp_path / "n.vtu", vc.unstructured(p, [(12, h)])))
    assert mesh.n_cells == 8 and mesh.n_points == len(p) - 2
    assert mesh.meta["nonfinite_points"]["count"] == 2
    p[3] = np.nan  # a point a cell uses: refused, and named
    with pytest.raises(MeshError, match="NaN or infinite coordinates"):
        read_mesh(vc.write_xml(tmp_path / "m.vtu", vc.unstructured(p, [(12, h)])))


def test_a_vector_named_vtkghosttype_is_no_ghost_array(tmp_path):
    p, h = vc.grid(2, 2, 2)
    ug = vc.unstructured(p, [(12, h)])
    g = numpy_to_vtk(np.ones((8, 3), dtype=np.uint8), deep=True)
    g.SetName("vtkGhostType")
    ug.GetCellData().AddArray(g)
    assert read_mesh(vc.write_xml(tmp_path / "g.vtu", ug)).n_cells == 8


@pytest.mark.parametrize(
    "scale, said",
    [(1e100, "a coordinate beyond 1e75"), (1e-150, "spans only 1e-150"), (1e-300, "spans only 1e-300")],
)
def test_coordinates_too_large_or_too_small_to_compute_with_are_said_so(tmp_path, scale, said):
    path = _block(tmp_path, "s.vtu", scale=scale)
    with pytest.raises(MeshError, match=said) as err:
        read_mesh(path)
    assert "coincide" not in str(err.value) and "corrupted or" not in str(err.value)
    shutil.rmtree(tmp_path)


def _cube_surface():
    """A unit cube's surface: 8 corners, 12 outward triangles."""
    p = np.array([[x, y, z] for z in (0, 1) for y in (0, 1) for x in (0, 1)], dtype=float)
    quads = [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]]
    return p, np.array([t for a, b, c, d in quads for t in ([a, b, c], [a, c, d])])


def test_a_surface_refusal_says_where_it_crosses_itself_before_pointing_at_fill(tmp_path):
    import meshio

    from models.mesh.check import check_file

    p, t = _cube_surface()
    path = tmp_path / "two.stl"
    meshio.write(str(path), meshio.Mesh(np.vstack([p, p + 0.5]), [("triangle", np.vstack([t, t + 8]))]))
    rep = check_file(str(path))
    said = " ".join(i["message"] for i in rep["issues"])
    assert rep["verdict"] == "error" and "nor can it be filled as it is: it intersects itself" in said, said
    assert "pairs of triangles cross, e.g. at (" in said


def test_a_t_junction_is_not_called_a_hole(tmp_path):
    """The cube's top split in two quads whose shared edge ends on the middle of the sides' edges."""
    from models.mesh.fill import check_closed, read_surface

    p, t = _cube_surface()
    p = np.vstack([p, [[0.5, 0, 1], [0.5, 1, 1]]])  # 8, 9: the middles of the top's front and back
    top = [[4, 8, 9], [4, 9, 6], [8, 5, 7], [8, 7, 9]]
    t = np.vstack([t[:2], t[4:], top])  # the top's two triangles replaced by four
    path = tmp_path / "tee.obj"
    path.write_text(
        "".join(f"v {x} {y} {z}\n" for x, y, z in p)
        + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in t)
    )
    with pytest.raises(
        MeshError, match=r"closed in space but not as triangles: .* \(T-junctions\), e\.g\. at \(0\.5"
    ):
        check_closed(read_surface(str(path)))


def test_a_symbolic_link_to_nothing_is_said_so(tmp_path, capsys):
    from models.cli.main import main

    os.symlink(tmp_path / "gone.vtu", tmp_path / "link.vtu")
    assert main(["check", str(tmp_path / "link.vtu")]) == 2
    assert "is a symbolic link that leads to no file" in capsys.readouterr().out


def test_files_of_no_components_or_another_format_are_said_so(tmp_path):
    p, h = vc.grid(2, 2, 2)
    path = vc.write_xml(tmp_path / "z.vtu", vc.unstructured(p, [(12, h)]), "ascii")
    text = (
        open(path)
        .read()
        .replace(
            "<PointData>",
            '<PointData><DataArray type="Float64" Name="nothing" '
            'NumberOfComponents="0" format="ascii"></DataArray>',
            1,
        )
    )
    open(path, "w").write(text)
    with pytest.raises(MeshError, match="its data array nothing declares 0 components per value"):
        read_mesh(path)
    (tmp_path / "b.obj").write_bytes(b"\x00" * 80 + b"\x01\x00\x00\x00" + b"\x00" * 50)
    with pytest.raises(MeshError, match=r"it has no point lines \('v x y z'\): is it an OBJ file\?"):
        read_mesh(str(tmp_path / "b.obj"))
    (tmp_path / "o.ply").write_text("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n")
    with pytest.raises(MeshError, match="it looks like an OFF file"):
        read_mesh(str(tmp_path / "o.ply"))
