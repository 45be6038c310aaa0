"""The live runs' bounded queue: the oldest data frame goes first, counted per key; control frames stay."""
import queue
import threading

import pytest

from common.codec import ENCODED_EOS, encode_frame, encode_watermark
from common.messages import Depth, Header
from common.worker import WAKE, DropOldestQueue


def _data(i):
    return encode_frame(Depth(header=Header(seq=i, stamp=i, frame_id=""), depth=float(i)))


def test_when_full_the_oldest_data_frame_is_dropped_and_counted_per_key():
    q = DropOldestQueue(3)
    q.put_nowait(("a", _data(0)))
    q.put_nowait(("a", encode_watermark(5)))
    q.put_nowait(("b", _data(1)))
    q.put_nowait(("a", _data(2)))
    q.put_nowait(("b", _data(3)))  # full: a/0 goes
    q.put_nowait(("a", ENCODED_EOS))
    q.put_nowait((WAKE, b""))
    q.put_nowait(("b", _data(4)))  # full: b/1 goes
    assert q.dropped == {"a": 1, "b": 1}
    got = [q.get(0.1) for _ in range(q.qsize())]
    assert got == [("a", encode_watermark(5)), ("a", _data(2)), ("b", _data(3)), ("a", ENCODED_EOS), (WAKE, b""),
                   ("b", _data(4))]
    assert q.empty()


def test_get_waits_for_a_frame_and_times_out_empty():
    q = DropOldestQueue(2)
    with pytest.raises(queue.Empty):
        q.get(0.05)
    threading.Timer(0.05, q.put_nowait, args=(("k", _data(7)),)).start()
    assert q.get(2.0) == ("k", _data(7))


def test_a_queue_needs_room_for_one_frame():
    with pytest.raises(ValueError, match="max_data"):
        DropOldestQueue(0)


def test_the_byte_bound_drops_the_oldest_data_frames_until_the_new_one_fits():
    frames = [_data(i) for i in range(4)]
    size = len(frames[0])
    q = DropOldestQueue(100, max_bytes=3 * size)   # room for three frames by bytes, a hundred by count
    q.put_nowait(("a", frames[0]))
    q.put_nowait(("a", encode_watermark(1)))        # control frames do not count against the bytes
    q.put_nowait(("b", frames[1]))
    q.put_nowait(("a", frames[2]))
    assert q.dropped == {} and q.data_bytes() == 3 * size
    q.put_nowait(("b", frames[3]))                  # 4 x size > 3 x size: a/0 goes
    assert q.dropped == {"a": 1} and q.data_frames() == 3 and q.data_bytes() == 3 * size
    big = ("c", frames[0] + b"\0" * (2 * size))     # three frames' worth: everything older goes
    q.put_nowait(big)
    assert q.dropped == {"a": 2, "b": 2}
    assert [q.get(0.1) for _ in range(q.qsize())] == [("a", encode_watermark(1)), big]
    assert q.data_bytes() == 0 and q.data_frames() == 0


def test_a_frame_larger_than_the_byte_bound_is_still_kept():
    q = DropOldestQueue(10, max_bytes=8)
    q.put_nowait(("a", _data(0)))
    q.put_nowait(("a", _data(1)))                   # over the bound alone: the older one goes, the new one stays
    assert q.dropped == {"a": 1}
    assert q.get(0.1) == ("a", _data(1))


def test_the_byte_bound_must_not_be_negative():
    with pytest.raises(ValueError, match="max_bytes"):
        DropOldestQueue(1, max_bytes=-1)


def test_a_lossless_queue_past_its_bounds_is_not_within_them():
    q = DropOldestQueue(2, max_bytes=2 * len(_data(0)))
    q.lossless = True                               # a restarted consumer catching up keeps every frame
    for i in range(3):
        q.put_nowait(("a", _data(i)))
    assert q.dropped == {} and not q.within_bounds()
    q.get(0.1)
    assert q.within_bounds()
