"""Files and refusals an outside sweep (session 43) found read wrongly or worded badly: an OBJ whose
`f` lines go on after a backslash, a big-endian binary PLY with colours and an extra face property
(meshio's reader refused both; VTK reads them), an Abaqus file missing a *NODE line, legacy offsets
that go back, and refusals that said a reader's prefix twice or offered filling where it does not
apply."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from models.errors import MeshError
from models.mesh.check import check_file
from models.mesh.read import read_mesh

# a flat 4 x 4 grid of unit squares, tilted: 25 points, 16 quads
_I, _J = np.meshgrid(np.arange(5.0), np.arange(5.0), indexing="ij")
_PTS = np.column_stack([_I.ravel(), _J.ravel(), 0.3 * _I.ravel()])
_Q = np.array(
    [[i * 5 + j, (i + 1) * 5 + j, (i + 1) * 5 + j + 1, i * 5 + j + 1] for i in range(4) for j in range(4)]
)
_AREA = 16 * np.sqrt(1 + 0.3**2)


def _area(mesh) -> float:
    return float(np.abs(mesh.meta["measures"]).sum())


def test_obj_faces_continued_after_a_backslash(tmp_path):
    lines = [f"v {x} {y} {z} 0.5 0.25 1.0" for x, y, z in _PTS]
    for a, b, c, d in _Q + 1:
        lines.append(f"f {a} {b} \\")  # (a long face line broken by the exporter)
        lines.append(f"  {c} {d}")
    path = tmp_path / "continued.obj"
    path.write_text("\n".join(lines) + "\n")
    mesh = read_mesh(str(path))
    assert mesh.n_cells == 16 and abs(_area(mesh) - _AREA) <= 1e-9 * _AREA


def test_big_endian_binary_ply_with_colours_and_extra_face_properties(tmp_path):
    head = (
        "ply\nformat binary_big_endian 1.0\n"
        f"element vertex {len(_PTS)}\nproperty float x\nproperty float y\nproperty float z\n"
        "property uchar red\nproperty uchar green\nproperty uchar blue\n"
        f"element face {len(_Q)}\nproperty list uchar int vertex_indices\nproperty int flags\nend_header\n"
    )
    vert = np.zeros(len(_PTS), dtype=[("p", ">f4", 3), ("c", "u1", 3)])
    vert["p"], vert["c"] = _PTS, 200
    face = np.zeros(len(_Q), dtype=[("n", "u1"), ("v", ">i4", 4), ("f", ">i4")])
    face["n"], face["v"], face["f"] = 4, _Q, 7
    path = tmp_path / "colours.ply"
    path.write_bytes(head.encode() + vert.tobytes() + face.tobytes())
    mesh = read_mesh(str(path))
    assert mesh.n_cells == 16 and abs(_area(mesh) - _AREA) <= 1e-5 * _AREA  # (float32 points)


def test_unreadable_ply_is_said_once_without_filling(tmp_path):
    path = tmp_path / "bom.ply"
    path.write_bytes(b"\xef\xbb\xbfply\nformat ascii 1.0\nelement vertex 3\n")
    msg = check_file(str(path))["issues"][0]["message"]
    assert msg.startswith("cannot read bom.ply as PLY: ")
    assert msg.count("cannot read") == 1 and "filled" not in msg


def test_a_flat_surface_with_too_few_cells_is_not_offered_filling(tmp_path):
    path = tmp_path / "flat.obj"
    path.write_text(
        "\n".join([f"v {x} {y} {z}" for x, y, z in _PTS] + [f"f {a} {b} {c} {d}" for a, b, c, d in _Q + 1])
        + "\n"
    )
    run = subprocess.run(
        [
            sys.executable,
            "-m",
            "models.cli",
            "agglomerate",
            str(path),
            "--k",
            "20",
            "-o",
            str(tmp_path / "o.vtu"),
        ],
        capture_output=True,
        text=True,
    )
    assert run.returncode == 2
    assert "larger than the number of cells" in run.stderr and "--fill" not in run.stderr, run.stderr


def test_abaqus_elements_of_a_node_never_defined_are_named(tmp_path):
    rows = ["*NODE"] + [f"{i + 1}, {x}, {y}, {z}" for i, (x, y, z) in enumerate(_PTS) if i != 12]
    rows += ["*ELEMENT, TYPE=S4, ELSET=plate"] + [
        f"{e + 1}, {a}, {b}, {c}, {d}" for e, (a, b, c, d) in enumerate(_Q + 1)
    ]
    path = tmp_path / "cut.inp"
    path.write_text("\n".join(rows) + "\n")
    with pytest.raises(MeshError) as e:
        read_mesh(str(path))
    msg = str(e.value)
    assert "4 of its 16 elements refer to nodes that no *NODE line defines" in msg
    assert "refers to node 13" in msg and "-1" not in msg


def test_legacy_offsets_that_go_back_are_said_so(tmp_path):
    cells = "\n".join(" ".join(map(str, q)) for q in _Q)
    offsets = list(range(0, 65, 4))
    offsets[6] = 99999999
    text = (
        "# vtk DataFile Version 5.1\nplate\nASCII\nDATASET UNSTRUCTURED_GRID\n"
        f"POINTS {len(_PTS)} double\n" + "\n".join(f"{x} {y} {z}" for x, y, z in _PTS) + "\n"
        f"CELLS {len(offsets)} {len(_Q) * 4}\nOFFSETS vtktypeint64\n" + "\n".join(map(str, offsets)) + "\n"
        "CONNECTIVITY vtktypeint64\n" + cells + "\n"
        f"CELL_TYPES {len(_Q)}\n" + "\n".join(["9"] * len(_Q)) + "\n"
    )
    path = tmp_path / "back.vtk"
    path.write_text(text)
    msg = check_file(str(path))["issues"][0]["message"]
    assert "nodes, fewer than" not in msg and "-9999" not in msg, msg


def test_a_closed_big_endian_ply_is_read_for_filling(tmp_path):
    """The filling reads PLY with VTK's reader too (in a child): a cube's 6 quads, big-endian."""
    from models.mesh.fill import check_closed, read_surface

    cube = np.array([[x, y, z] for z in (0, 1) for y in (0, 1) for x in (0, 1)], dtype=float)
    quads = np.array([[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [1, 3, 7, 5], [3, 2, 6, 7], [2, 0, 4, 6]])
    head = (
        "ply\nformat binary_big_endian 1.0\nelement vertex 8\nproperty double x\nproperty double y\n"
        "property double z\nproperty uchar red\nelement face 6\nproperty list uchar int vertex_indices\n"
        "property float quality\nend_header\n"
    )
    vert = np.zeros(8, dtype=[("p", ">f8", 3), ("c", "u1")])
    vert["p"] = cube
    face = np.zeros(6, dtype=[("n", "u1"), ("v", ">i4", 4), ("q", ">f4")])
    face["n"], face["v"] = 4, quads
    path = tmp_path / "cube.ply"
    path.write_bytes(head.encode() + vert.tobytes() + face.tobytes())
    surface = read_surface(str(path))
    check_closed(surface)
    assert len(surface.points) == 8 and len(surface.triangles) == 12


@pytest.mark.parametrize("binary", [False, True])
def test_a_legacy_file_going_on_after_its_mesh_is_read_as_vtk_reads_it(tmp_path, binary):
    """A hand-written legacy file with a comment or bytes after its last section: VTK's reader reads
    the mesh and stops at the unknown word; so do we, with a warning naming the line. The same word
    before the cells is still refused."""
    pytest.importorskip("vtk")
    import vtk_corpus as vc

    p, h = vc.grid(3, 2, 2)
    good = vc.write_legacy(tmp_path / "good.vtk", vc.unstructured(p, [(12, h)]), 42, binary)
    data = open(good, "rb").read()
    path = tmp_path / "tail.vtk"
    path.write_bytes(data + b"\n#garbage \x00\x01 from a script 123\n")
    mesh, ref = read_mesh(str(path)), read_mesh(good)
    assert mesh.n_cells == len(h) and _area(mesh) == pytest.approx(_area(ref), rel=1e-12)
    said = [i for i in check_file(str(path))["issues"] if i["kind"] == "trailing-bytes"]
    assert said and said[0]["message"].startswith(
        "the file goes on after its mesh with what is no legacy VTK section ('#garbage"
    )
    at = data.index(b"CELLS")
    inside = tmp_path / "inside.vtk"
    inside.write_bytes(data[:at] + b"#garbage\n" + data[at:])
    with pytest.raises(MeshError):
        read_mesh(str(inside))


def test_a_dolfin_file_refused_for_a_file_beside_it_names_that_file(tmp_path):
    """meshio's DOLFIN XML reader reads every <stem>_*.xml beside the file as cell data: a junk one
    made the file's own refusal ("corrupted or not in this format") blame the wrong file."""
    import meshio

    tri = np.array([[a, b, c] for a, b, c, _ in _Q] + [[a, c, d] for a, _, c, d in _Q])
    path = tmp_path / "m.xml"
    meshio.write(str(path), meshio.Mesh(_PTS, [("triangle", tri)]), file_format="dolfin-xml")
    assert read_mesh(str(path)).n_cells == 32
    (tmp_path / "m_notes.xml").write_text("<notes>not a mesh function</notes>\n")
    with pytest.raises(MeshError) as e:
        read_mesh(str(path))
    assert "the file m_notes.xml beside it" in str(e.value) and "move it away" in str(e.value)
