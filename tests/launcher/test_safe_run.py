"""Safe outputs of `poseidon run`; bad settings end the run at once."""
import hashlib
import os
import subprocess
import sys
import threading
import time

import pytest

from common.config import ConfigError
from common.mcap_io import read_messages
from launcher.run import RunFailed, ServiceStartError, run_embedded
from system.config import PoseidonConfig, load_config
from tests.common.recordings import six_stream_recording
from tests.conftest import REPO

pytestmark = pytest.mark.timeout(180)


def _sha(p):
    return hashlib.sha256(p.read_bytes()).hexdigest()


def _run(*args, timeout=120):
    return subprocess.run([sys.executable, "-m", "launcher.cli", "run", *map(str, args)], cwd=REPO,
                          capture_output=True, text=True, timeout=timeout)


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    path = tmp_path_factory.mktemp("safe") / "small.mcap"
    six_stream_recording(path, 400, image_every=10)
    return path


def test_out_equal_to_input_is_refused(small, tmp_path):
    before = _sha(small)
    link = tmp_path / "alias.mcap"
    os.link(small, link)  # another name of the same file
    for out in (small, small.parent / ".." / small.parent.name / small.name, link):
        proc = _run("--input", small, "--out", out, "--services", "none")
        assert proc.returncode == 2, proc.stderr
        assert "would overwrite the input recording" in proc.stderr
    assert _sha(small) == before


def test_bad_configuration_never_touches_an_existing_output(small, tmp_path):
    out = tmp_path / "run.mcap"
    out.write_bytes(b"an earlier run that must survive")
    for setting in ("robot_state.axis_remap=xxx", "htm.sp.num_active_columns=5000"):
        proc = _run("--input", small, "--out", out, "--set", setting)
        assert proc.returncode == 2, proc.stderr
        assert setting.split("=")[0] in proc.stderr
    assert out.read_bytes() == b"an earlier run that must survive"
    assert not (tmp_path / "run.partial.mcap").exists()


@pytest.mark.parametrize("embedded", [False, True])
def test_output_moves_into_place_only_on_success(small, tmp_path, embedded):
    out = tmp_path / "run.mcap"
    out.write_bytes(b"old")
    cfg = tmp_path / "cfg.yaml"
    cfg.write_text('{"service_classes": {"boom": "tests.common.nodes:Boom"}}')
    big = tmp_path / "big.mcap"
    six_stream_recording(big, 800, image_every=20)
    mode = ["--embedded"] if embedded else []
    proc = _run("--input", big, "--out", out, "--config", cfg, "--services", "boom", *mode)
    assert proc.returncode == 3 and "service 'boom' failed" in proc.stderr
    partial = tmp_path / "run.partial.mcap"
    assert out.read_bytes() == b"old"  # untouched
    assert len(list(read_messages(partial))) > 0 and str(partial) in proc.stderr
    proc = _run("--input", small, "--out", out, "--services", "none", *mode)
    assert proc.returncode == 0, proc.stderr
    assert not partial.exists() and len(list(read_messages(out, strict=True))) == 400


def test_cross_field_configuration_errors():
    for setting, text in (("htm.sp.num_active_columns=5000", "htm.sp.num_active_columns (5000) must be <= htm.sp.columns"),
                          ("htm.tm.min_threshold=9", "htm.tm.min_threshold (9) must be <= htm.tm.activation_threshold"),
                          ("robot_state.axis_remap=xxx", "permutation of xyz"),
                          ("robot_state.axis_sign_z=0.5", "axis_sign_z must be 1 or -1"),
                          ("posecells.number_of_neurons=[15,15,0,8]", "posecells.number_of_neurons.2"),
                          ("posecells.number_of_neurons=[4000,4000,4000,8]", "posecells.number_of_neurons.0"),
                          ("posecells.number_of_neurons=[500,500,500,8]", "at most 50 million"),
                          ("posecells.distance_between_neurons=[0.1,-1,0.1]", "distance_between_neurons.1"),
                          ("posecells.distance_between_neurons=[0.1,.nan,0.1]", "distance_between_neurons.1"),
                          ("posecells.top_k=100000", "top_k (100000) must be <="),
                          ("vpr_guard.vpr_min_rep=30", "vpr_guard.vpr_min_rep (30) must be <= vpr_guard.vpr_window")):
        with pytest.raises(ConfigError) as err:
            load_config(overrides=[setting])
        assert text in str(err.value), (setting, str(err.value))


def test_embedded_bad_setting_exits_at_once(small, tmp_path):
    t0 = time.monotonic()
    proc = _run("--embedded", "--input", small, "--out", tmp_path / "o.mcap", "--set",
                "htm.sp.num_active_columns=5000", "--timeout", "20", timeout=60)
    assert proc.returncode == 2 and "htm.sp.num_active_columns" in proc.stderr
    assert time.monotonic() - t0 < 30


def _poseidon_threads():
    return [t.name for t in threading.enumerate() if t.name.startswith("poseidon-")]


def test_embedded_service_that_cannot_start_is_named_and_leaves_nothing(small, tmp_path):
    cfg = PoseidonConfig(service_classes={"cannot_start": "tests.common.nodes:CannotStart"})
    with pytest.raises(ServiceStartError, match="service 'cannot_start' cannot start"):
        run_embedded(cfg, small, tmp_path / "o.mcap", services=["cannot_start"], progress=False, timeout_s=10)
    assert not (tmp_path / "o.partial.mcap").exists() and not _poseidon_threads()


def test_embedded_timeout_fires_and_stops_every_thread(small, tmp_path):
    cfg = PoseidonConfig(service_classes={"stall": "tests.common.nodes:Stall"})
    t0 = time.monotonic()
    with pytest.raises(RunFailed, match="did not finish within 2 s"):
        run_embedded(cfg, small, tmp_path / "o.mcap", services=["stall"], progress=False, timeout_s=2)
    assert time.monotonic() - t0 < 15
    assert not _poseidon_threads()
    assert len(list(read_messages(tmp_path / "o.partial.mcap"))) > 0
