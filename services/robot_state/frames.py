"""The frame conventions of ``robot_state``, defined in :mod:`common.geometry` (NED/FRD world
and body, ZYX Euler angles, the published frame :class:`OutputFrame`); re-exported here
for readers who look for them next to the filter."""
from __future__ import annotations

from common.geometry import (
                             OutputFrame,
                             euler_to_matrix,
                             euler_to_world_rate,
                             matrix_to_euler,
                             matrix_to_quaternion,
                             quaternion_to_matrix,
                             rot_x,
                             rot_y,
                             rot_z,
                             wrap_angle,
)

__all__ = ["rot_x", "rot_y", "rot_z", "euler_to_matrix", "euler_to_world_rate", "matrix_to_euler",
           "matrix_to_quaternion", "quaternion_to_matrix", "wrap_angle", "OutputFrame"]
