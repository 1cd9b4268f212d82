"""Fluent meshes section by section (models.mesh.fluent_sections, checked before VTK's reader opens
the file): binary sections (3010 nodes, 2013 faces), as Fluent writes them by default, read as VTK
reads them and, broken, refused with the section, the ids its header gives and the byte where it
goes wrong; ASCII sections with a character that is no number among their numbers refused with the
line (VTK's reader ran until the read's time limit on a '(' there, and read wrong coordinates, 105
to 1,559 for a volume of 128.4, on a '/' or '=' in a node's coordinates). Before, a binary section cut short, with a
face's node id out of range or a header byte flipped gave "its text cannot be parsed", "the file ends
before its data does (truncated?); the file ends inside a section", or "the Fluent case reader
crashed on this file: it is corrupted or not Fluent case" (a 200-mutant sweep: 43, 28 and 1 of them).
"""

from __future__ import annotations

import numpy as np
import pytest

vtk = pytest.importorskip("vtk")
import format_writers as fw  # noqa: E402

from models.errors import MeshError  # noqa: E402
from models.mesh.read import read_mesh  # noqa: E402
from models.mesh.sandbox import read_mesh_safe  # noqa: E402


@pytest.fixture
def binary(tmp_path):
    p, h = fw.grid(4, 3, 2)
    return fw.write_fluent(tmp_path / "bin.msh", p, h, binary=True), p, h


def _refusal(tmp_path, data: bytes, timeout_s: float = 20.0) -> str:
    bad = tmp_path / "bad.msh"
    bad.write_bytes(data)
    with pytest.raises(MeshError) as err:
        read_mesh_safe(str(bad), timeout_s=timeout_s)
    msg = str(err.value)
    assert msg.startswith("cannot read bad.msh as Fluent case: "), msg
    assert "corrupted or not" not in msg and "cannot be parsed" not in msg, msg
    return msg


def test_a_binary_fluent_mesh_reads_as_its_ascii_twin(tmp_path, binary):
    path, p, h = binary
    ascii_mesh = read_mesh(fw.write_fluent(tmp_path / "ascii.msh", p, h))
    mesh = read_mesh(path)
    assert mesh.n_cells == ascii_mesh.n_cells == len(h)
    assert float(mesh.meta["measures"].sum()) == pytest.approx(
        float(ascii_mesh.meta["measures"].sum()), rel=1e-12
    )
    r = vtk.vtkFLUENTReader()
    r.SetFileName(path)
    r.Update()
    assert r.GetOutput().GetBlock(0).GetNumberOfCells() == len(h)  # (VTK's own reading)


@pytest.mark.parametrize("section, cut", [("3010", 0.5), ("2013", 0.3)])
def test_a_binary_section_cut_short_is_named(tmp_path, binary, section, cut):
    path, p, _ = binary
    data = open(path, "rb").read()
    start = data.index(b"(" + section.encode())
    body = data.index(b")(", start) + 2
    end = data.index(b")\nEnd of Binary Section", body)
    msg = _refusal(tmp_path, data[: body + int((end - body) * cut)])
    kind = "nodes" if section == "3010" else "faces"
    assert f"the file ends inside section {section} ({kind} 1 to " in msg and msg.endswith(
        f", from byte {start:,}): its binary data needs {end - body:,} bytes from byte {body:,}, the file holds "
        f"{int((end - body) * cut):,} of them: it is truncated"
    ), msg


def test_a_face_with_a_node_id_past_the_nodes_is_named(tmp_path, binary):
    """VTK's reader indexes its node array with the id: it crashes or fails 'parsing'."""
    path, p, _ = binary
    data = bytearray(open(path, "rb").read())
    start = data.index(b"(2013")
    body = data.index(b")(", start) + 2
    face = 7  # (0-based) its second node
    at = body + 4 * (6 * face + 1)
    data[at : at + 4] = np.int32(len(p) + 100).tobytes()
    msg = _refusal(tmp_path, bytes(data))
    assert msg.endswith(
        f"section 2013 (faces 1 to {msg.split('faces 1 to ')[1].split(',')[0]}, from byte {start:,}): "
        f"face {face + 1} of the section (at byte {body + 4 * 6 * face:,}) refers to node {len(p) + 100:,}; "
        f"the nodes are 1 to {len(p):,}"
    ), msg


def test_a_binary_body_shorter_than_its_header_says_is_named(tmp_path, binary):
    path, p, _ = binary
    data = open(path, "rb").read()
    start = data.index(b"(3010")
    end = data.index(b")\nEnd of Binary Section   3010)")
    msg = _refusal(tmp_path, data[: end - 16] + data[end:])
    assert msg.endswith(
        f"section 3010 (nodes 1 to {len(p):,}, from byte {start:,}): its binary data ({len(p) * 24:,} bytes for "
        f"the {len(p):,} nodes its header declares) should be followed by ')End of Binary Section 3010)' at "
        f"byte {end:,}, not at byte {end - 16:,} where it is"
    ), msg


def test_a_damaged_ascii_header_between_binary_sections_is_named(tmp_path, binary):
    """'(12 (2 1 18 1 4))' with one byte flipped to '(': VTK's reader ran until the read's time
    limit (10 minutes by default)."""
    path, _, h = binary
    data = open(path, "rb").read()
    head = f"(12 (2 1 {len(h):x} 1 4))".encode()
    start = data.index(head)
    broken = head.replace(f" {len(h):x} ".encode(), f" {len(h):x}"[:-1].encode() + b"( ")
    msg = _refusal(tmp_path, data.replace(head, broken), timeout_s=4.0)
    assert f"section 12 (from byte {start:,}): its header " in msg and msg.endswith(
        "is not '(zone first last type ...)' in hexadecimal numbers"
    ), msg


@pytest.fixture
def ascii_file(tmp_path):
    p, h = fw.grid(4, 3, 2)
    return fw.write_fluent(tmp_path / "ascii.msh", p, h), p, h


@pytest.mark.parametrize("section, old, new, char", [("13", b" ", b"(", "'('"), ("10", b".", b"/", "'/'")])
def test_a_character_that_is_no_number_in_an_ascii_section_is_named_with_its_line(
    tmp_path, ascii_file, section, old, new, char
):
    path, _, _ = ascii_file
    data = open(path, "rb").read()
    start = data.index(b"\n(" + section.encode() + b" (1 " if section == "10" else b"\n(13 (3 ") + 1
    at = data.index(old, data.index(b")(", start) + 40)
    msg = _refusal(tmp_path, data[:at] + new + data[at + 1 :], timeout_s=60.0)
    line, first = data.count(b"\n", 0, at) + 1, data.count(b"\n", 0, start) + 1
    kind = "a real number" if section == "10" else "a hexadecimal number"
    assert msg.startswith(
        f"cannot read bad.msh as Fluent case: line {line:,} (section {section}, "
    ) and msg.endswith(f"from line {first:,}): {char} at byte {at:,} where {kind} is expected"), msg


@pytest.mark.parametrize("face", [0, 5, 20, 40])
def test_a_node_id_past_the_nodes_is_a_warning_where_vtk_reads_and_the_place_where_it_does_not(
    tmp_path, binary, face
):
    """VTK's reader builds a hexahedron from two of its six faces: a wrong node id in another face
    leaves the cell right (42 of 76 such mutants read as the original). Such a file is read, with a
    warning naming the face (check: fluent-faces); where VTK fails or crashes, the refusal names it."""
    path, p, h = binary
    data = bytearray(open(path, "rb").read())
    start = data.rindex(b"(2013")  # the boundary faces
    body = data.index(b")(", start) + 2
    at = body + 4 * (6 * face + 2)
    data[at : at + 4] = np.int32(len(p) + 7).tobytes()
    bad = tmp_path / "bad.msh"
    bad.write_bytes(bytes(data))
    said = f"face {face + 1} of the section (at byte {body + 24 * face:,}) refers to node {len(p) + 7:,}"
    try:
        mesh = read_mesh_safe(str(bad), timeout_s=20)
    except MeshError as err:
        assert said in str(err), str(err)
        return
    assert said in mesh.meta["fluent_faces"]["message"], mesh.meta
    from models.mesh.check import mesh_report

    issues = {i["kind"]: i for i in mesh_report(mesh)["issues"]}
    assert issues["fluent-faces"]["severity"] == "warning" and said in issues["fluent-faces"]["message"], (
        issues
    )


def test_a_face_between_cells_that_do_not_exist_is_refused(tmp_path, binary):
    """A c0 or c1 past the cells: VTK's reader crashed, ran on or refused on 37 of 44 mutants."""
    path, _, h = binary
    data = bytearray(open(path, "rb").read())
    start = data.index(b"(2013")
    body = data.index(b")(", start) + 2
    at = body + 4 * (6 * 3 + 5)  # the fourth face's c1
    data[at : at + 4] = np.int32(len(h) + 50).tobytes()
    msg = _refusal(tmp_path, bytes(data))
    assert msg.endswith(
        f"face 4 of the section (at byte {body + 72:,}) lies between cells {int.from_bytes(data[at - 4 : at], 'little'):,} "
        f"and {len(h) + 50:,}; the cells are 1 to {len(h):,} (0: none, on the boundary)"
    ), msg
