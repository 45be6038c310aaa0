"""PoseCellNetwork: attractor stability, path integration, injection, centroid, persistence."""
import math
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest

from services.posecells.config import PoseCellsConfig
from services.posecells.network import PoseCellNetwork, gaussian_kernel, wrapped_centroid_cells

DIMS = (15, 15, 15, 8)


def settled(cell: tuple[float, float, float, float] = (7, 7, 7, 0), updates: int = 30, **cfg: Any) -> PoseCellNetwork:
    net = PoseCellNetwork(PoseCellsConfig(**cfg))
    net.reset(cell)
    for _ in range(updates):
        net.update()
    return net


_DIMS_F = np.array(DIMS, dtype=float)


def wrapped_diff(a: npt.ArrayLike, b: npt.ArrayLike, n: np.ndarray = _DIMS_F) -> np.ndarray:
    out: np.ndarray = (np.asarray(a) - np.asarray(b) + n / 2) % n - n / 2
    return out


def unimodal_along_every_axis(p: np.ndarray) -> bool:
    """Each marginal rises to its peak and falls after it, walking around the wrap."""
    for axis in range(4):
        m = p.sum(axis=tuple(a for a in range(4) if a != axis))
        n = m.size
        peak = int(np.argmax(m))
        right = [m[(peak + k) % n] for k in range(n // 2 + 1)]
        left = [m[(peak - k) % n] for k in range(n // 2 + 1)]
        if any(b > a + 1e-15 for a, b in zip(right, right[1:])) or any(b > a + 1e-15 for a, b in zip(left, left[1:])):
            return False
    return True


def test_gaussian_kernel_sums_to_one_and_never_wraps_onto_itself() -> None:
    for sigma, n in ((1.0, 15), (1.0, 8), (3.0, 8), (0.5, 15)):
        off, w = gaussian_kernel(sigma, n)
        assert w.sum() == pytest.approx(1.0)
        assert len(set(o % n for o in off)) == off.size  # no cell reached twice
        assert np.all(w[: off.size // 2] < w[off.size // 2])


def test_lone_packet_stays_one_packet_with_total_one_after_100_updates() -> None:
    net = PoseCellNetwork(PoseCellsConfig())
    net.reset((3, 11, 0, 7))  # on the z wrap edge and the last yaw bin
    for _ in range(100):
        net.update()
    p = net.P
    assert p.sum() == pytest.approx(1.0, abs=1e-12)
    assert p.min() >= 0.0
    active = int((p > 0).sum())
    assert 0 < active < 0.05 * p.size, active  # compact: a few hundred of 27000 cells
    assert unimodal_along_every_axis(p)
    assert np.allclose(wrapped_diff(net.centroid_cells(), (3, 11, 0, 7)), 0.0, atol=1e-9)
    # the yaw axis keeps a heading (RatSLAM's phi = 0.00002 flattens it to uniform: rho ~ 0)
    rho, _ = net.heading_concentration()
    assert rho > 0.5
    # and it is a fixed point: 100 more updates change nothing of note
    before = p.copy()
    for _ in range(100):
        net.update()
    assert np.abs(net.P - before).sum() < 1e-9


def test_global_inhibition_too_strong_is_a_clear_error() -> None:
    net = PoseCellNetwork(PoseCellsConfig(global_inhibition=0.5))
    with pytest.raises(RuntimeError, match="posecells.global_inhibition"):
        net.update()


@pytest.mark.parametrize("motion, expected", [
    ((0.1, 0.0, 0.0, 0.0), (1, 0, 0, 0)),   # forward with heading east (yaw bin 0) = +x
    ((0.0, 0.1, 0.0, 0.0), (0, 1, 0, 0)),   # left of east = +y
    ((0.0, 0.0, 0.1, 0.0), (0, 0, 1, 0)),   # up = +z
    ((0.0, 0.0, 0.0, 2 * math.pi / 8), (0, 0, 0, 1)),  # one yaw bin of turn
])
def test_one_cell_of_motion_moves_the_centroid_by_one_cell(motion: tuple[float, float, float, float],
                                                           expected: tuple[int, int, int, int]) -> None:
    net = settled()
    c0 = net.centroid_cells()
    net.path_integrate(*motion)
    assert np.allclose(wrapped_diff(net.centroid_cells(), c0), expected, atol=1e-9)
    net.update()  # the attractor keeps it there
    assert np.allclose(wrapped_diff(net.centroid_cells(), c0), expected, atol=1e-9)


def test_forward_follows_the_packet_heading() -> None:
    net = settled(cell=(7, 7, 7, 2))  # heading north (90 deg)
    c0 = net.centroid_cells()
    net.path_integrate(0.1, 0.0, 0.0, 0.0)
    assert np.allclose(wrapped_diff(net.centroid_cells(), c0), (0, 1, 0, 0), atol=1e-9)
    net = settled(cell=(7, 7, 7, 3))  # 135 deg: forward 0.1 m = (-0.0707, +0.0707) m
    c0 = net.centroid_cells()
    net.path_integrate(0.1, 0.0, 0.0, 0.0)
    assert np.allclose(wrapped_diff(net.centroid_cells(), c0), (-math.sqrt(0.5), math.sqrt(0.5), 0, 0), atol=1e-9)


def test_whole_cell_moves_are_exact_rolls_of_the_activity() -> None:
    net = settled()
    p0 = net.P.copy()
    net.path_integrate(0.0, 0.0, 0.1, 0.0)
    assert np.array_equal(net.P, np.roll(p0, 1, axis=2))
    net.path_integrate(0.0, 0.0, 0.0, -2 * (2 * math.pi / 8))
    assert np.allclose(net.P, np.roll(np.roll(p0, 1, axis=2), -2, axis=3), atol=1e-15)


@pytest.mark.parametrize("half_move", [(0.05, 0.0, 0.0, 0.0), (0.0, 0.05, 0.0, 0.0), (0.0, 0.0, 0.05, 0.0),
                                       (0.0, 0.0, 0.0, math.pi / 8), (0.05, -0.05, 0.05, 0.0)])
def test_two_moves_of_half_a_cell_equal_one_move_of_one_cell(half_move: tuple[float, float, float, float]) -> None:
    half, whole = settled(), settled()
    for _ in range(2):
        half.path_integrate(*half_move)
    whole.path_integrate(*(2 * v for v in half_move))
    assert np.allclose(half.centroid_cells(), whole.centroid_cells(), atol=1e-9)
    assert np.array_equal(half.activity, whole.activity)  # activity included
    for _ in range(10):
        half.update()
        whole.update()
    assert np.array_equal(half.activity, whole.activity)
    assert np.allclose(half.centroid_cells(), whole.centroid_cells(), atol=1e-9)


def test_slow_motion_is_integrated_without_loss() -> None:
    """A 0.01 cell-per-step drift (a slow turn at 4 Hz) adds up: the attractor does not pin it."""
    net = settled()
    c0 = net.centroid_cells()
    for _ in range(300):
        net.step(forward=0.001, up=-0.0005, dyaw=0.01 * 2 * math.pi / 8)
    moved = wrapped_diff(net.centroid_cells(), c0)
    assert moved[2] == pytest.approx(-1.5, abs=1e-9)
    assert moved[3] == pytest.approx(3.0, abs=1e-9)


def test_packet_tracks_a_long_odometry_path() -> None:
    """A lap of constant motion: the centroid's unwrapped advance equals the distance."""
    net = settled()
    prev = net.centroid_cells()
    travelled = np.zeros(4)
    for _ in range(30):
        net.step(forward=0.07, up=-0.03, dyaw=0.0)
        now = net.centroid_cells()
        travelled += wrapped_diff(now, prev)
        prev = now
    assert travelled[0] == pytest.approx(30 * 0.7, rel=0.03)
    assert travelled[2] == pytest.approx(-30 * 0.3, rel=0.08)
    assert abs(travelled[1]) < 1e-6 and abs(travelled[3]) < 1e-6


def test_centroid_is_right_across_the_wrap_boundary() -> None:
    # a packet centred on the x = 0 / 14 seam and the yaw 7 / 0 seam
    net = settled(cell=(14.5, 7, 0, 7.5))
    c = net.centroid_cells()
    assert np.allclose(wrapped_diff(c, (14.5, 7, 0, 7.5)), 0.0, atol=1e-6)
    x, y, z, yaw = net.centroid()
    assert x == pytest.approx(1.45, abs=1e-6) and z == pytest.approx(0.0, abs=1e-6)
    assert yaw == pytest.approx(-math.pi / 8, abs=1e-6)  # bin 7.5 of 8 = 337.5 deg
    # a naive mean of the indices would be far off (toward the middle of the lattice)
    m = net.P.sum(axis=(1, 2, 3))
    assert abs(float(m @ np.arange(15)) - 14.5) > 5


def test_wrapped_centroid_of_a_marginal() -> None:
    m = np.zeros(10)
    m[[9, 0, 1]] = [1, 2, 1]
    assert wrapped_centroid_cells(m) == pytest.approx(0.0)
    m = np.zeros(10)
    m[[8, 9]] = [1, 1]
    assert wrapped_centroid_cells(m) == pytest.approx(8.5)
    with pytest.raises(ValueError):
        wrapped_centroid_cells(np.zeros(5))


def test_associations_are_sparse_capped_and_mature_after_the_lvc_is_gone() -> None:
    net = settled()
    for _ in range(40):  # LVCs 5 and 9 stay active while the packet moves 4 cells
        net.step(forward=0.01, active_lvcs=[5, 9])
    assert not net.beta and set(net.episode_beta) == {5, 9}  # an open episode is not injected
    b = net.episode_beta[5]
    assert 0 < b.cells.size <= net.cfg.beta_max_cells
    assert b.cells.dtype == np.int32 and b.values.dtype == np.float32
    assert np.all(np.diff(b.cells) > 0)
    assert np.array_equal(net.episode_beta[9].cells, b.cells)  # both active: same association
    assert float(b.values.max()) <= net.activity.max() * 1.5  # Eq. 4.19: max over time of lambda P
    for _ in range(net.cfg.lvc_maturity_steps):
        net.step(active_lvcs=[1])
    assert not net.beta  # absent for exactly lvc_maturity_steps frames: still open
    net.step(active_lvcs=[1])
    assert set(net.beta) == {5, 9} and set(net.episode_beta) == {1}
    assert np.array_equal(net.beta[5].cells, b.cells) and np.array_equal(net.beta[5].values, b.values)
    assert net.beta_cells() == 2 * b.cells.size + net.episode_beta[1].cells.size


def test_an_lvc_held_over_consecutive_frames_does_not_drag_the_packet_back() -> None:
    def run(maturity: int) -> float:
        net = settled(lvc_maturity_steps=maturity)
        c0 = net.centroid_cells()
        for _ in range(12):  # one id for 12 frames while moving 0.5 cell per frame
            net.step(forward=0.05, active_lvcs=[4])
        return float(wrapped_diff(net.centroid_cells(), c0)[0])

    assert run(10) == pytest.approx(6.0, abs=1e-9)
    assert run(0) < 5.5  # literal Eq. 4.19: the association of the previous frames pulls back


def revisit_setup(**cfg: Any) -> tuple[PoseCellNetwork, np.ndarray]:
    net = settled(**cfg)
    stored = net.centroid_cells()
    for _ in range(5):
        net.step(active_lvcs=[7])  # LVC 7 learns the pose (7, 7, 7, 0)
    for _ in range(net.cfg.lvc_maturity_steps + 1):
        net.step()  # LVC 7 gone: its association matures
    return net, stored


def test_injection_of_a_learned_lvc_pulls_the_packet_back_to_the_stored_pose() -> None:
    net, stored = revisit_setup()
    assert 7 in net.beta
    net.path_integrate(0.3, 0.0, 0.0, 0.0)  # drift: 3 cells away
    away = wrapped_diff(net.centroid_cells(), stored)[0]
    assert away == pytest.approx(3.0, abs=1e-6)
    control = PoseCellNetwork(net.cfg)
    control.activity[:] = net.activity
    control.offset[:] = net.offset
    for _ in range(40):
        net.step(active_lvcs=[7])  # revisit: LVC 7 seen again
        control.step()  # no LVC evidence: no pull
    pulled = wrapped_diff(net.centroid_cells(), stored)[0]
    assert pulled < 1.5, (away, pulled)
    assert wrapped_diff(control.centroid_cells(), stored)[0] == pytest.approx(away, abs=1e-6)
    # a stronger injection gain relocalises from farther away, within a few frames
    strong, stored = revisit_setup(lvc_injection_gain=1.0)
    strong.path_integrate(0.5, 0.0, 0.0, 0.0)
    for _ in range(10):
        strong.step(active_lvcs=[7])
    assert abs(wrapped_diff(strong.centroid_cells(), stored)[0]) < 0.1


def test_save_load_continue_equals_an_uninterrupted_run(tmp_path: Path) -> None:
    def drive(net: PoseCellNetwork, k0: int, k1: int) -> None:
        for k in range(k0, k1):
            net.step(forward=0.03 + 0.01 * (k % 3), left=0.01, up=0.002 * (k % 5 - 2), dyaw=0.05,
                     active_lvcs=[k // 4, 100 + k % 7])

    a = settled()
    drive(a, 0, 60)
    b = settled()
    drive(b, 0, 25)
    b.save(tmp_path / "pc.npz")
    c = PoseCellNetwork.load(tmp_path / "pc.npz", PoseCellsConfig())
    drive(c, 25, 60)
    assert np.array_equal(a.activity, c.activity)
    assert sorted(a.beta) == sorted(c.beta)
    for k in a.beta:
        assert np.array_equal(a.beta[k].cells, c.beta[k].cells) and np.array_equal(a.beta[k].values, c.beta[k].values)
    assert a.steps == c.steps == 60


def test_loading_a_state_of_another_lattice_names_the_file(tmp_path: Path) -> None:
    settled().save(tmp_path / "pc.npz")
    with pytest.raises(ValueError, match="pc.npz.*number_of_neurons"):
        PoseCellNetwork.load(tmp_path / "pc.npz", PoseCellsConfig(number_of_neurons=[11, 11, 11, 8]))


def dense_reference_update(p: np.ndarray, cfg: PoseCellsConfig) -> np.ndarray:
    """Eqs. 4.16-4.17 the obvious way: np.roll per kernel tap, every cell."""
    sig = (cfg.excitation_sigma_cells,) * 3 + (cfg.excitation_sigma_yaw_cells,)
    for axis, (s, n) in enumerate(zip(sig, DIMS)):
        offsets, weights = gaussian_kernel(s, n)
        p = sum(w * np.roll(p, int(o), axis=axis) for o, w in zip(offsets, weights))
    p = np.maximum(p - cfg.global_inhibition, 0.0)
    out: np.ndarray = p / p.sum()
    return out


def test_sparse_update_equals_the_dense_reference_after_moves_and_injections() -> None:
    net = settled(updates=10, lvc_maturity_steps=0)
    for k in range(12):
        net.mature()
        net.path_integrate(0.13, -0.07, 0.05 * (k % 2), 0.4)
        assert net.inject([1, 2, 3]) == min(k, 3)
        before = net.P.copy()
        net.update()
        assert np.allclose(net.P, dense_reference_update(before, net.cfg), rtol=0, atol=1e-15)
        net.learn([1 + k % 3])
        net.steps += 1
    assert net._tmp.any() == False  # noqa: E712 - the scratch the update relies on stays zero


@pytest.mark.parametrize("cell", [(0, 0, 0, 0), (14, 1, 13, 7), (2, 12, 7, 3)])
def test_sparse_update_equals_the_dense_reference_where_the_packet_wraps(cell: tuple[int, int, int, int]) -> None:
    # a packet at the lattice's ends: its excitation takes the wrapping path on every axis,
    # the cells r or more from both ends the straight one
    net = settled(cell=cell, updates=5)
    for _ in range(5):
        before = net.P.copy()
        net.update()
        assert np.allclose(net.P, dense_reference_update(before, net.cfg), rtol=0, atol=1e-15)
    assert net._tmp.any() == False  # noqa: E712 - the scratch the update relies on stays zero
