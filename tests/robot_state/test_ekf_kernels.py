"""The EKF kernels (services/robot_state/ekf_kernels.py): the prediction's covariance is the
analytic Jacobian's F P F' + Q (checked against a numerical Jacobian of the state step), and
the restricted update is the Joseph form with the gain zeroed outside the updated states."""
from __future__ import annotations

import numpy as np
import pytest

from services.robot_state.ekf_kernels import N_STATE, predict, restricted_update


def _spd(rng: np.random.Generator) -> np.ndarray:
    a = rng.normal(size=(N_STATE, N_STATE)) * 0.1
    return a @ a.T + np.eye(N_STATE) * 1e-3


def _state(rng: np.random.Generator) -> np.ndarray:
    x = rng.normal(size=N_STATE) * 0.1
    x[3:6] = [0.6, -0.1, 0.05]          # body velocity (m/s)
    x[6:9] = [0.05, -0.08, 1.2]         # roll, pitch, yaw (rad), yaw far from the wrap
    return x


@pytest.mark.parametrize("gyro_on, integrate, z_moves, a", [(True, True, True, 1.0), (True, True, False, 1.0),
                                                            (False, True, True, 0.9), (True, False, False, 1.0)])
def test_the_prediction_propagates_the_covariance_through_the_state_steps_jacobian(
        gyro_on: bool, integrate: bool, z_moves: bool, a: float) -> None:
    rng = np.random.default_rng(3)
    x0, P0 = _state(rng), _spd(rng)
    gyro = np.array([0.02, -0.03, 0.1])
    dt, g, q = 0.2, 0.2 * a, (1e-4, 2e-5, 3e-5, 4e-6, 5e-7, 6e-8)

    def step(x: np.ndarray) -> np.ndarray:
        x = x.copy()
        predict(x, np.zeros((N_STATE, N_STATE)), gyro, dt, a, g, *q[:1], gyro_on, integrate, z_moves, *q[1:])
        return x

    h = 1e-6
    J = np.empty((N_STATE, N_STATE))
    for i in range(N_STATE):
        d = np.zeros(N_STATE)
        d[i] = h
        J[:, i] = (step(x0 + d) - step(x0 - d)) / (2 * h)
    Q = np.zeros(N_STATE)
    Q[3:6], Q[6:9], Q[9], Q[14], Q[11:14] = q[0], q[1], q[3], q[4], q[5]
    Q[2] = q[2]
    x, P = x0.copy(), P0.copy()
    predict(x, P, gyro, dt, a, g, q[0], gyro_on, integrate, z_moves, *q[1:])
    np.testing.assert_allclose(x, step(x0), rtol=0, atol=0)
    np.testing.assert_allclose(P, J @ P0 @ J.T + np.diag(Q), rtol=0, atol=1e-9)
    assert np.array_equal(P, P.T)
    if integrate:
        assert not np.allclose(x[0:3], x0[0:3])
    else:
        assert np.array_equal(x[0:3], x0[0:3])


def test_the_restricted_update_is_the_joseph_form_with_a_gain_only_on_its_states() -> None:
    rng = np.random.default_rng(4)
    x0, P0 = _state(rng), _spd(rng)
    H = np.zeros((2, N_STATE))
    H[0, 8] = H[0, 10] = 1.0
    H[1, 3] = 1.0
    y, R = np.array([0.01, -0.02]), np.diag([1e-4, 4e-4])
    keep = np.zeros(N_STATE, bool)
    keep[[3, 8, 10]] = True
    x, P = x0.copy(), P0.copy()
    restricted_update(x, P, H, y, R, keep)
    K = P0 @ H.T @ np.linalg.inv(H @ P0 @ H.T + R)
    K[~keep] = 0.0
    ikh = np.eye(N_STATE) - K @ H
    want = ikh @ P0 @ ikh.T + K @ R @ K.T
    np.testing.assert_allclose(x, x0 + K @ y, rtol=0, atol=1e-15)
    np.testing.assert_allclose(P, 0.5 * (want + want.T), rtol=0, atol=1e-15)
    assert np.array_equal(x[~keep], x0[~keep])          # only the kept states move
    assert not np.allclose(x[keep], x0[keep])
    assert np.linalg.eigvalsh(P).min() > 0


def test_warm_up_compiles_on_a_throwaway_filter() -> None:
    from system.config import PoseidonConfig
    from system.services import build_node
    node = build_node("robot_state", PoseidonConfig())
    f = node.filter   # type: ignore[attr-defined]
    x, P, t, counters = f.x.copy(), f.P.copy(), f.t, dict(node.counters)
    node.warm_up()
    assert np.array_equal(f.x, x) and np.array_equal(f.P, P) and f.t == t and node.counters == counters
    assert predict.signatures and restricted_update.signatures     # compiled
