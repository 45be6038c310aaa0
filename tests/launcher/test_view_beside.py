"""``poseidon run --view``: the view is started first and the run's services only once it is ready
(subscribed to the run's hub, serving its page); a view that ends or is never ready stops the run
before any service started, with a message naming it."""
from __future__ import annotations

import socket
import subprocess
import sys
from pathlib import Path

import pytest

from launcher.view_beside import ViewProcess, ViewStartError
from tests.common.recordings import six_stream_recording
from tests.conftest import REPO

pytestmark = pytest.mark.timeout(300)
CLI = [sys.executable, "-m", "launcher.cli"]


def _python(code: str, *args: str) -> list[str]:
    return [sys.executable, "-c", code, *args]


def test_wait_ready_returns_once_the_view_wrote_its_address(tmp_path: Path) -> None:
    ready = tmp_path / "ready"
    code = "import pathlib, sys, time; time.sleep(0.3); pathlib.Path(sys.argv[1]).write_text('http://h:1/\\n'); " \
           "time.sleep(60)"
    view = ViewProcess(_python(code, str(ready)), ready, "--view 1", 30.0)
    try:
        view.wait_ready()
        assert view.url == "http://h:1/" and view.proc.poll() is None
    finally:
        view.stop()
    assert view.proc.returncode is not None


def test_after_a_run_that_ended_well_the_view_is_asked_for_the_recording_s_final_state(tmp_path: Path) -> None:
    """SIGUSR1 (``poseidon view --final-recording``) before the linger; none after a failed run."""
    ready, asked = tmp_path / "ready", tmp_path / "asked"
    code = ("import pathlib, signal, sys, time; a = pathlib.Path(sys.argv[2]); "
            "signal.signal(signal.SIGUSR1, lambda *_: a.write_text(a.read_text() + 'final\\n' if a.exists() else 'final\\n')); "
            "pathlib.Path(sys.argv[1]).write_text('http://h:1/\\n'); time.sleep(60)")
    for final in (True, False):
        asked.unlink(missing_ok=True)
        view = ViewProcess(_python(code, str(ready), str(asked)), ready, "--view 1", 30.0)
        view.wait_ready()
        view.stop(linger_s=0.5, final=final)
        assert (asked.read_text() if asked.exists() else "") == ("final\n" if final else "")
        ready.unlink()


def test_a_view_that_ends_before_it_is_ready_is_named_with_its_exit_code(tmp_path: Path) -> None:
    view = ViewProcess(_python("raise SystemExit(2)"), tmp_path / "ready", "--view 8080", 30.0)
    with pytest.raises(ViewStartError, match=r"--view 8080: the view exited with code 2 before it served its page"):
        view.wait_ready()


def test_a_view_never_ready_is_stopped_after_the_timeout_and_named(tmp_path: Path) -> None:
    view = ViewProcess(_python("import time; time.sleep(60)"), tmp_path / "ready", "--foxglove 8765", 1.0)
    with pytest.raises(ViewStartError, match=r"--foxglove 8765: the view was not .* within 1 s of its start"):
        view.wait_ready()
    assert view.proc.poll() is not None  # stopped, not left behind


@pytest.mark.slow
@pytest.mark.parametrize("live", [True, False])
def test_a_view_that_cannot_serve_its_page_stops_the_run_before_any_service(tmp_path: Path, live: bool) -> None:
    src = tmp_path / "mission.mcap"
    six_stream_recording(src, 300, image_every=50)
    out = tmp_path / "run.mcap"
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        mode = ["--live", "mcap", "--rate", "2"] if live else []
        proc = subprocess.run([*CLI, "run", *mode, "--input", str(src), "--services", "robot_state", "--out", str(out),
                               "--view", str(port)], cwd=REPO, capture_output=True, text=True, timeout=240)
    assert proc.returncode == 2, proc.stderr[-3000:]
    assert f"cannot serve the page on 127.0.0.1:{port}" in proc.stderr  # the view's own message
    assert f"poseidon run: --view {port}: the view exited with code 2 before it served its page" in proc.stderr
    assert not out.exists() and not (tmp_path / "run.partial.mcap").exists()  # no recorder was started


@pytest.mark.slow
def test_the_services_of_a_live_run_start_once_the_view_is_ready(tmp_path: Path) -> None:
    src = tmp_path / "mission.mcap"
    six_stream_recording(src, 300, image_every=50)
    out = tmp_path / "run.mcap"
    proc = subprocess.run([*CLI, "run", "--live", "mcap", "--rate", "2", "--input", str(src), "--services",
                           "robot_state", "--out", str(out), "--view", "0", "--log-level", "INFO"],
                          cwd=REPO, capture_output=True, text=True, timeout=240)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert out.exists()
    announced = proc.stderr.index("poseidon view: tcp/127.0.0.1:")  # printed just before it says it is ready
    assert announced < proc.stderr.index("live run: live_player (services robot_state)")
