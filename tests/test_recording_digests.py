"""The recordings a short simulated mission produces are byte-identical, key by key, to the
stored digests: a refactoring that changes no algorithm must not change one byte a service
publishes.  A change that is meant to alter outputs updates ``tests/data/recording_digests.json``
(``poseidon info RUN.mcap --digests --json``) in the same commit, so the diff shows which keys moved.

The bytes depend on the processor as well as on the code, so the file keeps one set of digests
per numeric platform (:func:`numeric_platform`): numpy's sin, cos and exp round differently in
their AVX-512 kernels than in their AVX2 ones (the simulator's trajectory, IMU and DVL move in
the last bits), and the encoder's backbone runs in bf16 only where the processor has AVX512-BF16
or AMX (``encoder.precision``).  On a platform with no stored set the mission is run twice and
the two recordings must agree on every key (the run is deterministic there); the failure message
of a stored platform names the keys that moved.
"""
from __future__ import annotations

import json
import platform
import warnings
from pathlib import Path

import pytest
from numpy._core._multiarray_umath import __cpu_features__ as NUMPY_CPU_FEATURES

from common.mcap_io import key_digests
from launcher.cli import main as poseidon
from missions.sim.cli import main as sim_main

GOLDEN = Path(__file__).resolve().parent / "data" / "recording_digests.json"
#: numpy's dispatch targets, widest first: the first one the processor has is the one its math runs
_SIMD = ("AVX512_SKX", "AVX2", "SSE42", "ASIMD")


def numeric_platform() -> str:
    """``MACHINE-SIMD-PRECISION``, e.g. ``x86_64-AVX2-f32``: the machine, numpy's widest SIMD
    target in use, and ``bf16`` where the processor runs the encoder's bf16 (AVX512-BF16 or AMX)."""
    simd = next((t for t in _SIMD if NUMPY_CPU_FEATURES.get(t)), "baseline")
    cpuinfo = Path("/proc/cpuinfo")
    flags = set(cpuinfo.read_text().split()) if cpuinfo.exists() else set()
    precision = "bf16" if flags & {"avx512_bf16", "amx_bf16"} else "f32"
    return f"{platform.machine()}-{simd}-{precision}"


def _run_mission(tmp_path: Path, name: str) -> dict[str, dict[str, object]]:
    mission = tmp_path / "sim.mcap"
    if not mission.exists():
        assert sim_main(["--minutes", "1", "--seed", "23", "--out", str(mission), "--no-progress"]) == 0
    run = tmp_path / f"{name}.mcap"
    assert poseidon(["run", "--embedded", "--input", str(mission), "--out", str(run), "--rate", "0"]) == 0
    return key_digests(run)


def test_the_platform_names_numpys_simd_and_the_encoders_precision() -> None:
    name = numeric_platform()
    machine, simd, precision = name.rsplit("-", 2)
    assert machine == platform.machine()
    assert simd in (*_SIMD, "baseline") and precision in ("bf16", "f32")


@pytest.mark.slow
def test_a_one_minute_mission_publishes_the_stored_bytes_on_all_21_keys(tmp_path: Path) -> None:
    stored: dict[str, dict[str, dict[str, object]]] = json.loads(GOLDEN.read_text())
    here = numeric_platform()
    got = _run_mission(tmp_path, "run")
    assert len(got) == 21, f"the run recorded {len(got)} keys: {sorted(got)}"
    expected = stored.get(here)
    if expected is None:
        warnings.warn(f"no stored digests for {here} (stored: {', '.join(sorted(stored))}): the run is only "
                      f"checked against a second run; add its `poseidon info RUN.mcap --digests --json` "
                      f"under {here!r} in {GOLDEN.name}", stacklevel=1)
        expected = _run_mission(tmp_path, "again")
    assert sorted(got) == sorted(expected), "keys differ"
    moved = [f"{k}: {got[k]['messages']} messages (stored {expected[k]['messages']})"
             for k in expected if got[k] != expected[k]]
    assert not moved, f"streams differ from {GOLDEN.name} [{here}]:\n" + "\n".join(moved)
