"""OpenFOAM cases (constant/polyMesh), read by VTK's vtkOpenFOAMReader as ParaView opens them:
given as the case's .foam file, its system/controlDict or its folder; over HTTP in an archive.
Cases written at test time (tests/openfoam_case.py): hexahedra, and polyhedra (pairs of
hexahedra merged: ten faces each); checked against VTK's own reading (cells, volume), patches as
named boundary groups, agglomerated and read back."""

from __future__ import annotations

import os
import re
import shutil

import meshio
import numpy as np
import openfoam_case as oc
import pytest
import vtk
import vtk_corpus as vc

from models.errors import MeshError
from models.mesh.read import read_mesh
from models.mesh.sandbox import read_mesh_cli, read_mesh_safe


def inlet_or_walls(centre) -> str:
    return "inlet" if centre[0] < 0.1 * centre[1] + 1e-9 else "walls"  # (the grid is sheared in x)


def reference(foam: str, tmp_path) -> tuple[int, float]:
    """VTK's reading of the case's internal mesh: its cells and volume (vtk_corpus.vtk_reference
    on it, written as a VTU by VTK)."""
    w = vtk.vtkXMLUnstructuredGridWriter()
    w.SetFileName(str(tmp_path / "vtk_internal.vtu"))
    w.SetInputData(oc.vtk_internal(foam))
    assert w.Write() == 1
    return vc.vtk_reference(str(tmp_path / "vtk_internal.vtu"))


@pytest.mark.parametrize("cells", ["hexahedra", "polyhedra"])
def test_openfoam_case_reads_as_vtk_reads_it(tmp_path, cells):
    p, h = oc.hex_grid(6, 4, 3)
    faces = oc.hex_cells(h) if cells == "hexahedra" else oc.merged_pairs(h, 6)
    case = tmp_path / "case"
    foam = oc.write_case(str(case), p, faces, inlet_or_walls)
    n_ref, vol_ref = reference(foam, tmp_path)
    assert n_ref == len(faces)
    for given in (foam, str(case), str(case / "system" / "controlDict")):
        mesh = read_mesh(given)
        assert mesh.n_cells == n_ref
        assert float(mesh.meta["measures"].sum()) == pytest.approx(vol_ref, rel=1e-9)
        assert (mesh.poly_cells is not None) == (cells == "polyhedra")
        names = mesh.meta["boundary_names"]
        assert sorted(names.values()) == ["inlet", "walls"]
        inlet = next(t for t, n in names.items() if n == "inlet")
        assert int(np.count_nonzero(mesh.boundary_tags == inlet)) == 4 * 3  # the x = 0 side's faces
        assert mesh.tags is None  # (patches are boundary groups, the internal mesh no group)
    assert read_mesh_cli(str(case)).n_cells == n_ref  # the CLI's way: VTK's reader in the sandbox
    res, n_out, vol_out = vc.agglomerate_read_back(foam, 5, tmp_path / "out.vtu")
    assert n_out == 5 and vol_out == pytest.approx(vol_ref, rel=1e-6)  # (VTK's reader: float32 points)


def test_openfoam_refusals_are_one_sentence(tmp_path):
    empty = tmp_path / "nocase"
    empty.mkdir()
    with pytest.raises(MeshError, match="is a folder, not a mesh file"):
        read_mesh_safe(str(empty))
    (empty / "lonely.foam").write_text("")
    with pytest.raises(MeshError) as err:
        read_mesh(str(empty / "lonely.foam"))
    msg = str(err.value)
    assert "lonely.foam" in msg and "OpenFOAM case" in msg and "constant/polyMesh" in msg and "\n" not in msg


@pytest.mark.parametrize("with_foam", [True, False])
def test_openfoam_case_in_an_archive(tmp_path, with_foam):
    """An uploaded case: a .zip of its folder, with or without a .foam file (then its
    system/controlDict opens it), beside a surface the case was meshed from
    (constant/triSurface/part.stl, as snappyHexMesh cases hold)."""
    p, h = oc.hex_grid(4, 2, 2)
    case = tmp_path / "case"
    oc.write_case(str(case), p, oc.hex_cells(h))
    if not with_foam:
        os.remove(case / "case.foam")
    (case / "constant" / "triSurface").mkdir()
    corners = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=float)
    tris = np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]])
    meshio.write(case / "constant" / "triSurface" / "part.stl", meshio.Mesh(corners, [("triangle", tris)]))
    archive = shutil.make_archive(str(tmp_path / "upload"), "zip", root_dir=tmp_path, base_dir="case")
    assert read_mesh_safe(archive).n_cells == len(h)


def test_openfoam_mutants_are_a_mesh_or_one_clear_sentence(tmp_path):
    """The mutation test (tests/mutants.py: flips, truncation, swapped or duplicated lines, bad
    numbers, zeroed blocks) over each polyMesh file of a case, read in the sandbox as the service
    reads: a Mesh, or one sentence that names the case's file and the format, with no library text
    (test_read_fuzz's rules). VTK's reader may crash or hang on some: a sentence too."""
    import re

    from mutants import mutants
    from test_read_fuzz import RAW_RE

    from models.errors import ParameterError
    from models.mesh.container import Mesh

    p, h = oc.hex_grid(3, 2, 2)
    good = tmp_path / "good"
    oc.write_case(str(good), p, oc.hex_cells(h), inlet_or_walls)
    outcomes = {"mesh": 0, "refused": 0}
    for k, part in enumerate(("points", "faces", "owner", "neighbour", "boundary")):
        data = (good / "constant" / "polyMesh" / part).read_bytes()
        for i, (how, bad) in enumerate(mutants(data, seed=2000 + k, n=8)):
            case = tmp_path / f"m{k}_{i}"
            shutil.copytree(good, case)
            (case / "constant" / "polyMesh" / part).write_bytes(bad)
            try:
                mesh = read_mesh_safe(str(case / "case.foam"), timeout_s=20, memory_bytes=2 << 30)
            except (MeshError, ParameterError) as exc:
                msg = str(exc)
                outcomes["refused"] += 1
                assert "case.foam" in msg and "OpenFOAM case" in msg, (part, how, msg)
                assert not RAW_RE.search(msg) and "\n" not in msg, (part, how, msg)
                assert not re.search(r"\bvtk[A-Z]|Foam::|\bfound\b|Expected", msg), (part, how, msg)
            else:
                assert isinstance(mesh, Mesh) and mesh.n_cells > 0
                outcomes["mesh"] += 1
            shutil.rmtree(case)
    assert outcomes["refused"] >= 10, outcomes


def decomposed_case(root, nx=6, ny=4, nz=3) -> int:
    """A case as decomposePar leaves it: processor0/ and processor1/ (the grid cut at x = 0.5),
    each its own points and cells, the same patch list on both (inlet, walls: empty where a
    processor has none) with the processor patch last; system/controlDict at the root, no
    constant/polyMesh there. Returns the number of cells."""
    p, h = oc.hex_grid(nx, ny, nz)
    cells = oc.hex_cells(h)
    centre = p[h].mean(axis=1)
    x = centre[:, 0] - 0.1 * centre[:, 1]  # (the grid is sheared)
    for proc, sel in enumerate([x < 0.5, x >= 0.5]):
        ids = np.flatnonzero(sel)
        used = np.unique(h[ids])
        new = np.full(len(p), -1)
        new[used] = np.arange(used.size)
        local = [[[int(new[n]) for n in f] for f in cells[c]] for c in ids]
        cut = f"procBoundary{proc}to{1 - proc}"

        def patch(c, cut=cut):
            x = c[0] - 0.1 * c[1]
            return cut if abs(x - 0.5) < 1e-9 else inlet_or_walls(c)

        entry = f"type processor;\n        myProcNo {proc};\n        neighbProcNo {1 - proc};"
        oc.write_case(
            str(root / f"processor{proc}"),
            p[used],
            local,
            patch,
            order=("inlet", "walls", cut),
            types={cut: entry},
        )
        shutil.rmtree(root / f"processor{proc}" / "system")
        os.remove(root / f"processor{proc}" / "case.foam")
    (root / "system").mkdir()
    (root / "system" / "controlDict").write_text(
        oc.HEADER.format(cls="dictionary", loc="system", obj="controlDict")
        + "startTime 0;\nendTime 1;\ndeltaT 1;\n"
    )
    return len(h)


def test_decomposed_openfoam_case_is_one_mesh(tmp_path):
    """A decomposed case (processor*/ only: VTK's vtkPOpenFOAMReader) reads as the whole mesh: the
    processors' cut points merged (one piece), the processor patches no boundary group, the same
    cells, points and volume as the case before decomposition; given as its folder, as a .foam file
    and as a .zip of the folder (its controlDict opens it)."""
    case = tmp_path / "case"
    n = decomposed_case(case)
    p, h = oc.hex_grid(6, 4, 3)
    whole = read_mesh(oc.write_case(str(tmp_path / "whole"), p, oc.hex_cells(h), inlet_or_walls))
    (case / "case.foam").write_text("")
    for given in (str(case), str(case / "case.foam")):
        mesh = read_mesh(given)
        assert (mesh.n_cells, mesh.n_points) == (n, whole.n_points)
        assert float(mesh.meta["measures"].sum()) == pytest.approx(
            float(whole.meta["measures"].sum()), rel=1e-12
        )
        assert sorted(mesh.meta["boundary_names"].values()) == ["inlet", "walls"]
        assert mesh.boundary_types.size == whole.boundary_types.size  # (no face of the cut)
    from models.mesh.check import check_file

    assert check_file(str(case))["components"] == 1
    os.remove(case / "case.foam")
    archive = shutil.make_archive(str(tmp_path / "decomposed"), "zip", root_dir=tmp_path, base_dir="case")
    assert read_mesh_safe(archive).n_cells == n


@pytest.mark.parametrize("cells", ["hexahedra", "polyhedra", "decomposed"])
def test_cell_zones_are_the_groups(tmp_path, cells):
    """constant/polyMesh/cellZones (a CFD case's regions: porous, MRF, solid) are the physical
    groups, named as the zones: a cell in two zones goes to the first; a cell in none to no group.
    In a decomposed case each processor's zones list its own cells."""
    p, h = oc.hex_grid(6, 4, 3)
    centre = p[h].mean(axis=1)
    x = centre[:, 0] - 0.1 * centre[:, 1]
    faces = oc.hex_cells(h) if cells != "polyhedra" else oc.merged_pairs(h, 6)
    if cells == "polyhedra":
        x = (x[0::2] + x[1::2]) / 2
    want = np.where(x < 0.34, 1, np.where(x > 0.66, 2, 0))  # left, right, the middle in none
    zones = {
        "left": np.flatnonzero(x < 0.34),
        "right": np.flatnonzero(x > 0.66),
        "tiny": np.flatnonzero(x < 0.2),
    }
    case = tmp_path / "case"
    if cells == "decomposed":
        decomposed_case(case)
        for proc, sel in enumerate([x < 0.5, x >= 0.5]):
            ids = np.flatnonzero(sel)
            local = {name: np.flatnonzero(np.isin(ids, z)) for name, z in zones.items()}
            oc.write_cell_zones(case / f"processor{proc}", local)
        given = str(case)
    else:
        given = oc.write_case(str(case), p, faces, inlet_or_walls)
        oc.write_cell_zones(str(case), zones)
    mesh = read_mesh(given)
    assert sorted(mesh.meta["group_names"].values()) == ["left", "right"]  # ('tiny': all in 'left')
    names = {n: t for t, n in mesh.meta["group_names"].items()}
    tags = np.select([mesh.tags == names["left"], mesh.tags == names["right"]], [1, 2], 0)
    if cells != "decomposed":  # the case's cell order is kept
        assert np.array_equal(tags, want)
    else:  # the processors' cells one after the other: the cells' centres say which is which
        c = (
            np.add.reduceat(mesh.points[mesh.connectivity], mesh.offsets[:-1])
            / np.diff(mesh.offsets)[:, None]
        )
        got = c[:, 0] - 0.1 * c[:, 1]
        assert np.array_equal(tags, np.where(got < 0.34, 1, np.where(got > 0.66, 2, 0)))
    assert np.bincount(tags, minlength=3).tolist() == np.bincount(want, minlength=3).tolist()


def test_corrupted_cell_addressing_is_refused_or_said(tmp_path):
    """constant/polyMesh's owner and neighbour lists, which VTK's reader believes: a neighbour id
    made large is refused naming the list, the entry and the id (it was 'cells without a volume');
    two neighbour lines swapped (faces moved to the wrong cells, 1% of the volume misplaced, read
    with no word) are said in a warning; the valid case has neither. ASCII and binary lists."""
    from models.mesh.check import check_file
    from models.mesh.foam_lists import read_labels

    p, h = oc.hex_grid(4, 3, 2)
    good = tmp_path / "good"
    foam = oc.write_case(str(good), p, oc.hex_cells(h), inlet_or_walls)
    mesh = read_mesh_safe(foam)
    assert "openfoam_order" not in mesh.meta
    nb_path = good / "constant" / "polyMesh" / "neighbour"
    text = nb_path.read_text()
    labels = read_labels(str(nb_path))
    assert labels is not None and labels.size > 10

    big = tmp_path / "big"
    shutil.copytree(good, big)
    rows = text.split("\n")
    first = next(i for i, r in enumerate(rows) if r.strip() == "(") + 1
    rows[first + 5] = "99999"
    (big / "constant" / "polyMesh" / "neighbour").write_text("\n".join(rows))
    with pytest.raises(
        MeshError, match=r"constant/polyMesh/neighbour, entry 5: cell 99,999, .*fewer than 4 faces"
    ):
        read_mesh_safe(str(big / "case.foam"))

    swapped = tmp_path / "swapped"
    shutil.copytree(good, swapped)
    rows = text.split("\n")
    rows[first + 2], rows[first + 40] = rows[first + 40], rows[first + 2]  # (faces far apart)
    (swapped / "constant" / "polyMesh" / "neighbour").write_text("\n".join(rows))
    mesh = read_mesh_safe(str(swapped / "case.foam"))
    assert "upper-triangular order" in mesh.meta["openfoam_order"]["message"]
    assert any(i["kind"] == "openfoam-order" for i in check_file(str(swapped / "case.foam"))["issues"])

    binary = tmp_path / "binary"  # the same lists written binary (as OpenFOAM's writeFormat binary)
    shutil.copytree(good, binary)
    for name in ("owner", "neighbour"):
        path = binary / "constant" / "polyMesh" / name
        values = read_labels(str(path))
        head = path.read_bytes().split(b"FoamFile", 1)
        header = head[1].split(b"}", 1)[0].replace(b"format      ascii;", b"format      binary;")
        if b"format      binary;" not in header:
            header = re.sub(rb"format\s+ascii;", b"format binary;", header)
        body = b"%d\n(" % values.size + values.astype("<i4").tobytes() + b")\n"
        path.write_bytes(head[0] + b"FoamFile" + header + b"}\n\n" + body)
        assert np.array_equal(read_labels(str(path)), values)
    assert read_mesh_safe(str(binary / "case.foam")).n_cells == len(h)
