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
.venv/bin/python -m pip install --quiet --no-compile "torch==2.13.0"
.venv/bin/python -m pip install --quiet --no-compile -e ".[dev,secure]"
# Byte-compile the installed packages and ours once, on all cores, leaving out test folders.
# Python writes no .pyc on import where PYTHONDONTWRITEBYTECODE is set (CI machines, many
# containers): every process would compile what it imports again, torch alone 2-3 s per
# process start, in each service and each restart. Measured: import torch 4.2-5.0 s -> 2.0-2.4 s;
# this step takes about 35 s on 2 cores.
site=$(.venv/bin/python -c "import sysconfig; print(sysconfig.get_path('purelib'))")
.venv/bin/python -m compileall -q -j 0 -x '/(tests?|testing)/' "$site" common services system launcher eval \
  missions products
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
# Optional: ROS 1 from the system packages (Debian ros-core), for the live bridge
# (`poseidon bridge ros1`, `poseidon run --live ros1`) and its tests (tests/bridge_ros1).
# Same rules as Chromium: root with apt-get, only when roscore (or the diagnostic messages that
# `rostopic echo /diagnostics` needs) is missing, a failure leaves the bridge's live tests
# skipping with the reason. POSEIDON_NO_ROS1=1 leaves it out. The venv's python finds rospy by
# appending /usr/lib/python3/dist-packages to sys.path at run time
# (services/bridge_ros1/ros_io.py); nothing is written into the venv.
if [ -z "${POSEIDON_NO_ROS1:-}" ] && { ! command -v roscore >/dev/null 2>&1 \
     || [ ! -d /usr/lib/python3/dist-packages/diagnostic_msgs ]; } && [ "$(id -u)" = 0 ] \
   && command -v apt-get >/dev/null 2>&1; then
  ros_log=$(mktemp /tmp/poseidon-ros1-install.XXXXXX.log)
  echo "installing ROS 1 (Debian ros-core and message packages) for the live bridge; log: $ros_log" >&2
  if DEBIAN_FRONTEND=noninteractive apt-get update -q >"$ros_log" 2>&1 \
     && DEBIAN_FRONTEND=noninteractive apt-get install -y -q ros-core python3-sensor-msgs python3-nav-msgs \
        python3-geometry-msgs python3-visualization-msgs python3-std-msgs python3-diagnostic-msgs \
        >>"$ros_log" 2>&1; then
    echo "ROS 1 installed: $(command -v roscore)" >&2
  else
    echo "ROS 1 could not be installed (see $ros_log); the bridge's live tests will skip" >&2
  fi
fi
# Optional: Survex from the system packages (Debian survex: cavern, survexport), for the test
# that processes `poseidon export --survex` output (tests/products/test_map_exports.py). Same
# rules as Chromium: root with apt-get, only when cavern is missing, a failure leaves that test
# skipping with the reason. POSEIDON_NO_SURVEX=1 leaves it out.
if [ -z "${POSEIDON_NO_SURVEX:-}" ] && ! command -v cavern >/dev/null 2>&1 && [ "$(id -u)" = 0 ] \
   && command -v apt-get >/dev/null 2>&1; then
  survex_log=$(mktemp /tmp/poseidon-survex-install.XXXXXX.log)
  echo "installing survex (Debian package) for the Survex export's test; log: $survex_log" >&2
  if DEBIAN_FRONTEND=noninteractive apt-get update -q >"$survex_log" 2>&1 \
     && DEBIAN_FRONTEND=noninteractive apt-get install -y -q --no-install-recommends survex >>"$survex_log" 2>&1; then
    echo "survex installed: $(cavern --version 2>/dev/null | head -n 1 || command -v cavern)" >&2
  else
    echo "survex could not be installed (see $survex_log); the Survex export's test will skip" >&2
  fi
fi
echo "PoseidonSLAM installed in $(pwd)/.venv" >&2
