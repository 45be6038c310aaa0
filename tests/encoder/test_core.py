"""EncoderCore driven directly (no node, no transport; a stub encoder instead of the CNN)."""
from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import pytest

from common.messages import Image
from services.encoder.core import EncoderCore
from tests.encoder.test_clock import S, beam, clock, frame


class StubEncoder:
    """Embedding = mean of the image; SDR = [round(1000 * y)] per modality."""

    def __init__(self) -> None:
        self.batches: list[int] = []

    def embed(self, images: Sequence[np.ndarray]) -> list[np.ndarray]:
        self.batches.append(len(images))
        return [np.array([float(np.mean(im))], np.float32) for im in images]

    def sdr(self, modality: str, embedding: np.ndarray, update: bool = True) -> np.ndarray:
        return np.array([int(round(1000 * float(embedding[0]))) + (0 if modality == "camera" else 100000)], np.uint32)

    def settled(self, modality: str, frames: int) -> bool:
        return True

    def fuse(self, sdrs: Mapping[str, np.ndarray | None], mode: str | None = None) -> np.ndarray:
        out: np.ndarray = np.unique(np.concatenate([v for v in sdrs.values() if v is not None]))
        return out


def test_core_batches_camera_and_due_sonar_and_reuses_the_sonar_sdr() -> None:
    enc = StubEncoder()
    core = EncoderCore(enc, clock())
    core.on_sonar(beam(0.0, 0.0))
    (o1,) = core.on_camera(frame(0.1))
    out = o1.sdrs
    assert set(out) == {"camera", "sonar"} and enc.batches == [2] and o1.stamp == int(0.1 * S) and o1.frame_id == "cam"
    core.on_sonar(beam(0.15, 9.0))
    (o2,) = core.on_camera(frame(0.2))           # 9 deg < 45: reused
    out2 = o2.sdrs
    assert enc.batches == [2, 1] and np.array_equal(out2["sonar"], out["sonar"])
    ev = [k for k, _n in core.take_events()]
    assert ev == ["sonar_beams", "sonar_encodings", "sonar_beams", "sonar_sdr_reused"]
    (o3,) = core.on_camera(frame(5.0))
    assert list(o3.sdrs) == ["camera"] and np.array_equal(o3.sdrs["camera"], out2["camera"])   # stale sonar: camera only
    assert core.take_events() == [("frames_without_sonar", 1)]


def test_core_sonar_mode_ignores_frames_and_emits_on_the_sweep() -> None:
    core = EncoderCore(StubEncoder(), clock("sonar"))
    assert core.on_camera(frame(0.0)) == []
    outs = [core.on_sonar(beam(k * 0.05, 9.0 * k)) for k in range(81)]
    emitted = [k for k, o in enumerate(outs) if o]
    assert emitted == [40, 80] and all(len(outs[k]) == 1 and set(outs[k][0].sdrs) == {"sonar"} for k in emitted)
    o40 = outs[40][0]
    assert o40.sonar_clocked and core.fuse(o40.sdrs).tolist() == o40.sdrs["sonar"].tolist()


@pytest.mark.parametrize("mode", ["union", "and"])
def test_core_camera_dropout_hands_the_clock_to_the_sonar(mode: str) -> None:
    core = EncoderCore(StubEncoder(), clock(mode))
    core.on_camera(frame(0.0))
    outs = [core.on_sonar(beam(0.01 + k * 0.05, 9.0 * k)) for k in range(50)]
    # the camera is stale after 0.5 s; the sweep since the frame's output reaches 360 deg at beam 40
    assert [k for k, o in enumerate(outs) if o] == [40]


class CountingEncoder(StubEncoder):
    """The stub with running statistics: an embedding counts once per ``update``; the SDR is
    [round(1000 * (y - mean of the embeddings counted so far))] (offset by 500000 to stay positive)."""

    def __init__(self) -> None:
        super().__init__()
        self.seen: dict[str, list[float]] = {"camera": [], "sonar": []}

    def sdr(self, modality: str, embedding: np.ndarray, update: bool = True) -> np.ndarray:
        y = float(embedding[0])
        past = self.seen[modality]
        mu = float(np.mean(past)) if past else 0.0
        if update:
            past.append(y)
        base = 0 if modality == "camera" else 100000
        return np.array([500000 + base + int(round(1000 * (y - mu)))], np.uint32)

    def settled(self, modality: str, frames: int) -> bool:
        return len(self.seen[modality]) >= frames


def shade(t: float, v: int) -> Image:
    img = frame(t)
    img.data[:] = v
    return img


def test_warm_up_hold_releases_the_first_frames_hashed_with_the_statistics_of_all_of_them() -> None:
    enc = CountingEncoder()
    core = EncoderCore(enc, clock("camera"), hold=3, hold_max=50)
    values = [10, 20, 30, 40]
    outs = [core.on_camera(shade(0.1 * (k + 1), v)) for k, v in enumerate(values[:2])]
    assert outs == [[], []] and core.oldest_held_stamp == int(0.1 * S)
    outs += [core.on_camera(shade(0.1 * (k + 3), v)) for k, v in enumerate(values[2:])]
    released = outs[2]
    assert [o.stamp for o in released] == [int(0.1 * S), int(0.2 * S), int(0.3 * S)]
    mu = np.mean(values[:3])   # every held frame centred by the mean of all three
    for o, v in zip(released, values):
        assert o.sdrs["camera"].tolist() == [500000 + int(round(1000 * (v - mu)))]
    assert core.oldest_held_stamp is None and not core.holding
    (last,) = outs[3]                               # after the hold: hashed at once, as before
    assert last.sdrs["camera"].tolist() == [500000 + int(round(1000 * (40 - mu)))]
    assert ("outputs_held", 3) in core.take_events()


def test_warm_up_hold_follows_the_camera_and_renews_the_sonar_sdr() -> None:
    enc = CountingEncoder()
    core = EncoderCore(enc, clock("union", reencode_deg=1000.0), hold=2, hold_max=4)   # sonar encoded once
    core.on_sonar(beam(0.0, 0.0))
    outs = [core.on_camera(shade(0.05 * (k + 1), 10 * (k + 1))) for k in range(3)]
    assert [len(o) for o in outs] == [0, 2, 1]          # two camera embeddings: released; the sonar joins with one
    sonar_bits = {o.sdrs["sonar"][0] for o in outs[1] + outs[2]}
    assert sonar_bits == {500000 + 100000}          # the one sonar frame centred by itself, also after the hold
    capped = EncoderCore(CountingEncoder(), clock("camera"), hold=10, hold_max=3)
    assert [len(capped.on_camera(frame(0.1 * k))) for k in range(4)] == [0, 0, 3, 1]   # at most hold_max held


def test_no_hold_when_the_statistics_are_settled_and_the_end_flushes_what_is_held() -> None:
    core = EncoderCore(StubEncoder(), clock("camera"), hold=10)
    assert len(core.on_camera(frame(0.1))) == 1 and not core.holding
    held = EncoderCore(CountingEncoder(), clock("camera"), hold=10)
    assert held.on_camera(frame(0.1)) == [] and held.on_camera(frame(0.2)) == []
    assert [o.stamp for o in held.flush()] == [int(0.1 * S), int(0.2 * S)] and held.flush() == []
    with pytest.raises(ValueError, match="hold"):
        EncoderCore(StubEncoder(), clock(), hold=-1)


def test_warm_up_hold_ends_by_event_time_even_without_new_outputs() -> None:
    core = EncoderCore(CountingEncoder(), clock("sonar"), hold=10, hold_max=50, hold_max_ns=2 * S)
    outs = [core.on_sonar(beam(k * 0.05, 9.0 * k)) for k in range(41)]   # one sweep: one sonar-clocked output
    assert sum(len(o) for o in outs) == 0 and core.oldest_held_stamp == int(round(40 * 0.05 * S))
    assert core.expire(int(round(3.9 * S))) == []                        # 1.9 s past it: still held
    released = core.expire(4 * S)                                         # 2 s past it: released by event time
    assert [o.stamp for o in released] == [int(round(40 * 0.05 * S))] and not core.holding
    with pytest.raises(ValueError, match="hold_max_ns"):
        EncoderCore(StubEncoder(), clock(), hold=1, hold_max_ns=0)
