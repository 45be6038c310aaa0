"""The console of a run shows warnings, progress and results; the full log is in a file beside
the run's output (launcher/logs.py), with the service that wrote each line."""
import logging
import subprocess
import sys

import pytest

from launcher import logs
from missions.sim.cli import main as sim_main
from tests.conftest import REPO

pytestmark = pytest.mark.timeout(600)


@pytest.fixture(scope="module")
def mission(tmp_path_factory):
    path = tmp_path_factory.mktemp("mission") / "cave.mcap"
    assert sim_main(["--minutes", "0.2", "--seed", "3", "--out", str(path), "--no-progress"]) == 0
    return path


def _poseidon(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "launcher.cli", *args], cwd=REPO, capture_output=True, text=True,
                          timeout=500)


def _info_lines(text: str) -> list[str]:
    return [line for line in text.splitlines() if line.startswith("INFO") or " INFO " in line]


@pytest.mark.parametrize("embedded", [True, False], ids=["embedded", "distributed"])
def test_a_runs_console_has_no_info_lines_and_its_log_file_has_every_services_lines(mission, tmp_path, embedded):
    out = tmp_path / "run.mcap"
    args = ["run", "--input", str(mission), "--out", str(out), "--services", "robot_state",
            "--set", "player.replay=consumed"]  # the player says at INFO which keys it leaves out
    done = _poseidon(*args, *(["--embedded"] if embedded else []))
    assert done.returncode == 0, done.stderr
    assert not _info_lines(done.stdout + done.stderr), done.stdout + done.stderr
    log = out.with_suffix(".log")
    assert done.stdout.splitlines()[-1] == f"log: {log}"
    text = log.read_text()
    assert "INFO [run] services.player.player: player.replay consumed: not replayed" in text
    assert "DEBUG [robot_state] common.runtime: robot_state: warmed up" in text   # a service's own line
    if not embedded:
        assert "[recorder]" in text and "[player]" in text   # the service processes appended to it


def test_verbose_puts_info_on_the_console_too(mission, tmp_path):
    out = tmp_path / "run.mcap"
    done = _poseidon("run", "--embedded", "--verbose", "--input", str(mission), "--out", str(out),
                     "--services", "robot_state", "--set", "player.replay=consumed", "--json")
    assert done.returncode == 0, done.stderr
    assert any("player.replay consumed" in line for line in _info_lines(done.stderr)), done.stderr
    assert '"log": "' + str(out.with_suffix(".log")) + '"' in done.stdout


def test_setup_levels_the_console_and_the_file_and_replaces_an_earlier_setup(tmp_path):
    root = logging.getLogger()
    before = list(root.handlers), root.level
    try:
        logs.setup("WARNING", tmp_path / "a.log", service="run")
        assert logs.console_level() == "WARNING" and logs.log_file() == tmp_path / "a.log"
        assert logs.child_args() == ["--log-level", "WARNING", "--log-file", str(tmp_path / "a.log")]
        logging.getLogger("services.x").debug("routine")
        logging.getLogger("numba.core").debug("not ours: not in the file below INFO")
        logs.setup("INFO", None)
        assert logs.log_file() is None and logs.child_args() == ["--log-level", "INFO"]
        assert sum(getattr(h, "_poseidon", False) for h in root.handlers) == 1
        text = (tmp_path / "a.log").read_text()
        assert "DEBUG [run] services.x: routine" in text and "numba" not in text
        assert logs.console_level_of(None, False) == logging.WARNING
        assert logs.console_level_of(None, True) == logging.INFO
        assert logs.console_level_of("debug", False) == logging.DEBUG
        with pytest.raises(ValueError, match="unknown log level"):
            logs.console_level_of("LOUD", False)
    finally:
        for h in list(root.handlers):
            if getattr(h, "_poseidon", False):
                root.removeHandler(h)
                h.close()
        for h in before[0]:
            if h not in root.handlers:
                root.addHandler(h)
        root.setLevel(before[1])
        for name in logs.PACKAGES:
            logging.getLogger(name).setLevel(logging.NOTSET)
