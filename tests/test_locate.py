"""The place in a text mesh file where it goes wrong (models/mesh/locate.py), and refusals that
say it: legacy VTK ASCII, gmsh ASCII 2.2 and 4.1, AVS UCD ASCII, each written valid by meshio (or
our UCD writer) and broken at a known line."""

from __future__ import annotations

import meshio
import numpy as np
import pytest

from models.errors import MeshError
from models.mesh.locate import locate
from models.mesh.read import read_mesh

PTS = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]], float)
TETS = np.array([[0, 1, 2, 3], [1, 2, 3, 4]])


def _write(tmp_path, name, **kw):
    path = tmp_path / name
    meshio.write(str(path), meshio.Mesh(PTS, [("tetra", TETS)]), **kw)
    return path


def _replace_line(path, pred, new: bytes) -> int:
    """Replace the first line for which pred(line) holds; its 1-based number."""
    lines = path.read_bytes().split(b"\n")
    i = next(j for j, ln in enumerate(lines) if pred(ln))
    lines[i] = new
    path.write_bytes(b"\n".join(lines))
    return i + 1


FILES = {
    "legacy": lambda t: _write(t, "m.vtk", binary=False),
    "gmsh22": lambda t: _write(t, "m22.msh", file_format="gmsh22", binary=False),
    "gmsh41": lambda t: _write(t, "m41.msh", file_format="gmsh", binary=False),
}
KIND = {"legacy": "legacy", "gmsh22": "gmsh", "gmsh41": "gmsh"}


@pytest.mark.parametrize("name", sorted(FILES))
def test_valid_files_have_no_place(tmp_path, name):
    assert locate(FILES[name](tmp_path), KIND[name]) is None


def test_legacy_vtk_bad_coordinate(tmp_path):
    path = FILES["legacy"](tmp_path)
    n = _replace_line(path, lambda ln: ln.startswith(b"POINTS"), b"POINTS 5 double")
    lines = path.read_bytes().split(b"\n")
    lines[n] = b"0.0 0.0 zero " + b" ".join(lines[n].split()[3:])  # the third coordinate
    path.write_bytes(b"\n".join(lines))
    where = locate(path, "legacy")
    assert where == f"line {n + 1} (section POINTS, from line {n}): 'zero' where a coordinate is expected"
    with pytest.raises(MeshError) as err:
        read_mesh(path)
    assert str(err.value).startswith("cannot read m.vtk as legacy VTK: ") and where in str(err.value)


def test_legacy_vtk_point_id_out_of_range(tmp_path):
    path = FILES["legacy"](tmp_path)
    conn = _replace_line(path, lambda ln: ln.startswith(b"CONNECTIVITY"), b"CONNECTIVITY vtktypeint64")
    lines = path.read_bytes().split(b"\n")
    lines[conn] = b"0 1 2 3 1 2 3 7"  # point 7 of 5
    path.write_bytes(b"\n".join(lines))
    where = locate(path, "legacy")
    assert (
        where.startswith(f"line {conn + 1} (section CELLS, from line ")
        and "'7' where a point id in 0..4" in where
    )
    with pytest.raises(MeshError) as err:
        read_mesh(path)
    assert where in str(err.value)


def test_gmsh22_unclosed_section(tmp_path):
    path = FILES["gmsh22"](tmp_path)
    n = _replace_line(path, lambda ln: ln == b"$EndNodes", b"")
    where = locate(path, "gmsh")
    assert where.startswith("section $Nodes (from line ") and "has no $EndNodes before line" in where
    with pytest.raises(MeshError) as err:
        read_mesh(path)
    assert "m22.msh" in str(err.value) and "gmsh" in str(err.value) and "$EndNodes" in str(err.value)
    assert n > 1


def test_gmsh41_unknown_node_in_an_element(tmp_path):
    path = FILES["gmsh41"](tmp_path)
    lines = path.read_bytes().split(b"\n")
    end = lines.index(b"$EndElements")
    lines[end - 1] = b" ".join(lines[end - 1].split()[:-1] + [b"99"])  # the last element's last node
    path.write_bytes(b"\n".join(lines))
    where = locate(path, "gmsh")
    assert where.startswith(f"line {end} (section $Elements, from line ")
    assert where.endswith("'99' where a node tag that $Nodes defines is expected")
    with pytest.raises(MeshError) as err:
        read_mesh(path)
    assert where in str(err.value)


def test_ucd_cell_line_with_an_unknown_point(tmp_path):
    path = tmp_path / "m.ucd"
    path.write_text(
        "# two tets\n5 2 0 0 0\n"
        + "".join(f"{i + 1} {x} {y} {z}\n" for i, (x, y, z) in enumerate(PTS))
        + "1 1 tet 1 2 3 4\n2 1 tet 2 3 4 9\n"
    )
    where = locate(path, "ucd")
    assert (
        where
        == "line 9 (section cells, from line 8): '9' where a point id that the points section defines is expected"
    )
    with pytest.raises(MeshError) as err:
        read_mesh(path)
    assert str(err.value).startswith("cannot read m.ucd") and where in str(err.value)


def test_ucd_with_data_sections_is_placed_where_it_goes_wrong(tmp_path):
    """Sweep T: a UCD file whose header announces node or cell data (deal.II writes them) was
    blamed at its header ('3' where a data count (0) is expected) whatever was wrong; a repeated
    point id had no place of its own."""
    body = "".join(f"{i + 1} {x} {y} {z}\n" for i, (x, y, z) in enumerate(PTS))
    data = "1 1\nu, none\n" + "".join(f"{i + 1} 0.5\n" for i in range(5))
    path = tmp_path / "m.ucd"
    path.write_text(
        "5 2 1 0 0\n" + body.replace("2 1.0", "2 1,0", 1) + "1 1 tet 1 2 3 4\n2 1 tet 2 3 4 5\n" + data
    )
    assert locate(path, "ucd").startswith("line 3 (section points, from line 2): '1,0' where a coordinate")
    path.write_text(
        "5 2 1 0 0\n" + body.replace("2 1.0", "1 1.0", 1) + "1 1 tet 1 2 3 4\n2 1 tet 2 3 4 5\n" + data
    )
    where = locate(path, "ucd")
    assert (
        where == "line 3 (section points, from line 2): '1' where a point id no earlier point has is expected"
    )
    with pytest.raises(MeshError) as err:
        read_mesh(path)
    assert where in str(err.value)
