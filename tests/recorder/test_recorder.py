"""The recorder: a sink on the shared worker base (common.worker.Sink).

It ends on end-of-stream of every expected key, writes what has already arrived when
stopped or aborted and closes a complete file, survives hostile frames, checkpoints when
supervised, a SIGKILL leaves every flushed chunk readable, and keys copied from the input
(player.replay copied) reach the file exactly once, restarted or not."""
import json
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from mcap.exceptions import McapError
from mcap.reader import make_reader

from common.bus import Bus, open_hub
from common.codec import encode_frame
from common.mcap_io import FileDigest, file_sha256, read_file_order, read_messages, read_metadata
from common.messages import Depth, Header
from common.ordering import END_OF_TIME
from common.resume import Supervision, load_checkpoint
from services.player.player import Player
from services.recorder.recorder import Recorder
from tests.common.recordings import HOSTILE, inconsistent_image, payloads_by_key, six_stream_recording
from tests.conftest import REPO

pytestmark = pytest.mark.timeout(180)
CLI = [sys.executable, "-m", "launcher.cli"]


def _free_endpoint():
    import socket
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


def _standard_reader_count(path: Path) -> int:
    with open(path, "rb") as f:
        return sum(1 for _ in make_reader(f).iter_messages())


def _depth(i: int, stamp_ns: int) -> Depth:
    return Depth(header=Header(seq=i, stamp=stamp_ns), depth=float(i))


def _start(rec: Recorder) -> tuple[threading.Thread, dict]:
    result: dict = {}
    t = threading.Thread(target=lambda: result.setdefault("stats", rec.run()))
    t.start()
    rec.bus.wait_alive([rec.name], 10)
    return t, result


def _wait_queued(rec: Recorder, n: int, timeout_s: float = 10) -> None:
    deadline = time.monotonic() + timeout_s
    while rec.queue.qsize() < n:
        assert time.monotonic() < deadline, f"{rec.queue.qsize()} of {n} frames arrived"
        time.sleep(0.01)


def test_end_of_stream_on_every_expected_key_ends_the_recording(tmp_path, bus):
    out = tmp_path / "r.mcap"
    watcher = bus.watch_progress()
    rec = Recorder(bus, out, expect=["depth_sensor", "dvl_linkquest"], metadata={"tool": "test"})
    t, result = _start(rec)
    depth, dvl = bus.publisher("depth_sensor"), bus.publisher("dvl_linkquest")
    for i in range(5):
        depth.send(_depth(i, 1000 + i))
    depth.send_eos()
    time.sleep(0.3)
    assert t.is_alive()  # dvl_linkquest has not ended
    dvl.send_eos()
    t.join(timeout=10)
    assert not t.is_alive()
    stats = result["stats"]
    assert stats.recorded == {"depth_sensor": 5} and sorted(stats.ended) == ["depth_sensor", "dvl_linkquest"]
    assert stats.aborted == ""
    assert _standard_reader_count(out) == 5  # closed with its summary
    deadline = time.monotonic() + 5
    while watcher.get("recorder") != END_OF_TIME and time.monotonic() < deadline:
        time.sleep(0.02)
    assert watcher.get("recorder") == END_OF_TIME  # the player learns that it finished


def test_a_stopped_recorder_writes_what_has_arrived_and_closes_a_complete_file(tmp_path, bus):
    out = tmp_path / "r.mcap"
    rec = Recorder(bus, out, expect=["depth_sensor"])
    pub = bus.publisher("depth_sensor")
    time.sleep(0.2)
    for i in range(200):
        pub.send(_depth(i, 1000 + i))
    _wait_queued(rec, 200)  # every frame queued, none handled: the recorder has not started
    rec.stop()
    stats = rec.run()
    assert stats.recorded == {"depth_sensor": 200}
    got = list(read_messages(out, strict=True))
    assert [r.stamp for r in got] == [1000 + i for i in range(200)]


def test_the_input_digest_is_written_at_the_end_and_a_cut_recording_still_names_its_run(tmp_path, bus):
    """A normal end writes the metadata again with the input's SHA-256 (readers take the last
    record); a stopped recorder does not wait for it and keeps the first record, configuration and
    all, with ``input_sha256`` empty."""
    src = tmp_path / "input.bin"
    src.write_bytes(bytes(range(256)) * 4096)
    out = tmp_path / "r.mcap"
    digest = FileDigest(src)
    rec = Recorder(bus, out, expect=["depth_sensor"], metadata={"tool": "test", "config": {"a": 1}},
                   input_digest=digest.result)
    t, _result = _start(rec)
    pub = bus.publisher("depth_sensor")
    for i in range(5):
        pub.send(_depth(i, 1000 + i))
    pub.send_eos()
    t.join(timeout=30)
    assert not t.is_alive()
    meta = read_metadata(out)["poseidon"]
    assert meta["input_sha256"] == file_sha256(src) and meta["tool"] == "test" and meta["config"] == '{"a": 1}'
    with open(out, "rb") as f:  # both records are in the file, the empty one first
        records = [dict(m.metadata) for m in make_reader(f).iter_metadata()]
    assert [m["input_sha256"] for m in records] == ["", file_sha256(src)]

    cut = tmp_path / "cut.mcap"
    asked: list[str] = []
    rec = Recorder(bus, cut, expect=["depth_sensor"], metadata={"tool": "test"},
                   input_digest=lambda: asked.append("digest") or "0" * 64)
    rec.stop()
    rec.run()
    assert read_metadata(cut)["poseidon"] == {"tool": "test", "input_sha256": ""} and asked == []


def test_an_abort_stops_the_recorder_and_the_file_holds_what_arrived(tmp_path, bus):
    out = tmp_path / "r.mcap"
    rec = Recorder(bus, out, expect=["depth_sensor"])
    t, result = _start(rec)
    pub = bus.publisher("depth_sensor")
    for i in range(10):
        pub.send(_depth(i, 1000 + i))
    time.sleep(0.3)
    bus.abort("service boom failed")
    t.join(timeout=10)
    assert not t.is_alive()
    stats = result["stats"]
    assert stats.aborted == "service boom failed"
    assert stats.recorded == {"depth_sensor": 10}
    assert _standard_reader_count(out) == 10


def test_recorder_survives_hostile_frames(tmp_path, bus):
    rec = Recorder(bus, tmp_path / "r.mcap", expect=["depth_sensor"])
    t, result = _start(rec)
    pub = bus.publisher("depth_sensor")
    other = bus.publisher("camera/image_raw")
    for frame in HOSTILE + [encode_frame(Depth(header=Header(seq=0, stamp=10), depth=1.0))]:
        pub.send_raw(frame)
    name = b"poseidon_msgs/Depth"
    for payload in (b"\x81\xa6header\x81\xa5stamp\xff", b"\x81\xa6header\x82\xa5stamp\xcf" + b"\xff" * 8 + b"\xa3seq\x00",
                    b"\x80", b"\xc1"):
        pub.send_raw(b"D" + bytes([len(name)]) + name + payload)
    other.send(Depth(header=Header(seq=0, stamp=12), depth=1.0))
    other.send_raw(encode_frame(inconsistent_image(Header(seq=1, stamp=13))))  # another type on the same key
    pub.send_eos()
    t.join(timeout=30)
    stats = result["stats"]
    assert stats.recorded == {"depth_sensor": 1, "camera/image_raw": 1}
    assert stats.invalid == {"depth_sensor": len(HOSTILE) + 4, "camera/image_raw": 1}
    assert len(list(read_messages(tmp_path / "r.mcap", strict=True))) == 2


def test_a_supervised_recorder_checkpoints_what_its_file_holds(tmp_path, bus):
    """Every 1 s of event time: the file synced, the counts and next transport indices saved."""
    sup = Supervision(tmp_path / "state", {"depth_sensor": ["recorder"]}, recorder_checkpoint_interval_ns=10**9)
    reports: list[bytes] = []
    bus.subscribe_callback("@ckpt/recorder", lambda _key, payload: reports.append(payload))
    rec = Recorder(bus, tmp_path / "r.mcap", expect=["depth_sensor"], supervision=sup)
    t, result = _start(rec)
    pub = bus.publisher("depth_sensor", retain=True)  # numbered frames, as supervised publishers send
    for i in range(25):  # 0 .. 2.4 s of event time
        pub.send(_depth(i, i * 100_000_000))
    pub.send_eos()
    t.join(timeout=10)
    stats = result["stats"]
    assert stats.recorded == {"depth_sensor": 25} and stats.checkpoints == 2
    state = load_checkpoint(tmp_path / "state" / "recorder.ckpt")
    assert state["counts"] == {"depth_sensor": 21} and state["positions"] == {"depth_sensor": 21}
    deadline = time.monotonic() + 5
    while len(reports) < 2 and time.monotonic() < deadline:  # the publishers learn it (they may forget)
        time.sleep(0.02)
    assert [json.loads(r) for r in reports] == [{"depth_sensor": 11}, {"depth_sensor": 21}]


def test_the_recorder_receives_while_the_disk_syncs_and_reports_only_what_is_synced(tmp_path, bus):
    """The fsync runs on the recorder's sync thread: with the disk held, frames are still
    recorded, and the checkpoint is neither saved nor reported until its sync is done."""
    sup = Supervision(tmp_path / "state", {"depth_sensor": ["recorder"]}, recorder_checkpoint_interval_ns=10**9)
    reports: list[bytes] = []
    bus.subscribe_callback("@ckpt/recorder", lambda _key, payload: reports.append(payload))
    rec = Recorder(bus, tmp_path / "r.mcap", expect=["depth_sensor"], supervision=sup, flush_interval_s=3600)
    t, result = _start(rec)
    disk, syncing = threading.Event(), threading.Event()
    real_fsync = rec.writer.fsync

    def held_fsync() -> None:
        syncing.set()
        assert disk.wait(30), "the test never released the disk"
        real_fsync()
    rec.writer.fsync = held_fsync
    pub = bus.publisher("depth_sensor", retain=True)
    for i in range(12):  # 0 .. 1.1 s of event time: the checkpoint at 1.0 s starts a sync
        pub.send(_depth(i, i * 100_000_000))
    assert syncing.wait(10)
    for i in range(12, 16):  # recorded while the disk is held
        pub.send(_depth(i, i * 100_000_000))
    deadline = time.monotonic() + 10
    while rec.stats.recorded.get("depth_sensor", 0) < 16:
        assert time.monotonic() < deadline, f"{rec.stats.recorded} recorded while the disk was held"
        time.sleep(0.01)
    time.sleep(0.2)
    assert reports == [] and not (tmp_path / "state" / "recorder.ckpt").exists()
    disk.set()
    deadline = time.monotonic() + 10
    while not reports:
        assert time.monotonic() < deadline, "no checkpoint reported after the sync"
        time.sleep(0.01)
    assert json.loads(reports[0]) == {"depth_sensor": 11}  # the frames before the chunk's end
    assert load_checkpoint(tmp_path / "state" / "recorder.ckpt")["counts"] == {"depth_sensor": 11}
    pub.send_eos()
    t.join(timeout=10)
    assert result["stats"].recorded == {"depth_sensor": 16} and result["stats"].checkpoints == 1


def test_recorder_killed_with_sigkill_keeps_flushed_chunks(tmp_path):
    src = tmp_path / "imgs.mcap"
    six_stream_recording(src, 1500, image_every=2)
    endpoint = _free_endpoint()
    hub = open_hub(endpoint)
    out = tmp_path / "killed.mcap"
    rec = subprocess.Popen(CLI + ["service", "recorder", "--connect", endpoint, "--out", str(out),
                                  "--set", "recorder.chunk_size=262144"], cwd=REPO)
    bus = Bus(connect=[endpoint])
    try:
        Player(bus, src, wait_for=["recorder"], progress=False, startup_timeout_s=30).run()
        time.sleep(2.0)  # > the recorder's flush interval
        rec.send_signal(signal.SIGKILL)
        rec.wait(timeout=10)
    finally:
        bus.close()
        hub.close()
    sent: dict[str, list[bytes]] = {}
    for r in read_messages(src):
        sent.setdefault(r.key, []).append(r.payload)
    recovered = list(read_messages(out))  # no summary: read up to the last complete chunk
    total = sum(len(v) for v in sent.values())
    assert len(recovered) >= total * 0.9, (len(recovered), total)
    for r in recovered:
        assert r.payload in sent[r.key]
    with pytest.raises(McapError):  # no summary: the standard reader cannot open it as it is
        _standard_reader_count(out)
    info = subprocess.run(CLI + ["info", str(out)], cwd=REPO, capture_output=True, text=True, timeout=60)
    assert info.returncode == 1 and "--recover" in info.stderr
    fixed = tmp_path / "fixed.mcap"
    info = subprocess.run(CLI + ["info", str(out), "--recover", str(fixed)], cwd=REPO, capture_output=True,
                          text=True, timeout=60)
    assert info.returncode == 0, info.stderr
    assert _standard_reader_count(fixed) == len(recovered)
    assert [r.payload for r in read_messages(fixed, strict=True)] == [r.payload for r in recovered]
    assert subprocess.run(CLI + ["info", str(fixed)], cwd=REPO, capture_output=True, timeout=60).returncode == 0


def _replay_key(bus, src: Path, key: str, until_ns: int | None = None, eos: bool = True) -> None:
    """Publish ``key`` of ``src`` (numbered frames, as supervised publishers send) and, unless
    stopped at ``until_ns``, its end-of-stream."""
    pub = bus.publisher(key, retain=True)
    for m in read_messages(src, keys=[key]):
        if until_ns is not None and m.stamp > until_ns:
            return
        pub.send_data(m.type_name, m.payload, m.stamp)
    if eos:
        pub.send_eos()


def test_copied_keys_come_from_the_input_in_event_time_order_and_the_file_equals_the_input(tmp_path, bus):
    """player.replay copied: depth_sensor over the bus, the other five keys copied from the input;
    each copied message is written once the received event time passed its stamp (so the file's
    order interleaves the two), the rest at the end; the file holds the input byte for byte."""
    src = tmp_path / "in.mcap"
    counts = six_stream_recording(src, 400, image_every=10)
    copied = sorted(k for k in counts if k != "depth_sensor")
    rec = Recorder(bus, tmp_path / "r.mcap", expect=["depth_sensor"], copy_from=src, copy_keys=copied)
    t, result = _start(rec)
    _replay_key(bus, src, "depth_sensor")
    t.join(timeout=20)
    assert result["stats"].recorded == counts
    got, want = payloads_by_key(tmp_path / "r.mcap"), payloads_by_key(src)
    assert got == want
    order = [m.key for m in read_file_order(tmp_path / "r.mcap")[0]]
    assert order.index("sonar_micron") < len(order) - counts["sonar_micron"]  # not all appended at the end
    with pytest.raises(ValueError, match="is the output recording itself"):
        Recorder(bus, src, copy_from=src, copy_keys=copied)


def test_a_restarted_recorder_continues_the_copied_keys_after_its_checkpoint(tmp_path, bus):
    """Stopped after its checkpoint at 1 s of event time and restarted: the final file holds every
    copied message exactly once (those up to the checkpoint kept from the first file)."""
    src = tmp_path / "in.mcap"
    counts = six_stream_recording(src, 600, image_every=10)
    copied = sorted(k for k in counts if k != "depth_sensor")
    t0 = next(read_messages(src)).stamp
    sup = Supervision(tmp_path / "state", {"depth_sensor": ["recorder"]}, recorder_checkpoint_interval_ns=10**9)
    out = tmp_path / "r.mcap"
    rec = Recorder(bus, out, expect=["depth_sensor"], supervision=sup, copy_from=src, copy_keys=copied)
    t, result = _start(rec)
    _replay_key(bus, src, "depth_sensor", until_ns=t0 + 1_500_000_000, eos=False)
    deadline = time.monotonic() + 10
    while result.get("stats") is None and rec.stats.checkpoints < 1:
        assert time.monotonic() < deadline, "no checkpoint within 10 s"
        time.sleep(0.02)
    time.sleep(0.3)
    rec.stop()
    t.join(timeout=10)
    state = load_checkpoint(tmp_path / "state" / "recorder.ckpt")
    assert 0 < state["counts"]["sonar_micron"] < counts["sonar_micron"]
    resumed = Recorder(bus, out, expect=["depth_sensor"], copy_from=src, copy_keys=copied,
                       supervision=Supervision(tmp_path / "state", {"depth_sensor": ["recorder"]},
                                               recorder_checkpoint_interval_ns=10**9, resume=True))
    t, result = _start(resumed)
    _replay_key(bus, src, "depth_sensor")  # the whole stream again: the gate drops what the file holds
    t.join(timeout=20)
    assert payloads_by_key(out) == payloads_by_key(src)
