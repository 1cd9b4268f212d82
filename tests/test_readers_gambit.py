"""Gambit neutral files as gmsh writes them: bricks and pyramids in Gambit's node order (the base
lexicographic, (0,0) (1,0) (0,1) (1,1)), which VTK's reader keeps, so that every such cell came out
twisted ("64 degenerate (zero-volume) cells ... --weld" before). Read in VTK's order, said in one
line; the same model written by gmsh as MSH is the reference. A file in VTK's order stays as it is."""

from __future__ import annotations

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
