"""Regenerate the `--help` blocks of docs/cli.md ("## magnet NAME" followed by a fenced block) from
the real parser: `python scripts/cli_help_md.py` (tests/test_docs.py checks every flag is there)."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def help_text(name: str) -> str:
    env = dict(os.environ, COLUMNS="110", PYTHONPATH=str(ROOT))
    out = subprocess.run(
        [sys.executable, "-m", "models.cli", name, "--help"],
        capture_output=True,
        text=True,
        env=env,
        cwd=ROOT,
    )
    return out.stdout.rstrip() + "\n"


def main() -> None:
    path = ROOT / "docs" / "cli.md"
    text = path.read_text()

    def block(m: re.Match) -> str:
        return f"## magnet {m.group(1)}\n\n```\n{help_text(m.group(1))}```\n"

    text = re.sub(r"## magnet (\w+)\n\n```\n.*?```\n", block, text, flags=re.S)
    path.write_text(text)


if __name__ == "__main__":
    main()
