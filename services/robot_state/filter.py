"""Dead-reckoning navigation filter of ``robot_state`` (dissertation Section 4.2.4).

(Over 500 lines because the state, the process model and each sensor's measurement model
with its Jacobian are one filter; the arithmetic of the prediction and the update is in
:mod:`services.robot_state.ekf_kernels`.)

The back-end's only motion input is the fused ``/Odometry`` stream (Eq. 4.15 differences it),
built from DVL velocity, IMU attitude/rates and pressure depth.  This is DolphinSLAM's 3D
path integration (Eqs. 3.10-3.11: body velocity rotated to the world frame by
``R(phi, theta, psi)`` and integrated) inside an extended Kalman filter so that the
estimate carries a covariance and survives bad or missing data.

Why an EKF on Euler angles (and not an error-state filter): the attitude is *measured*
directly (the ADIS16480 AHRS or the DVL's own compass), the filter never has to integrate
accelerometers, and roll/pitch stay far from the Euler singularity for an AUV; a plain
EKF is then exact enough, simple to audit, and its prediction reproduces Eqs. 3.10-3.11
exactly when the inputs are noise-free (tested to 1e-9).  Gyro biases are states (the
attitude measurements make them observable; unmodelled, a 0.03 deg/s bias lagged the yaw
by ~0.6 deg on the simulated missions); a DVL velocity bias is not (unobservable without
an absolute position fix).

State ``x`` (15; conventions in :mod:`common.geometry`): position NED ``p``
(m), body-frame (FRD) velocity ``v`` (m/s), attitude ``e = (roll, pitch, yaw)`` (rad),
``b_imu`` (error of the IMU's reported yaw, prior 0: the IMU defines the initial heading;
it grows at the rate ``d_imu`` plus a random walk ``imu.yaw_drift_sigma_deg_s``),
``b_dvl`` (the DVL compass mounting offset, constant, prior std
``dvl.heading_offset_sigma_deg``), gyro biases ``b_g`` (rad/s, prior std
``imu.gyro_bias_sigma_deg_s``, random walk ``imu.gyro_bias_rw_deg_s``) and ``d_imu`` (rad/s, the
drift rate of the IMU yaw error, prior std ``imu.yaw_drift_rate_sigma_deg_min``, random
walk ``imu.yaw_drift_rate_rw_deg_min_s``).

Why a drift *rate*: an AHRS yaw drifts steadily (its own gyro bias integrated);
modelled as a zero-mean random walk only, the early part of the ramp was taken for the
compass offset, which then held the heading 0.3-0.8 deg off for the rest of the mission
(sim seeds 101-105: mean yaw error +0.2 to +0.8 deg).  With ``d_imu`` the difference IMU yaw
minus compass is a line whose intercept at ``b_imu = 0`` is the compass offset, and the
whole mission refines it.
Velocity is kept in the body frame because a vehicle that turns during a DVL dropout keeps
moving forward, not along its old world direction.

- **Prediction** (at every input's stamp, in event-time order; sub-steps <= 0.5 s while
  the gyro drives the attitude):
  ``p += R(e) v dt`` (Eqs. 3.10-3.11), ``e += E(e) (w - b_g) dt`` with the latest gyro rates ``w``
  (zero-order hold) while the IMU is fresh (``imu.timeout_s``), ``v`` constant with a
  random-walk ``process_accel_sigma``.  Covariance ``P = F P F' + Q`` with the analytic
  Jacobian, so heading uncertainty grows cross-track position uncertainty.
- **DVL velocity update**: ``v_body = sign * R_bd velocityinst - w x r_d`` (extrinsic
  rotation ``dvl.rotation_rpy_deg``, lever arm ``dvl.translation_m``, sign
  ``dvl.velocity_sign``).  Records are rejected (and counted) when ``velocityinstflag != 1``
  (``dvl_invalid_flag``), fewer than ``dvl.min_good_beams`` beams are good
  (``dvl_few_beams``), a value is NaN/inf (``dvl_nonfinite``), the speed exceeds
  ``dvl.max_speed`` (``dvl_too_fast``), or (optional) the innovation fails a chi-square gate
  (``dvl_outlier``; three in a row re-initialise the velocity, ``dvl_reinit``).
- **Depth update**: ``z = depth + depth.offset_m`` observes ``p_z`` (sigma ``depth.sigma``).
  z comes from pressure, never from integrated velocity: the vertical velocity only carries
  z across the interval between two depth records (<= ``depth.timeout_s``); beyond that z
  is held and its variance grows (``depth_dropout``).
- **Attitude**: with an IMU, roll/pitch (``imu.roll_pitch_sigma_deg``) and yaw + ``b_imu``
  (``imu.heading_sigma_deg``) are measurements and the gyro drives the prediction
  (``imu.gyro_sigma_deg_s``).  With ``dvl.heading_fusion`` the DVL compass heading is a second
  yaw measurement (yaw + ``b_dvl``, ``dvl.heading_sigma_deg``): while the IMU yaw is still
  good the compass offset is learned, later the drift-free compass holds the IMU's yaw
  drift in check (an AHRS yaw drifts; a magnetic compass does not, but sits at an
  unknown offset).  Without a fresh IMU (none recorded, ``imu.enabled`` false, or older
  than ``imu.timeout_s``) the DVL's roll/pitch/heading (degrees) are taken as the attitude
  (a reset, minus the learned compass offset: with no rate sensor there is nothing to
  blend them with).  Yaw innovations beyond ``heading_gate_chi2`` (1 dof): a compass
  heading is rejected (``dvl_heading_outlier``: magnetic disturbance); an IMU yaw resets the
  yaw alone (``imu_yaw_reset``: the gyro prediction failed, e.g. a turn faster than the
  10 Hz samples follow) -- without the gate one such event spread a 100+ deg innovation
  into the compass-offset state, biasing the heading ~1 deg for the rest of the mission.
  A DVL without a
  compass reports exactly 0 for all three (the Girona LinkQuest logs do, for every record):
  such records are counted (``dvl_attitude_zero``) and the output is flagged
  ``heading_unobserved`` -- the heading is then constant and turns are invisible.
- **Updates only correct their own states** (a Schmidt-style restricted gain with the Joseph
  covariance update, which stays consistent for any gain): the DVL never moves the
  position, the depth never moves x/y.  The published dead reckoning therefore never
  jumps horizontally; the back-end differentiates it (Eq. 4.15).
- **DVL dropout**: for ``dvl.timeout_s`` after the last valid record the velocity is held
  (variance growing with ``process_accel_sigma``); after that it decays towards zero
  (hovering) as a first-order Gauss-Markov process with time constant
  ``dvl.dropout_decay_s`` (30 s: a cruising vehicle keeps its speed; with 5 s the filter
  lost ~1% of the distance in the DVL's dropout bursts, which plain integration, holding
  the last velocity, did not) and stationary std ``dvl.dropout_speed_sigma``.  A dropout of any
  length (a 30 s gap included) therefore moves the estimate by at most
  ``|v| (dvl.timeout_s + dvl.dropout_decay_s)`` while the covariance keeps growing.
- **Time**: inputs are processed in event-time order; a record older than its own stream's
  previous one (stamp or seq going backwards) is rejected (``timestamp_backwards``); one
  older than the state time but in order on its stream is applied at the state time
  (``late``).  NaN/inf fields are rejected per source (``*_nonfinite``).

First measurements initialise their block directly (velocity, attitude, depth); the filter
is ``initialised`` once it has an attitude and a velocity, and the horizontal origin is the
position at that moment.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from common.geometry import euler_to_matrix, matrix_to_euler, wrap_angle
from common.messages import Depth, Imu, LinkquestDvl
from services.robot_state.config import RobotStateConfig
from services.robot_state.ekf_kernels import predict, restricted_update

__all__ = ["DeadReckoningFilter", "FilterSnapshot", "NS", "warm_up_kernels"]

NS = 1_000_000_000
MAX_STEP_NS = NS // 2  # prediction sub-step bound (s): keeps the Euler integration of attitude fine
_GATE_MAX_REJECTS = 3

P_IDX = [0, 1, 2]
V_IDX = [3, 4, 5]
E_IDX = [6, 7, 8]
B_IMU = 9  # IMU yaw error (its reported yaw = yaw + b_imu)
B_DVL = 10  # DVL compass offset (its reported heading = yaw + b_dvl)
BG_IDX = [11, 12, 13]  # gyro biases (rad/s): measured rate = true rate + b_g
D_IMU = 14  # drift rate of the IMU yaw error (rad/s): d b_imu / dt = d_imu
N_STATE = 15  # = ekf_kernels.N_STATE


@dataclass
class FilterSnapshot:
    """The filter at one instant (NED/FRD, SI units)."""

    stamp: int
    position: np.ndarray
    velocity_body: np.ndarray
    euler: np.ndarray
    angular_velocity: np.ndarray
    covariance: np.ndarray  # N_STATE x N_STATE (p, v, e, b_imu, b_dvl, b_g, d_imu)
    flags: list[str]


def _finite(*values: float) -> bool:
    return all(math.isfinite(v) for v in values)


_DIRECT_H: dict[tuple[int, ...], np.ndarray] = {}


def _direct_h(idx: list[int]) -> np.ndarray:
    """Measurement matrix of a direct measurement of the states ``idx`` (cached; never written: left
    writable so the update kernel has one signature)."""
    key = tuple(idx)
    H = _DIRECT_H.get(key)
    if H is None:
        H = np.zeros((len(idx), N_STATE))
        H[np.arange(len(idx)), idx] = 1.0
        _DIRECT_H[key] = H
    return H


_KEEP: dict[tuple[int, ...], np.ndarray] = {}


def _keep(idx: list[int]) -> np.ndarray:
    """(N_STATE,) bool: the states ``idx`` a restricted gain may correct (cached; never written)."""
    key = tuple(idx)
    out = _KEEP.get(key)
    if out is None:
        out = np.zeros(N_STATE, bool)
        out[list(key)] = True
        _KEEP[key] = out
    return out


class DeadReckoningFilter:
    """EKF dead reckoning from DVL, IMU and depth; see the module docstring."""

    def __init__(self, cfg: RobotStateConfig):
        if cfg.dvl.velocity_sign not in (1.0, -1.0):
            raise ValueError(f"robot_state.dvl.velocity_sign must be 1 or -1, got {cfg.dvl.velocity_sign}")
        self.cfg = cfg
        self.r_bd = euler_to_matrix(*np.radians(cfg.dvl.rotation_rpy_deg))
        self.r_bi = euler_to_matrix(*np.radians(cfg.imu.rotation_rpy_deg))
        self.dvl_identity = not any(cfg.dvl.rotation_rpy_deg)
        self.imu_identity = not any(cfg.imu.rotation_rpy_deg)
        self.r_dvl = np.asarray(cfg.dvl.translation_m, dtype=float)
        self.x = np.zeros(N_STATE)
        fusion = cfg.dvl.heading_fusion
        self.P = np.diag([0.0, 0.0, 1e4, 1e2, 1e2, 1e2, 1e2, 1e2, 1e2, 0.0,
                          math.radians(cfg.dvl.heading_offset_sigma_deg) ** 2]
                         + [math.radians(cfg.imu.gyro_bias_sigma_deg_s) ** 2] * 3
                         + [math.radians(cfg.imu.yaw_drift_rate_sigma_deg_min / 60.0) ** 2 if fusion else 0.0])
        self.t: int | None = None  # state time (ns)
        # process-noise variance rates (per s) of the prediction
        self._q_rates = {"gyro": math.radians(cfg.imu.gyro_sigma_deg_s) ** 2,
                         "attitude_rw": math.radians(cfg.attitude_rw_sigma_deg_s) ** 2,
                         "imu_yaw": math.radians(cfg.imu.yaw_drift_sigma_deg_s) ** 2 if fusion else 0.0,
                         "imu_yaw_rate": math.radians(cfg.imu.yaw_drift_rate_rw_deg_min_s / 60.0) ** 2
                         if fusion else 0.0,
                         "gyro_bias": math.radians(cfg.imu.gyro_bias_rw_deg_s) ** 2}
        self.gyro = np.zeros(3)
        self.have_velocity = False
        self.have_attitude = False
        self.have_depth = False
        self.last_dvl_t: int | None = None
        self.last_imu_t: int | None = None
        self.last_depth_t: int | None = None
        self.attitude_source = "none"
        self.dvl_attitude_zero = False
        self._last: dict[str, tuple[int, int]] = {}
        self._gate_rejects = 0
        self.counters: dict[str, int] = {}
        self.pending: set[str] = set()  # reasons counted since the last take_pending()

    # ------------------------------------------------------------------ bookkeeping
    def count(self, what: str, n: int = 1) -> None:
        self.counters[what] = self.counters.get(what, 0) + n
        self.pending.add(what)

    def take_pending(self) -> list[str]:
        out = sorted(self.pending)
        self.pending = set()
        return out

    @property
    def initialised(self) -> bool:
        return self.have_velocity and self.have_attitude

    def imu_fresh(self, t: int) -> bool:
        return (self.cfg.imu.enabled and self.last_imu_t is not None
                and t - self.last_imu_t <= self.cfg.imu.timeout_s * NS)

    def dvl_fresh(self, t: int) -> bool:
        return self.last_dvl_t is not None and t - self.last_dvl_t <= self.cfg.dvl.timeout_s * NS

    def depth_fresh(self, t: int) -> bool:
        return self.last_depth_t is not None and t - self.last_depth_t <= self.cfg.depth.timeout_s * NS

    def _admit(self, stream: str, stamp: int, seq: int) -> int | None:
        """Order checks of one record; returns the time to apply it at, or None (rejected)."""
        last = self._last.get(stream)
        if last is not None:
            last_stamp, last_seq = last
            if stamp < last_stamp or (seq < last_seq and seq != 0):
                self.count("timestamp_backwards")
                self.count(f"{stream}_timestamp_backwards")
                return None
            if seq == 0 and last_seq > 0:
                self.count(f"{stream}_seq_restart")
        self._last[stream] = (stamp, seq)
        if self.t is None:
            self.t = stamp
            return stamp
        if stamp < self.t:
            self.count("late")
            return self.t
        self.propagate(stamp)
        return stamp

    # ------------------------------------------------------------------ prediction
    def _boundaries(self, t0: int, t1: int) -> list[int]:
        cuts = {t1}
        for last, timeout in ((self.last_dvl_t, self.cfg.dvl.timeout_s), (self.last_imu_t, self.cfg.imu.timeout_s),
                              (self.last_depth_t, self.cfg.depth.timeout_s)):
            if last is not None:
                b = last + int(round(timeout * NS)) + 1  # first instant at which the source is stale
                if t0 < b < t1:
                    cuts.add(b)
        out, prev = [], t0
        for c in sorted(cuts):
            # sub-steps only while the gyro drives the (nonlinear) attitude integration;
            # without it the step is exact for any length (constant attitude, closed-form decay)
            if self.imu_fresh(prev):
                while c - prev > MAX_STEP_NS:
                    prev += MAX_STEP_NS
                    out.append(prev)
            out.append(c)
            prev = c
        return out

    def propagate(self, t: int) -> None:
        """Predict the state to time ``t`` (ns); no-op for ``t`` at or before the state time."""
        if self.t is None:
            self.t = t
            return
        if t <= self.t:
            return
        for tk in self._boundaries(self.t, t):
            self._step(self.t, tk)
            self.t = tk

    def _step(self, t0: int, t1: int) -> None:
        """Predict from ``t0`` to ``t1`` (ns): the inputs' freshness decides the model
        (:func:`~services.robot_state.ekf_kernels.predict` does the arithmetic)."""
        cfg = self.cfg
        dt = (t1 - t0) / NS
        gyro_on = self.imu_fresh(t0)
        if self.dvl_fresh(t0) or not self.have_velocity:
            a, g = 1.0, dt
            qv = cfg.process_accel_sigma ** 2 * dt
        else:
            tau = cfg.dvl.dropout_decay_s
            a = math.exp(-dt / tau)
            g = tau * (1.0 - a)
            qv = cfg.dvl.dropout_speed_sigma ** 2 * (1.0 - a * a)
        integrate = self.initialised
        z_moves = integrate and self.depth_fresh(t0)
        q = self._q_rates
        q_att = (q["gyro"] if gyro_on else q["attitude_rw"]) * dt
        q_z = cfg.dvl.dropout_speed_sigma ** 2 * dt * 1.0 if integrate and not z_moves else 0.0  # z held: 1 s correlation
        predict(self.x, self.P, self.gyro, dt, a, g, qv, gyro_on, integrate, z_moves, q_att, q_z,
                q["imu_yaw"] * dt, q["imu_yaw_rate"] * dt, q["gyro_bias"] * dt)

    # ------------------------------------------------------------------ updates
    def _init_block(self, idx: list[int], z: np.ndarray, r: np.ndarray) -> None:
        self.x[idx] = z
        self.P[idx, :] = 0.0
        self.P[:, idx] = 0.0
        self.P[np.ix_(idx, idx)] = r

    def _update(self, idx: list[int], y: np.ndarray, r: np.ndarray, H: np.ndarray | None = None) -> None:
        """Kalman update with innovation ``y`` of a linear measurement ``H x`` (default: a
        direct measurement of states ``idx``); the gain is restricted to the states ``idx``
        (Joseph form keeps P consistent for any gain)."""
        restricted_update(self.x, self.P, _direct_h(idx) if H is None else H, np.asarray(y, np.float64),
                          np.asarray(r, np.float64), _keep(idx))

    def _yaw_gated(self, y: float, s: float) -> bool:
        """True when a yaw innovation ``y`` (variance ``s``) fails the ``heading_gate_chi2`` gate."""
        gate = self.cfg.heading_gate_chi2
        return gate > 0 and y * y > gate * s

    def _reset_yaw(self, z: float, r: float, bias: int) -> None:
        """yaw := z - b (a measurement with unit gain on the yaw alone); the covariance of the
        new yaw follows from the reset's linear map, the biases keep their estimates."""
        P = self.P
        self.x[8] = wrap_angle(z - self.x[bias])
        row = -P[bias, :].copy()
        row[8] = r + P[bias, bias]
        P[8, :] = row
        P[:, 8] = row

    def _set_attitude(self, e: np.ndarray, sig: np.ndarray, reset: bool, bias: int) -> None:
        """Attitude measurement whose yaw carries the bias state ``bias`` (yaw_meas = yaw + b).

        A yaw innovation beyond ``heading_gate_chi2`` (the gyro prediction failed, e.g. a turn
        faster than the IMU's sampling can follow) resets the yaw to the measurement instead of
        spreading the innovation into the bias states (counted ``imu_yaw_reset``)."""
        r = np.diag(sig ** 2)
        if reset or not self.have_attitude:
            self._init_block(E_IDX, np.array([e[0], e[1], wrap_angle(e[2] - self.x[bias])]), r)
            self.have_attitude = True
            return
        H = np.zeros((3, N_STATE))
        H[0, 6] = H[1, 7] = H[2, 8] = 1.0
        H[2, bias] = 1.0
        y = e - self.x[6:9]
        y[2] -= self.x[bias]
        y = np.array([wrap_angle(a) for a in y])
        idx = E_IDX + [B_IMU, B_DVL] + BG_IDX + [D_IMU]
        s_yaw = float(H[2] @ self.P @ H[2]) + r[2, 2]
        if self._yaw_gated(float(y[2]), s_yaw):
            self.count("imu_yaw_reset")
            self._reset_yaw(float(e[2]), float(r[2, 2]), bias)
            self._update(idx, y[:2], r[:2, :2], H[:2])
        else:
            self._update(idx, y, r, H)
        self.x[8] = wrap_angle(self.x[8])

    def _fuse_dvl_heading(self, heading: float) -> None:
        """DVL compass heading = yaw + b_dvl (with a fresh IMU; corrects yaw and both biases).
        Innovations beyond ``heading_gate_chi2`` are rejected (``dvl_heading_outlier``)."""
        H = np.zeros((1, N_STATE))
        H[0, 8] = H[0, B_DVL] = 1.0
        y = np.array([wrap_angle(heading - self.x[8] - self.x[B_DVL])])
        r = np.array([[math.radians(self.cfg.dvl.heading_sigma_deg) ** 2]])
        if self._yaw_gated(float(y[0]), float(H[0] @ self.P @ H[0]) + float(r[0, 0])):
            self.count("dvl_heading_outlier")
            return
        self._update([8, B_IMU, B_DVL] + BG_IDX + [D_IMU], y, r, H)
        self.x[8] = wrap_angle(self.x[8])

    def update_imu(self, msg: Imu) -> bool:
        """IMU attitude (measurement) and gyro rates (prediction input). False: rejected."""
        stamp = msg.header.stamp
        vals = (msg.roll, msg.pitch, msg.yaw, msg.gx, msg.gy, msg.gz)
        if not _finite(*vals):
            self.count("imu_nonfinite")
            return False
        if not self.cfg.imu.enabled:
            return False
        t = self._admit("imu", stamp, msg.header.seq)
        if t is None:
            return False
        w = np.array([msg.gx, msg.gy, msg.gz], dtype=float)
        e = np.array([msg.roll, msg.pitch, msg.yaw], dtype=float)
        if not self.imu_identity:
            w = self.r_bi @ w
            e = np.array(matrix_to_euler(euler_to_matrix(*e) @ self.r_bi.T))
        # a switch of attitude source (first IMU record, or the IMU back after a timeout) resets
        reset = self.attitude_source != "imu" or not self.imu_fresh(t)
        self.gyro = w
        self.last_imu_t = t
        sig = np.radians([self.cfg.imu.roll_pitch_sigma_deg, self.cfg.imu.roll_pitch_sigma_deg, self.cfg.imu.heading_sigma_deg])
        self._set_attitude(e, sig, reset=reset, bias=B_IMU)
        self.attitude_source = "imu"
        return True

    def update_depth(self, msg: Depth) -> bool:
        """Pressure depth -> z (NED, down +). False: rejected."""
        if not _finite(msg.depth):
            self.count("depth_nonfinite")
            return False
        t = self._admit("depth", msg.header.stamp, msg.header.seq)
        if t is None:
            return False
        z = msg.depth + self.cfg.depth.offset_m
        r = np.array([[self.cfg.depth.sigma ** 2]])
        if not self.have_depth or not self.depth_fresh(t):
            # first depth, or z was held without depth: pressure is absolute, take it
            if self.have_depth:
                self.count("depth_reacquired")
            self._init_block([2], np.array([z]), r)
            self.have_depth = True
        else:
            self._update([2], np.array([z - self.x[2]]), r)
        self.last_depth_t = t
        return True

    def update_dvl(self, msg: LinkquestDvl) -> bool:
        """DVL bottom velocity (and, without a fresh IMU, its attitude). False: rejected."""
        cfg = self.cfg
        vi = msg.velocityinst
        att = (msg.roll, msg.pitch, msg.heading)
        if not _finite(*vi):
            self.count("dvl_nonfinite")
            return False
        t = self._admit("dvl", msg.header.stamp, msg.header.seq)
        if t is None:
            return False
        # attitude from the DVL: the attitude itself without a fresh IMU, else (optionally)
        # its compass heading fused with the IMU yaw
        zero_att = att == (0.0, 0.0, 0.0)
        e = None
        if _finite(*att) and not zero_att:
            e = np.radians(att)
            if not self.dvl_identity:
                e = np.array(matrix_to_euler(euler_to_matrix(*e) @ self.r_bd.T))
        if not self.imu_fresh(t):
            self.dvl_attitude_zero = zero_att
            if zero_att:
                self.count("dvl_attitude_zero")  # no compass: roll, pitch and heading exactly 0
                e = np.zeros(3)
            if e is not None:
                sig = np.radians([cfg.imu.roll_pitch_sigma_deg, cfg.imu.roll_pitch_sigma_deg, cfg.imu.heading_sigma_deg])
                self._set_attitude(e, sig, reset=True, bias=B_DVL)
                self.attitude_source = "dvl"
            else:
                self.count("dvl_attitude_nonfinite")
        elif cfg.dvl.heading_fusion and e is not None and self.have_attitude:
            self._fuse_dvl_heading(float(e[2]))
        if msg.velocityinstflag != 1:
            self.count("dvl_invalid_flag")
            return False
        if sum(1 for g in msg.datagood if g == 1) < cfg.dvl.min_good_beams:
            self.count("dvl_few_beams")
            return False
        v_inst = np.asarray(vi, dtype=float)
        if float(np.linalg.norm(v_inst)) > cfg.dvl.max_speed:
            self.count("dvl_too_fast")
            return False
        v_b = cfg.dvl.velocity_sign * (v_inst if self.dvl_identity else self.r_bd @ v_inst)
        w = self.gyro - self.x[11:14] if self.imu_fresh(t) else np.zeros(3)
        v_b = v_b - np.cross(w, self.r_dvl)
        r = np.eye(3) * cfg.dvl.velocity_sigma ** 2
        if not self.have_velocity or not self.dvl_fresh(t):
            if self.have_velocity:
                self.count("dvl_reacquired")
            self._init_block(V_IDX, v_b, r)
            self.have_velocity = True
        else:
            y = v_b - self.x[3:6]
            if cfg.dvl.gate_chi2 > 0:
                S = self.P[3:6, 3:6] + r
                d2 = float(y @ np.linalg.solve(S, y))
                if d2 > cfg.dvl.gate_chi2:
                    self._gate_rejects += 1
                    if self._gate_rejects < _GATE_MAX_REJECTS:
                        self.count("dvl_outlier")
                        return False
                    self.count("dvl_reinit")
                    self._init_block(V_IDX, v_b, r)
                    self._gate_rejects = 0
                    self.last_dvl_t = t
                    return True
            self._gate_rejects = 0
            self._update(V_IDX, y, r)
        self.last_dvl_t = t
        return True

    # ------------------------------------------------------------------ output
    def flags(self, t: int) -> list[str]:
        """Status flags of the estimate at time ``t``."""
        out = []
        if self.cfg.imu.enabled and not self.imu_fresh(t):
            out.append("imu_absent")
        out.append(f"attitude_{self.attitude_source}")
        if self.attitude_source == "dvl" and self.dvl_attitude_zero:
            out.append("heading_unobserved")
        if not self.dvl_fresh(t):
            out.append("dvl_dropout")
        if not self.depth_fresh(t):
            out.append("depth_dropout")
        return out

    def snapshot(self) -> FilterSnapshot:
        t = self.t if self.t is not None else 0
        w = self.gyro - self.x[11:14] if self.imu_fresh(t) else np.zeros(3)
        return FilterSnapshot(stamp=t, position=self.x[0:3].copy(), velocity_body=self.x[3:6].copy(),
                              euler=self.x[6:9].copy(), angular_velocity=w.copy(), covariance=self.P.copy(),
                              flags=self.flags(t))


def warm_up_kernels(cfg: RobotStateConfig) -> None:
    """Compile the EKF kernels (:mod:`services.robot_state.ekf_kernels`) for the argument types
    the filter passes them, on a throwaway filter: a prediction, a direct and a general update."""
    f = DeadReckoningFilter(cfg)
    f._step(0, NS // 10)
    f._update([2], np.zeros(1), np.eye(1))
    H = np.zeros((1, N_STATE))
    H[0, 8] = 1.0
    f._update([8], np.zeros(1), np.eye(1), H)
