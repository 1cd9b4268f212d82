"""ParaView's parallel legacy files (.pvtk, VTK's vtkPDataSetWriter: an XML list of <Piece
fileName=...> legacy .vtk files, as ParaView opens them with vtkPDataSetReader): the pieces read by
VTK's legacy reader and joined into one mesh (the points on the cuts merged, as for .pvtu). The
writer writes the piece paths it was given, often absolute: where those lie outside the file's
folder, the file of that name beside the .pvtk is read (the set moved, or uploaded as an archive)."""

from __future__ import annotations

import os
import shutil

import pytest
import vtk_corpus as vc

from models.errors import MeshError
from models.mesh.read import read_mesh
from models.mesh.sandbox import read_mesh_safe


def _write(path, pieces=3):
    from vtkmodules.vtkFiltersParallel import vtkExtractUnstructuredGridPiece
    from vtkmodules.vtkIOParallel import vtkPDataSetWriter

    p, hexes = vc.grid(6, 5, 4)
    cut = vtkExtractUnstructuredGridPiece()
    cut.SetInputData(vc.unstructured(p, [(12, hexes)]))
    w = vtkPDataSetWriter()
    w.SetFileName(str(path))
    w.SetInputConnection(cut.GetOutputPort())
    w.SetFileTypeToBinary()  # (ASCII: the points at 6 digits)
    w.SetNumberOfPieces(pieces)
    w.SetStartPiece(0)
    w.SetEndPiece(pieces - 1)
    assert w.Write() == 1
    return str(path), p, hexes


def test_pvtk_pieces_are_one_mesh(tmp_path):
    path, p, hexes = _write(tmp_path / "cut.pvtk")
    text = open(path).read()
    assert text.count("<Piece") == 3 and str(tmp_path) in text  # (absolute piece paths, as written)
    n_ref, vol_ref = vc.vtk_reference(path)  # VTK's reading (float32 points, as the pieces hold them)
    assert n_ref == len(hexes)
    for reader in (read_mesh, read_mesh_safe):
        mesh = reader(path)
        assert (mesh.n_cells, mesh.n_points) == (len(hexes), len(p))  # (cut points merged)
        assert float(mesh.meta["measures"].sum()) == pytest.approx(vol_ref, rel=1e-9)
        assert mesh.tags is None  # (the pieces are no groups)
    res, n_out, vol_out = vc.agglomerate_read_back(path, 5, tmp_path / "out.vtu")
    assert n_out == 5 and vol_out == pytest.approx(vol_ref, rel=1e-9)
    import zipfile

    with zipfile.ZipFile(tmp_path / "cut.zip", "w") as zf:  # over HTTP: the .pvtk and its pieces
        for f in sorted(os.listdir(tmp_path)):
            if f.startswith("cut.") and not f.endswith(".zip"):
                zf.write(tmp_path / f, f)
    assert read_mesh_safe(str(tmp_path / "cut.zip")).n_cells == len(hexes)
    # moved to another folder: its absolute piece paths now name files elsewhere; those beside it are read
    moved = tmp_path / "moved"
    moved.mkdir()
    for f in os.listdir(tmp_path):
        if f.startswith("cut"):
            shutil.copy(tmp_path / f, moved / f)
    for f in os.listdir(tmp_path):
        if f.startswith("cut."):
            os.remove(tmp_path / f)
    assert read_mesh(str(moved / "cut.pvtk")).n_cells == len(hexes)
    os.remove(moved / "cut.1.vtk")
    with pytest.raises(
        MeshError, match=r"^cannot read cut.pvtk as VTK parallel legacy: its piece file .*cut.1.vtk"
    ):
        read_mesh(str(moved / "cut.pvtk"))


def test_pvtk_never_reads_a_file_outside_its_folder(tmp_path):
    inner = tmp_path / "inner"
    inner.mkdir()
    (tmp_path / "secret.vtk").write_text("# vtk DataFile Version 3.0\nx\nASCII\nDATASET UNSTRUCTURED_GRID\n")
    (inner / "evil.pvtk").write_text(
        '<File version="pvtk-1.0" dataType="vtkUnstructuredGrid" numberOfPieces="1" >\n'
        '  <Piece fileName="../secret.vtk" />\n</File>\n'
    )
    with pytest.raises(MeshError, match="lies outside the file's folder"):
        read_mesh(str(inner / "evil.pvtk"))
    (inner / "none.pvtk").write_text('<File version="pvtk-1.0" numberOfPieces="0" >\n</File>\n')
    with pytest.raises(MeshError, match=r"it lists no data set \(no <Piece fileName=...>\)"):
        read_mesh(str(inner / "none.pvtk"))
