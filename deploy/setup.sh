#!/usr/bin/env bash
# Set up PoseidonSLAM on a fresh machine: a virtual environment in .venv with every
# dependency from this project's own files. Safe to run again.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
  "$PY" -m venv .venv
fi
# torch first, pinned: its CPU build; a plain 'torch' requirement would pull CUDA packages.
.venv/bin/python -m pip install --quiet "torch==2.13.0"
.venv/bin/python -m pip install --quiet -e ".[dev,secure]"
# Optional: Chromium from the system packages, for the headless-browser test of the HTML
# report (tests/eval/report). Only as root with apt-get, and only when it is missing. A
# failure does not fail the setup: the test then skips and says why. POSEIDON_NO_CHROMIUM=1
# leaves it out.
if [ -z "${POSEIDON_NO_CHROMIUM:-}" ] && [ ! -x /usr/bin/chromium ] && [ "$(id -u)" = 0 ] \
   && command -v apt-get >/dev/null 2>&1; then
  chromium_log=$(mktemp /tmp/poseidon-chromium-install.XXXXXX.log)
  echo "installing chromium (Debian package) for the report's browser test; log: $chromium_log" >&2
  if DEBIAN_FRONTEND=noninteractive apt-get update -q >"$chromium_log" 2>&1 \
     && DEBIAN_FRONTEND=noninteractive apt-get install -y -q --no-install-recommends chromium fonts-liberation \
        >>"$chromium_log" 2>&1; then
    echo "chromium installed: $(/usr/bin/chromium --version 2>/dev/null || echo '/usr/bin/chromium')" >&2
  else
    echo "chromium could not be installed (see $chromium_log); the report's browser test will skip" >&2
  fi
fi
echo "PoseidonSLAM installed in $(pwd)/.venv" >&2
