"""SonarClock and EncoderCore driven directly (no node, no transport; a stub encoder instead of the CNN)."""
from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np
import pytest

from common.messages import Header, Image, RangeImageBeam
from services.encoder.clock import EncoderCore, SonarClock
from services.encoder.sonar import SonarRaster

S = 1_000_000_000
STALE = S // 2


def beam(t: float, deg: float, seq: int = 0) -> RangeImageBeam:
    data = np.zeros(50, dtype=np.int32)
    data[10] = 200
    a = math.radians(deg) % (2 * math.pi)
    return RangeImageBeam(header=Header(seq=seq, stamp=int(round(t * S)), frame_id="sonar"),
                          angle_grad=math.degrees(a), angle_rad=a, nbins=50, max_range=30, beam_data=data)


def frame(t: float) -> Image:
    return Image(header=Header(seq=0, stamp=int(round(t * S)), frame_id="cam"), height=8, width=8,
                 encoding="rgb8", data=np.zeros((8, 8, 3), np.uint8))


def clock(mode: str = "union", reencode_deg: float = 45.0) -> SonarClock:
    return SonarClock(SonarRaster(32, 32, 30.0), mode, STALE, math.radians(reencode_deg))


def test_sweep_clock_fires_after_360_deg_while_the_camera_is_silent() -> None:
    c = clock()
    fired = []
    for k in range(60):
        if c.add(beam(k * 0.05, 9.0 * k)).clocked:
            c.emitted()
            fired.append(k)
    assert fired == [40]   # 40 steps of 9 deg; the first beam has no predecessor
    assert c.sweep_rad == pytest.approx(math.radians(9.0 * 19))   # counted from the output at beam 40


def test_sweep_clock_stays_off_while_the_camera_is_fresh_and_in_camera_mode() -> None:
    c = clock()
    ups = []
    for k in range(60):
        c.camera_seen(int(k * 0.05 * S))
        ups.append(c.add(beam(k * 0.05, 9.0 * k)))
    assert not any(u.clocked for u in ups)
    cam = clock("camera")
    assert not any(cam.add(beam(k * 0.05, 9.0 * k)).clocked for k in range(60))
    son = clock("sonar")
    son.camera_seen(0)
    assert [k for k in range(45) if son.add(beam(k * 0.05, 9.0 * k)).clocked] == [40, 41, 42, 43, 44]


def test_a_gap_resets_the_ring_and_forgets_the_sonar_sdr() -> None:
    c = clock()
    for k in range(10):
        c.add(beam(k * 0.05, 9.0 * k))
    c.encoded(np.array([1, 2], np.uint32))
    assert not c.due and c.sweep_rad > 0
    up = c.add(beam(10.0, 0.0))   # 9.5 s later: stale
    assert up.reset and up.beams == 1 and c.sweep_rad == 0.0 and c.sonar_sdr is None and c.due


def test_re_encoding_rule_and_freshness() -> None:
    c = clock(reencode_deg=45.0)
    assert not c.fresh(0)                        # no beams yet
    c.add(beam(1.0, 0.0))
    assert c.fresh(int(1.2 * S)) and not c.fresh(int(1.6 * S))
    assert c.due                                 # no SDR yet
    c.encoded(np.array([3], np.uint32))
    for k in range(1, 5):
        c.add(beam(1.0 + 0.05 * k, 9.0 * k))     # 36 deg
    assert not c.due
    c.add(beam(1.25, 45.0))                      # 45 deg
    assert c.due
    assert not clock("camera").fresh(0)


class StubEncoder:
    """Embedding = mean of the image; SDR = [round(1000 * y)] per modality."""

    def __init__(self) -> None:
        self.batches: list[int] = []

    def embed(self, images: Sequence[np.ndarray]) -> list[np.ndarray]:
        self.batches.append(len(images))
        return [np.array([float(np.mean(im))], np.float32) for im in images]

    def sdr(self, modality: str, embedding: np.ndarray) -> np.ndarray:
        return np.array([int(round(1000 * float(embedding[0]))) + (0 if modality == "camera" else 100000)], np.uint32)

    def fuse(self, sdrs: Mapping[str, np.ndarray | None], mode: str | None = None) -> np.ndarray:
        out: np.ndarray = np.unique(np.concatenate([v for v in sdrs.values() if v is not None]))
        return out


def test_core_batches_camera_and_due_sonar_and_reuses_the_sonar_sdr() -> None:
    enc = StubEncoder()
    core = EncoderCore(enc, clock())
    core.on_sonar(beam(0.0, 0.0))
    out = core.on_camera(frame(0.1))
    assert out is not None and set(out) == {"camera", "sonar"} and enc.batches == [2]
    core.on_sonar(beam(0.15, 9.0))
    out2 = core.on_camera(frame(0.2))           # 9 deg < 45: reused
    assert out2 is not None and enc.batches == [2, 1] and np.array_equal(out2["sonar"], out["sonar"])
    ev = [k for k, _n in core.take_events()]
    assert ev == ["sonar_beams", "sonar_encodings", "sonar_beams", "sonar_sdr_reused"]
    assert core.on_camera(frame(5.0)) == {"camera": out2["camera"]}    # stale sonar: camera only
    assert core.take_events() == [("frames_without_sonar", 1)]


def test_core_sonar_mode_ignores_frames_and_emits_on_the_sweep() -> None:
    core = EncoderCore(StubEncoder(), clock("sonar"))
    assert core.on_camera(frame(0.0)) is None
    outs = [core.on_sonar(beam(k * 0.05, 9.0 * k)) for k in range(81)]
    emitted = [k for k, o in enumerate(outs) if o is not None]
    assert emitted == [40, 80] and all(set(outs[k] or {}) == {"sonar"} for k in emitted)
    o40 = outs[40]
    assert o40 is not None and core.fuse(o40).tolist() == o40["sonar"].tolist()


@pytest.mark.parametrize("mode", ["union", "and"])
def test_core_camera_dropout_hands_the_clock_to_the_sonar(mode: str) -> None:
    core = EncoderCore(StubEncoder(), clock(mode))
    core.on_camera(frame(0.0))
    outs = [core.on_sonar(beam(0.01 + k * 0.05, 9.0 * k)) for k in range(50)]
    # the camera is stale after 0.5 s; the sweep since the frame's output reaches 360 deg at beam 40
    assert [k for k, o in enumerate(outs) if o is not None] == [40]
