"""PLOT3D grid files (NASA's structured multi-block format, as CFD grid generators write it), read
by VTK's vtkMultiBlockPLOT3DReader: ASCII, C binary and Fortran unformatted, single and double
precision, 3D (.xyz, .p3d) and 2D (.xy), one grid or several, with iblanks. Written at test time;
the grids' blocks join into one mesh (their shared faces' points merged); volumes are exact."""

from __future__ import annotations

import format_writers as fw
import numpy as np
import pytest

from models.mesh.check import check_file
from models.mesh.read import read_mesh


def block(x0, x1, n=(5, 4, 3), dim=3):
    """A sheared box grid [x0, x1] x [0, 1] x [0, 0.5] (its volume x1 - x0 halved; 2D: the area)."""
    axes = [np.linspace(x0, x1, n[0]), np.linspace(0, 1, n[1]), np.linspace(0, 0.5, n[-1])][:dim]
    g = list(np.meshgrid(*axes, indexing="ij"))
    g[0] = g[0] + 0.1 * g[1]
    return tuple(g)


@pytest.mark.parametrize("mode", ["ascii", "c", "fortran"])
@pytest.mark.parametrize("dtype", ["<f8", "<f4", ">f8"])
def test_plot3d_multigrid(tmp_path, mode, dtype):
    if mode == "ascii" and dtype != "<f8":
        pytest.skip("(ASCII has no precision or byte order)")
    path = fw.write_plot3d(tmp_path / "grid.xyz", [block(0, 1), block(1, 2)], mode, dtype=dtype)
    mesh = read_mesh(path)
    assert (mesh.n_cells, mesh.n_points) == (48, 2 * 60 - 12)
    assert float(mesh.meta["measures"].sum()) == pytest.approx(
        1.0, rel=1e-6 if dtype.endswith("4") else 1e-12
    )
    assert check_file(path)["components"] == 1


@pytest.mark.parametrize("mode", ["ascii", "fortran"])
def test_plot3d_2d_and_single_grid(tmp_path, mode):
    path = fw.write_plot3d(tmp_path / "plane.xy", [block(0, 1, (6, 5), 2), block(1, 3, (6, 5), 2)], mode)
    mesh = read_mesh(path)
    assert mesh.dim == 2 and mesh.n_cells == 2 * 20 and set(np.unique(mesh.cell_types).tolist()) == {9}
    assert float(mesh.meta["measures"].sum()) == pytest.approx(3.0, rel=1e-12)
    one = fw.write_plot3d(tmp_path / "one.p3d", [block(0, 2)], mode)
    assert read_mesh(one).n_cells == 24


@pytest.mark.parametrize("mode", ["ascii", "fortran"])
def test_plot3d_iblanked_points_leave_their_cells_out(tmp_path, mode):
    """iblank 0 blanks a point (overset grids' holes): the cells on it are left out, as VTK draws them."""
    grid = block(0, 1, (6, 6, 3))
    blank = np.ones(grid[0].shape, np.int32)
    blank[2, 2, :] = 0  # one column of points: the 4 x 2 cells around it go
    path = fw.write_plot3d(tmp_path / "holes.xyz", [grid], mode, iblank=[blank])
    mesh = read_mesh(path)
    assert mesh.n_cells == 5 * 5 * 2 - 4 * 2


def test_plot3d_mutants_are_a_mesh_or_one_clear_sentence(tmp_path):
    """The mutation test (tests/mutants.py) over an ASCII and a Fortran PLOT3D file, read in the
    sandbox as the service reads: a Mesh, or one sentence naming the file and the format, with no
    library text (test_read_fuzz's rules); a crash or a hang of VTK's reader is a sentence too."""
    from mutants import read_mutants

    outcomes = {"mesh": 0, "refused": 0}
    for k, mode in enumerate(("ascii", "fortran")):
        good = fw.write_plot3d(tmp_path / f"good_{mode}.xyz", [block(0, 1), block(1, 2)], mode)
        got = read_mutants(tmp_path, open(good, "rb").read(), f"m_{mode}_", ".xyz", "PLOT3D", 3000 + k, 12)
        outcomes = {key: outcomes[key] + got[key] for key in outcomes}
    assert outcomes["refused"] >= 6, outcomes
