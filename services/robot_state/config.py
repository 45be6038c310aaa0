"""The dead-reckoning filter's configuration section (``robot_state:``).

Validated at start-up as part of the whole configuration (``system/config.py``); a
wrong value fails naming its dotted field.
"""
from __future__ import annotations

from typing import Literal

from pydantic import Field, model_validator

from common.config import ConfigSection, check

__all__ = ["RobotStateConfig"]


class RobotStateConfig(ConfigSection):
    source: Literal["dvl_imu_depth", "wheel_odometry"] = Field(
        "dvl_imu_depth", description="dvl_imu_depth: the EKF of DVL, IMU and depth; wheel_odometry: a ground "
        "robot's odometry (key wheel_odometry, e.g. an imported CARMEN log) republished as Odometry")
    use_imu: bool = True
    imu_topic: Literal["imu_adis_ros", "imu_adis"] = "imu_adis_ros"
    axis_remap: str = Field("yxz", pattern=r"^[xyz]{3}$", description="dead-reckoning frame alignment")
    axis_sign_z: float = Field(-1.0, description="sign applied to z of the published position")
    dvl_rotation_rpy_deg: list[float] = Field(default_factory=lambda: [0.0, 0.0, 0.0], min_length=3, max_length=3)
    dvl_translation_m: list[float] = Field(default_factory=lambda: [0.0, 0.0, 0.0], min_length=3, max_length=3)
    imu_rotation_rpy_deg: list[float] = Field(default_factory=lambda: [0.0, 0.0, 0.0], min_length=3, max_length=3)
    depth_offset_m: float = 0.0
    dvl_velocity_sigma: float = Field(0.02, gt=0, description="m/s")
    depth_sigma: float = Field(0.05, gt=0, description="m")
    heading_sigma_deg: float = Field(1.0, gt=0)
    process_accel_sigma: float = Field(0.05, gt=0, description="m/s^2 random-walk of velocity")
    dvl_max_speed: float = Field(3.0, gt=0, description="m/s; faster records are rejected")
    dvl_timeout_s: float = Field(2.0, gt=0, description="beyond this without DVL the state is in dropout")
    max_gap_s: float = Field(30.0, gt=0, description="gap after which prediction is bridged and flagged")
    publish_rate_hz: float = Field(10.0, gt=0)
    # --- added for the robot_state filter (issue 5); see services/robot_state/filter.py
    dvl_velocity_sign: float = Field(1.0, description="+1: velocityinst is the vehicle's velocity; -1: the "
                                     "bottom's velocity relative to the instrument (Girona LinkQuest logs)")
    dvl_min_good_beams: int = Field(3, ge=1, le=4, description="records with fewer datagood beams are rejected")
    dvl_gate_chi2: float = Field(0.0, ge=0, description="innovation gate on DVL velocity (chi2, 3 dof); 0: off")
    dvl_dropout_decay_s: float = Field(30.0, gt=0, description="after dvl_timeout_s velocity decays with this "
                                       "time constant (s) towards hovering (a cruising vehicle keeps its speed "
                                       "for tens of seconds; 5 s lost ~1% of the distance in DVL dropout bursts)")
    dropout_speed_sigma: float = Field(0.5, gt=0, description="m/s; std of the unobserved velocity in dropout")
    depth_timeout_s: float = Field(1.0, gt=0, description="beyond this without depth, z is held (s)")
    imu_timeout_s: float = Field(0.5, gt=0, description="beyond this without IMU, attitude falls back to DVL (s)")
    gyro_sigma_deg_s: float = Field(0.05, gt=0, description="gyro noise, deg/s/sqrt(Hz)")
    roll_pitch_sigma_deg: float = Field(0.5, gt=0, description="IMU roll/pitch measurement sigma (deg)")
    attitude_rw_sigma_deg_s: float = Field(5.0, gt=0, description="attitude random walk without gyro, deg/sqrt(s)")
    dvl_heading_fusion: bool = Field(True, description="with an IMU, also fuse the DVL compass heading, estimating "
                                     "its mounting offset and the drift of the IMU yaw")
    dvl_heading_sigma_deg: float = Field(2.0, gt=0, description="DVL compass heading noise (deg)")
    dvl_heading_offset_sigma_deg: float = Field(5.0, gt=0, description="prior std of the DVL compass offset (deg)")
    imu_yaw_drift_sigma_deg_s: float = Field(0.05, ge=0, description="random walk of the IMU yaw error, deg/sqrt(s)")
    gyro_bias_sigma_deg_s: float = Field(0.1, ge=0, description="prior std of each gyro bias (deg/s)")
    gyro_bias_rw_deg_s: float = Field(0.001, ge=0, description="random walk of the gyro biases, deg/s/sqrt(s)")
    # --- added for dead reckoning across seeds (issue 9); see services/robot_state/filter.py
    imu_yaw_drift_rate_sigma_deg_min: float = Field(1.0, ge=0, description="prior std of the drift rate of the "
                                                    "IMU yaw error (deg/min; an AHRS yaw drifts at a slow rate)")
    imu_yaw_drift_rate_rw_deg_min_s: float = Field(0.001, ge=0, description="random walk of that drift rate, "
                                                   "deg/min/sqrt(s)")
    heading_gate_chi2: float = Field(25.0, ge=0, description="chi2 gate (1 dof) on yaw innovations: a compass "
                                     "heading beyond it is rejected, an IMU yaw beyond it resets the yaw; 0: off")

    # --- added for sessions (issue 20): fault injection, for tests and evaluation only
    fault_jump_at_s: float = Field(0.0, ge=0, description="FAULT INJECTION (tests): from this many seconds after "
                                   "the first published Odometry on, add fault_jump_m to every published position "
                                   "(a kidnapped vehicle, an odometry reset); 0: off")
    fault_jump_m: list[float] = Field(default_factory=lambda: [0.0, 0.0, 0.0], min_length=3, max_length=3,
                                      description="the jump (m, published frame) of fault_jump_at_s")

    @model_validator(mode="after")
    def _consistent(self) -> RobotStateConfig:
        check(sorted(self.axis_remap) == ["x", "y", "z"],
               f"robot_state.axis_remap {self.axis_remap!r} must be a permutation of xyz (e.g. yxz)")
        check(self.axis_sign_z in (-1.0, 1.0), f"robot_state.axis_sign_z must be 1 or -1, got {self.axis_sign_z}")
        check(self.dvl_velocity_sign in (-1.0, 1.0),
               f"robot_state.dvl_velocity_sign must be 1 or -1, got {self.dvl_velocity_sign}")
        return self
