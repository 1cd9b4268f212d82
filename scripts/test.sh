#!/usr/bin/env bash
# Set everything up and run the whole test suite (what CI runs).
set -euo pipefail
cd "$(dirname "$0")/.."
./scripts/setup.sh
# GNU Octave for the Matlab-wrapper test (skipped with a reason when it cannot be installed)
if ! command -v octave-cli >/dev/null 2>&1 && command -v apt-get >/dev/null 2>&1; then
  (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends octave) >/tmp/magnet-octave-install.log 2>&1 \
    || echo "note: octave could not be installed; the Octave test will be skipped (see /tmp/magnet-octave-install.log)"
fi
# Debian's chromium for the web-page test, driven by Playwright (never `playwright install`: its own
# browser download is not available); the test is skipped with a reason when it cannot be installed
if ! command -v chromium >/dev/null 2>&1 && command -v apt-get >/dev/null 2>&1; then
  (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends chromium chromium-driver) >/tmp/magnet-chromium-install.log 2>&1 \
    || echo "note: chromium could not be installed; the web-page test will be skipped (see /tmp/magnet-chromium-install.log)"
fi
# Redis for the queue tests (the machine's own at 127.0.0.1:6379; started if it is down)
if command -v redis-cli >/dev/null 2>&1 && ! redis-cli -h 127.0.0.1 -p 6379 ping >/dev/null 2>&1; then
  redis-server --daemonize yes --bind 127.0.0.1 --port 6379 --save "" --appendonly no >/dev/null 2>&1 || true
fi
export MPLBACKEND=Agg
exec .venv/bin/python -m pytest -q -p no:cacheprovider "$@"
