"""Supervision: de-duplication of replayed frames, replay and trimming on the bus,
the retry bound of the launcher (a service that always dies)."""
import subprocess
import sys
import time

import numpy as np
import pytest

from common.bus import Bus, open_local_session
from common.codec import decode_frame, encode_sequenced
from common.messages import Depth, Header
from common.resume import (
    BLOCK_BYTES,
    LostFrames,
    Retention,
    SequenceGate,
    Supervision,
    blocks_dir,
    load_checkpoint,
    save_checkpoint,
)
from common.worker import DropOldestQueue
from tests.common.recordings import six_stream_recording
from tests.conftest import REPO

pytestmark = pytest.mark.timeout(300)


def test_replayed_duplicates_are_dropped_and_a_restarted_consumer_waits_for_its_replay():
    live = SequenceGate(owner="t")
    assert [live.data("k", i) for i in (0, 1, 2)] == [True, True, True]
    live.replay("k", 1)  # somebody else's replay: the frames from 1 come again
    assert [live.data("k", i) for i in (1, 2, 3)] == [False, False, True]
    assert live.duplicates == 2 and live.expected["k"] == 4
    assert live.data("k", -1)  # an unnumbered (foreign) frame is never de-duplicated

    restarted = SequenceGate({"k": 5}, catch_up=["k"], owner="t")
    assert not restarted.data("k", 9)  # live frames ahead of its checkpoint: they come again in the replay
    assert not restarted.control("k")  # nor watermarks / end-of-stream before the replay
    restarted.replay("k", 3)
    assert restarted.control("k")
    assert [restarted.data("k", i) for i in (3, 4, 5, 6)] == [False, False, True, True]

    restarted = SequenceGate({"k": 5}, catch_up=["k"], owner="t")
    assert restarted.data("k", 5) and restarted.in_step("k")  # the expected frame itself puts it in step

    with pytest.raises(LostFrames, match="frames 5..8 of k"):
        SequenceGate({"k": 5}, catch_up=["k"], owner="t").replay("k", 9)


def test_a_live_consumer_asks_again_for_a_gap_in_transit_and_counts_what_its_publisher_no_longer_kept():
    dropped = {"k": 0}
    gate = SequenceGate(owner="htm", live=True, queue_dropped=lambda _k, lo, hi: dropped["k"])
    assert [gate.data("k", i) for i in (0, 1)] == [True, True]
    assert not gate.data("k", 4) and not gate.in_step("k")  # 2, 3 lost in flight: asked for again
    gate.replay("k", 3, by="expmap")  # another consumer's answer, starting after what htm expects
    assert not gate.in_step("k")
    gate.replay("k", 2, by="htm")
    assert [gate.data("k", i) for i in (2, 3, 4)] == [True, True, True] and gate.missing == {}

    dropped["k"] = 2  # the gap is the consumer's own bounded queue dropping: counted, not asked for
    assert gate.data("k", 7) and gate.missing == {"k": 2} and gate.in_step("k")

    restarted = SequenceGate({"k": 5}, catch_up=["k"], owner="htm", live=True)
    restarted.replay("k", 9, by="htm")  # frames 5..8 were no longer kept: counted, the stream goes on
    assert restarted.in_step("k") and restarted.lost == {"k": 4} and restarted.missing == {"k": 4}
    assert restarted.data("k", 9)

    waiting = SequenceGate({"h": 3}, catch_up=["h"], owner="recorder")
    assert waiting.data("h", -1) and waiting.in_step("h")  # an unnumbered stream is never replayed


def test_retention_forgets_frames_older_than_its_age_or_beyond_its_bytes_and_the_queue_keeps_all_while_catching_up():
    session = open_local_session()
    bus = Bus(session=session)
    try:
        pub = bus.publisher("depth_sensor", retain=True)
        bound = Retention(max_age_ns=10, max_bytes=0)
        gone = []
        for stamp in range(0, 30, 2):
            pub.send(Depth(header=Header(seq=stamp, stamp=stamp), depth=0.0))
            gone += bound.sent(pub, stamp)
        assert [i for i, _f in pub.retained] == list(range(9, 15))  # stamps 18..28: within 10 ns of 28
        assert gone == list(range(9))
        size = len(pub.retained[-1][1])
        assert Retention(0, 2 * size).sent(pub, 28) == [9, 10, 11, 12] and len(pub.retained) == 2

        restarted = bus.publisher("depth_restored", retain=True)  # frames restored from a checkpoint stay
        restarted.restore({"index": 5, "retained": [(i, b"S") for i in range(5)], "watermark": -1})
        restarted.send(Depth(header=Header(seq=5, stamp=1000), depth=0.0))
        assert Retention(max_age_ns=10).sent(restarted, 1000) == [] and len(restarted.retained) == 6
    finally:
        bus.close()
        session.close()

    q = DropOldestQueue(2)
    frames = [("k", encode_sequenced(i, "poseidon_msgs/Depth", b"x")) for i in range(4)]
    for f in frames:
        q.put_nowait(f)
    assert q.dropped == {"k": 2} and q.dropped_between("k", 0, 3) == 2 and q.dropped_between("k", 0, 3) == 0
    q.lossless = True  # a sink catching up: nothing dropped, beyond the bound too
    for f in frames:
        q.put_nowait(f)
    assert q.data_frames() == 6 and q.dropped == {"k": 2}


def test_publisher_replays_what_it_kept_and_forgets_what_was_checkpointed(tmp_path):
    session = open_local_session()
    bus = Bus(session=session)
    received = []
    bus.subscribe_callback("depth_sensor", lambda _k, data: received.append(decode_frame(data)))
    pub = bus.publisher("depth_sensor", retain=True)
    time.sleep(0.2)
    try:
        for i in range(10):
            pub.send(Depth(header=Header(seq=i, stamp=100 + i), depth=float(i)))
        pub.send_watermark(200)
        pub.send_eos()
        pub.trim(4)
        assert [i for i, _f in pub.retained] == list(range(4, 10))
        assert pub.replay(2) == 4  # frames 2, 3 were forgotten: the replay says it starts at 4
        deadline = time.monotonic() + 5
        while len(received) < 10 + 2 + 1 + 6 + 2 and time.monotonic() < deadline:
            time.sleep(0.02)
    finally:
        bus.close()
        session.close()
    kinds = [(f.kind, f.index) for f in received]
    assert kinds[:12] == [("data", i) for i in range(10)] + [("watermark", -1), ("eos", -1)]
    assert kinds[12:] == [("replay", 4)] + [("data", i) for i in range(4, 10)] + [("watermark", -1), ("eos", -1)]
    # a consumer that had checkpointed at 6 gets each message exactly once
    gate = SequenceGate({"k": 6}, catch_up=["k"], owner="t")
    got = []
    for f in received:
        if f.kind == "replay":
            gate.replay("k", f.index)
        elif f.kind == "data" and gate.data("k", f.index):
            got.append(f.message().header.seq)
    assert got == [6, 7, 8, 9]


def test_checkpoints_are_written_atomically(tmp_path):
    path = tmp_path / "svc.ckpt"
    assert load_checkpoint(path) is None
    size = save_checkpoint(path, {"node": {"x": [1, 2]}})
    assert size.total == size.written == path.stat().st_size and load_checkpoint(path)["node"] == {"x": [1, 2]}
    assert not list(tmp_path.glob("*.tmp"))
    path.write_bytes(b"garbage")
    with pytest.raises(ValueError, match="svc.ckpt: unreadable checkpoint"):
        load_checkpoint(path)


def test_a_service_that_always_dies_fails_the_run_after_max_restarts(tmp_path):
    src = tmp_path / "in.mcap"
    six_stream_recording(src, 800, image_every=20)
    cfg = tmp_path / "cfg.yaml"
    cfg.write_text('{"service_classes": {"boom": "tests.common.nodes:Boom"}, '
                   '"supervise": {"max_restarts": 2, "restart_backoff_s": 0.05}}')
    out = tmp_path / "run.mcap"
    proc = subprocess.run([sys.executable, "-m", "launcher.cli", "run", "--input", str(src), "--out", str(out),
                           "--config", str(cfg), "--services", "boom", "--json"], cwd=REPO, capture_output=True,
                          text=True, timeout=240)
    assert proc.returncode == 3, proc.stderr[-3000:]
    assert "service 'boom' failed: exited with code 1 after 2 restart(s)" in proc.stderr
    assert "supervise: service boom died (exit code 1); restart 1 of 2" in proc.stderr
    assert "supervise: service boom died (exit code 1); restart 2 of 2" in proc.stderr
    assert "restart 3 of" not in proc.stderr
    assert "boom died (exit code 1) and used its 2 restarts" in proc.stderr
    assert not out.exists() and (tmp_path / "run.partial.mcap").exists()


def test_numbered_and_replay_frames_decode_and_malformed_ones_are_rejected():
    from common.codec import DecodeError, encode, encode_replay_start, encode_sequenced
    msg = Depth(header=Header(seq=3, stamp=5), depth=1.5)
    f = decode_frame(encode_sequenced(41, msg.type_name, encode(msg)))
    assert (f.kind, f.index, f.message()) == ("data", 41, msg)
    assert (decode_frame(encode_replay_start(7)).kind, decode_frame(encode_replay_start(7)).index) == ("replay", 7)
    for bad in (b"S", b"S\x01\x00\x00\x00\x00\x00\x00\x00", b"S" + b"\xff" * 8 + b"\x05Depth",
                encode_sequenced(1, msg.type_name, b"")[:12], encode_sequenced(1, msg.type_name, b""), b"R\x01",
                b"R" + b"\xff" * 8):
        with pytest.raises(DecodeError):
            decode_frame(bad)


def test_supervision_file_round_trip_carries_both_checkpoint_intervals(tmp_path):
    from launcher.run import plan_run, supervision_plan
    from missions.sim.cli import main as sim_main
    from system.config import load_config
    assert sim_main(["--minutes", "0.05", "--seed", "1", "--out", str(tmp_path / "m.mcap")]) == 0
    cfg = load_config(overrides=["supervise.checkpoint_interval_s=12", "supervise.recorder_checkpoint_interval_s=1.5"])
    sup = supervision_plan(cfg, plan_run(cfg, tmp_path / "m.mcap", None), tmp_path / "state")
    f = tmp_path / "sup.json"
    f.write_text(sup.to_json())
    back = Supervision.from_file(f, resume=True)
    assert back.checkpoint_interval_ns == 12_000_000_000
    assert back.recorder_checkpoint_interval_ns == 1_500_000_000
    assert back.resume and back.consumers == sup.consumers and "recorder" in back.consumers["camera/image_raw"]
    f.write_text('{"state_dir": "x"}')
    with pytest.raises(ValueError, match="not a supervision file"):
        Supervision.from_file(f)


def test_a_growing_state_writes_only_what_changed(tmp_path):
    """Checkpoints of a state that grows by appending (a sequence memory's frames in a
    preallocated array) write its new tail, not the whole array; every checkpoint loads back
    equal (values, dtype, shape, writable), and blocks no checkpoint names are removed."""
    path = tmp_path / "htm.ckpt"
    rng = np.random.default_rng(3)
    frames = np.zeros((4000, 256), np.uint64)          # 8 MB: 8 blocks
    frames[:1000] = rng.integers(0, 2**63, (1000, 256), dtype=np.uint64)
    small = {"n": 1000, "ids": np.arange(10)}
    first = save_checkpoint(path, {"node": {"frames": frames, "small": small}})
    assert first.total > frames.nbytes and first.written < 0.6 * first.total   # the zero blocks are one block
    frames[1000:1100] = rng.integers(0, 2**63, (100, 256), dtype=np.uint64)
    second = save_checkpoint(path, {"node": {"frames": frames, "small": small}})
    assert second.total == first.total
    assert second.written < 2.5 * BLOCK_BYTES < frames.nbytes / 3   # the block holding rows 1000-1099, the file
    back = load_checkpoint(path)["node"]
    np.testing.assert_array_equal(back["frames"], frames)
    assert back["frames"].dtype == frames.dtype and back["frames"].flags.writeable
    np.testing.assert_array_equal(back["small"]["ids"], small["ids"])
    # a later, smaller state: the blocks only the old one named are gone
    save_checkpoint(path, {"node": {"frames": frames[:200].copy()}})   # 400 kB: one block
    assert len(list(blocks_dir(path).iterdir())) == 1


def test_a_checkpoint_missing_a_block_names_it(tmp_path):
    path = tmp_path / "expmap.ckpt"
    save_checkpoint(path, {"node": np.ones((1 << 16,), np.float64)})
    block = next(blocks_dir(path).iterdir())
    block.unlink()
    with pytest.raises(ValueError, match=f"expmap.ckpt: array block {block.name} is missing"):
        load_checkpoint(path)


def test_a_version_1_checkpoint_still_loads(tmp_path):
    """Before incremental checkpoints every array was inside the pickle."""
    import pickle
    path = tmp_path / "old.ckpt"
    path.write_bytes(pickle.dumps({"version": 1, "node": np.arange(1 << 16)}))
    np.testing.assert_array_equal(load_checkpoint(path)["node"], np.arange(1 << 16))


def test_a_reader_racing_the_writer_reads_the_new_checkpoint(tmp_path, monkeypatch):
    """A reader that opened the old file while the writer replaced it and deleted the old
    blocks (the race a monitoring read of a live service's checkpoint can hit) reads again
    and gets the new checkpoint, not a 'block missing' error."""
    import common.resume as resume

    path = tmp_path / "htm.ckpt"
    save_checkpoint(path, {"node": np.ones((1 << 16,), np.float64)})
    real = resume._BlockUnpickler.persistent_load
    raced = []

    def load_while_the_writer_replaces(self, pid):
        if not raced:
            raced.append(True)
            save_checkpoint(path, {"node": np.full((1 << 16,), 2.0)})   # old block deleted here
        return real(self, pid)

    monkeypatch.setattr(resume._BlockUnpickler, "persistent_load", load_while_the_writer_replaces)
    back = load_checkpoint(path)
    assert raced and np.all(back["node"] == 2.0)
