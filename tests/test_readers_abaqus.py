"""Abaqus and Nastran decks: element types meshio's table lacks (models/mesh/abaqus_types.py): plane-strain,
axisymmetric, heat-transfer and coupled-temperature elements read by the shape of their nodes;
a type no table knows is named in the refusal (outside sweep S: plane-strain CPE4 was refused as
"corrupted or not in this format")."""

from __future__ import annotations

import numpy as np
import pytest
import vtk_corpus as vc

from models.errors import MeshError
from models.mesh.read import read_mesh


def write_inp(path, points, cells, etype, elset="PART-1"):
    """An Abaqus input file as Abaqus/CAE writes a flat one: *NODE rows id, x, y[, z] and an
    *ELEMENT block of one type, ids from 1."""
    lines = ["*HEADING", "written at test time", "*NODE"]
    lines += [f"{i + 1}, " + ", ".join(f"{v:.17g}" for v in p) for i, p in enumerate(points)]
    lines.append(f"*ELEMENT, TYPE={etype}, ELSET={elset}")
    lines += [f"{i + 1}, " + ", ".join(str(int(v) + 1) for v in c) for i, c in enumerate(cells)]
    lines.append("*END PART")
    path.write_text("\n".join(lines) + "\n")
    return str(path)


def _square(nx=4, ny=3):
    p, q = vc.quad_grid(nx, ny)
    return p[:, :2], q


@pytest.mark.parametrize(
    "etype,shape",
    [
        ("CPE4", "quad"),
        ("CPE4R", "quad"),
        ("CAX4R", "quad"),
        ("DC2D4", "quad"),
        ("CPE3", "tri"),
        ("CAX3", "tri"),
    ],
)
def test_planar_types_read_with_their_area(tmp_path, etype, shape):
    p, q = _square()
    cells = q if shape == "quad" else np.concatenate([q[:, [0, 1, 2]], q[:, [0, 2, 3]]])
    mesh = read_mesh(write_inp(tmp_path / f"{etype}.inp", p, cells, etype))
    assert mesh.dim == 2 and mesh.n_cells == len(cells)
    d1, d2 = p[q[:, 2]] - p[q[:, 0]], p[q[:, 3]] - p[q[:, 1]]
    area = np.abs(d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]).sum() / 2
    assert float(np.abs(mesh.meta["measures"]).sum()) == pytest.approx(area, rel=1e-12)


@pytest.mark.parametrize("etype", ["C3D8T", "C3D8RT", "DC3D8"])
def test_solid_types_read_with_their_volume(tmp_path, etype):
    p, h = vc.grid(3, 2, 2)
    path = write_inp(tmp_path / f"{etype}.inp", p, h, etype)
    mesh = read_mesh(path)
    assert mesh.dim == 3 and mesh.n_cells == len(h)
    ref = read_mesh(write_inp(tmp_path / "plain.inp", p, h, "C3D8"))
    assert float(np.abs(mesh.meta["measures"]).sum()) == pytest.approx(
        float(np.abs(ref.meta["measures"]).sum()), rel=1e-12
    )


def test_an_unknown_type_is_named(tmp_path):
    p, q = _square()
    path = write_inp(tmp_path / "odd.inp", p, q, "CPE9Q")
    with pytest.raises(MeshError) as err:
        read_mesh(path)
    msg = str(err.value)
    assert "odd.inp" in msg and "CPE9Q" in msg and "corrupted" not in msg


# --- parts, assemblies and instances, as Abaqus/CAE writes every model ---------------------------


def _block(nx, ny, nz, scale=(1.0, 1.0, 1.0)):
    p, h = vc.grid(nx, ny, nz)
    return p @ np.linalg.inv(vc.A).T / [nx, ny, nz] * scale, h


def _part(name, points, cells, etype="C3D8R", sets=()):
    rows = [f"*Part, name={name}", "*Node"]
    rows += [f"{i + 1:7d}, " + ", ".join(f"{v:13.6g}" for v in q) for i, q in enumerate(points)]
    rows.append(f"*Element, type={etype}")
    rows += [f"{i + 1}, " + ", ".join(str(int(v) + 1) for v in c) for i, c in enumerate(cells)]
    rows += [
        f"*Nset, nset=Set-1, generate\n 1, {len(points)}, 1",
        f"*Elset, elset=Set-1, generate\n 1, {len(cells)}, 1",
    ]
    for set_name, ids in sets:
        rows += [f"*Elset, elset={set_name}", ", ".join(str(i) for i in ids)]
    rows += ["** Section: Section-1", "*Solid Section, elset=Set-1, material=Steel", ",", "*End Part", "**"]
    return "\n".join(rows) + "\n"


def _assembly(*instances):
    rows = ["**", "** ASSEMBLY", "**", "*Assembly, name=Assembly", "**"]
    for name, part, placement in instances:
        rows.append(f"*Instance, name={name}, part={part}")
        rows += [", ".join(f"{v:12.6g}" for v in row) for row in placement]
        rows += ["*End Instance", "**"]
    rows += ["*Nset, nset=Fixed, instance=Block-1", " 1, 2, 3", "*End Assembly"]
    return "\n".join(rows) + "\n"


HEAD = "*Heading\n** Job name: Job-1 Model name: Model-1\n*Preprint, echo=NO, model=NO, history=NO\n**\n** PARTS\n**\n"


def _boxes(mesh):
    conn = mesh.connectivity.reshape(mesh.n_cells, -1)
    out = {}
    for gid, name in mesh.meta["group_names"].items():
        p = mesh.points[np.unique(conn[mesh.tags == gid])]
        vol = float(np.abs(mesh.meta["measures"][mesh.tags == gid]).sum())
        out[name] = (p.min(0).round(9).tolist(), p.max(0).round(9).tolist(), round(vol, 9))
    return out


def test_an_assembly_places_each_instance_of_each_part(tmp_path):
    """Two parts, one instanced twice (the second moved), the other moved and turned 90 degrees
    about the z axis through (0, 5, 0): every instance where Abaqus puts it, each a group. meshio's
    reader let the second part's *Node replace the first's points and refused the file."""
    pb, hb = _block(4, 4, 4)
    pr, hr = _block(2, 3, 5, (1.0, 1.0, 2.0))
    text = HEAD + _part("Block", pb, hb) + _part("Bar", pr, hr)
    text += _assembly(
        ("Block-1", "Block", []),
        ("Block-2", "Block", [[3.0, 0.0, 0.0]]),
        ("Bar-1", "Bar", [[0.0, 5.0, 0.0], [0.0, 5.0, 0.0, 0.0, 5.0, 1.0, 90.0]]),
    )
    path = tmp_path / "model.inp"
    path.write_text(text)
    mesh = read_mesh(str(path))
    assert mesh.n_cells == 2 * len(hb) + len(hr) and mesh.dim == 3
    assert _boxes(mesh) == {
        "Block-1": ([0, 0, 0], [1, 1, 1], 1.0),
        "Block-2": ([3, 0, 0], [4, 1, 1], 1.0),
        "Bar-1": ([-1, 5, 0], [0, 6, 2], 2.0),
    }
    from models import agglomerate

    res = agglomerate(str(path), model="metis", k=9, metrics=False)
    assert res.n_elements == 9 and set(res.labels[mesh.tags == 3]) != set(res.labels[mesh.tags == 1])


def test_parts_without_an_assembly_and_flat_files_of_several_node_blocks(tmp_path):
    """Parts and no *Assembly: each part once, as written. A flat file whose nodes come in several
    *NODE blocks (a pre-processor writes one per component): all of them (meshio kept the last)."""
    pb, hb = _block(3, 3, 3)
    pr, hr = _block(2, 2, 2)
    path = tmp_path / "parts.inp"
    path.write_text(HEAD + _part("A", pb, hb) + _part("B", pr + [2, 0, 0], hr))
    mesh = read_mesh(str(path))
    assert mesh.n_cells == len(hb) + len(hr)
    assert _boxes(mesh) == {"A": ([0, 0, 0], [1, 1, 1], 1.0), "B": ([2, 0, 0], [3, 1, 1], 1.0)}
    n = len(pb)
    rows = ["*HEADING", "*NODE"] + [f"{i + 1}, {x}, {y}, {z}" for i, (x, y, z) in enumerate(pb[: n // 2])]
    rows += ["*NODE, NSET=REST"] + [
        f"{i + 1 + n // 2}, {x}, {y}, {z}" for i, (x, y, z) in enumerate(pb[n // 2 :])
    ]
    rows += ["*ELEMENT, TYPE=C3D8, ELSET=EB1"] + [
        f"{i + 1}, " + ", ".join(str(v + 1) for v in c) for i, c in enumerate(hb)
    ]
    flat = tmp_path / "flat.inp"
    flat.write_text("\n".join(rows) + "\n")
    mesh = read_mesh(str(flat))
    assert mesh.n_cells == len(hb) and float(np.abs(mesh.meta["measures"]).sum()) == pytest.approx(1.0)


def test_continued_rows_sets_of_sets_includes_and_point_elements(tmp_path):
    """20-node bricks whose rows go on over two lines; an *ELSET made of other sets; the nodes in
    an *INCLUDE file beside it; a MASS element (a type no table knows, one node: a point, not a
    reason to refuse). An *INCLUDE of a file outside the folder is refused in one sentence."""
    p, h = vc.grid(2, 2, 2)
    ref = read_mesh(write_inp(tmp_path / "linear.inp", p, h, "C3D8"))
    # a C3D20 block: corners of the grid's hexahedra plus 12 mid-edge nodes each, on two lines
    edges = [(0, 1), (1, 2), (2, 3), (3, 0), (4, 5), (5, 6), (6, 7), (7, 4), (0, 4), (1, 5), (2, 6), (3, 7)]
    mids = {}
    pts = [tuple(q) for q in p]
    rows20 = []
    for c in h:
        extra = []
        for a, b in edges:
            key = tuple(sorted((int(c[a]), int(c[b]))))
            if key not in mids:
                mids[key] = len(pts)
                pts.append(tuple((p[key[0]] + p[key[1]]) / 2))
            extra.append(mids[key])
        rows20.append([int(v) + 1 for v in c] + [v + 1 for v in extra])
    (tmp_path / "nodes.inp").write_text(
        "*NODE\n"
        + "".join(f"{i + 1}, {float(x)!r}, {float(y)!r}, {float(z)!r}\n" for i, (x, y, z) in enumerate(pts))
    )
    body = ["*HEADING", "** nodes beside it", "*INCLUDE, INPUT=nodes.inp", "*ELEMENT, TYPE=C3D20R, ELSET=LOW"]
    for i, r in enumerate(rows20[:4]):
        body += [f"{i + 1}, " + ", ".join(map(str, r[:15])) + ",", ", ".join(map(str, r[15:]))]
    body += ["*ELEMENT, TYPE=C3D20R, ELSET=HIGH"]
    for i, r in enumerate(rows20[4:]):
        body += [f"{i + 5}, " + ", ".join(map(str, r[:15])) + ",", ", ".join(map(str, r[15:]))]
    body += [
        "*ELSET, ELSET=ALL",
        "LOW, HIGH",
        "*ELEMENT, TYPE=MASS, ELSET=M",
        "100, 1",
        "*MASS, ELSET=M",
        "1.0",
    ]
    path = tmp_path / "c3d20.inp"
    path.write_text("\n".join(body) + "\n")
    mesh = read_mesh(str(path))
    assert mesh.n_cells == len(h)
    assert np.allclose(np.sort(np.abs(mesh.meta["measures"])), np.sort(np.abs(ref.meta["measures"])))
    assert set(mesh.meta["group_names"].values()) == {"LOW", "HIGH"}
    import zipfile

    from models.mesh.sandbox import read_mesh_safe

    with zipfile.ZipFile(tmp_path / "model.zip", "w") as zf:  # over HTTP: the file and its include
        zf.write(tmp_path / "nodes.inp", "nodes.inp")
        zf.write(path, "c3d20.inp")
    assert read_mesh_safe(str(tmp_path / "model.zip")).n_cells == len(h)
    outside = tmp_path / "sub"
    outside.mkdir()
    (outside / "bad.inp").write_text("*HEADING\n*INCLUDE, INPUT=../nodes.inp\n" + "\n".join(body[3:]) + "\n")
    with pytest.raises(
        MeshError, match=r"^cannot read bad.inp as Abaqus: line 2 includes ../nodes.inp, which is outside"
    ):
        read_mesh(str(outside / "bad.inp"))


def test_assembly_mutants_are_read_or_refused_in_one_sentence(tmp_path):
    from mutants import read_mutants

    pb, hb = _block(3, 3, 3)
    text = (
        HEAD
        + _part("Block", pb, hb)
        + _assembly(("Block-1", "Block", []), ("Block-2", "Block", [[2.0, 0, 0]]))
    )
    seen = read_mutants(tmp_path, text.encode(), "asm", ".inp", "Abaqus", seed=23, n=120)
    assert seen["mesh"] > 10 and seen["refused"] > 10


def test_independent_instances_carry_their_own_mesh(tmp_path):
    """Abaqus/CAE writes an independent instance (meshed on the instance) as an empty *Part and the
    nodes and elements inside the *Instance block; an assembly *Elset with instance= is a set of
    that instance's elements."""
    pb, hb = _block(3, 3, 3)
    mesh_rows = ["*Node"] + [f"{i + 1}, " + ", ".join(f"{v:.9g}" for v in q) for i, q in enumerate(pb)]
    mesh_rows += ["*Element, type=C3D8R"] + [
        f"{i + 1}, " + ", ".join(str(v + 1) for v in c) for i, c in enumerate(hb)
    ]
    text = HEAD + "*Part, name=Block\n*End Part\n**\n*Assembly, name=Assembly\n**\n"
    for name, shift in (("Block-1", 0.0), ("Block-2", 2.0)):
        text += (
            f"*Instance, name={name}, part=Block\n{shift}, 0., 0.\n"
            + "\n".join(mesh_rows)
            + "\n*End Instance\n**\n"
        )
    text += "*Elset, elset=Corner, instance=Block-2\n 1, 2, 3\n*End Assembly\n"
    path = tmp_path / "independent.inp"
    path.write_text(text)
    mesh = read_mesh(str(path))
    assert mesh.n_cells == 2 * len(hb)
    boxes = _boxes(mesh)
    assert boxes["Block-1"][:2] == ([0, 0, 0], [1, 1, 1]) and boxes["Block-2.Corner"][2] == pytest.approx(
        3 / 27
    )
    assert boxes["Block-2"][0][0] == 2.0 and boxes["Block-2"][1][0] == 3.0


def test_a_set_of_every_element_does_not_hide_the_materials(tmp_path):
    """*ELSET EALL (every element) written before the materials' sets STEEL and CORE: each cell goes
    to the smallest set that holds it (outside sweep V: EALL took every cell, STEEL and CORE were
    lost and segregated elements mixed them)."""
    p, h = vc.grid(4, 2, 2)
    path = write_inp(tmp_path / "m.inp", p, h, "C3D8", elset="EALL")
    ids = np.arange(1, len(h) + 1)
    steel, core = ids[: len(h) // 4], ids[len(h) // 4 :]
    text = open(path).read().replace("*END PART\n", "")
    text += "*ELSET, ELSET=STEEL\n" + ", ".join(map(str, steel)) + "\n"
    text += "*ELSET, ELSET=CORE\n" + ", ".join(map(str, core)) + "\n"
    (tmp_path / "m.inp").write_text(text)
    mesh = read_mesh(path)
    names = {n: t for t, n in mesh.meta["group_names"].items()}
    assert set(names) == {"STEEL", "CORE"}
    assert np.count_nonzero(mesh.tags == names["STEEL"]) == steel.size
    assert np.count_nonzero(mesh.tags == names["CORE"]) == core.size


def test_nastran_property_ids_are_the_groups(tmp_path):
    """A Nastran deck's elements carry their property id (PSOLID/PSHELL: the material): the groups
    (outside sweep V: 'physical groups: none', and segregated mode refused the file)."""
    import meshio

    p, h = vc.grid(4, 2, 2)
    pid = np.where(np.arange(len(h)) < 4, 1, 2)
    meshio.write(
        str(tmp_path / "m.nas"), meshio.Mesh(p, [("hexahedron", h)], cell_data={"nastran:ref": [pid]})
    )
    mesh = read_mesh(str(tmp_path / "m.nas"))
    assert np.bincount(mesh.tags).tolist() == [0, 4, len(h) - 4]
