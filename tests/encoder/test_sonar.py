"""Sonar raster geometry: a beam at bearing a with an echo at range r lights the right pixel."""
from __future__ import annotations

import math

import numpy as np
import pytest

from common.messages import Header, LaserScan, RangeImageBeam
from services.encoder.sonar import SonarRaster


def beam(angle: float, echo_m: float | None, stamp: int = 0, nbins: int = 300, max_range: int = 30,
         value: int = 200, seq: int = 0) -> RangeImageBeam:
    data = np.zeros(nbins, dtype=np.int32)
    if echo_m is not None:
        data[int(echo_m / max_range * nbins)] = value
    return RangeImageBeam(header=Header(seq=seq, stamp=stamp), angle_grad=math.degrees(angle), angle_rad=angle,
                          nbins=nbins, max_range=max_range, beam_data=data)


@pytest.mark.parametrize("angle,r", [(0.0, 0.05), (1.0, 10.0), (math.pi, 29.9), (5.9, 15.0), (-0.5, 7.3)])
def test_single_beam_lights_expected_polar_pixel(angle: float, r: float) -> None:
    ras = SonarRaster(224, 224, rmax=30.0)
    ras.add_beam(beam(angle, r))
    img = ras.image()
    ys, xs = np.nonzero(img)
    col = int((angle % (2 * math.pi)) / (2 * math.pi) * 224)
    # the echo is in bin floor(r/0.1); its centre range decides the row
    centre = (int(r / 30 * 300) + 0.5) * 0.1
    assert xs.tolist() == [col]
    assert ys.tolist() == [int(centre / 30 * 224)]
    assert img[ys[0], xs[0]] == pytest.approx(200 / 255)


def test_range_beyond_rmax_is_dropped_and_shorter_rmax_scales_rows() -> None:
    ras = SonarRaster(64, 100, rmax=10.0)
    ras.add_beam(beam(0.3, 20.0, max_range=50, nbins=500))
    assert not ras.image().any()
    ras.add_beam(beam(0.3, 5.0, max_range=50, nbins=500))
    ys, _ = np.nonzero(ras.image())
    assert ys.tolist() == [int(5.05 / 10 * 100)]


def test_ring_keeps_latest_beam_per_bearing_and_fills_small_steps() -> None:
    ras = SonarRaster(360, 50, rmax=30.0)  # 1 deg per column
    step = math.radians(1.8)
    for i in range(201):  # a full sweep plus a bit
        ras.add_beam(beam(i * step, 10.0, stamp=i))
    assert ras.filled.all()  # 1.8 deg steps leave no empty 1 deg column
    assert (ras.image() > 0).sum(axis=0).max() == 1
    ras.add_beam(beam(200 * step + step, 20.0, stamp=300))  # newest beam overwrites its columns
    col = ras.column(201 * step)
    assert np.nonzero(ras.image()[:, col])[0].tolist() == [int(20.05 / 30 * 50)]
    ras.reset()
    assert not ras.has_data and not ras.image().any()


def test_intensities_off_marks_strongest_echo_only() -> None:
    ras = SonarRaster(90, 60, rmax=30.0, use_intensities=False)
    data = np.zeros(300, dtype=np.int32)
    data[50] = 40
    data[120] = 90  # strongest: 12.05 m
    ras.add_beam(RangeImageBeam(header=Header(seq=0, stamp=0), angle_grad=0.0, angle_rad=0.0, nbins=300,
                                max_range=30, beam_data=data))
    ys, xs = np.nonzero(ras.image())
    assert ys.tolist() == [int(12.05 / 30 * 60)] and xs.tolist() == [0]
    assert ras.image().max() == 1.0


def test_cartesian_fan_geometry() -> None:
    ras = SonarRaster(200, 200, rmax=30.0, cartesian=True)
    # straight up, ~half the radius (polar rows are 0.15 m, Cartesian pixels 0.3 m: pick a range
    # whose polar row contains a pixel centre)
    ras.add_beam(beam(math.pi / 2, 15.15))
    img = ras.image()
    ys, xs = np.nonzero(img)
    assert ys.size > 0
    # every lit pixel is ~15 m above the centre
    dy = (100 - (ys + 0.5)) / 100 * 30
    dx = (xs + 0.5 - 100) / 100 * 30
    assert np.all(np.abs(dx) < 1.0) and np.all(np.abs(dy - 15.15) < 0.3)


def test_laserscan_form_and_errors() -> None:
    ras = SonarRaster(100, 100, rmax=30.0)
    scan = LaserScan(header=Header(seq=0, stamp=0), angle_min=1.0, angle_max=1.0, angle_increment=0.0,
                     range_min=0.1, range_max=50.0, ranges=np.array([12.0]), intensities=np.array([255.0]))
    ras.add_scan(scan)
    ys, xs = np.nonzero(ras.image())
    assert xs.tolist() == [ras.column(1.0)] and ys.tolist() == [ras.row(12.0)] == [40]
    assert ras.image3().shape == (100, 100, 3)
    bad = beam(0.0, 5.0)
    bad.nbins = 10
    with pytest.raises(ValueError, match="nbins=10 but beam_data has 300"):
        ras.add_beam(bad)


def test_laserscan_beam_profile_matches_range_image_beam() -> None:
    # the *_ros form of one MSIS beam: a single bearing, ranges = bin centres, intensities = echoes
    b = beam(2.0, 11.0, nbins=200, max_range=20, value=150)
    centres = ((np.arange(200) + 0.5) * 20 / 200).astype(np.float32)
    scan = LaserScan(header=Header(seq=0, stamp=0), angle_min=2.0, angle_max=2.0, angle_increment=math.radians(1.8),
                     range_min=0.0, range_max=20.0, ranges=centres, intensities=b.beam_data.astype(np.float32))
    a, c = SonarRaster(128, 96, rmax=30.0), SonarRaster(128, 96, rmax=30.0)
    a.add_beam(b)
    assert c.add_scan(scan) == [2.0]
    assert np.array_equal(a.image(), c.image()) and a.image().any()


def test_laserscan_multi_bearing_scan() -> None:
    ras = SonarRaster(360, 60, rmax=30.0, use_intensities=False)
    scan = LaserScan(header=Header(seq=0, stamp=0), angle_min=0.0, angle_max=math.radians(20),
                     angle_increment=math.radians(10), range_min=0.5, range_max=40.0,
                     ranges=np.array([5.0, np.inf, 25.0]), intensities=np.zeros(0))
    assert ras.add_scan(scan) == pytest.approx([0.0, math.radians(10), math.radians(20)])
    img = ras.image()
    assert img[ras.row(5.0), ras.column(0.0)] == 1.0 and img[ras.row(25.0), ras.column(math.radians(20))] == 1.0
    # each ray fills the columns back to the previous bearing (10 deg <= max_fill): the inf return
    # clears columns 1-10, the 25 m return lights columns 11-20
    assert img.sum() == 11.0 and img[ras.row(25.0), 15] == 1.0 and not img[:, 1:11].any()


def test_beam_profile_kernel_is_bit_for_bit_the_array_expression() -> None:
    """The compiled beam profile equals the numpy expression it replaced (float32 intensities /
    scale clipped, row = bin centre / rmax * height, maximum per row), bit for bit, over
    random beams: long and short, ranges beyond rmax, intensities above the scale."""
    rng = np.random.default_rng(5)
    raster = SonarRaster(width=224, height=224, rmax=30.0, intensity_scale=255.0)
    for _ in range(300):
        n = int(rng.integers(1, 600))
        max_range = int(rng.integers(1, 80))
        data = rng.integers(0, 400, n).astype(np.int32)
        centres = (np.arange(n) + 0.5) * (float(max_range) / n)
        vals = np.clip(data.astype(np.float32) / raster.intensity_scale, 0.0, 1.0)
        want = raster._profile_from_bins(vals, centres)
        raster.add_beam(RangeImageBeam(header=Header(seq=0, stamp=1), angle_grad=0.0, angle_rad=0.0, nbins=n,
                                       max_range=max_range, beam_data=data))
        assert np.array_equal(raster.polar[:, 0].view(np.uint32), want.view(np.uint32))


def _scan_by_bearing(raster: SonarRaster, msg: LaserScan) -> list[float]:
    """The per-bearing reference: one profile per bearing through ``_write``."""
    ranges = np.asarray(msg.ranges, dtype=np.float64)
    inten = np.asarray(msg.intensities, dtype=np.float64)
    angles = []
    for i, r in enumerate(ranges):
        angle = msg.angle_min + i * msg.angle_increment
        prof = np.zeros(raster.height, dtype=np.float32)
        row = raster.row(float(r)) if math.isfinite(r) and msg.range_min <= r <= msg.range_max else -1
        if row >= 0:
            prof[row] = float(np.clip(inten[i] / raster.intensity_scale, 0.0, 1.0)) \
                if raster.use_intensities and inten.size else 1.0
        raster._write(angle, prof, msg.header.stamp)
        angles.append(float(angle))
    return angles


@pytest.mark.parametrize("use_intensities", [True, False])
def test_multi_bearing_scan_kernel_is_bit_for_bit_the_per_bearing_writes(use_intensities: bool) -> None:
    """Scans of random bearings (negative starts and steps, steps above the fill limit), ranges
    (NaN, inf, beyond rmax and range_max) and intensities (with and without): the compiled ring
    update equals writing each bearing's profile in turn, bit for bit, with the same bearings."""
    rng = np.random.default_rng(11)
    fast = SonarRaster(width=90, height=64, rmax=20.0, use_intensities=use_intensities)
    slow = SonarRaster(width=90, height=64, rmax=20.0, use_intensities=use_intensities)
    for k in range(120):
        n = int(rng.integers(1, 200))
        ranges = rng.uniform(-1.0, 35.0, n)
        ranges[rng.random(n) < 0.05] = np.nan
        ranges[rng.random(n) < 0.05] = np.inf
        inten = rng.uniform(-50.0, 400.0, n) if k % 3 else np.zeros(0)
        inc = float(rng.choice([math.radians(1.0), -math.radians(0.5), math.radians(14.0), 0.013]))
        msg = LaserScan(header=Header(seq=k, stamp=k), angle_min=float(rng.uniform(-7.0, 7.0)),
                        angle_max=float(rng.uniform(7.5, 9.0)), angle_increment=inc, range_min=0.2,
                        range_max=30.0, ranges=ranges, intensities=inten)
        assert fast.add_scan(msg) == _scan_by_bearing(slow, msg)
        assert np.array_equal(fast.polar.view(np.uint32), slow.polar.view(np.uint32))
        assert np.array_equal(fast.filled, slow.filled)
        assert (fast.last_angle, fast.last_stamp, fast.beams) == (slow.last_angle, slow.last_stamp, slow.beams)
