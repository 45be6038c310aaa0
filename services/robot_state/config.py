"""The dead-reckoning filter's configuration section (``robot_state:``).

Validated at start-up as part of the whole configuration (``system/config.py``); a
wrong value fails naming its dotted field.
"""
from __future__ import annotations

from typing import Literal

from pydantic import Field, model_validator

from common.config import ConfigSection, check

__all__ = ["RobotStateConfig", "DvlConfig", "ImuConfig", "DepthConfig"]


def _zeros3() -> list[float]:
    return [0.0, 0.0, 0.0]


class DvlConfig(ConfigSection):
    """The Doppler velocity log: its mounting, its velocity and compass measurements, and dropouts."""

    rotation_rpy_deg: list[float] = Field(default_factory=_zeros3, min_length=3, max_length=3,
                                          description="the DVL's mounting rotation on the body, roll pitch yaw "
                                          "[deg]")
    translation_m: list[float] = Field(default_factory=_zeros3, min_length=3, max_length=3,
                                       description="the DVL's lever arm on the body, x y z [m]")
    velocity_sign: float = Field(1.0, description="+1: velocityinst is the vehicle's velocity; -1: the bottom's "
                                 "velocity relative to the instrument (Girona LinkQuest logs)")
    velocity_sigma: float = Field(0.02, gt=0, description="std of a DVL velocity measurement [m/s]")
    max_speed: float = Field(3.0, gt=0, description="records of a faster speed are rejected [m/s]")
    min_good_beams: int = Field(3, ge=1, le=4, description="records with fewer datagood beams are rejected "
                                "[beams]")
    gate_chi2: float = Field(0.0, ge=0, description="innovation gate on the DVL velocity (chi2, 3 dof); 0: off "
                             "[chi2]")
    timeout_s: float = Field(2.0, gt=0, description="beyond this without DVL the state is in dropout [s]")
    dropout_decay_s: float = Field(30.0, gt=0, description="after timeout_s the velocity decays with this time "
                                   "constant towards hovering (a cruising vehicle keeps its speed for tens of "
                                   "seconds; 5 s lost ~1% of the distance in DVL dropout bursts) [s]")
    dropout_speed_sigma: float = Field(0.5, gt=0, description="std of the unobserved velocity in dropout [m/s]")
    heading_fusion: bool = Field(True, description="with an IMU, also fuse the DVL compass heading, estimating its "
                                 "mounting offset and the drift of the IMU yaw")
    heading_sigma_deg: float = Field(2.0, gt=0, description="DVL compass heading noise [deg]")
    heading_offset_sigma_deg: float = Field(5.0, gt=0, description="prior std of the DVL compass offset [deg]")


class ImuConfig(ConfigSection):
    """The inertial unit: its mounting, its attitude measurements and the gyro that drives the prediction."""

    enabled: bool = Field(True, description="use the IMU; false: the DVL's attitude only")
    topic: Literal["imu_adis_ros", "imu_adis"] = Field("imu_adis_ros", description="IMU key")
    rotation_rpy_deg: list[float] = Field(default_factory=_zeros3, min_length=3, max_length=3,
                                          description="the IMU's mounting rotation on the body, roll pitch yaw "
                                          "[deg]")
    timeout_s: float = Field(0.5, gt=0, description="beyond this without IMU, the attitude falls back to the "
                             "DVL's [s]")
    heading_sigma_deg: float = Field(1.0, gt=0, description="std of an IMU yaw measurement [deg]")
    roll_pitch_sigma_deg: float = Field(0.5, gt=0, description="std of an IMU roll/pitch measurement [deg]")
    gyro_sigma_deg_s: float = Field(0.05, gt=0, description="gyro noise [deg/s/sqrt(Hz)]")
    gyro_bias_sigma_deg_s: float = Field(0.1, ge=0, description="prior std of each gyro bias [deg/s]")
    gyro_bias_rw_deg_s: float = Field(0.001, ge=0, description="random walk of the gyro biases [deg/s/sqrt(s)]")
    yaw_drift_sigma_deg_s: float = Field(0.05, ge=0, description="random walk of the IMU yaw error "
                                         "[deg/sqrt(s)]")
    yaw_drift_rate_sigma_deg_min: float = Field(1.0, ge=0, description="prior std of the drift rate of the IMU "
                                                "yaw error (an AHRS yaw drifts at a slow rate) [deg/min]")
    yaw_drift_rate_rw_deg_min_s: float = Field(0.001, ge=0, description="random walk of that drift rate "
                                               "[deg/min/sqrt(s)]")


class DepthConfig(ConfigSection):
    """The pressure depth sensor, which alone gives z."""

    offset_m: float = Field(0.0, description="added to every depth record [m]")
    sigma: float = Field(0.05, gt=0, description="std of a depth measurement [m]")
    timeout_s: float = Field(1.0, gt=0, description="beyond this without depth, z is held [s]")


class RobotStateConfig(ConfigSection):
    """Dead reckoning: the EKF of DVL, IMU and depth (services/robot_state/filter.py), or a ground
    robot's odometry."""

    source: Literal["dvl_imu_depth", "wheel_odometry"] = Field(
        "dvl_imu_depth", description="dvl_imu_depth: the EKF of DVL, IMU and depth; wheel_odometry: a ground "
        "robot's odometry (key wheel_odometry, e.g. an imported CARMEN log) republished as Odometry")
    wheel_time_offset_s: float | None = Field(
        0.0, ge=-0.5, le=0.5, description="source wheel_odometry: each Odometry is stamped this much after the "
        "wheel odometry's own stamp, putting it on the range sensor's clock (the scan stamp minus the odometry "
        "stamp of the same instant; services/expmap/scan_clock.py); null: measured from the input recording at "
        "the start of a run (laser preset), 0 where it cannot be (live runs) [s]")
    axis_remap: str = Field("yxz", pattern=r"^[xyz]{3}$", description="dead-reckoning frame alignment: the "
                            "published x y z are these NED axes")
    axis_sign_z: float = Field(-1.0, description="sign applied to z of the published position (1 or -1)")
    process_accel_sigma: float = Field(0.05, gt=0, description="random walk of the velocity [m/s^2]")
    attitude_rw_sigma_deg_s: float = Field(5.0, gt=0, description="attitude random walk without gyro "
                                           "[deg/sqrt(s)]")
    heading_gate_chi2: float = Field(25.0, ge=0, description="chi2 gate (1 dof) on yaw innovations: a compass "
                                     "heading beyond it is rejected, an IMU yaw beyond it resets the yaw; 0: off "
                                     "[chi2]")
    max_gap_s: float = Field(30.0, gt=0, description="a gap between inputs after which the prediction is bridged "
                             "and flagged [s]")
    publish_rate_hz: float = Field(5.0, gt=0, description="rate of the published Odometry (5: one per frame of the "
                                   "~4-5 Hz camera; the experience map carries a pose to each sonar beam's stamp) [Hz]")
    dvl: DvlConfig = Field(default_factory=DvlConfig)
    imu: ImuConfig = Field(default_factory=ImuConfig)
    depth: DepthConfig = Field(default_factory=DepthConfig)

    @model_validator(mode="after")
    def _consistent(self) -> RobotStateConfig:
        check(sorted(self.axis_remap) == ["x", "y", "z"],
              f"robot_state.axis_remap {self.axis_remap!r} must be a permutation of xyz (e.g. yxz)")
        check(self.axis_sign_z in (-1.0, 1.0), f"robot_state.axis_sign_z must be 1 or -1, got {self.axis_sign_z}")
        check(self.dvl.velocity_sign in (-1.0, 1.0),
              f"robot_state.dvl.velocity_sign must be 1 or -1, got {self.dvl.velocity_sign}")
        return self
