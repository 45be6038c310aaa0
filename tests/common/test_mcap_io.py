import hashlib
import os
import threading
import time
from concurrent.futures import CancelledError

import numpy as np
import pytest

from common.mcap_io import (
    DIGEST_CACHE_ENV,
    DigestCache,
    FileDigest,
    RecordingError,
    RecordingWriter,
    digest_from_file,
    file_sha256,
    read_messages,
    read_metadata,
    recording_keys,
    recording_message_count,
    recording_summary,
)
from common.messages import Depth, Header, Image
from tests.common.recordings import six_stream_recording


def test_write_read_in_event_time_order_with_metadata(tmp_path):
    path = tmp_path / "r.mcap"
    with RecordingWriter(path) as w:
        w.write("depth_sensor", Depth(header=Header(seq=0, stamp=30), depth=3.0))
        w.write("depth_sensor", Depth(header=Header(seq=1, stamp=10), depth=1.0))
        w.write("camera/image_raw", Image(header=Header(seq=0, stamp=20), height=2, width=2,
                                          data=np.ones((2, 2, 3), np.uint8)))
        w.add_metadata("poseidon", {"code_revision": "abc", "config": {"x": 1}})
    msgs = list(read_messages(path))
    assert [m.stamp for m in msgs] == [10, 20, 30]
    assert msgs[0].message() == Depth(header=Header(seq=1, stamp=10), depth=1.0)
    assert recording_keys(path) == {"depth_sensor": "poseidon_msgs/Depth", "camera/image_raw": "poseidon_msgs/Image"}
    assert read_metadata(path)["poseidon"] == {"code_revision": "abc", "config": '{"x": 1}'}
    assert recording_summary(path)["counts"] == {"depth_sensor": 2, "camera/image_raw": 1}
    assert recording_message_count(path) == 3 and recording_message_count(path, ["depth_sensor"]) == 2


def test_truncated_file_names_file_and_offset_and_keeps_what_is_intact(tmp_path):
    path = tmp_path / "full.mcap"
    six_stream_recording(path, 600, image_every=5)
    original = list(read_messages(path))
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: int(len(data) * 0.6)])
    with pytest.raises(RecordingError) as err:
        list(read_messages(cut, strict=True))
    assert str(cut) in str(err.value) and "byte" in str(err.value)
    recovered = list(read_messages(cut))
    assert 0 < len(recovered) < len(original)
    by_key = {}
    for r in original:
        by_key.setdefault(r.key, []).append(r.payload)
    for r in recovered:  # every recovered message is an original one, byte for byte
        assert r.payload in by_key[r.key]


def test_garbage_and_missing_files(tmp_path):
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"not an mcap at all" * 10)
    for strict in (True, False):  # nothing to recover: an error even when not strict
        with pytest.raises(RecordingError, match=r"junk.mcap: not an MCAP recording \(180 bytes, unreadable from byte 0"):
            list(read_messages(junk, strict=strict))
    with pytest.raises(RecordingError, match="no such recording"):
        list(read_messages(tmp_path / "nope.mcap"))


def test_channel_type_is_fixed_per_key(tmp_path):
    with RecordingWriter(tmp_path / "x.mcap") as w:
        w.write("k", Depth(header=Header(seq=0, stamp=1), depth=1.0))
        with pytest.raises(ValueError, match="carries poseidon_msgs/Depth"):
            w.write("k", Image(header=Header(seq=0, stamp=2), height=1, width=1, encoding="mono8",
                               data=np.zeros((1, 1), np.uint8)))


def test_iter_file_order_streams_the_intact_messages_of_a_damaged_file(tmp_path):
    from common.mcap_io import iter_file_order, read_file_order
    path = tmp_path / "full.mcap"
    six_stream_recording(path, 600, image_every=5)
    cut = tmp_path / "cut.mcap"
    data = path.read_bytes()
    cut.write_bytes(data[: int(len(data) * 0.6)])
    listed, _meta = read_file_order(cut)
    it = iter_file_order(cut)
    first = next(it)          # a message before the file was read through: nothing is held but the one
    streamed = [first, *it]
    assert 0 < len(streamed) == len(listed)
    assert [(m.key, m.stamp, m.payload) for m in streamed] == [(m.key, m.stamp, m.payload) for m in listed]


def test_the_zstd_level_changes_the_file_not_the_messages(tmp_path):
    """recorder.zstd_level: level -1 (the default) and 19 hold the same messages; -1 is larger
    on compressible payloads; a level outside [-7, 22] is refused."""
    from common.mcap_io import RecordingWriter, read_messages
    from common.messages import Depth, Header

    sizes = {}
    for level in (-1, 19):
        path = tmp_path / f"l{level}.mcap"
        with RecordingWriter(path, zstd_level=level) as w:
            for i in range(3000):
                w.write("depth_sensor", Depth(header=Header(seq=i, stamp=1000 + i), depth=float(i % 7)))
        sizes[level] = path.stat().st_size
    a, b = list(read_messages(tmp_path / "l-1.mcap")), list(read_messages(tmp_path / "l19.mcap"))
    assert [(m.stamp, m.payload) for m in a] == [(m.stamp, m.payload) for m in b] and len(a) == 3000
    assert sizes[-1] > sizes[19]
    with pytest.raises(ValueError, match="zstd level must be in"):
        RecordingWriter(tmp_path / "bad.mcap", zstd_level=30)


def test_a_published_digest_reaches_another_reader_and_so_does_its_error(tmp_path):
    path = tmp_path / "blob.bin"
    path.write_bytes(b"x" * 5000)
    digest = FileDigest(path)
    digest.publish_to(tmp_path / "input.sha256")
    assert digest_from_file(tmp_path / "input.sha256", timeout_s=30) == hashlib.sha256(b"x" * 5000).hexdigest()
    failed = FileDigest(tmp_path / "missing.bin")
    failed.publish_to(tmp_path / "failed.sha256")
    with pytest.raises(RecordingError, match=r"failed.sha256: no digest of the input: error: FileNotFoundError"):
        digest_from_file(tmp_path / "failed.sha256", timeout_s=30)
    with pytest.raises(RecordingError, match="never.sha256: the input's digest did not arrive within 0 s"):
        digest_from_file(tmp_path / "never.sha256", timeout_s=0.1)


def test_the_summary_is_read_again_when_the_file_changes(tmp_path):
    """The parsed summary is kept per file version: a recording rewritten at the same path is
    read again, a file cut short (no summary) is read through."""
    path = tmp_path / "r.mcap"
    for keys in (["depth_sensor"], ["depth_sensor", "dvl_depth"]):
        with RecordingWriter(path) as w:
            for i, key in enumerate(keys):
                w.write(key, Depth(header=Header(seq=i, stamp=1000 + i), depth=1.0))
        assert sorted(recording_keys(path)) == keys
        assert recording_message_count(path) == len(keys)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])  # no summary any more
    assert recording_message_count(path) is None
    with pytest.raises(RecordingError, match="no such recording"):
        recording_keys(tmp_path / "missing.mcap")


def test_an_unchanged_file_is_not_hashed_again_and_a_changed_one_is(tmp_path, caplog):
    """The digest cache: the second digest of a file comes from the cache and is the file's
    SHA-256; a file written again (same size, its modification time set back) is hashed again;
    a malformed entry is logged and the file hashed; small files and pipes are never cached."""
    cache = DigestCache(tmp_path / "cache", min_bytes=1024)
    path = tmp_path / "mission.mcap"
    data = np.random.default_rng(7).integers(0, 256, size=200_000, dtype=np.uint8).tobytes()
    path.write_bytes(data)
    first = FileDigest(path, cache=cache)
    assert first.result(timeout=30) == hashlib.sha256(data).hexdigest() and not first.cached
    entries = list((tmp_path / "cache").glob("*.json"))
    assert len(entries) == 1
    again = FileDigest(path, cache=cache)
    assert again.cached and again.result(timeout=30) == hashlib.sha256(data).hexdigest()
    # the same size and modification time, other bytes: the status-change time gives it away
    st = os.stat(path)
    changed = bytes([data[0] ^ 1]) + data[1:]
    time.sleep(0.01)
    path.write_bytes(changed)
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns))
    assert os.stat(path).st_mtime_ns == st.st_mtime_ns and os.stat(path).st_size == st.st_size
    third = FileDigest(path, cache=cache)
    assert not third.cached and third.result(timeout=30) == hashlib.sha256(changed).hexdigest()
    assert FileDigest(path, cache=cache).cached
    entries[0].write_text("{not json")
    with caplog.at_level("WARNING", logger="common.mcap_io"):
        fourth = FileDigest(path, cache=cache)
        assert not fourth.cached and fourth.result(timeout=30) == hashlib.sha256(changed).hexdigest()
    assert "unreadable" in caplog.text and str(path) in caplog.text
    small = tmp_path / "small.bin"
    small.write_bytes(b"x" * 100)
    assert FileDigest(small, cache=cache).result(timeout=30) == hashlib.sha256(b"x" * 100).hexdigest()
    assert not FileDigest(small, cache=cache).cached
    with pytest.raises(FileNotFoundError, match="missing.bin"):
        FileDigest(tmp_path / "missing.bin", cache=cache).result(timeout=30)


def test_the_digest_cache_keeps_its_newest_entries_and_obeys_the_environment(tmp_path, monkeypatch):
    cache = DigestCache(tmp_path / "cache", min_bytes=10, max_entries=2)
    for i in range(4):
        f = tmp_path / f"f{i}.bin"
        f.write_bytes(bytes([i]) * 100)
        assert FileDigest(f, cache=cache).result(timeout=30) == hashlib.sha256(bytes([i]) * 100).hexdigest()
        time.sleep(0.01)
    assert len(list((tmp_path / "cache").glob("*.json"))) == 2
    assert FileDigest(tmp_path / "f3.bin", cache=cache).cached
    assert not FileDigest(tmp_path / "f0.bin", cache=cache).cached
    monkeypatch.setenv(DIGEST_CACHE_ENV, "off")
    assert DigestCache.default() is None
    monkeypatch.setenv(DIGEST_CACHE_ENV, str(tmp_path / "elsewhere"))
    assert DigestCache.default().directory == tmp_path / "elsewhere"
    monkeypatch.delenv(DIGEST_CACHE_ENV)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert DigestCache.default().directory == tmp_path / "xdg" / "poseidonslam" / "digests"


def test_the_file_digest_is_the_sha256_hands_on_its_error_and_cancels(tmp_path):
    path = tmp_path / "blob.bin"
    data = np.random.default_rng(5).integers(0, 256, size=3 * (1 << 20) + 17, dtype=np.uint8).tobytes()
    path.write_bytes(data)
    digest = FileDigest(path)
    assert digest.result(timeout=30) == hashlib.sha256(data).hexdigest() == file_sha256(path)
    digest.cancel()  # after the result: nothing left to stop
    with pytest.raises(FileNotFoundError, match="missing.bin"):
        FileDigest(tmp_path / "missing.bin").result(timeout=30)
    # cancelled mid-file (a pipe the test feeds, so the thread is surely still reading): no digest
    # of part of the file, and no thread left
    fifo = tmp_path / "feed"
    os.mkfifo(fifo)
    stopped = FileDigest(fifo, chunk=1024)
    with open(fifo, "wb") as feed:
        feed.write(data[:4096])
        feed.flush()
        canceller = threading.Thread(target=stopped.cancel)
        canceller.start()
        while not stopped._stop.is_set():
            time.sleep(0.001)
    canceller.join(timeout=30)  # the pipe's end woke the reader
    assert not canceller.is_alive()
    assert not any(t.name == "poseidon-sha256" for t in threading.enumerate())
    with pytest.raises(CancelledError):
        stopped.result(timeout=30)
