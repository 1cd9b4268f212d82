#!/usr/bin/env bash
# Create .venv and install the project with every extra (idempotent; a no-op when up to date).
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
  "$PY" -m venv .venv
fi
stamp=.venv/.magnet-installed
# (again when a compiled module's source or build changed: setup.py builds models/*/_fast*.c, their
# headers and the files they include: every models/**/_fast*.c and .h)
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ] || [ client/pyproject.toml -nt "$stamp" ] \
  || [ setup.py -nt "$stamp" ] || [ -n "$(find models -name '_fast*.[ch]' -newer "$stamp" -print -quit)" ] \
  || [ models/_buffers.h -nt "$stamp" ]; then
  .venv/bin/python -m pip install -q --upgrade pip
  # torch pinned first: the CPU wheel (a bare "torch" would pull a multi-GB CUDA build)
  .venv/bin/python -m pip install -q "torch==2.13.0" || .venv/bin/python -m pip install -q "torch>=2.2,<2.15"
  .venv/bin/python -m pip install -q -e ".[neural,service,test]"
  .venv/bin/python -m pip install -q -e ./client
  touch "$stamp"
fi
