"""``robot_state`` service: fused dead reckoning ``Odometry`` (dissertation Section 4.2.4).

Inputs (priority order for equal stamps): the IMU (``imu.topic``, default
``imu_adis_ros``; not subscribed when ``imu.enabled`` is false; first, so that a DVL record
stamped like an IMU record sees its rates for the lever-arm term), ``dvl_linkquest``,
``depth_sensor`` and the recording's reference ``odometry``.  Outputs: ``Odometry`` and ``ground_truth``.

Publication policy (event time only, never the wall clock): ``Odometry`` is published on
a fixed grid of stamps ``k / publish_rate_hz`` (absolute multiples of the period, so two
runs over the same inputs give the same stamps).  When a sensor record stamped ``t``
arrives, every not yet published grid stamp ``g < t`` is published first, from the state
predicted to ``g``; the output stamped ``g`` therefore reflects every input stamped
``<= g`` and nothing later (causal).  The grid starts once the filter has an attitude and a
velocity; the remaining grid stamps up to the last input are published at the end.  DVL
updates are not published separately: the grid (5 Hz by default, one pose per frame of the
~4-5 Hz camera) is faster than the DVL (~3 Hz on the Girona logs) and a regular stream is
what the back-end's Eq. 4.15 differencing wants; the sonar beams between two poses are
placed by the experience map with the pose carried to their own stamps
(:class:`services.expmap.scans.SweepBuffer`).

A silence of ``max_gap_s`` or more on every sensor is a gap (counted ``gap``): the grid
inside it is bridged by prediction (velocity held, then decaying, covariance growing,
:mod:`services.robot_state.filter`) for up to ``max_gap_s`` and then resumes at the last
grid stamp before the next input, every bridged output flagged ``gap_bridged``.

``Odometry`` (frame ``odom_<frame>``, child ``base_link``; conventions in
:mod:`common.geometry`): ``position`` and ``orientation`` in the published
frame (``axis_remap``/``axis_sign_z``, default ENU), ``linear_velocity`` and
``angular_velocity`` in the published body frame, ``pose_covariance`` (x y z roll pitch
yaw, row-major 6x6) and ``twist_covariance`` transformed to the published frame.
``status`` holds the state flags (``attitude_imu``/``attitude_dvl``, ``imu_absent``,
``dvl_dropout``, ``depth_dropout``, ``gap_bridged``) and the name of every rejection or
event counted since the previous output (``dvl_invalid_flag``, ``dvl_nonfinite``,
``timestamp_backwards``, ``late``, ...); the totals are in ``counters``.

``ground_truth`` relays each ``odometry`` message unchanged except its header seq.

Fault injection (tests and evaluation only; ``debug.fault_jump_at_s`` and ``debug.fault_jump_m``,
passed by the launcher as ``fault_jump_at_s`` / ``fault_jump_m``): with ``fault_jump_at_s`` > 0, every
``Odometry`` published that many seconds or more after the first one has ``fault_jump_m``
(m, published frame) added to its position and ``fault_jump`` in its status (counted once,
``fault_jump``, and logged as a warning): a kidnapped vehicle, or a navigation reset.

Ground robots (``robot_state.source: wheel_odometry``, the laser preset): the only input
besides ``odometry`` is ``wheel_odometry`` (e.g. a CARMEN log's ODOM records) and each of
its messages is republished as ``Odometry`` with the same pose and velocities (frame
``odom_wheel``, status ``wheel_odometry``), stamped ``wheel_time_offset_s`` after its own
stamp: wheel odometry is already a pose, and the offset puts it on the range sensor's clock
(measured by :mod:`services.expmap.scan_clock`; a negative offset lowers the node's
watermark by as much, since its outputs are then stamped before its inputs).  A message with a non-finite pose or a zero
quaternion is logged, counted (``wheel_odometry_invalid``) and skipped.
"""
from __future__ import annotations

import logging
from collections.abc import Sequence

import numpy as np

from common.geometry import OutputFrame, euler_to_matrix, matrix_to_quaternion
from common.messages import Depth, Header, Imu, LinkquestDvl, Message, Odometry
from common.node import ServiceNode
from services.robot_state.config import RobotStateConfig
from services.robot_state.filter import NS, DeadReckoningFilter, FilterSnapshot, warm_up_kernels

__all__ = ["RobotStateNode", "odometry_from_snapshot"]

log = logging.getLogger(__name__)


#: the pose block (position, Euler) of the filter's covariance, as an index of P
_POSE_IX = np.ix_([0, 1, 2, 6, 7, 8], [0, 1, 2, 6, 7, 8])


def odometry_from_snapshot(snap: FilterSnapshot, frame: OutputFrame, header: Header, status: list[str],
                           gyro_sigma_rad_s: float) -> Odometry:
    """Odometry message of a filter snapshot in the published frame."""
    p = frame.position(snap.position)
    r_out = frame.rotation(euler_to_matrix(*snap.euler))
    P = snap.covariance
    J = np.zeros((6, 6))
    J[0:3, 0:3] = frame.m
    J[3:6, 3:6] = frame.euler_jacobian(*snap.euler)
    pose_cov = J @ P[_POSE_IX] @ J.T
    twist_cov = np.zeros((6, 6))
    twist_cov[0:3, 0:3] = frame.b @ P[3:6, 3:6] @ frame.b
    twist_cov[3:6, 3:6] = np.eye(3) * gyro_sigma_rad_s ** 2
    return Odometry(
        header=header, child_frame_id="base_link",
        position=[float(v) for v in p],
        orientation=matrix_to_quaternion(r_out),
        linear_velocity=[float(v) for v in frame.b @ snap.velocity_body],
        angular_velocity=[float(v) for v in frame.b @ snap.angular_velocity],
        pose_covariance=[float(v) for v in pose_cov.ravel()],
        twist_covariance=[float(v) for v in twist_cov.ravel()],
        status=status,
    )


class RobotStateNode(ServiceNode[RobotStateConfig]):
    """Dead reckoning from DVL, IMU and depth; relays the reference odometry."""

    name = "robot_state"
    inputs = ("imu_adis_ros", "dvl_linkquest", "depth_sensor", "odometry")
    outputs = ("Odometry", "ground_truth")

    @classmethod
    def io_keys(cls, config: RobotStateConfig) -> tuple[tuple[str, ...], tuple[str, ...]]:
        """Inputs under ``config``: the configured IMU key (none with ``imu.enabled`` false) first."""
        cfg = config
        if cfg.source == "wheel_odometry":
            return ("wheel_odometry", "odometry"), cls.outputs
        imu = (cfg.imu.topic,) if cfg.imu.enabled else ()
        return imu + ("dvl_linkquest", "depth_sensor", "odometry"), cls.outputs

    def __init__(self, config: RobotStateConfig, fault_jump_at_s: float = 0.0,
                 fault_jump_m: Sequence[float] = (0.0, 0.0, 0.0)):
        """:param config: the ``robot_state`` section.
        :param fault_jump_at_s: fault injection (``debug.fault_jump_at_s``): the published position
            jumps from this long after the first published Odometry on (s; 0: off).
        :param fault_jump_m: the jump, x y z in the published frame (m; ``debug.fault_jump_m``).
        """
        super().__init__(config)
        cfg = config
        self.cfg = cfg
        self.fault_jump_at_s = float(fault_jump_at_s)
        self.fault_jump_m = [float(v) for v in fault_jump_m]
        self.imu_key = cfg.imu.topic
        self.frame = OutputFrame(cfg.axis_remap, cfg.axis_sign_z)
        self.filter = DeadReckoningFilter(cfg)
        self.filter.counters = self.counters  # one set of counters for the run summary
        self.period = int(round(NS / cfg.publish_rate_hz))
        self.frame_id = f"odom_{self.frame.name}"
        self._next_pub: int | None = None
        self._last_input: int | None = None
        self._gap_from = 0  # outputs stamped strictly between these are bridged
        self._gap_until: int | None = None
        self._gyro_sigma = float(np.radians(cfg.imu.gyro_sigma_deg_s))
        self._first_pub: int | None = None   # stamp of the first published Odometry (fault injection clock)
        self._jumped = False
        if cfg.source == "wheel_odometry" and cfg.wheel_time_offset_s is None:
            # null is resolved from the input at the start of a replay (system.calibration); a live run has none
            log.warning("robot_state: wheel_time_offset_s is null and was not measured from an input: 0 s")
        self._wheel_offset_ns = int(round((cfg.wheel_time_offset_s or 0.0) * NS))

    # ------------------------------------------------------------------ publishing
    def warm_up(self) -> None:
        """Compile the EKF's numba kernels before the service says it is alive (a throwaway
        filter; this node's is untouched)."""
        warm_up_kernels(self.cfg)

    def _publish_until(self, t: int, inclusive: bool) -> None:
        """Publish every grid stamp g < t (or <= t) not yet published."""
        if self._next_pub is None:
            return
        max_gap = int(round(self.cfg.max_gap_s * NS))
        while self._next_pub < t or (inclusive and self._next_pub == t):
            g = self._next_pub
            bridged = self._gap_until is not None and self._gap_from < g < self._gap_until
            if bridged and self._last_input is not None and g > self._last_input + max_gap:
                # long silence: skip to the last grid stamp before the input that ends it
                last = ((t - 1) // self.period) * self.period if not inclusive else (t // self.period) * self.period
                if last > g:
                    g = last
            self.filter.propagate(g)
            snap = self.filter.snapshot()
            status = snap.flags + (["gap_bridged"] if bridged else []) + self.filter.take_pending()
            out = odometry_from_snapshot(snap, self.frame, self.header("Odometry", g, self.frame_id), status,
                                         self._gyro_sigma)
            if self._first_pub is None:
                self._first_pub = g
            if self.fault_jump_at_s > 0 and g - self._first_pub >= self.fault_jump_at_s * NS:
                if not self._jumped:
                    log.warning("robot_state: FAULT INJECTION: published position jumps by %s m from stamp %d "
                                "(debug.fault_jump_at_s)", self.fault_jump_m, g)
                    self._jumped = True
                    self.count("fault_jump")
                out.position = [p + d for p, d in zip(out.position, self.fault_jump_m)]
                out.status = out.status + ["fault_jump"]
            self.publish("Odometry", out)
            self._next_pub = g + self.period

    # ------------------------------------------------------------------ ServiceNode
    def process(self, key: str, msg: Message) -> None:
        stamp = msg.header.stamp
        if key == "odometry":
            self.publish("ground_truth", msg.model_copy(
                update={"header": self.header("ground_truth", stamp, msg.header.frame_id)}))
            return
        if key == "wheel_odometry":
            assert isinstance(msg, Odometry)
            self._on_wheel_odometry(msg)
            return
        if self._last_input is not None and stamp - self._last_input >= self.cfg.max_gap_s * NS:
            self.count("gap")
            self._gap_from, self._gap_until = self._last_input, stamp
        self._publish_until(stamp, inclusive=False)
        if key == "dvl_linkquest":
            assert isinstance(msg, LinkquestDvl)
            self.filter.update_dvl(msg)
        elif key == self.imu_key:
            assert isinstance(msg, Imu)
            self.filter.update_imu(msg)
        elif key == "depth_sensor":
            assert isinstance(msg, Depth)
            self.filter.update_depth(msg)
        else:
            raise KeyError(f"robot_state: unexpected input key {key!r} (inputs {self.inputs})")
        if self._next_pub is None and self.filter.initialised and self.filter.t is not None:
            self._next_pub = -(-self.filter.t // self.period) * self.period
            self.count("initialised")
        self._last_input = stamp if self._last_input is None else max(self._last_input, stamp)

    def _on_wheel_odometry(self, msg: Odometry) -> None:
        q = np.asarray(msg.orientation, np.float64)
        if not (np.all(np.isfinite(msg.position)) and np.all(np.isfinite(q))) or float(q @ q) < 1e-12:
            log.warning("robot_state: wheel_odometry seq %d skipped: non-finite pose or zero quaternion",
                        msg.header.seq)
            self.count("wheel_odometry_invalid")
            return
        self.count("wheel_odometry")
        self.publish("Odometry", msg.model_copy(update={
            "header": self.header("Odometry", msg.header.stamp + self._wheel_offset_ns, "odom_wheel"),
            "child_frame_id": "base_link",
            "status": ["wheel_odometry"]}))

    def finish(self) -> None:
        if self._last_input is not None:
            self._publish_until(self._last_input, inclusive=True)

    def output_watermark(self, input_watermark: int) -> int:
        if self.cfg.source == "wheel_odometry":
            return input_watermark + min(0, self._wheel_offset_ns)
        if self._next_pub is not None:
            return min(input_watermark, self._next_pub)
        if self._last_input is not None:
            return min(input_watermark, self._last_input)
        return input_watermark
