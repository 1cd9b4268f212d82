"""The user documents stay true to the code: every `magnet` sub-command and flag is in docs/cli.md,
every relative link of the README and docs/ points at a file that exists, the README stays short,
and no document names a module path that the models/ split removed."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from models.cli.main import build_parser

ROOT = Path(__file__).resolve().parents[1]
DOCS = sorted((ROOT / "docs").glob("*.md"))
USER_DOCS = [ROOT / "README.md", ROOT / "service" / "README.md", ROOT / "client" / "README.md", *DOCS]
SUBCOMMANDS = [
    "agglomerate", "check", "info", "plot", "compare", "generate",
    "train", "hierarchy", "mgcheck", "keys", "serve", "worker",
]  # fmt: skip


def _subparser(name: str):
    parser = build_parser([name])
    action = next(a for a in parser._actions if a.dest == "command" or getattr(a, "choices", None))
    return action.choices[name]


def test_the_sub_command_list_is_complete():
    parser = build_parser([])
    action = next(a for a in parser._actions if getattr(a, "choices", None))
    assert sorted(action.choices) == sorted(SUBCOMMANDS)


@pytest.mark.parametrize("name", SUBCOMMANDS)
def test_every_flag_of_every_sub_command_is_in_cli_md(name):
    text = (ROOT / "docs" / "cli.md").read_text()
    assert f"## magnet {name}\n" in text
    section = text.split(f"## magnet {name}\n", 1)[1].split("\n## ", 1)[0]
    flags = {s for a in _subparser(name)._actions for s in a.option_strings if s.startswith("--")}
    assert flags, name
    missing = sorted(f for f in flags if not re.search(re.escape(f) + r"\b", section))
    assert missing == [], f"docs/cli.md, magnet {name}: {missing} (regenerate the --help block)"


def test_readme_is_a_short_users_document():
    lines = (ROOT / "README.md").read_text().splitlines()
    assert len(lines) <= 260
    text = "\n".join(lines)
    for heading in ("## Python", "## Formats", "## HTTP", "## Models and modes"):
        assert heading in text, heading
    for doc in ("cli.md", "python.md", "service.md", "hierarchy.md", "benchmarks.md", "design.md"):
        assert f"docs/{doc}" in text, doc
    assert "Octave" in text and "chromium" in text and "root" in text


@pytest.mark.parametrize("doc", USER_DOCS, ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_point_at_files(doc):
    broken = []
    for target in re.findall(r"\]\(([^)\s]+)\)", doc.read_text()):
        if re.match(r"[a-z]+:", target) or target.startswith("#"):
            continue
        path = (doc.parent / target.split("#", 1)[0]).resolve()
        if not path.exists():
            broken.append(target)
    assert broken == []


STALE = [
    "models/metrics.py", "models/io.py", "models/hierarchy.py", "models/cli.py", "models/rl.py",
    "models/flow.py", "models/groups.py", "models/ucd.py", "models/vtu.py", "models/gnn.py",
    "models/_fastmetrics.c", "models/_fastgraph.c", "models/dataset.py", "models/generate.py",
    "models.gnn.", "models.rl.", "models.partitioners", "models.dataset.", "models.metrics",
]  # fmt: skip


@pytest.mark.parametrize(
    "doc",
    USER_DOCS
    + sorted((ROOT / "models" / "weights").glob("*.md"))
    + [ROOT / "client" / "matlab" / "README.md"],
    ids=lambda p: str(p.relative_to(ROOT)),
)
def test_no_document_names_a_module_that_moved(doc):
    text = doc.read_text()
    assert [s for s in STALE if s in text] == []


def test_docs_modules_named_exist():
    """Every models/... file path that a document names is in the tree."""
    missing = set()
    for doc in USER_DOCS:
        for path in re.findall(r"\bmodels/[\w/]+\.(?:py|c|h|md|pt)\b", doc.read_text()):
            if not (ROOT / path).exists():
                missing.add(f"{doc.name}: {path}")
    assert sorted(missing) == []
