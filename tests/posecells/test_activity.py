"""``posecells/activity``: the node publishes the activity's x-y and z-yaw projections at the
configured event-time rate; they are the network's, sum to its total activity and peak at its
centroid; the same input gives the same bytes; a period of 0 publishes nothing."""
from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from common.codec import encode
from common.messages import PoseCellActivity
from common.node import run_offline
from services.posecells.activity import ACTIVITY_KEY, activity_projections, quantise
from system.config import PoseidonConfig
from system.services import build_node, node_io
from tests.posecells.test_posecells_node import NS, stream


def _config(period_s: float) -> PoseidonConfig:
    cfg = PoseidonConfig()
    cfg.posecells.activity_period_s = period_s
    return cfg


def _wrapped(a: float, b: float, n: int) -> float:
    d = abs(a - b) % n
    return min(d, n - d)


def test_activity_at_the_configured_rate_is_the_network_s_and_peaks_at_the_centroid() -> None:
    node: Any = build_node("posecells", _config(0.5))
    msgs = stream(seconds=30.0, ids=lambda k: (k // 3) % 9)   # revisits: injections move the packet
    frames = [m for k, m in msgs if k == "local_view_cells"]
    published: list[PoseCellActivity] = []
    for key, msg in msgs:   # no equal stamps: this is the order the runtime delivers
        node.process(key, msg)
        for k, out in node.take_outbox():
            if k != ACTIVITY_KEY:
                continue
            assert isinstance(out, PoseCellActivity)
            # the network's projections as they are now, quantised the same way
            xy, zyaw = activity_projections(node.net.P)
            (qxy, sxy), (qzyaw, szyaw) = quantise(xy), quantise(zyaw)
            assert out.xy.tobytes() == qxy.tobytes() and out.zyaw.tobytes() == qzyaw.tobytes()
            assert (out.xy_scale, out.zyaw_scale) == (sxy, szyaw) and out.centroid == node.net.centroid()
            published.append(out)
    # frames every 0.25 s: one message per 0.5 s of event time, the first at the first step
    stamps = [m.header.stamp for m in published]
    assert stamps[0] == frames[0].header.stamp
    assert set(np.diff(stamps)) == {NS // 2}
    assert len(published) == (len(frames) + 1) // 2
    assert [m.header.seq for m in published] == list(range(len(published)))
    assert {m.header.frame_id for m in published} == {"camera"}
    nx, ny, nz, n_yaw = node.net.dims
    for m in published:
        assert m.xy.shape == (nx, ny) and m.zyaw.shape == (nz, n_yaw) and m.xy.dtype == np.uint8
        # both projections hold the whole activity (1 after each update), up to the uint8 rounding
        total_xy, total_zyaw = m.xy.sum() * m.xy_scale, m.zyaw.sum() * m.zyaw_scale
        assert total_xy == pytest.approx(1.0, abs=0.02) and total_zyaw == pytest.approx(1.0, abs=0.02)
        assert m.xy.max() == m.zyaw.max() == 255
        # the peak cell is within a cell of the centroid (sub-cell offset included), on every axis
        cx, cy, cz = (c / s for c, s in zip(m.centroid[:3], m.spacing))
        cq = (m.centroid[3] % (2 * math.pi)) / (2 * math.pi / n_yaw)
        px, py = np.unravel_index(int(np.argmax(m.xy)), m.xy.shape)
        pz, pq = np.unravel_index(int(np.argmax(m.zyaw)), m.zyaw.shape)
        assert _wrapped(px, cx, nx) <= 1.0 and _wrapped(py, cy, ny) <= 1.0
        assert _wrapped(pz, cz, nz) <= 1.0 and _wrapped(pq, cq, n_yaw) <= 1.0
    # the packet moved over the run: the centroids differ
    assert len({tuple(np.round(m.centroid, 2)) for m in published}) > 10


def test_the_period_bounds_the_rate_and_zero_turns_it_off() -> None:
    msgs = stream(seconds=10.0)
    slow = [m for k, m in run_offline(build_node("posecells", _config(0.6)), msgs) if k == ACTIVITY_KEY]
    assert len(slow) > 5 and set(np.diff([m.header.stamp for m in slow])) == {3 * NS // 4}  # frames every 0.25 s
    cfg = _config(0.0)
    assert ACTIVITY_KEY not in node_io("posecells", cfg)[1]
    off = run_offline(build_node("posecells", cfg), msgs)
    assert off and {k for k, _ in off} == {"experience_event"}


def test_the_same_input_gives_the_same_bytes() -> None:
    msgs = stream(seconds=8.0, ids=lambda k: (k // 3) % 4)
    runs = [[(k, encode(m)) for k, m in run_offline(build_node("posecells", _config(0.5)), msgs)] for _ in range(2)]
    assert runs[0] == runs[1] and any(k == ACTIVITY_KEY for k, _ in runs[0])
