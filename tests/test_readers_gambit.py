"""Gambit neutral files as gmsh writes them: bricks and pyramids in Gambit's node order (the base
lexicographic, (0,0) (1,0) (0,1) (1,1)), which VTK's reader keeps, so that every such cell came out
twisted ("64 degenerate (zero-volume) cells ... --weld" before). Read in VTK's order, said in one
line; the same model written by gmsh as MSH is the reference. A file in VTK's order stays as it is."""

from __future__ import annotations

import re
import subprocess
import sys

import numpy as np
import pytest

from models.mesh.read import read_mesh

gmsh = pytest.importorskip("gmsh")


def _box(tmp_path, name: str, hexes: bool) -> tuple[str, str]:
    """A unit box meshed by gmsh (transfinite hexahedra, or tetrahedra with pyramids under
    recombined faces), written as .neu and .msh."""
    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add(name)
        gmsh.model.occ.addBox(0, 0, 0, 1, 2, 3)
        gmsh.model.occ.synchronize()
        if hexes:
            for _, c in gmsh.model.getEntities(1):
                gmsh.model.mesh.setTransfiniteCurve(c, 4)
            for _, s in gmsh.model.getEntities(2):
                gmsh.model.mesh.setTransfiniteSurface(s)
                gmsh.model.mesh.setRecombine(2, s)
            gmsh.model.mesh.setTransfiniteVolume(1)
            gmsh.model.mesh.setRecombine(3, 1)
        else:
            gmsh.option.setNumber("Mesh.MeshSizeMax", 0.5)
            gmsh.model.mesh.setRecombine(2, 1)
        gmsh.model.addPhysicalGroup(3, [1], name="solid")
        gmsh.model.mesh.generate(3)
        neu, msh = str(tmp_path / f"{name}.neu"), str(tmp_path / f"{name}.msh")
        gmsh.write(neu)
        gmsh.write(msh)
    finally:
        gmsh.finalize()
    return neu, msh


@pytest.mark.parametrize(
    "hexes, kind, count_type", [(True, "bricks", "hexahedron"), (False, "pyramids", "pyramid")]
)
def test_gmsh_gambit_bricks_and_pyramids_read_in_gambits_order(tmp_path, hexes, kind, count_type):
    neu, msh = _box(tmp_path, "box", hexes)
    m, ref = read_mesh(neu), read_mesh(msh)
    assert m.n_cells == ref.n_cells
    assert np.isclose(np.abs(m.meta["measures"]).sum(), 6.0, rtol=1e-9)  # the box, 1 x 2 x 3
    np.testing.assert_allclose(  # (the .neu holds 12 digits)
        np.sort(m.meta["measures"]), np.sort(ref.meta["measures"]), rtol=1e-9
    )
    note = m.meta["reordered_cells"]["message"]
    assert f"{kind} read in Gambit's node order" in note, note
    r = subprocess.run(
        [sys.executable, "-m", "models.cli", "check", neu], capture_output=True, text=True, timeout=120
    )
    assert r.returncode == 0 and "Gambit's node order" in r.stdout, (r.stdout, r.stderr)


def test_a_gambit_file_in_vtks_order_stays_as_it_is(tmp_path):
    """A hand-rolled writer that wrote VTK's order: no bow-tie bases, nothing reordered."""
    import format_writers as fw

    p, blocks = fw.blocks()
    path = fw.write_gambit(tmp_path / "vtk_order.neu", p, blocks)
    m = read_mesh(path)
    assert "reordered_cells" not in m.meta
    assert m.n_cells == sum(len(c) for _, c in blocks)


@pytest.mark.parametrize(
    "cut, said",
    [
        (
            "truncate",
            r"the file ends in section ELEMENTS/CELLS \(from line \d+\) (after \d+ of its \d+ elements|where .* is expected): it is truncated",
        ),
        (
            "nelem",
            r"line \d+: section ELEMENTS/CELLS \(from line \d+\) holds \d+ elements, fewer than the \d+ the header declares \(NELEM\)",
        ),
    ],
)
def test_a_broken_gambit_file_is_refused_with_its_place(tmp_path, cut, said):
    """VTK's reader crashes on these (it reads NELEM records whatever follows): the crash sentence
    now says where the file goes wrong, from our scan of its sections (models.mesh.locate)."""
    import re

    import format_writers as fw

    from models.errors import MeshError
    from models.mesh.sandbox import read_mesh_safe

    p, blocks = fw.blocks()
    path = fw.write_gambit(tmp_path / "m.neu", p, blocks)
    lines = open(path).read().split("\n")
    start = next(i for i, ln in enumerate(lines) if "ELEMENTS/CELLS" in ln)
    if cut == "truncate":
        text = "\n".join(lines[: start + 6]) + "\n"
    else:
        head = next(i for i, ln in enumerate(lines) if ln.split()[:2] == ["NUMNP", "NELEM"]) + 1
        v = lines[head].split()
        v[1] = str(int(v[1]) + 40)
        lines[head] = "".join(f"{x:>10}" for x in v)
        text = "\n".join(lines)
    bad = tmp_path / "bad.neu"
    bad.write_text(text)
    with pytest.raises(MeshError) as err:
        read_mesh_safe(str(bad))
    msg = str(err.value)
    assert msg.startswith("cannot read bad.neu as Gambit neutral: ") and re.search(said, msg), msg


def test_gmsh_gambit_file_with_boundary_conditions_reads(tmp_path):
    """gmsh writes one ENDOFSECTION too many before the BOUNDARY CONDITIONS sections of a model with
    surface groups; VTK's reader then frees memory twice and dies (refused as 'the reader crashed';
    mutation sweep Z). Read from a copy without the extra line: the same cells and volume as the MSH."""
    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("bc")
        gmsh.model.occ.addBox(0, 0, 0, 1, 2, 3)
        gmsh.model.occ.synchronize()
        gmsh.model.addPhysicalGroup(3, [1], name="solid")
        gmsh.model.addPhysicalGroup(2, [1, 2], name="walls")
        gmsh.option.setNumber("Mesh.MeshSizeMax", 0.5)
        gmsh.model.mesh.generate(3)
        neu, msh = str(tmp_path / "bc.neu"), str(tmp_path / "bc.msh")
        gmsh.write(neu)
        gmsh.write(msh)
    finally:
        gmsh.finalize()
    from models.mesh.sandbox import read_mesh_safe

    text = open(neu).read()
    assert "ENDOFSECTION\nENDOFSECTION" in text.replace(" ", "")  # (gmsh's quirk, else this tests nothing)
    m, ref = read_mesh_safe(neu), read_mesh(msh)
    assert m.n_cells == ref.n_cells
    assert float(m.meta["measures"].sum()) == pytest.approx(6.0, rel=1e-9)


def _two_materials(tmp_path, dim: int, surfaces: bool) -> tuple[str, str]:
    """Two blocks side by side (steel, copper: 3D boxes or 2D rectangles), each a physical group,
    and (surfaces) a boundary group on the outer faces: as .neu and .msh."""
    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add(f"two{dim}")
        occ = gmsh.model.occ
        if dim == 3:
            a, b = occ.addBox(0, 0, 0, 1, 1, 1), occ.addBox(1, 0, 0, 2, 1, 1)
        else:
            a, b = occ.addRectangle(0, 0, 0, 1, 1), occ.addRectangle(1, 0, 0, 2, 1)
        occ.fragment([(dim, a)], [(dim, b)])
        occ.synchronize()
        gmsh.model.addPhysicalGroup(dim, [a], 7, name="steel")
        gmsh.model.addPhysicalGroup(dim, [b], 9, name="copper")
        if surfaces:
            outer = [t for _, t in gmsh.model.getBoundary([(dim, a), (dim, b)], oriented=False)]
            gmsh.model.addPhysicalGroup(dim - 1, outer, 11, name="walls")
        gmsh.option.setNumber("Mesh.MeshSizeMax", 0.3)
        gmsh.model.mesh.generate(dim)
        neu, msh = str(tmp_path / f"two{dim}.neu"), str(tmp_path / f"two{dim}.msh")
        gmsh.write(neu)
        gmsh.write(msh)
    finally:
        gmsh.finalize()
    return neu, msh


@pytest.mark.parametrize("dim, surfaces", [(3, True), (3, False)])  # (gmsh writes no 2D .neu)
def test_gambit_element_groups_are_the_physical_groups(tmp_path, dim, surfaces):
    """A Gambit file's ELEMENT GROUPs (one per gmsh physical group, named) come in as the mesh's
    physical groups, with their names and numbers: the same cells and measure per group as gmsh's
    own MSH of the model (VTK's reader kept only each group's MATERIAL, 0 in all of them). With
    boundary groups gmsh repeats ENDOFSECTION several times, on which VTK's reader died."""
    from models.mesh.sandbox import read_mesh_safe

    neu, msh = _two_materials(tmp_path, dim, surfaces)
    if surfaces and dim == 3:
        assert re.search(r"ENDOFSECTION\s+ENDOFSECTION\s+ENDOFSECTION", open(neu).read())
    m, ref = read_mesh_safe(neu), read_mesh(msh)
    assert m.n_cells == ref.n_cells and m.tags is not None
    assert {int(k): v for k, v in m.meta["group_names"].items()} == {7: "steel", 9: "copper"}
    for gid in (7, 9):
        ours, theirs = m.tags == gid, ref.tags == gid
        assert ours.sum() == theirs.sum() > 0
        assert float(m.meta["measures"][ours].sum()) == pytest.approx(
            float(ref.meta["measures"][theirs].sum()), rel=1e-9
        )
    assert float(m.meta["measures"][m.tags == 7].sum()) == pytest.approx(1.0, rel=1e-9)


def test_gambit_groups_that_do_not_fit_are_said_not_guessed(tmp_path):
    """An element group listing an element past the file's elements: the mesh is read without groups
    and a note says why (no cell put in a group it may not belong to)."""
    from models.mesh.sandbox import read_mesh_safe

    neu, _ = _two_materials(tmp_path, 3, False)
    text = open(neu).read()
    head = re.search(r"GROUP:\s+(\d+) ELEMENTS:\s+(\d+)", text)
    n_elem = int(re.search(r"NUMNP\s+NELEM.*\n\s*\d+\s+(\d+)", text).group(1))
    body = re.search(r"(GROUP:[^\n]*\n[^\n]*\n[^\n]*\n)(\s*)(\d+)", text)
    bad = text[: body.start(3)] + str(n_elem + 5) + text[body.end(3) :]
    path = tmp_path / "bad_group.neu"
    path.write_text(bad)
    m = read_mesh_safe(str(path))
    assert head and m.tags is None
    assert f"lists element {n_elem + 5:,}" in m.meta["gambit_groups"]["message"]


NEU_2D = """        CONTROL INFO 2.0.0
** GAMBIT NEUTRAL FILE
two quads and two triangles
PROGRAM:                Gambit     VERSION:  2.4.6
Sun Dec  6 12:00:00 2026
     NUMNP     NELEM     NGRPS    NBSETS     NDFCD     NDFVL
         7         4         2         0         2         2
ENDOFSECTION
   NODAL COORDINATES 2.4.6
         1   0.0   0.0
         2   1.0   0.0
         3   2.0   0.0
         4   0.0   1.0
         5   1.0   1.0
         6   2.0   1.0
         7   3.0   0.0
ENDOFSECTION
      ELEMENTS/CELLS 2.4.6
       1  2  4        1       2       5       4
       2  2  4        2       3       6       5
       3  3  3        3       7       6
       4  3  3        2       6       5
ENDOFSECTION
       ELEMENT GROUP 2.4.6
GROUP:          1 ELEMENTS:          2 MATERIAL:          2 NFLAGS:          1
                           fluid
       0
       1       2
ENDOFSECTION
       ELEMENT GROUP 2.4.6
GROUP:          2 ELEMENTS:          1 MATERIAL:          4 NFLAGS:          1
                           solid
       0
       3
ENDOFSECTION
"""


def test_a_planar_gambit_file_has_its_groups(tmp_path):
    """A 2D Gambit file (NDFCD 2; gmsh writes none, so written here as Gambit does): its element
    groups are 2D physical groups; an element listed in two groups stays in the smaller, an element
    in none is group 0, both said in a note."""
    from models.mesh.sandbox import read_mesh_safe

    path = tmp_path / "plane.neu"
    path.write_text(
        NEU_2D.replace("       1       2\nENDOFSECTION", "       1       2       4\nENDOFSECTION")
        .replace("ELEMENTS:          2 MATERIAL:          2", "ELEMENTS:          3 MATERIAL:          2")
        .replace("       3\nENDOFSECTION", "       3       4\nENDOFSECTION")
        .replace("ELEMENTS:          1 MATERIAL:          4", "ELEMENTS:          2 MATERIAL:          4")
    )
    m = read_mesh_safe(str(path))
    assert m.dim == 2 and m.n_cells == 4
    assert {int(k): v for k, v in m.meta["group_names"].items()} == {1: "fluid", 2: "solid"}
    assert m.tags.tolist() == [1, 1, 2, 2]  # element 4 in both: kept in the smaller group (2 of 2 < 3)
    assert "1 element listed in two element groups: it is kept" in m.meta["gambit_groups"]["message"]
    loose = NEU_2D.replace("       3\nENDOFSECTION", "       3\nENDOFSECTION", 1)
    path.write_text(loose)
    m = read_mesh_safe(str(path))
    assert (
        m.tags.tolist() == [1, 1, 2, 0]
        and "1 element in no element group" in m.meta["gambit_groups"]["message"]
    )


def _bc_model(tmp_path, kind: str) -> tuple[str, str]:
    """A solid of tetrahedra, bricks, wedges (an extruded rectangle) or tetrahedra with pyramids,
    its outer faces in two boundary groups (walls, rest): as .neu and .msh."""
    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add(kind)
        occ = gmsh.model.occ
        if kind == "wedges":
            rect = occ.addRectangle(0, 0, 0, 1, 2)
            occ.synchronize()
            gmsh.option.setNumber("Mesh.MeshSizeMax", 0.5)
            vol = [t for d, t in occ.extrude([(2, rect)], 0, 0, 1, numElements=[2]) if d == 3]
            occ.synchronize()
        else:
            vol = [occ.addBox(0, 0, 0, 1, 2, 3)]
            occ.synchronize()
            gmsh.option.setNumber("Mesh.MeshSizeMax", 0.6)
            if kind == "bricks":
                for _, c in gmsh.model.getEntities(1):
                    gmsh.model.mesh.setTransfiniteCurve(c, 3)
                for _, s in gmsh.model.getEntities(2):
                    gmsh.model.mesh.setTransfiniteSurface(s)
                    gmsh.model.mesh.setRecombine(2, s)
                gmsh.model.mesh.setTransfiniteVolume(vol[0])
                gmsh.model.mesh.setRecombine(3, vol[0])
            elif kind == "pyramids":
                gmsh.model.mesh.setRecombine(2, 1)
        gmsh.model.addPhysicalGroup(3, vol, 1, name="solid")
        outer = [t for _, t in gmsh.model.getBoundary([(3, v) for v in vol], oriented=False)]
        gmsh.model.addPhysicalGroup(2, outer[:3], 2, name="walls")
        gmsh.model.addPhysicalGroup(2, outer[3:], 3, name="rest")
        gmsh.model.mesh.generate(3)
        neu, msh = str(tmp_path / f"{kind}.neu"), str(tmp_path / f"{kind}.msh")
        gmsh.write(neu)
        gmsh.write(msh)
    finally:
        gmsh.finalize()
    return neu, msh


def _face_centres(m, name: str) -> list:
    tag = next(k for k, v in m.meta["boundary_names"].items() if v == name)
    o, c = m.boundary_offsets, m.boundary_connectivity
    sel = np.flatnonzero(m.boundary_tags == tag)
    return sorted(tuple(np.round(m.points[c[o[i] : o[i + 1]]].mean(axis=0), 9)) for i in sel.tolist())


@pytest.mark.parametrize("kind", ["tetrahedra", "bricks", "wedges", "pyramids"])
def test_gambit_boundary_conditions_are_boundary_groups(tmp_path, kind):
    """A Gambit file's BOUNDARY CONDITIONS (element, type, face number by Gambit's face definitions)
    come in as named boundary groups: exactly the faces of gmsh's own MSH of the model, group by
    group, for every element type's face table (VTK's reader ignores them)."""
    from models.mesh.sandbox import read_mesh_safe

    neu, msh = _bc_model(tmp_path, kind)
    m, ref = read_mesh_safe(neu), read_mesh(msh)
    assert m.n_cells == ref.n_cells
    assert sorted(m.meta["boundary_names"].values()) == ["rest", "walls"]
    for name in ("walls", "rest"):
        ours = _face_centres(m, name)
        assert ours and ours == _face_centres(ref, name)


def test_a_gambit_boundary_condition_that_does_not_fit_is_said_not_used(tmp_path):
    """A face number past its element's faces: that condition is left out and said; the others and
    the element groups stay."""
    from models.mesh.sandbox import read_mesh_safe

    neu, _ = _bc_model(tmp_path, "tetrahedra")
    text = open(neu).read()
    at = text.index("walls")
    first = re.compile(r"(\n\s+\d+\s+6\s+)(\d)").search(text, at)
    path = tmp_path / "bad_face.neu"
    path.write_text(text[: first.start(2)] + "9" + text[first.end(2) :])
    m = read_mesh_safe(str(path))
    assert sorted(m.meta["boundary_names"].values()) == ["rest"]
    assert (
        "boundary condition 'walls' names faces that are not faces of their elements"
        in (m.meta["gambit_groups"]["message"])
    )
    assert m.meta["group_names"] == {1: "solid"}


def _bc_rows(m, values: bytes) -> bytes:
    """A boundary condition's section with NVALUES set to the number of `values` after each face."""
    name, itype, count, _, code = m.group(2).split()
    rows = [r for r in m.group(3).split(b"\n") if r.strip()]
    n = len(values.split())
    return (
        m.group(1)
        + b"%32s%8s%8s%8d%8s\n" % (name, itype, count, n, code)
        + b"".join(r + values + b"\n" for r in rows)
    )


_BC_SECTION = rb"(BOUNDARY CONDITIONS[^\n]*\n)([^\n]*)\n(.*?)(?=ENDOFSECTION)"
_BC_HEAD = rb"(BOUNDARY CONDITIONS[^\n]*\n)([^\n]*)\n"


def _head(fmt):
    return lambda m: m.group(1) + fmt(*m.group(2).split()) + b"\n"


def _shift_ids(data: bytes, by: int) -> bytes:
    """Element ids from 1 + by, in the elements, the groups and the boundary conditions alike."""
    e = re.search(rb"ELEMENTS/CELLS[^\n]*\n(.*?)ENDOFSECTION", data, re.S)
    body = re.sub(
        rb"(?m)^( *)(\d+)( +\d+ +\d+ +\d+)",
        lambda m: m.group(1) + b"%d" % (int(m.group(2)) + by) + m.group(3),
        e.group(1),
    )
    data = data[: e.start(1)] + body + data[e.end(1) :]
    data = re.sub(
        rb"(NFLAGS:[^\n]*\n[^\n]*\n\s+0\n)(.*?)(?=ENDOFSECTION)",
        lambda m: m.group(1) + re.sub(rb"\d+", lambda x: b"%d" % (int(x.group(0)) + by), m.group(2)),
        data,
        flags=re.S,
    )
    return re.sub(
        rb"(BOUNDARY CONDITIONS[^\n]*\n[^\n]*\n)(.*?)(?=ENDOFSECTION)",
        lambda m: (
            m.group(1)
            + re.sub(rb"(?m)^(\s*)(\d+)", lambda x: x.group(1) + b"%d" % (int(x.group(2)) + by), m.group(2))
        ),
        data,
        flags=re.S,
    )


EDITS = {  # what other writers (and Windows) make of gmsh's file; VTK's reader died on most
    "crlf": lambda d: d.replace(b"\n", b"\r\n"),
    "tabs": lambda d: re.sub(rb"(?m)^ +", b"\t", re.sub(rb"(?<=\S) {2,}(?=\S)", b"\t", d)),
    "values after each face": lambda d: re.sub(
        _BC_SECTION, lambda m: _bc_rows(m, b"  1.5e+00  -2"), d, flags=re.S
    ),
    "two IBCODEs": lambda d: re.sub(
        _BC_HEAD, _head(lambda n, i, c, v, k: b"%32s%8s%8s%8s%8s%8s" % (n, i, c, v, k, b"3")), d
    ),
    "no IBCODE": lambda d: re.sub(_BC_HEAD, _head(lambda n, i, c, v, k: b"%32s%8s%8s%8s" % (n, i, c, v)), d),
    "Gambit's header layout": lambda d: re.sub(
        _BC_HEAD, _head(lambda n, i, c, v, k: b"%-32s%10s%10s%10s%10s" % (n, i, c, v, b"6")), d
    ),
    "ids from 1001": lambda d: _shift_ids(d, 1000),
    "a group miscounted": lambda d: re.sub(
        rb"ELEMENTS:\s+(\d+)", lambda m: b"ELEMENTS: %10d" % (int(m.group(1)) + 1), d, count=1
    ),
}


@pytest.mark.parametrize("edit", list(EDITS))
def test_gambit_files_as_other_writers_write_them(tmp_path, edit):
    """gmsh's Gambit file of two materials, a boundary condition on the outer faces and one on the
    interface, edited as other writers and editors leave such files: CRLF line ends, tabs, values
    after each face (NVALUES), headers with two IBCODEs or none or in Gambit's own column layout,
    element ids not from 1, a group's count off by one. Each reads as gmsh's MSH of the model: the
    same cells, groups and boundary faces (the interface's faces once each, though gmsh lists them
    for both sides). VTK's reader crashed on most of them."""
    from models.mesh.sandbox import read_mesh_safe

    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("edits")
        a, b = gmsh.model.occ.addBox(0, 0, 0, 1, 1, 1), gmsh.model.occ.addBox(1, 0, 0, 1, 1, 1)
        gmsh.model.occ.fragment([(3, a)], [(3, b)])
        gmsh.model.occ.synchronize()
        gmsh.model.addPhysicalGroup(3, [a], 1, name="left")
        gmsh.model.addPhysicalGroup(3, [b], 2, name="right")
        faces_a = {t for _, t in gmsh.model.getBoundary([(3, a)], oriented=False)}
        faces_b = {t for _, t in gmsh.model.getBoundary([(3, b)], oriented=False)}
        gmsh.model.addPhysicalGroup(2, sorted(faces_a ^ faces_b), 11, name="outer")
        gmsh.model.addPhysicalGroup(2, sorted(faces_a & faces_b), 12, name="interface")
        gmsh.option.setNumber("Mesh.MeshSizeMax", 0.4)
        gmsh.model.mesh.generate(3)
        neu, msh = str(tmp_path / "m.neu"), str(tmp_path / "m.msh")
        gmsh.write(neu)
        gmsh.write(msh)
    finally:
        gmsh.finalize()
    data = open(neu, "rb").read()
    edited = EDITS[edit](data)
    assert edited != data
    path = tmp_path / "edited.neu"
    path.write_bytes(edited)
    m, ref = read_mesh_safe(str(path)), read_mesh(msh)
    assert m.n_cells == ref.n_cells
    assert {int(k): v for k, v in m.meta["group_names"].items()} == {1: "left", 2: "right"}
    for gid in (1, 2):
        assert np.count_nonzero(m.tags == gid) == np.count_nonzero(ref.tags == gid)
    assert sorted(m.meta["boundary_names"].values()) == ["interface", "outer"]
    for name in ("outer", "interface"):
        assert _face_centres(m, name) == _face_centres(ref, name)
    if edit == "a group miscounted":
        assert "where its header says" in m.meta["gambit_groups"]["message"]
