"""What this session's checks of files that hold no area or volume found: a file of points alone
was said to be a "1D mesh"."""

from __future__ import annotations

import meshio
import numpy as np
import pytest

from models.errors import MeshError
from models.mesh.read import read_mesh


@pytest.mark.parametrize("fmt,ext", [("vtu", ".vtu"), ("gmsh22", ".msh")])
def test_points_alone_and_lines_alone_are_said_as_such(tmp_path, fmt, ext):
    p = np.random.default_rng(0).random((10, 3))
    pts = tmp_path / f"pts{ext}"
    lines = tmp_path / f"lines{ext}"
    meshio.write(pts, meshio.Mesh(p, [("vertex", np.arange(10)[:, None])]), file_format=fmt)
    meshio.write(lines, meshio.Mesh(p, [("line", np.c_[np.arange(9), np.arange(1, 10)])]), file_format=fmt)
    with pytest.raises(MeshError) as e:
        read_mesh(str(pts))
    msg = str(e.value)
    assert "points alone are not supported" in msg and "1D" not in msg and "vertex" in msg
    with pytest.raises(MeshError) as e:
        read_mesh(str(lines))
    msg = str(e.value)
    assert "1D meshes are not supported" in msg and "line" in msg
