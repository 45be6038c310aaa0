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
.venv/bin/python -m pip install --quiet -e ".[dev]"
echo "PoseidonSLAM installed in $(pwd)/.venv" >&2
