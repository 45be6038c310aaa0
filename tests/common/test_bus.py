"""The bus end to end: player -> Zenoh -> services -> recorder, across processes and in one."""
import json
import os
import subprocess
import sys
import time

import pytest

from common.bus import Bus, open_hub, open_local_session
from common.mcap_io import read_messages
from launcher.run import RunFailed, run_distributed, run_embedded
from services.player.player import Player
from system.config import PoseidonConfig
from tests.common.recordings import KEYS6, payloads_by_key, six_stream_recording
from tests.conftest import REPO

pytestmark = pytest.mark.timeout(300)


@pytest.fixture(scope="module")
def big_recording(tmp_path_factory):
    path = tmp_path_factory.mktemp("rec") / "six.mcap"
    counts = six_stream_recording(path, 10_000)
    return path, counts


def _free_port():
    import socket
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.parametrize("mode", ["distributed", "embedded"])
def test_round_trip_every_message_byte_for_byte(big_recording, tmp_path, mode):
    src, counts = big_recording
    assert sum(counts.values()) >= 10_000 and len(counts) == 6 and counts["camera/image_raw"] > 100
    out = tmp_path / f"out_{mode}.mcap"
    runner = run_distributed if mode == "distributed" else run_embedded
    result = runner(PoseidonConfig(), src, out, services=[], progress=False, timeout_s=240)
    assert result.recording["counts"] == counts
    sent, got = payloads_by_key(src), payloads_by_key(out)
    assert set(got) == set(KEYS6)
    for key in KEYS6:
        assert got[key] == sent[key], f"{key}: payloads or order differ"


def test_slow_subscriber_loses_nothing(tmp_path):
    """A consumer 2 ms/message, far slower than the player: flow control, not loss."""
    src = tmp_path / "small.mcap"
    counts = six_stream_recording(src, 2500, image_every=10)
    cfg = PoseidonConfig()
    cfg.bus.flow_window_ms = 200
    cfg.service_classes = {"slow_echo": "tests.common.nodes:SlowEcho"}
    result = run_distributed(cfg, src, tmp_path / "slow.mcap", services=["slow_echo"], progress=False,
                             timeout_s=240)
    assert result.recording["counts"]["echo/depth"] == counts["depth_sensor"]
    assert result.services["slow_echo"]["counters"]["images"] == counts["camera/image_raw"]
    echoed = [m.message().depth for m in read_messages(tmp_path / "slow.mcap", keys=["echo/depth"])]
    sent = [m.message().depth for m in read_messages(src, keys=["depth_sensor"])]
    assert echoed == sent


def test_services_may_start_before_the_hub(tmp_path):
    src = tmp_path / "small.mcap"
    counts = six_stream_recording(src, 400, image_every=10)
    endpoint = f"tcp/127.0.0.1:{_free_port()}"
    out = tmp_path / "before.mcap"
    expect = ",".join(sorted(counts))
    env = dict(os.environ, PYTHONPATH=str(REPO))
    rec = subprocess.Popen([sys.executable, "-m", "launcher.cli", "service", "recorder", "--connect", endpoint,
                            "--out", str(out), "--expect", expect, "--stats", str(tmp_path / "rec.json")],
                           cwd=REPO, env=env)
    try:
        time.sleep(1.5)  # the recorder is up and retrying; no hub yet
        assert rec.poll() is None
        hub = open_hub(endpoint)
        bus = Bus(connect=[endpoint])
        try:
            Player(bus, src, wait_for=["recorder"], progress=False, startup_timeout_s=30,
                   drain_timeout_s=60).run()
        finally:
            bus.close()
        assert rec.wait(timeout=60) == 0
        hub.close()
    finally:
        if rec.poll() is None:
            rec.kill()
    assert json.loads((tmp_path / "rec.json").read_text())["recorded"] == counts
    assert payloads_by_key(out) == payloads_by_key(src)


def test_a_client_is_back_within_a_second_of_its_hub(tmp_path):
    """The hub goes away for 3.3 s.  Zenoh's default retry would next try at 7 s (1, 2, 4 s
    apart) and leave the client silent for 3.7 s after the hub is back; ours retries at most
    every second."""
    endpoint = f"tcp/127.0.0.1:{_free_port()}"
    hub = open_hub(endpoint)
    sender = Bus(connect=[endpoint])
    hub.close()
    time.sleep(3.3)
    hub = open_hub(endpoint)
    back = time.monotonic()
    receiver = Bus(connect=[endpoint])
    arrivals: list[float] = []
    receiver.subscribe_callback("probe", lambda _k, _d: arrivals.append(time.monotonic()))
    try:
        while not arrivals and time.monotonic() - back < 10:
            sender.session.put(sender.full_key("probe"), b"1")
            time.sleep(0.02)
    finally:
        receiver.close()
        sender.close()
        hub.close()
    assert arrivals and arrivals[0] - back < 1.5


def test_failing_service_is_named_and_recording_kept(tmp_path):
    src = tmp_path / "small.mcap"
    six_stream_recording(src, 600, image_every=20)
    out = tmp_path / "fail.mcap"
    cfg = {"service_classes": {"boom": "tests.common.nodes:Boom"}}
    cfg_file = tmp_path / "cfg.yaml"
    cfg_file.write_text(json.dumps(cfg))
    proc = subprocess.run([sys.executable, "-m", "launcher.cli", "run", "--input", str(src), "--out", str(out),
                           "--config", str(cfg_file), "--services", "boom", "--json"], cwd=REPO,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 3, proc.stderr
    assert "service 'boom' failed" in proc.stderr
    assert "deliberate failure at seq 50" in proc.stderr
    partial = tmp_path / "fail.partial.mcap"
    assert not out.exists() and len(list(read_messages(partial))) > 0
    assert str(partial) in proc.stderr


def test_failing_service_embedded_raises_with_its_name(tmp_path):
    src = tmp_path / "small.mcap"
    six_stream_recording(src, 600, image_every=20)
    cfg = PoseidonConfig(service_classes={"boom": "tests.common.nodes:Boom"})
    with pytest.raises(RunFailed) as err:
        run_embedded(cfg, src, tmp_path / "fail.mcap", services=["boom"], progress=False, timeout_s=60)
    assert err.value.service == "boom"


def test_invalid_messages_are_skipped_counted_and_logged(caplog):
    """A message failing validation is logged with its key and seq, counted, and skipped."""
    import threading

    from common.codec import encode
    from common.messages import Depth, Header
    from common.runtime import NodeRunner
    from tests.common.nodes import SlowEcho

    session = open_local_session()
    bus = Bus(session=session)
    runner = NodeRunner(SlowEcho(PoseidonConfig()), bus)
    result = {}
    t = threading.Thread(target=lambda: result.setdefault("stats", runner.run()))
    t.start()
    bus.wait_alive(["slow_echo"], 10)
    depth, camera = bus.publisher("depth_sensor"), bus.publisher("camera/image_raw")
    good = Depth(header=Header(seq=0, stamp=10), depth=1.0)
    bad = encode(Depth(header=Header(seq=1, stamp=20), depth=2.0)).replace(b"depth\xcb", b"width\xcb")
    name = Depth.type_name.encode()
    camera.send_eos()
    depth.send(good)
    depth.send_raw(b"D" + bytes([len(name)]) + name + bad)
    depth.send_raw(b"Q not a frame")
    depth.send(Depth(header=Header(seq=3, stamp=40), depth=4.0))
    depth.send_eos()
    t.join(timeout=20)
    bus.close()
    session.close()
    stats = result["stats"]
    assert stats.invalid == {"depth_sensor": 2}
    assert stats.published == {"echo/depth": 2}
    messages = " ".join(r.getMessage() for r in caplog.records)
    assert "invalid message on depth_sensor seq 1" in messages
    assert "bad frame on depth_sensor" in messages


def test_run_rejects_unreadable_input_and_bad_config(tmp_path):
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"\x89MCAP0\r\n" + b"\x00" * 40)
    proc = subprocess.run([sys.executable, "-m", "launcher.cli", "run", "--input", str(junk), "--out",
                           str(tmp_path / "o.mcap")], cwd=REPO, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and "junk.mcap" in proc.stderr and "byte" in proc.stderr
    src = tmp_path / "small.mcap"
    six_stream_recording(src, 50)
    proc = subprocess.run([sys.executable, "-m", "launcher.cli", "run", "--input", str(src), "--out",
                           str(tmp_path / "o.mcap"), "--set", "htm.sp.num_active_columns=lots"],
                          cwd=REPO, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and "htm.sp.num_active_columns" in proc.stderr


def test_heartbeat_watermarks_only_keys_that_were_silent():
    """A data frame stamped t promises W >= t, so a key with data every 50 ms gets no separate
    watermark from a 100-ms heartbeat; a key silent for 100 ms or more gets one."""
    import queue

    from common.codec import decode_frame
    from common.messages import Depth, Header

    session = open_local_session()
    bus = Bus(session=session)
    sink: queue.SimpleQueue = queue.SimpleQueue()
    bus.subscribe("depth_sensor", sink)
    bus.subscribe("dvl_linkquest", sink)
    time.sleep(0.3)
    busy, quiet = bus.publisher("depth_sensor"), bus.publisher("dvl_linkquest")
    ms = 1_000_000
    for k in range(20):  # 0 .. 950 ms: depth data every 50 ms, heartbeat every 100 ms
        t = k * 50 * ms
        busy.send(Depth(header=Header(seq=k, stamp=t), depth=1.0))
        if k % 2 == 0:
            busy.heartbeat(t, 100 * ms)
            quiet.heartbeat(t, 100 * ms)
    busy.heartbeat(1200 * ms, 100 * ms)  # silent since 950 ms: a watermark
    deadline = time.monotonic() + 10
    frames: dict[str, list] = {"depth_sensor": [], "dvl_linkquest": []}
    while sum(len(v) for v in frames.values()) < 20 + 1 + 10 and time.monotonic() < deadline:
        try:
            key, data = sink.get(timeout=0.5)
        except queue.Empty:
            continue
        frames[key].append(decode_frame(data))
    bus.close()
    session.close()
    depth_kinds = [f.kind for f in frames["depth_sensor"]]
    assert depth_kinds.count("data") == 20 and depth_kinds.count("watermark") == 1
    assert frames["depth_sensor"][-1].kind == "watermark" and frames["depth_sensor"][-1].stamp == 1200 * ms
    assert [f.stamp for f in frames["dvl_linkquest"]] == [t * 100 * ms for t in range(10)]


def test_a_service_says_it_is_alive_only_after_its_warm_up():
    import threading
    import time

    from common.runtime import NodeRunner
    from tests.common.nodes import SlowWarmUp

    session = open_local_session()
    bus = Bus(session=session)
    node = SlowWarmUp(PoseidonConfig())
    runner = NodeRunner(node, bus)
    t = threading.Thread(target=runner.run)
    t.start()
    bus.wait_alive(["slow_warm_up"], 10)
    alive_at = time.monotonic()
    for key in ("depth_sensor", "camera/image_raw"):
        bus.publisher(key).send_eos()
    t.join(timeout=20)
    bus.close()
    session.close()
    assert node.warmed_at <= alive_at
