"""The house style holds on the whole repository: `ruff check` (lint rules in pyproject.toml) and
`ruff format --check` (every file as the formatter writes it)."""

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def ruff() -> list[str]:
    exe = Path(sys.executable).parent / "ruff"
    if exe.exists():
        return [str(exe)]
    found = shutil.which("ruff")
    if not found:
        pytest.skip("ruff is not installed (it comes with the project's test extra)")
    return [found]


@pytest.mark.parametrize("args", [["check", "--no-cache", "."], ["format", "--check", "--no-cache", "."]])
def test_ruff(args):
    r = subprocess.run(ruff() + args, cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout[-4000:] + r.stderr[-2000:]


def test_pyproject_license_is_an_spdx_string_setuptools_takes_without_warning():
    """setuptools >= 77 warns `project.license as a TOML table is deprecated` on {text = ...}."""
    import warnings
    from pathlib import Path

    from setuptools.config.pyprojecttoml import read_configuration

    root = Path(__file__).resolve().parents[1]
    for path in (root / "pyproject.toml", root / "client" / "pyproject.toml"):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            conf = read_configuration(path)
        assert conf["project"]["license"] == "MIT"
        assert [str(w.message) for w in caught if "license" in str(w.message).lower()] == []
