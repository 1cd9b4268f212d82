"""The `magnet` command line: a full run with every output, and one clear error per bad input."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest
from conftest import BRAIN, EMILIA


def magnet(*args, cwd=None):
    env = dict(os.environ, MPLBACKEND="Agg")
    return subprocess.run(
        [sys.executable, "-m", "models.cli", *map(str, args)],
        capture_output=True,
        text=True,
        cwd=cwd,
        env=env,
        timeout=600,
    )


def test_agglomerate_all_outputs(tmp_path):
    out = tmp_path / "brain.vtu"
    r = magnet(
        "agglomerate",
        BRAIN,
        "-o",
        out,
        "--model",
        "metis",
        "--mode",
        "kway",
        "--k",
        128,
        "--metrics",
        tmp_path / "m.json",
        "--labels",
        tmp_path / "l.json",
        "--lymph",
        tmp_path / "l.mat",
        "--plot",
        tmp_path / "p.png",
    )
    assert r.returncode == 0, r.stderr
    assert r.stdout.startswith("128 elements from 14372 cells")
    assert "graph" in r.stdout and "partition" in r.stdout
    rep = json.loads((tmp_path / "m.json").read_text())
    assert rep["elements"] == 128
    assert set(rep["summary"]) >= {
        "circle_ratio",
        "area_perimeter_ratio",
        "uniformity_factor",
        "volume_difference",
    }
    assert set(rep["partition"]) >= {"cut", "normalized_cut", "parts", "connected"}
    assert rep["partition"]["connected"] is True and rep["partition"]["parts"] == 128
    assert len(rep["per_element"]["circle_ratio"]) == 128
    labels = json.loads((tmp_path / "l.json").read_text())
    assert len(labels) == 14372 and set(labels) == set(range(128))
    from scipy.io import loadmat

    mat = loadmat(tmp_path / "l.mat")
    assert "region" in mat and "neighbor" in mat
    assert (tmp_path / "p.png").stat().st_size > 1000
    # plot from the labels
    r = magnet("plot", BRAIN, "--labels", tmp_path / "l.json", "-o", tmp_path / "q.png")
    assert r.returncode == 0, r.stderr and (tmp_path / "q.png").exists()


def test_segregated_and_subset(tmp_path):
    r = magnet(
        "agglomerate",
        EMILIA,
        "-o",
        tmp_path / "e.vtu",
        "--mode",
        "segregated",
        "--mult-factor",
        0.1,
        "--metrics",
        tmp_path / "e.json",
    )
    assert r.returncode == 0, r.stderr
    rep = json.loads((tmp_path / "e.json").read_text())
    assert "heterogeneity_preservation" in rep["summary"]
    assert min(rep["per_element"]["heterogeneity_preservation"]) == 1.0
    (tmp_path / "s.txt").write_text(" ".join(map(str, range(0, 3000))))
    nref3 = ("agglomerate", BRAIN, "-o", tmp_path / "s.vtu", "--mode", "nref", "--nref", 3)
    subset = ("--subset", tmp_path / "s.txt", "--labels", tmp_path / "sl.json")
    r = magnet(*nref3, *subset)
    # the first 3000 cells are scattered pieces: 2^3 elements cannot hold them (exact, as k)
    assert r.returncode != 0 and "2^nref = 8 cannot be met" in r.stderr and "2^nref >= " in r.stderr
    r = magnet(*nref3, "--allow-extra", *subset)
    assert r.returncode == 0, r.stderr
    lab = np.array(json.loads((tmp_path / "sl.json").read_text()))
    assert np.unique(lab[3000:]).size == 14372 - 3000


def test_compare(tmp_path):
    r = magnet(
        "compare",
        BRAIN,
        "--methods",
        "metis:kway,kmeans:kway,metis:nref",
        "--k",
        16,
        "--nref",
        4,
        "-o",
        tmp_path / "c.png",
        "--json",
        tmp_path / "c.json",
    )
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "c.png").exists()
    data = json.loads((tmp_path / "c.json").read_text())
    assert set(data) == {"metis:kway", "kmeans:kway", "metis:nref"}


def _bad(tmp_path, *args, match):
    r = magnet(*args)
    assert r.returncode == 2, (r.stdout, r.stderr)
    assert "Traceback" not in r.stderr
    assert match in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1


@pytest.mark.parametrize(
    "extra, match",
    [
        (["--k", 0], "k must be >= 1"),
        (["--k", 100000], "larger than the number of cells"),
        (["--mode", "nref", "--nref", -1], "nref must be >= 0"),
        (["--mode", "nref", "--nref", 1000], "nref must be <= 30"),
        (["--nref", 20], "asks for 2^20"),
        (["--mode", "nope"], "mode must be one of"),
        (["--model", "nope", "--k", 3], "model must be one of"),
        (["--nref", 3, "--k", 4], "give one size parameter, not k and nref"),
        (["--mode", "kway", "--nref", 3], "nref does not go with mode 'kway', which takes k"),
        (["--mode", "segregated", "--mult-factor", 0.1], "physical groups"),
        (["--mode", "mult-factor", "--mult-factor", 5], "--mult-factor must be <= 1"),
        (["--physical-tag", "zzz", "--k", 4], "zzz"),
    ],
)
def test_bad_parameters_exit_2(tmp_path, extra, match):
    _bad(tmp_path, "agglomerate", BRAIN, "-o", tmp_path / "x.vtu", *extra, match=match)


def test_bad_subset(tmp_path):
    (tmp_path / "s.json").write_text(json.dumps([1, 2, 99999999]))
    _bad(
        tmp_path,
        "agglomerate",
        BRAIN,
        "-o",
        tmp_path / "x.vtu",
        "--k",
        2,
        "--subset",
        tmp_path / "s.json",
        match="unknown cell ids",
    )
    (tmp_path / "t.json").write_text('[1, 2, "x"]')
    _bad(
        tmp_path,
        "agglomerate",
        BRAIN,
        "-o",
        tmp_path / "x.vtu",
        "--k",
        2,
        "--subset",
        tmp_path / "t.json",
        match="integer cell ids",
    )


def test_bad_files(tmp_path):
    (tmp_path / "a.qqq").write_text("hello")
    _bad(
        tmp_path,
        "agglomerate",
        tmp_path / "a.qqq",
        "-o",
        tmp_path / "x.vtu",
        "--k",
        2,
        match="unknown mesh format",
    )
    data = open(BRAIN, "rb").read()
    (tmp_path / "t.vtu").write_bytes(data[:5000])
    _bad(tmp_path, "agglomerate", tmp_path / "t.vtu", "-o", tmp_path / "x.vtu", "--k", 2, match="cannot read")
    _bad(
        tmp_path,
        "agglomerate",
        tmp_path / "missing.vtu",
        "-o",
        tmp_path / "x.vtu",
        "--k",
        2,
        match="not found",
    )
    (tmp_path / "nan.vtk").write_text(
        "# vtk DataFile Version 4.2\nx\nASCII\nDATASET UNSTRUCTURED_GRID\n"
        "POINTS 3 double\n0 0 0\n1 nan 0\n0 1 0\nCELLS 1 4\n3 0 1 2\nCELL_TYPES 1\n5\n"
    )
    _bad(tmp_path, "agglomerate", tmp_path / "nan.vtk", "-o", tmp_path / "x.vtu", "--k", 1, match="NaN")
    (tmp_path / "deg.vtk").write_text(
        "# vtk DataFile Version 4.2\nx\nASCII\nDATASET UNSTRUCTURED_GRID\n"
        "POINTS 4 double\n0 0 0\n1 0 0\n2 0 0\n0 1 0\nCELLS 2 8\n3 0 1 2\n3 0 1 3\nCELL_TYPES 2\n5\n5\n"
    )
    _bad(
        tmp_path, "agglomerate", tmp_path / "deg.vtk", "-o", tmp_path / "x.vtu", "--k", 1, match="degenerate"
    )
    (tmp_path / "miss.vtk").write_text(
        "# vtk DataFile Version 4.2\nx\nASCII\nDATASET UNSTRUCTURED_GRID\n"
        "POINTS 3 double\n0 0 0\n1 0 0\n0 1 0\nCELLS 1 4\n3 0 1 7\nCELL_TYPES 1\n5\n"
    )
    _bad(
        tmp_path,
        "agglomerate",
        tmp_path / "miss.vtk",
        "-o",
        tmp_path / "x.vtu",
        "--k",
        1,
        match="missing points",
    )
    (tmp_path / "line.vtk").write_text(
        "# vtk DataFile Version 4.2\nx\nASCII\nDATASET UNSTRUCTURED_GRID\n"
        "POINTS 3 double\n0 0 0\n1 0 0\n2 0 0\nCELLS 2 6\n2 0 1\n2 1 2\nCELL_TYPES 2\n3\n3\n"
    )
    _bad(tmp_path, "agglomerate", tmp_path / "line.vtk", "-o", tmp_path / "x.vtu", "--k", 1, match="1D")
    (tmp_path / "empty.vtu").write_bytes(b"")
    _bad(tmp_path, "agglomerate", tmp_path / "empty.vtu", "-o", tmp_path / "x.vtu", "--k", 1,
         match="cannot read empty.vtu as VTK XML (VTU): the file is empty (0 bytes)")  # fmt: skip
    import gzip

    (tmp_path / "brain.vtu.gz").write_bytes(gzip.compress(open(BRAIN, "rb").read()))  # compressed whole
    _bad(
        tmp_path, "agglomerate", tmp_path / "brain.vtu.gz", "-o", tmp_path / "x.vtu", "--k", 2,
        match="brain.vtu.gz is a .vtu file compressed whole: decompress it first, e.g. gunzip brain.vtu.gz",
    )  # fmt: skip
    (tmp_path / "zero.vtu").write_text(
        '<?xml version="1.0"?>\n<VTKFile type="UnstructuredGrid" version="1.0">\n<UnstructuredGrid>\n'
        '<Piece NumberOfPoints="0" NumberOfCells="0">\n<Points><DataArray type="Float64" NumberOfComponents="3" '
        'format="ascii"></DataArray></Points>\n<Cells><DataArray type="Int64" Name="connectivity" format="ascii">'
        '</DataArray><DataArray type="Int64" Name="offsets" format="ascii"></DataArray><DataArray type="UInt8" '
        'Name="types" format="ascii"></DataArray></Cells>\n</Piece>\n</UnstructuredGrid>\n</VTKFile>\n'
    )  # the words of the service's upload check (service/mesh_check.py)
    _bad(tmp_path, "agglomerate", tmp_path / "zero.vtu", "-o", tmp_path / "x.vtu", "--k", 2,
         match="the mesh has no cells (every piece declares NumberOfCells=0)")  # fmt: skip
    seam = os.path.join(os.path.dirname(__file__), "data", "defects", "duplicate_seam.vtu")  # (cut by a seam)
    _bad(
        tmp_path,
        "agglomerate",
        seam,
        "-o",
        tmp_path / "x.vtu",
        "--k",
        1,
        match="merge them with --weld (a distance)",
    )
    os.mkfifo(tmp_path / "pipe.vtu")  # no size and no end: said as what it is, not "empty", and no wait
    _bad(
        tmp_path,
        "agglomerate",
        tmp_path / "pipe.vtu",
        "-o",
        tmp_path / "x.vtu",
        "--k",
        2,
        match="pipe.vtu is a named pipe",
    )
    r = magnet("check", tmp_path / "pipe.vtu")
    assert r.returncode == 2 and "error: pipe.vtu is a named pipe, not a mesh file" in r.stdout, (
        r.stdout,
        r.stderr,
    )


def test_lymph_on_3d_refused(tmp_path):
    import meshio
    from meshes import tets

    p, t = tets(2)
    meshio.write(tmp_path / "c.vtu", meshio.Mesh(p, [("tetra", t)]))
    _bad(
        tmp_path,
        "agglomerate",
        tmp_path / "c.vtu",
        "-o",
        tmp_path / "x.vtu",
        "--k",
        2,
        "--lymph",
        tmp_path / "x.mat",
        match="2D",
    )


def test_an_internal_error_is_one_sentence_not_a_traceback(tmp_path, capsys, monkeypatch):
    """A bug of ours (here: the partition stage raising an IndexError, as a one-cell mesh once did)
    reaches the user as one sentence and exit status 70; MAGNET_TRACEBACK=1 re-raises it."""
    import meshio

    import models.pipeline as pipeline
    from models.cli.main import EXIT_INTERNAL, main

    src = tmp_path / "square.vtu"
    n = 6
    x, y = np.meshgrid(np.linspace(0, 1, n + 1), np.linspace(0, 1, n + 1))
    q = (np.arange(n)[:, None] * (n + 1) + np.arange(n)).ravel()
    meshio.write(
        src,
        meshio.Mesh(
            np.c_[x.ravel(), y.ravel(), 0 * x.ravel()], [("quad", np.c_[q, q + 1, q + n + 2, q + n + 1])]
        ),
    )

    def broken(*args, **kwargs):
        raise IndexError("index 9223372036854775807 is out of bounds for axis 0 with size 4")

    monkeypatch.setattr(pipeline, "split_holes", broken)
    monkeypatch.delenv("MAGNET_TRACEBACK", raising=False)
    rc = main(["agglomerate", str(src), "--k", "2", "-o", str(tmp_path / "out.vtu")])
    err = capsys.readouterr().err
    assert rc == EXIT_INTERNAL
    assert "internal error in 'agglomerate'" in err
    assert "Traceback" not in err and "9223372036854775807" not in err and "IndexError" not in err
    monkeypatch.setenv("MAGNET_TRACEBACK", "1")
    with pytest.raises(IndexError):
        main(["agglomerate", str(src), "--k", "2", "-o", str(tmp_path / "out.vtu")])


def test_running_out_of_memory_is_said_as_such(tmp_path, capsys, monkeypatch):
    """A MemoryError is no bug of ours: the user is told the mesh needs more memory (exit 2)."""
    import meshio

    import models.pipeline as pipeline
    from models.cli.main import EXIT_USER_ERROR, main

    src = tmp_path / "square.vtu"
    pts = np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [2, 0, 0], [2, 1, 0]])
    meshio.write(src, meshio.Mesh(pts, [("quad", np.array([[0, 1, 2, 3], [1, 4, 5, 2]]))]))

    def hungry(*args, **kwargs):
        raise MemoryError

    monkeypatch.setattr(pipeline, "split_holes", hungry)
    rc = main(["agglomerate", str(src), "--k", "2", "-o", str(tmp_path / "out.vtu")])
    err = capsys.readouterr().err
    assert rc == EXIT_USER_ERROR and "out of memory in 'agglomerate'" in err and "bug" not in err


def test_output_names_at_the_file_name_limit(tmp_path):
    """A name of the file system's longest (255 bytes) has no room for a `.tmp` sibling: each
    output is still written whole, through a short sibling, and nothing is left beside it."""
    limit = os.pathconf(tmp_path, "PC_NAME_MAX")
    names = {ext: "e" * (limit - len(ext)) + ext for ext in (".vtu", ".json", ".mat")}
    metrics = tmp_path / ("m" * (limit - 5) + ".json")
    r = magnet(
        "agglomerate", EMILIA, "-o", tmp_path / names[".vtu"], "--model", "metis", "--k", 8,
        "--labels", tmp_path / names[".json"], "--lymph", tmp_path / names[".mat"], "--metrics", metrics,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([*names.values(), metrics.name])
    assert len(set(json.loads((tmp_path / names[".json"]).read_text()))) == 8
    assert json.loads(metrics.read_text())["elements"] == 8
    from scipy.io import loadmat

    assert "region" in loadmat(tmp_path / names[".mat"])
    import vtk

    reader = vtk.vtkXMLUnstructuredGridReader()
    reader.SetFileName(str(tmp_path / names[".vtu"]))
    reader.Update()
    assert reader.GetOutput().GetNumberOfCells() == 8


def test_a_failed_write_leaves_the_old_file_and_no_sibling(tmp_path):
    from models.export import atomic

    for name in ("out.json", "x" * (os.pathconf(tmp_path, "PC_NAME_MAX") - 2) + ".j"):
        path = tmp_path / name
        path.write_text("old")
        with pytest.raises(RuntimeError), atomic.replacing(path, "w") as fh:
            fh.write("half")
            raise RuntimeError("disk full")
        assert path.read_text() == "old" and [p.name for p in tmp_path.iterdir()] == [name]
        atomic.write_text(path, "new")
        assert path.read_text() == "new" and [p.name for p in tmp_path.iterdir()] == [name]
        path.unlink()


def test_a_closed_pipe_ends_quietly():
    """`magnet check --json x.vtu | head -1`: the reader closed the pipe before the report was
    written; no 'error: Broken pipe' and no status 2 (bad input), but 141 as SIGPIPE would give."""
    p = subprocess.Popen(
        [sys.executable, "-m", "models.cli", "check", "--json", str(BRAIN)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env=dict(os.environ, MPLBACKEND="Agg"),
    )
    p.stdout.close()  # (before the command has even read the mesh: its first write meets a closed pipe)
    err = p.stderr.read().decode()
    assert p.wait(timeout=600) == 141, err
    assert "Broken pipe" not in err and "error" not in err


def test_odd_outputs_and_settings_are_said(tmp_path):
    """--lymph writes Matlab's .mat (or JSON): another suffix is refused before any work, not written
    as a .mat under that name; a read limit in the environment that is no number is said, not
    silently replaced."""
    r = magnet("agglomerate", BRAIN, "-o", tmp_path / "x.vtu", "--k", 4, "--lymph", tmp_path / "x.txt")
    assert r.returncode == 2 and "--lymph file" in r.stderr and "must end with .mat or .json" in r.stderr
    assert not (tmp_path / "x.txt").exists() and not (tmp_path / "x.vtu").exists()
    env = dict(os.environ, MAGNET_READ_TIMEOUT_S="abc", MAGNET_READ_MEMORY_MB="lots", MPLBACKEND="Agg")
    r = subprocess.run(
        [sys.executable, "-m", "models.cli", "info", str(BRAIN)],
        capture_output=True,
        text=True,
        env=env,
        timeout=600,
    )
    assert r.returncode == 0, r.stderr
    assert "MAGNET_READ_TIMEOUT_S='abc' is ignored: it must be a number of seconds > 0" in r.stderr
    assert "MAGNET_READ_MEMORY_MB='lots' is ignored" in r.stderr


def test_subset_ids_given_on_the_command_line(tmp_path):
    """--subset 1,2,3 (ids, not a file) was "cannot read subset file 1,2,3: No such file or
    directory": ids are taken as they are; a missing file is still said."""
    from models.cli.main import _read_subset

    assert _read_subset("1,2,3").tolist() == [1, 2, 3]
    assert _read_subset("4 5  6").tolist() == [4, 5, 6]
    (tmp_path / "7").write_text("8 9")  # (a file of that name is read, as before)
    import os

    cwd = os.getcwd()
    os.chdir(tmp_path)
    try:
        assert _read_subset("7").tolist() == [8, 9]
    finally:
        os.chdir(cwd)
    from models.errors import ParameterError

    with pytest.raises(
        ParameterError, match=r"cannot read subset file nofile.txt: no such file or directory"
    ):
        _read_subset("nofile.txt")
