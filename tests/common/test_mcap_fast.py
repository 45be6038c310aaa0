"""The fast paths of common.mcap_io give exactly what mcap's own reader and writer give."""
import numpy as np
import pytest
from mcap.reader import make_reader

from common import mcap_io
from common.mcap_io import RecordingWriter, read_messages, recording_summary
from common.messages import Depth, Header, Image

KEYS = ["depth_sensor", "odometry_depth", "camera/image_raw", "other_depth"]


def _shuffled_recording(path, n=600, chunk_size=700, seed=3, fast=True, compression="zstd", mcap_chunks=False):
    """Messages written out of stamp order, many stamps shared across keys, chunks of a few
    messages (they overlap in time), a few forced chunk ends; returns the writer's counts.
    ``mcap_chunks``: the chunks ended by mcap's own writer (its compression level)."""
    rng = np.random.default_rng(seed)
    w = RecordingWriter(path, chunk_size=chunk_size, compression=compression)
    if mcap_chunks:
        del w._writer._Writer__finalize_chunk
        w._finalize_chunk = w._writer._Writer__finalize_chunk
    w._fast = fast and w._fast
    w.add_metadata("poseidon", {"seed": seed})
    seqs = {}
    for i in range(n):
        key = KEYS[int(rng.integers(len(KEYS)))]
        stamp = int(rng.integers(0, 80)) * 1000 + (0 if rng.random() < 0.7 else int(rng.integers(1, 999)))
        seq = seqs.get(key, 0)
        seqs[key] = seq + 1
        h = Header(seq=seq, stamp=stamp)
        if key == "camera/image_raw":
            msg = Image(header=h, height=2, width=3, encoding="mono8",
                        data=rng.integers(0, 255, (2, 3), dtype=np.uint8))
        else:
            msg = Depth(header=h, depth=float(rng.normal()))
        w.write(key, msg)
        if i % 97 == 96:
            w.sync()
    w.close()
    return dict(w.counts)


def _mcap_order(path, keys=None, start_ns=None, end_ns=None):
    with open(path, "rb") as f:
        return [(c.topic, s.name, m.log_time, m.sequence, bytes(m.data))
                for s, c, m in make_reader(f).iter_messages(topics=keys, starting_at=start_ns, ending_before=end_ns,
                                                            log_time_order=True)]


def _ours(path, keys=None, start_ns=None, end_ns=None):
    return [(r.key, r.type_name, r.stamp, r.seq, r.payload)
            for r in read_messages(path, keys=keys, start_ns=start_ns, end_ns=end_ns)]


def test_read_messages_is_mcaps_log_time_order(tmp_path):
    path = tmp_path / "shuffled.mcap"
    _shuffled_recording(path)
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    chunks = sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
    assert len(chunks) > 20  # several chunks ...
    assert any(b.message_start_time < a.message_end_time for a, b in zip(chunks, chunks[1:]))  # ... overlapping
    ref = _mcap_order(path)
    assert len(ref) == 600 and [m[2] for m in ref] == sorted(m[2] for m in ref)
    stamps = [m[2] for m in ref]
    assert any(a == b and ka[0] != kb[0] for a, b, ka, kb in zip(stamps, stamps[1:], ref, ref[1:]))  # equal stamps, other key
    assert [m[0] for m in ref] != [m[0] for m in sorted(ref, key=lambda m: (m[2], m[0]))]  # file order decides ties
    assert _ours(path) == ref
    for keys in (["depth_sensor"], ["camera/image_raw", "other_depth"], [], ["no/such/key"]):
        assert _ours(path, keys=keys) == _mcap_order(path, keys=keys)
    for start in (0, 1000, 40_000, 40_500, 79_000, 10**9):
        assert _ours(path, start_ns=start) == _mcap_order(path, start_ns=start)
        assert _ours(path, keys=["odometry_depth", "depth_sensor"], start_ns=start) == \
            _mcap_order(path, keys=["odometry_depth", "depth_sensor"], start_ns=start)
    for start, end in ((None, 1000), (1000, 40_000), (40_500, 40_501), (39_000, 79_000), (0, 10**9), (5000, 5000)):
        ours = _ours(path, start_ns=start, end_ns=end)
        assert ours == _mcap_order(path, start_ns=start, end_ns=end)
        assert all((start is None or m[2] >= start) and m[2] < end for m in ours)
    assert _ours(path, start_ns=39_000, end_ns=41_000)       # not empty: the window holds messages


def test_fast_writer_writes_mcaps_bytes(tmp_path):
    a, b = tmp_path / "mcap_writer.mcap", tmp_path / "fast.mcap"
    assert _shuffled_recording(a, fast=False) == _shuffled_recording(b, fast=True)
    assert a.read_bytes() == b.read_bytes()
    big_a, big_b = tmp_path / "big_a.mcap", tmp_path / "big_b.mcap"  # default chunk size: one chunk
    _shuffled_recording(big_a, n=300, chunk_size=1 << 20, fast=False)
    _shuffled_recording(big_b, n=300, chunk_size=1 << 20, fast=True)
    assert big_a.read_bytes() == big_b.read_bytes()


def test_recording_summary_from_statistics_equals_full_scan(tmp_path, monkeypatch):
    path = tmp_path / "s.mcap"
    counts = _shuffled_recording(path)
    fast = recording_summary(path)
    assert fast["counts"] == {k: counts[k] for k in sorted(counts)}
    assert fast["types"] == {"camera/image_raw": "poseidon_msgs/Image", "depth_sensor": "poseidon_msgs/Depth",
                             "odometry_depth": "poseidon_msgs/Depth", "other_depth": "poseidon_msgs/Depth"}
    ref = _mcap_order(path)
    assert (fast["start_ns"], fast["end_ns"]) == (min(m[2] for m in ref), max(m[2] for m in ref))
    monkeypatch.setattr(mcap_io, "_summary_statistics", lambda p: None)  # the killed-writer path
    scanned = recording_summary(path)
    assert scanned == fast and list(scanned["counts"]) == list(fast["counts"])
    assert type(scanned["duration_s"]) is type(fast["duration_s"]) is float


def test_recording_summary_of_a_file_without_summary(tmp_path):
    path = tmp_path / "full.mcap"
    _shuffled_recording(path)
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])  # a writer killed half way: no summary section
    kept = list(read_messages(cut))
    assert [r.stamp for r in read_messages(cut, start_ns=20_000, end_ns=50_000)] == \
        [r.stamp for r in kept if 20_000 <= r.stamp < 50_000]
    intact = list(read_messages(cut))
    got = recording_summary(cut)
    assert 0 < sum(got["counts"].values()) == len(intact) < 600
    assert got["start_ns"] == min(r.stamp for r in intact) and got["end_ns"] == max(r.stamp for r in intact)
    empty = tmp_path / "empty.mcap"
    RecordingWriter(empty).close()
    assert recording_summary(empty) == {"counts": {}, "types": {}, "start_ns": None, "end_ns": None, "duration_s": 0.0}


def _chunks(path):
    """(chunk index without compressed size, decompressed records, message indexes) of each chunk."""
    from mcap.data_stream import ReadDataStream
    from mcap.records import Chunk

    from common.mcap_io import _chunk_records
    out = []
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
        for ci in summary.chunk_indexes:
            f.seek(ci.chunk_start_offset + 9)
            chunk = Chunk.read(ReadDataStream(f))
            f.seek(ci.chunk_start_offset + ci.chunk_length)
            indexes = f.read(ci.message_index_length)
            offsets = {k: v - ci.chunk_start_offset - ci.chunk_length for k, v in ci.message_index_offsets.items()}
            out.append((ci.message_start_time, ci.message_end_time, ci.chunk_length - len(chunk.data), offsets,
                        ci.compression, ci.uncompressed_size, chunk.uncompressed_crc,
                        _chunk_records(chunk, validate_crc=True), indexes))
    return out


def test_chunks_are_mcaps_own_but_for_the_zstd_level(tmp_path):
    for compression in ("none", "lz4"):
        a, b = tmp_path / f"mcap_{compression}.mcap", tmp_path / f"ours_{compression}.mcap"
        _shuffled_recording(a, compression=compression, mcap_chunks=True)
        _shuffled_recording(b, compression=compression)
        assert a.read_bytes() == b.read_bytes(), compression
    a, b = tmp_path / "mcap_zstd.mcap", tmp_path / "ours_zstd.mcap"
    _shuffled_recording(a, mcap_chunks=True)
    _shuffled_recording(b)
    ours = _chunks(b)
    assert len(ours) > 20 and _chunks(a) == ours      # every record the same once decompressed
    assert _mcap_order(a) == _mcap_order(b) == _ours(b)


def test_mapped_chunk_reader_gives_mcaps_records_and_fails_cleanly(tmp_path):
    """The memory-mapped reader of read_messages returns, chunk by chunk, the records of mcap's
    own Chunk.read for every compression; a damaged chunk is a RecordingError (the map closed,
    not a BufferError over it), and a truncated file an EOFError naming the chunk."""
    import pytest
    from mcap.data_stream import ReadDataStream
    from mcap.records import Chunk

    from common.mcap_io import RecordingError, _chunk_records, _ChunkReader
    for compression in ("zstd", "lz4", "none"):
        path = tmp_path / f"{compression}.mcap"
        _shuffled_recording(path, compression=compression)
        with open(path, "rb") as f:
            summary = make_reader(f).get_summary()
            reader = _ChunkReader(f)
            for ci in summary.chunk_indexes:
                f.seek(ci.chunk_start_offset + 9)
                assert reader(ci, True) == _chunk_records(Chunk.read(ReadDataStream(f)), validate_crc=True)
            reader.close()
        assert _ours(path) == _mcap_order(path), compression
    path = tmp_path / "none.mcap"
    with open(path, "rb") as f:
        ci = sorted(make_reader(f).get_summary().chunk_indexes, key=lambda c: c.chunk_start_offset)[3]
    data = bytearray(path.read_bytes())
    data[ci.chunk_start_offset + ci.chunk_length - 5] ^= 0xFF      # a byte of a stored chunk's records
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    with pytest.raises(RecordingError, match="corrupt chunk"):
        list(read_messages(bad))
    short = tmp_path / "short.mcap"
    short.write_bytes(path.read_bytes()[:ci.chunk_start_offset + 20])
    with open(short, "rb") as f, pytest.raises(EOFError, match=f"chunk at byte {ci.chunk_start_offset}"):
        _ChunkReader(f)(ci, True)


def test_chunk_buffer_reused_and_let_go_after_a_large_message(tmp_path):
    """The writer rewinds its chunk buffer instead of allocating one per chunk: a chunk shorter
    than the one before (stale bytes after it in the buffer) is written alone, and a buffer grown
    past 4 chunks by one large message is replaced."""
    path = tmp_path / "sizes.mcap"
    w = RecordingWriter(path, chunk_size=1000)
    sizes = [900, 50, 5000, 20, 900, 3, 1200, 10]
    for i, n in enumerate(sizes):
        img = Image(header=Header(seq=i, stamp=1000 * i), height=1, width=n, encoding="mono8",
                    data=np.full((1, n), i, dtype=np.uint8))
        w.write("camera/image_raw", img)
        w.sync()   # one chunk per message
        if n == 5000:
            assert w._chunk_builder.record_writer._buffer.getbuffer().nbytes == 0   # let go
    w.close()
    got = [m.message() for m in read_messages(path)]
    assert [m.width for m in got] == sizes
    assert all(int(np.asarray(m.data).max()) == i for i, m in enumerate(got))
    assert _ours(path) == _mcap_order(path)


def _rss_file_kib() -> int:
    for line in open("/proc/self/status"):
        if line.startswith("RssFile:"):
            return int(line.split()[1])
    raise AssertionError("no RssFile in /proc/self/status")


def test_a_read_recording_does_not_stay_resident_in_the_reader(tmp_path):
    """48 MB of incompressible images in 64 KiB chunks, read through the mapped reader: each chunk
    (and what the kernel mapped around it) is unmapped again once read, so the process's
    file-backed resident memory grows by a few chunks, not by the file."""
    if mcap_io._MADV_DONTNEED is None:
        pytest.skip("no MADV_DONTNEED on this platform: mapped chunks stay resident")
    path = tmp_path / "big.mcap"
    rng = np.random.default_rng(11)
    with RecordingWriter(path, chunk_size=1 << 16) as w:
        for i in range(2400):
            px = rng.integers(0, 256, size=(80, 85, 3), dtype=np.uint8)  # ~20 kB, incompressible
            w.write("camera/image_raw", Image(header=Header(seq=i, stamp=i * 1000), height=80, width=85,
                                              encoding="rgb8", data=px))
    size_kib = path.stat().st_size // 1024
    assert size_kib > 45_000
    before = _rss_file_kib()
    n = 0
    for _ in read_messages(path):
        n += 1
        if n == 2000:  # the map is still open here
            grown = _rss_file_kib() - before
    assert n == 2400
    assert grown < 8_000, f"file-backed RSS grew by {grown} KiB reading a {size_kib} KiB recording"
