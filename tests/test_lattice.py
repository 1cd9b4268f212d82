"""Structured grids read through the lattice path (models/mesh/lattice.py) give what the general
orientation and measure path gives: same cells, same orientation record, measures to rounding."""

import numpy as np
import pytest
import vtk_corpus as vc

from models.mesh import vtk_readers as vr
from models.mesh.read import read_mesh

# these tests check VTK's path (vtk_readers): our numpy path for .vti/.vts/.vtr (xml_grid) is off
pytestmark = pytest.mark.usefixtures("vtk_xml_path")


def _cases(tmp):
    im = vc.image((5, 4, 6))
    im.SetSpacing(0.5, -0.25, 2.0)  # negative spacing: every cell left-handed, flipped
    im.SetOrigin(1, 2, 3)
    rot = vc.image((5, 4, 6))
    rot.SetDirectionMatrix(0, 1, 0, 1, 0, 0, 0, 0, 1)  # a reflection: no closed form, flipped
    mirror = vc.structured_grid((4, 5, 6))
    folded = vc.structured_grid((4, 5, 6))
    for g, f in ((mirror, lambda x, y, z: (-x, y, z)), (folded, None)):
        p = g.GetPoints()
        if f is not None:
            for i in range(p.GetNumberOfPoints()):
                p.SetPoint(i, *f(*p.GetPoint(i)))
    folded.GetPoints().SetPoint(0, 3.0, 3.0, 3.0)  # the first corner pushed through its cell
    return {
        "vti": vc.write_xml(tmp / "a.vti", vc.image((5, 4, 6)), "appended"),
        "vti-negative-spacing": vc.write_xml(tmp / "n.vti", im, "appended"),
        "vti-reflected": vc.write_xml(tmp / "r.vti", rot, "appended"),
        "structured-points": vc.write_legacy(tmp / "sp.vtk", vc.image((5, 4, 6))),
        "vts": vc.write_xml(tmp / "s.vts", vc.structured_grid((4, 5, 6)), "binary"),
        "vts-mirrored": vc.write_xml(tmp / "m.vts", mirror, "binary"),
        "vts-folded": vc.write_xml(tmp / "f.vts", folded, "binary"),
    }


@pytest.mark.parametrize(
    "case",
    [
        "vti",
        "vti-negative-spacing",
        "vti-reflected",
        "structured-points",
        "vts",
        "vts-mirrored",
        "vts-folded",
    ],
)
def test_lattice_path_matches_general_path(tmp_path, monkeypatch, case):
    path = str(_cases(tmp_path)[case])
    fast = read_mesh(path)
    monkeypatch.setattr(vr, "_lattice", lambda *a: None)  # the general path
    ref = read_mesh(path)
    assert np.array_equal(fast.connectivity, ref.connectivity)
    assert fast.meta["orientation"] == ref.meta["orientation"]
    for k in ("measures", "centroids", "signed_measures"):
        np.testing.assert_allclose(
            fast.meta[k], ref.meta[k], rtol=1e-12, atol=1e-12 * np.abs(ref.meta[k]).max()
        )
    if case == "vts-folded":
        assert ref.meta["orientation"]["folded"] > 0
    if case in ("vti-negative-spacing", "vti-reflected", "vts-mirrored"):
        assert ref.meta["orientation"]["flipped"] == ref.n_cells


def test_lattice_hint_only_for_whole_3d_grids(tmp_path):
    assert vr._lattice(vc.image((5, 4, 1)), 12) is None  # 2D: quads, the general path
    assert vr._lattice(vc.image((5, 4, 6)), 59) is None  # a cell hidden: the general path
    assert vr._lattice(vc.image((5, 4, 6)), 60)["axes"] is not None
    assert vr._lattice(vc.structured_grid((4, 5, 6)), 60)["axes"] is None
