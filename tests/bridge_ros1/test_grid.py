"""The bridge's live ``/map`` grid builder without ROS (services/bridge_ros1/grid.py): the same grid
as ``poseidon export --grid`` from the same messages, rebuilt at most every period of event
time, bounded in memory, and following a map correction."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from services.bridge_ros1.config import BridgeRos1Config
from services.bridge_ros1.convert import Outgoing
from services.bridge_ros1.grid import GridUpdate, LiveGrid
from tests.bridge_ros1.gridrun import RES, drift_run, exported, feed, sonar_model, wall_offsets


def _grid(period_s: float = 5.0, max_returns: int = 10_000_000, max_poses: int = 1_000_000,
          sonar: bool = False) -> LiveGrid:
    return LiveGrid(period_s, RES, max_returns, max_poses, 16_000_000, sonar_model() if sonar else None)


def _on_walls(g: GridUpdate) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    f = g.frame
    return wall_offsets(f.origin, f.resolution, f.width, f.height, g.data)


@pytest.mark.parametrize("sensor", ["laser", "sonar"])
def test_the_live_grid_is_the_export_grid_of_the_same_messages(tmp_path: Path, sensor: str) -> None:
    run = drift_run(tmp_path, sensor)
    live = _grid(sonar=sensor == "sonar")
    feed(live, run)
    g = live.build(force=True)
    assert g is not None
    frame, cells = exported(run)
    assert g.frame == frame                      # resolution, origin, width and height
    assert g.data.dtype == np.int8 and np.array_equal(g.data, cells)
    assert set(np.unique(g.data)) == {-1, 0, 100}
    _x, _y, off = _on_walls(g)
    assert len(off) > 300 and np.max(off) <= 2.5 * RES, "an occupied cell off the corridor's walls"


def test_rebuilt_at_most_every_period_of_event_time_and_only_when_something_changed(tmp_path: Path) -> None:
    run = drift_run(tmp_path)
    live = _grid(period_s=5.0)
    built: list[int] = []

    def maybe() -> None:
        if live.due():
            g = live.build()
            assert g is None or g.stamp == live.clock
            built.append(live.clock or 0)
    feed(live, run, on_each=maybe)
    gaps = np.diff(built)
    span_s = (built[-1] - built[0]) / 1e9
    assert len(built) >= 10 and np.min(gaps) >= 5e9, built   # ~80 s of event time fed in no wall time at all
    assert len(built) <= span_s / 5 + 1
    assert not live.due()                        # nothing new since the last build
    last = live.build(force=True)                # the end: what came since the last build
    assert last is not None and live.build(force=True) is None   # nothing changed since
    assert _grid(period_s=0.0).enabled is False


def test_memory_is_bounded_and_thinned_returns_keep_their_weight(tmp_path: Path) -> None:
    run = drift_run(tmp_path)
    full = _grid()
    feed(full, run)
    ref = full.build(force=True)
    bounded = _grid(max_returns=5000, max_poses=150)
    peak = [0, 0]

    def watch() -> None:
        peak[0] = max(peak[0], bounded._laser.n)
        peak[1] = max(peak[1], len(bounded._poses[0]) + len(bounded._odom))
    feed(bounded, run, on_each=watch)
    g = bounded.build(force=True)
    assert ref is not None and g is not None
    assert peak[0] <= 5000 and bounded.thinned > 60_000 and bounded.dropped == 0
    assert g.returns == ref.returns              # each kept return stands for those it replaced
    print(f"bounded: {bounded._laser.n} of {ref.returns} returns kept, {len(bounded._poses[0])} poses")
    assert len(bounded._poses[0]) <= 150 and peak[1] <= 150 + 150 // 4
    x, y, off = _on_walls(g)
    assert np.max(off) <= 3 * RES and len(off) > 300
    for wall in (1.5, -1.5):
        assert np.ptp(x[np.abs(y - wall) < 0.1]) > 19.0, f"the wall at y={wall} m is not drawn end to end"


def test_a_map_correction_moves_the_walls_onto_the_corrected_poses(tmp_path: Path) -> None:
    run = drift_run(tmp_path)
    live = _grid()
    feed(live, run, skip=("map",))
    before = live.build(force=True)              # dead reckoning: the way back draws the walls elsewhere
    feed(live, run, skip=("scan", "Odometry"))   # the experience map arrives (a loop closure's result)
    after = live.build(force=True)
    assert before is not None and after is not None
    _x, _y, off_before = _on_walls(before)
    _x, _y, off_after = _on_walls(after)
    assert np.mean(off_before > 0.3) > 0.2, "the drifting odometry should draw walls off the corridor"
    assert np.max(off_after) <= 2.5 * RES
    assert after.returns == before.returns       # the same returns, moved


def test_the_grid_serialises_as_nav_msgs_occupancy_grid(tmp_path: Path) -> None:
    from rosbags.typesys import Stores, get_typestore

    live = _grid()
    feed(live, drift_run(tmp_path))
    g = live.build(force=True)
    assert g is not None
    msg = get_typestore(Stores.ROS1_NOETIC).deserialize_ros1(Outgoing().occupancy_grid(g), "nav_msgs/msg/OccupancyGrid")
    assert (msg.info.width, msg.info.height) == (g.frame.width, g.frame.height)
    assert msg.info.resolution == pytest.approx(RES) and msg.header.frame_id == "odom"
    assert (msg.info.origin.position.x, msg.info.origin.position.y) == pytest.approx(g.frame.origin)
    assert np.array_equal(msg.data, g.data) and msg.header.stamp.sec == g.stamp // 1_000_000_000
    c = BridgeRos1Config()
    assert c.grid_topic == "/map" and c.grid_resolution_m == RES and c.grid_period_s > 0
