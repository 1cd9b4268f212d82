#!/usr/bin/env bash
# Set everything up and start the service with its embedded queue (no Redis needed):
# API on http://127.0.0.1:8000 (OpenAPI at /docs) plus one worker.
set -euo pipefail
cd "$(dirname "$0")/.."
./scripts/setup.sh
exec .venv/bin/magnet serve "$@"
