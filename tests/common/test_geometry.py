"""common.geometry: angle wrapping at the seam, quaternion <-> yaw, rotations and the published frame."""
import math

import numpy as np
import pytest

from common.config import ConfigError
from common.geometry import (
    OutputFrame,
    enu_to_ned,
    euler_to_matrix,
    matrix_to_euler,
    matrix_to_quaternion,
    ned_to_enu,
    published_to_ned,
    quaternion_of_yaw,
    quaternion_to_matrix,
    rot_z,
    wrap_angle,
    wrap_angles,
    yaw_enu_to_ned,
    yaw_of_quaternion,
    yaws_of_quaternions,
)

# --------------------------------------------------------------------------- wrapping


def test_wrap_angle_keeps_minus_pi_and_maps_plus_pi_to_minus_pi() -> None:
    assert wrap_angle(-math.pi) == -math.pi
    assert wrap_angle(math.pi) == -math.pi
    assert wrap_angle(3 * math.pi) == -math.pi
    assert wrap_angle(-3 * math.pi) == -math.pi
    # just inside the seam stays where it is, on its own side
    assert wrap_angle(math.pi - 1e-9) == pytest.approx(math.pi - 1e-9, abs=1e-15)
    assert wrap_angle(-math.pi + 1e-9) == pytest.approx(-math.pi + 1e-9, abs=1e-15)
    assert 0.0 < wrap_angle(math.pi - 1e-9) and wrap_angle(-math.pi + 1e-9) < 0.0


@pytest.mark.parametrize("a, expected", [(0.0, 0.0), (0.5, 0.5), (-0.5, -0.5), (2 * math.pi, 0.0),
                                         (2 * math.pi + 0.25, 0.25), (-2 * math.pi - 0.25, -0.25),
                                         (7.0, 7.0 - 2 * math.pi), (-7.0, -7.0 + 2 * math.pi),
                                         (100.0, 100.0 - 32 * math.pi)])
def test_wrap_angle_values(a: float, expected: float) -> None:
    w = wrap_angle(a)
    assert w == pytest.approx(expected, abs=1e-12)
    assert -math.pi <= w < math.pi


def test_wrap_angles_is_the_same_wrap_elementwise_and_bit_for_bit() -> None:
    rng = np.random.default_rng(3)
    a = np.concatenate([rng.uniform(-50.0, 50.0, 1000), [math.pi, -math.pi, 0.0, 3 * math.pi, -2 * math.pi]])
    w = wrap_angles(a)
    assert w.dtype == np.float64 and w.shape == a.shape
    assert np.all((w >= -math.pi) & (w < math.pi))
    assert np.array_equal(w, np.array([wrap_angle(float(v)) for v in a]))  # array and scalar agree exactly
    np.testing.assert_allclose(np.cos(w), np.cos(a), atol=1e-12)
    np.testing.assert_allclose(np.sin(w), np.sin(a), atol=1e-12)
    assert wrap_angles([math.pi, 0.25]).tolist() == [-math.pi, 0.25]  # lists are accepted


def test_wrap_angle_is_idempotent_on_its_range() -> None:
    a = np.linspace(-math.pi, math.pi, 1001, endpoint=False)
    np.testing.assert_allclose(wrap_angles(wrap_angles(a)), wrap_angles(a), atol=1e-15)


# --------------------------------------------------------------------------- quaternion <-> yaw


@pytest.mark.parametrize("yaw", [0.0, 0.3, -0.3, 1.5, -1.5, math.pi / 2, -math.pi / 2, 3.0, -3.0,
                                 math.pi - 1e-9, -math.pi + 1e-9])
def test_yaw_quaternion_round_trip(yaw: float) -> None:
    q = quaternion_of_yaw(yaw)
    assert np.linalg.norm(q) == pytest.approx(1.0) and q[3] >= 0.0
    assert yaw_of_quaternion(q) == pytest.approx(yaw, abs=1e-12)
    assert float(yaws_of_quaternions(np.array(q))) == pytest.approx(yaw, abs=1e-12)
    np.testing.assert_allclose(quaternion_to_matrix(q), rot_z(yaw), atol=1e-12)


def test_yaw_at_pi_and_of_a_wrapped_angle() -> None:
    # +-pi: the same rotation; the yaw comes back on the seam with either sign
    for yaw in (math.pi, -math.pi):
        assert abs(yaw_of_quaternion(quaternion_of_yaw(yaw))) == pytest.approx(math.pi, abs=1e-12)
    # a yaw beyond the seam comes back wrapped (up to the seam's sign)
    for yaw in (4.0, -4.0, 10.0, -10.0):
        assert yaw_of_quaternion(quaternion_of_yaw(yaw)) == pytest.approx(wrap_angle(yaw), abs=1e-12)


def test_yaw_of_a_tilted_attitude() -> None:
    for roll, pitch, yaw in ((0.2, -0.1, 2.5), (-0.4, 0.3, -2.9), (0.0, 0.5, 0.1)):
        q = np.array(matrix_to_quaternion(euler_to_matrix(roll, pitch, yaw)))
        assert yaw_of_quaternion(q) == pytest.approx(yaw, abs=1e-12)
        np.testing.assert_allclose(matrix_to_euler(quaternion_to_matrix(q)), (roll, pitch, yaw), atol=1e-12)
    qs = np.array([quaternion_of_yaw(y) for y in (0.1, -2.0, 3.0)])
    np.testing.assert_allclose(yaws_of_quaternions(qs), [0.1, -2.0, 3.0], atol=1e-12)


def test_quaternion_to_matrix_rejects_zero_and_matrix_to_quaternion_keeps_w_positive() -> None:
    with pytest.raises(ValueError, match="zero norm"):
        quaternion_to_matrix([0.0, 0.0, 0.0, 0.0])
    rng = np.random.default_rng(5)
    for _ in range(50):
        r = euler_to_matrix(*rng.uniform(-3.0, 3.0, 3))
        q = matrix_to_quaternion(r)
        assert q[3] >= 0.0 and np.linalg.norm(q) == pytest.approx(1.0)
        np.testing.assert_allclose(quaternion_to_matrix(q), r, atol=1e-12)


# --------------------------------------------------------------------------- frames


def test_frames_enu_ned() -> None:
    ned = np.array([[1.0, 2.0, 3.0], [-4.0, 5.0, -6.0]])
    enu = ned_to_enu(ned)
    assert enu.tolist() == [[2.0, 1.0, -3.0], [5.0, -4.0, 6.0]]
    assert np.allclose(enu_to_ned(enu), ned)
    # robot_state's default published frame (yxz, z sign -1) is ENU; xyz/+1 is NED unchanged
    assert np.allclose(published_to_ned(enu), ned)
    assert np.allclose(published_to_ned(ned, "xyz", 1.0), ned)
    # heading north (NED yaw 0) is ENU yaw pi/2; east (NED pi/2) is ENU 0
    assert yaw_enu_to_ned(math.pi / 2) == pytest.approx(0.0)
    assert yaw_enu_to_ned(0.0) == pytest.approx(math.pi / 2)


def test_published_frame_matches_output_frame() -> None:
    rng = np.random.default_rng(0)
    for remap, sign in (("yxz", -1.0), ("xyz", 1.0), ("yxz", 1.0), ("xzy", -1.0)):
        try:
            f = OutputFrame(remap, sign)
        except ValueError:
            continue  # a reflection: not a valid published frame
        p = rng.normal(size=3)
        assert np.allclose(published_to_ned(f.position(p), remap, sign), p)
        assert np.allclose(f.position_to_ned(f.position(p)), p)


def test_output_frame_rejects_bad_remaps() -> None:
    with pytest.raises(ConfigError, match="permutation"):
        OutputFrame("xxz", -1.0)
    with pytest.raises(ConfigError, match="1 or -1"):
        OutputFrame("yxz", 2.0)
    with pytest.raises(ConfigError, match="reflection"):
        OutputFrame("yxz", 1.0)
    assert OutputFrame().name == "enu" and OutputFrame("xyz", 1.0).identity


def test_robot_state_frames_re_exports_the_common_definitions() -> None:
    import common.geometry as g
    import services.robot_state.frames as frames
    for name in frames.__all__:
        assert getattr(frames, name) is getattr(g, name), name
