"""SonarClock driven directly (no node, no transport): the sweep clock, the ring reset, re-encoding and freshness."""
from __future__ import annotations

import math

import numpy as np
import pytest

from common.messages import Header, Image, RangeImageBeam
from services.encoder.clock import SonarClock
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
