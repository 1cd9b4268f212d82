"""models.mesh.heap: the reading process keeps its heap between reads (issue 23). Between two of
our sandboxed reads a service does other work; here VTK's own reader of the same file, as in
bench/bench_read_formats.py. Without the kept heap every read of 13,824 hexahedra met ~200 of its
pages again as new ones (a page fault each), and a read of 10^5 ~1,500; kept, none."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

SCRIPT = textwrap.dedent(
    """
    import json, os, resource, sys
    sys.path[:0] = [ROOT, os.path.join(ROOT, "tests")]
    import vtk
    import vtk_corpus as vc
    from models.mesh import heap, zygote
    from models.mesh.sandbox import read_mesh_safe

    p, h = vc.grid(24, 24, 24)
    path = vc.write_legacy(os.path.join(FOLDER, "hex.vtk"), vc.unstructured(p, [(12, h)]), 42, True)
    zygote.wait_ready(120)

    def faults():
        return resource.getrusage(resource.RUSAGE_SELF).ru_minflt

    got = []
    for _ in range(6):
        r = vtk.vtkUnstructuredGridReader()  # other work between two reads
        r.SetFileName(path)
        r.Update()
        del r
        before = faults()
        mesh = read_mesh_safe(path)
        got.append(faults() - before)
        assert mesh.n_cells == 13824
        del mesh
    print(json.dumps({"kept": heap.keep(), "faults": got}))
    """
)


def _run(tmp_path, **env) -> dict:
    code = SCRIPT.replace("ROOT", repr(ROOT)).replace("FOLDER", repr(str(tmp_path)))
    out = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        timeout=300,
        env={**os.environ, **env},
        cwd=ROOT,
    )
    assert out.returncode == 0, out.stderr[-2000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_reads_reuse_their_pages(tmp_path):
    got = _run(tmp_path)
    if not got["kept"]:
        pytest.skip("not glibc: malloc is left as it is")
    assert max(got["faults"][2:]) <= 20, got  # the first reads grow the heap; then none


def test_the_heap_is_left_alone_when_asked(tmp_path):
    got = _run(tmp_path, MAGNET_READ_HEAP="0")
    assert got["kept"] is False
