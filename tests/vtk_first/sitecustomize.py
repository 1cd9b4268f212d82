"""Test hook (on PYTHONPATH only in tests/test_read_fuzz.py's processes): `read_mesh` first reads
.exo/.vtk/.vtu files with VTK's own C++ reader, as the VTK-based readers of models.mesh do, so that
a file that crashes VTK crashes the read in every process of a deployment (CLI, API, worker).
"""

import os
import sys

if os.environ.get("MAGNET_TEST_VTK_FIRST") == "1":
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    from mutants import vtk_read  # tests/mutants.py

    import models.mesh.read as _read

    _original = _read.read_mesh

    def read_mesh(path, *args, **kwargs):
        if str(path).endswith((".exo", ".e", ".vtk", ".vtu")):
            vtk_read(str(path))
        return _original(path, *args, **kwargs)

    _read.read_mesh = read_mesh
