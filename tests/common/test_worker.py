"""The shared base of the player, the recorder and the services' runner (common.worker):
one abort stops every kind of worker, each saying why; a service that stops before the
end of its inputs aborts the run for the others."""
import threading
import time

import pytest

from common.mcap_io import RecordingWriter
from common.messages import Depth, Header
from system.config import PoseidonConfig
from system.services import WorkerSpec, build_worker

pytestmark = pytest.mark.timeout(60)


def _slow_recording(path, n=50):
    with RecordingWriter(path) as w:  # 5 s at real time
        for i in range(n):
            w.write("depth_sensor", Depth(header=Header(seq=i, stamp=10**18 + i * 100_000_000), depth=float(i)))
    return path


def _run_all(workers):
    results: dict = {}
    threads = [threading.Thread(target=lambda n=n, w=w: results.setdefault(n, w.run())) for n, w in workers.items()]
    for t in threads:
        t.start()
    return threads, results


def test_one_abort_stops_every_kind_of_worker_with_its_reason(tmp_path, bus):
    config = PoseidonConfig(service_classes={"slow_echo": "tests.common.nodes:SlowEcho"})
    config.player.rate = 1.0
    workers = {
        "recorder": build_worker("recorder", config, bus, WorkerSpec(out=tmp_path / "r.mcap", expect=["echo/depth"])),
        "slow_echo": build_worker("slow_echo", config, bus),
        "player": build_worker("player", config, bus, WorkerSpec(input=_slow_recording(tmp_path / "in.mcap"),
                                                                  wait_for=["recorder", "slow_echo"], progress=False)),
    }
    threads, results = _run_all(workers)
    time.sleep(1.5)
    bus.abort("operator stop")
    for t in threads:
        t.join(timeout=10)
    assert not any(t.is_alive() for t in threads)
    assert {n: st.aborted for n, st in results.items()} == dict.fromkeys(workers, "operator stop")
    assert 0 < results["player"].published["depth_sensor"] < 50


def test_a_service_stopped_early_aborts_the_run_naming_itself(tmp_path, bus):
    config = PoseidonConfig(service_classes={"slow_echo": "tests.common.nodes:SlowEcho"})
    config.player.rate = 1.0
    runner = build_worker("slow_echo", config, bus)
    player = build_worker("player", config, bus, WorkerSpec(input=_slow_recording(tmp_path / "in.mcap"),
                                                            wait_for=["slow_echo"], progress=False))
    threads, results = _run_all({"slow_echo": runner, "player": player})
    time.sleep(1.5)
    runner.stop()
    for t in threads:
        t.join(timeout=10)
    reason = "service slow_echo stopped before the end of its inputs"
    assert results["slow_echo"].aborted == reason and results["player"].aborted == reason
