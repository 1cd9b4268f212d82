"""Output path problems: one line on stderr, exit status 2, nothing computed (no traceback)."""

from __future__ import annotations

import os

import pytest
from conftest import BRAIN
from test_cli import _bad


def test_output_in_a_missing_folder(tmp_path):
    _bad(tmp_path, "agglomerate", BRAIN, "-o", "/nonexistent/x.vtu", "--k", 4, match="does not exist")
    _bad(
        tmp_path,
        "agglomerate",
        BRAIN,
        "-o",
        tmp_path / "x.vtu",
        "--k",
        4,
        "--metrics",
        tmp_path / "no" / "m.json",
        match="does not exist",
    )


def test_output_is_a_folder(tmp_path):
    (tmp_path / "d.vtu").mkdir()
    _bad(tmp_path, "agglomerate", BRAIN, "-o", tmp_path / "d.vtu", "--k", 4, match="is a folder")
    _bad(
        tmp_path,
        "agglomerate",
        BRAIN,
        "-o",
        tmp_path / "x.vtu",
        "--k",
        4,
        "--labels",
        tmp_path,
        match="is a folder",
    )


def test_output_with_the_wrong_extension(tmp_path):
    _bad(tmp_path, "agglomerate", BRAIN, "-o", tmp_path / "x.vtk", "--k", 4, match="must end with .vtu")


@pytest.mark.skipif(os.geteuid() == 0, reason="root may write anywhere: the permission check cannot fail")
def test_output_without_permission(tmp_path):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        _bad(tmp_path, "agglomerate", BRAIN, "-o", ro / "x.vtu", "--k", 4, match="permission denied")
    finally:
        ro.chmod(0o700)
