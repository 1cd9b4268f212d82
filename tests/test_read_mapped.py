"""Our pure-Python readers map the file instead of reading it (models/mesh/mapped.py): nothing of
the mapping may outlive the read. Each file is read in-process in a child interpreter, then cut to
zero bytes and overwritten, and every array of the Mesh (and of its meta) is touched: a view of the
mapping left in the Mesh would end the child with SIGBUS, or show the new bytes."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
import vtk_corpus as vc

from models.mesh.mapped import Mapped, file_bytes, owned

ROOT = Path(__file__).resolve().parent.parent

CHILD = textwrap.dedent(
    """
    import os, sys
    import numpy as np
    os.environ["MAGNET_READ_SANDBOX"] = "0"
    from models.mesh.read import read_mesh

    path = sys.argv[1]
    m = read_mesh(path)
    reader = m.meta.get("reader", "")
    size = os.path.getsize(path)
    with open(path, "r+b") as fh:  # cut to nothing, then other bytes of the same length
        fh.truncate(0)
    arrays = [v for v in vars(m).values() if isinstance(v, np.ndarray)]
    arrays += [v for v in m.meta.values() if isinstance(v, np.ndarray)]
    total = sum(float(np.asarray(a, dtype=np.float64).sum()) for a in arrays if a.size)
    with open(path, "wb") as fh:
        fh.write(b"\\xff" * size)
    again = sum(float(np.asarray(a, dtype=np.float64).sum()) for a in arrays if a.size)
    print(len(arrays), bool(total == again and np.isfinite(total)), reader)
    """
)


def _files(tmp: Path):
    p, h = vc.grid(6, 5, 4)
    ug = vc.unstructured(p, [(12, h)])
    yield vc.write_xml(tmp / "raw.vtu", ug, encode=False)
    yield vc.write_xml(tmp / "base64.vtu", ug)
    yield vc.write_legacy(tmp / "binary51.vtk", ug, 51, True)
    yield vc.write_legacy(tmp / "binary42.vtk", ug, 42, True)
    yield vc.write_legacy(tmp / "ascii.vtk", ug, 51)
    q, qq = vc.quad_grid(7, 5)
    yield vc.write_xml(tmp / "quads_raw.vtu", vc.unstructured(q, [(9, qq)]), encode=False)
    yield vc.write_xml(tmp / "raw.vts", vc.structured_grid((6, 5, 4)), "appended", encode=False)
    yield vc.write_xml(tmp / "raw.vtr", vc.rectilinear((6, 5, 4)), "appended", encode=False)
    yield vc.write_xml(tmp / "raw.vti", vc.image((6, 5, 4)), "appended", encode=False)


NAMES = ["raw.vtu", "base64.vtu", "binary51.vtk", "binary42.vtk", "ascii.vtk", "quads_raw.vtu"]
NAMES += ["raw.vts", "raw.vtr", "raw.vti"]


@pytest.mark.parametrize("name", NAMES)
def test_nothing_of_the_mapped_file_outlives_the_read(tmp_path, name):
    files = {Path(f).name: f for f in _files(tmp_path)}
    run = subprocess.run(
        [sys.executable, "-c", CHILD, files[name]], cwd=ROOT, capture_output=True, text=True, timeout=120
    )
    assert run.returncode == 0, f"the child ended with {run.returncode}: {run.stderr[-2000:]}"
    n_arrays, same, reader = run.stdout.strip().split(maxsplit=2)
    assert "numpy" in reader, f"{name} was not read by our numpy readers: {reader}"
    assert int(n_arrays) >= 3 and same == "True"


def test_mapped_bytes_answer_as_bytes_do(tmp_path):
    """Mapped's find / rfind / index / startswith / slices and memoryview: those of the bytes."""
    data = b"<VTKFile><Piece a='1'/>_\x00<\x01</AppendedData></VTKFile>"
    path = tmp_path / "f.bin"
    path.write_bytes(data)
    m = file_bytes(path)
    assert isinstance(m, Mapped)
    for sub, start in ((b"<", 0), (b"<", 5), (b"</AppendedData>", 0), (b"Piece", 3)):
        assert m.find(sub, start) == data.find(sub, start)
        assert m.index(sub, start) == data.index(sub, start)
        assert m.startswith(sub, start) == data.startswith(sub, start)
        assert m.startswith(sub, data.find(sub, start))
    assert m.rfind(b"<") == data.rfind(b"<")
    with pytest.raises(ValueError):
        m.index(b"nowhere")
    assert m[3:12] == data[3:12] and bytes(memoryview(m)[1:4]) == data[1:4]
    (tmp_path / "empty").write_bytes(b"")
    assert file_bytes(tmp_path / "empty") == b""
    view = np.frombuffer(memoryview(m)[0:8], np.uint8)
    assert owned(view) is not view and np.array_equal(owned(view), view)
    mine = np.arange(4)
    assert owned(mine) is mine and owned(mine[1:]).base is mine
