"""The driver API: how a vendor's driver (no ROS) puts its sensor records on the bus, live.

    from common.bus import Bus
    from common.driver import SensorDriver

    with SensorDriver(Bus("poseidon", connect=["tcp/127.0.0.1:7447"]), announce=["dvl_linkquest"]) as drv:
        drv.camera_frame(rgb)                       # (h, w, 3) uint8 -> camera/image_raw
        drv.sonar_beam(angle_rad, intensities, 20)  # one beam -> sonar_micron
        drv.dvl([vx, vy, vz], altitude)             # bottom velocity (m/s, instrument frame) -> dvl_linkquest
        drv.imu(roll, pitch, yaw, gyro=(...), accel=(...))   # rad, rad/s, m/s^2 -> imu_adis_ros

Each call builds our message (:mod:`common.messages`; a wrong shape or type raises naming the
field) with a per-key seq and the record's stamp (ns; default: now, the wall clock -- pass the
sensor's own time when it has one) and publishes it at once: a driver never waits for its
consumers.  Keys default to the ones the services read (``key=`` overrides).  While the driver
is open, every key it published and every ``announce``-d key gets a wall-clock watermark every
``watermark_interval_ms`` (:mod:`common.live`: the rule and the ``lateness_ms`` bound), so a
silent sensor does not stall the services; :meth:`SensorDriver.close` (or leaving the ``with``)
sends end-of-stream on all of them.  Counters: ``published``, ``late`` (per key); a consumer
lost mid-run is an outage (:mod:`common.live`: each key keeps its last ``outage_frames`` frames,
at most ``outage_bytes``, and sends them again when a consumer is back; counters in
``source.counters()``).

A driver that produces records at a fixed rate (a frame grabber, a simulated sensor) paces
itself with :class:`Pacer`: an absolute schedule, each record stamped with its scheduled instant.
Example: ``deploy/examples/stream_images.py`` streams a folder of images at a given rate.
"""
from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from types import TracebackType
from typing import Any

import numpy as np

from common.bus import Bus
from common.live import LiveSource
from common.messages import Header, Image, Imu, LinkquestDvl, Message, RangeImageBeam

__all__ = ["SensorDriver", "Pacer"]

_ENCODING = {1: "mono8", 3: "rgb8", 4: "rgba8"}


def _quaternion(roll: float, pitch: float, yaw: float) -> tuple[float, float, float, float]:
    """x y z w of ZYX Euler angles (rad)."""
    cr, sr = np.cos(roll / 2), np.sin(roll / 2)
    cp, sp = np.cos(pitch / 2), np.sin(pitch / 2)
    cy, sy = np.cos(yaw / 2), np.sin(yaw / 2)
    return (float(sr * cp * cy - cr * sp * sy), float(cr * sp * cy + sr * cp * sy),
            float(cr * cp * sy - sr * sp * cy), float(cr * cp * cy + sr * sp * sy))


class Pacer:
    """The schedule of a fixed-rate source: record ``i`` is due at ``start + i / rate_hz``, where
    ``start`` is the first call of :meth:`wait` (record 0 is due when it is first ready).

    The schedule is absolute (a slow record does not shift the ones after it) and kept on one
    clock, ``clock_ns`` (monotonic); a record's stamp is the wall-clock time of its due instant,
    ``wall_ns`` at the start plus the same offset, so stamps are exactly ``1 / rate_hz`` apart
    whatever the time spent reading or sending a record.  A record that is behind its schedule
    (a loaded machine) is stamped when it is taken, never earlier: stamps never run ahead of the
    schedule and never lie in the past of the record's own publication.

    :param rate_hz: records per second (> 0)
    :param clock_ns: the pacing clock (ns), default :func:`time.monotonic_ns`
    :param sleep: waits that many seconds, default :func:`time.sleep`
    :param wall_ns: the stamps' clock (ns), default :func:`time.time_ns`, read once at the start
    :raises ValueError: ``rate_hz`` is not > 0
    """

    def __init__(self, rate_hz: float, clock_ns: Callable[[], int] = time.monotonic_ns,
                 sleep: Callable[[float], Any] = time.sleep, wall_ns: Callable[[], int] = time.time_ns):
        if not rate_hz > 0:
            raise ValueError(f"rate must be > 0 records/s, got {rate_hz}")
        self.period_ns = 1e9 / rate_hz
        self._clock_ns, self._sleep, self._wall_ns = clock_ns, sleep, wall_ns
        self._start: int | None = None
        self._wall_start = 0

    def due_ns(self, i: int) -> int:
        """Offset of record ``i``'s due instant from the start (ns)."""
        return int(round(i * self.period_ns))

    def wait(self, i: int) -> int:
        """Sleep until record ``i`` is due (at once when it is overdue); its stamp (ns, wall clock)."""
        if self._start is None:
            self._start, self._wall_start = self._clock_ns(), self._wall_ns()
        due = self.due_ns(i)
        ahead = self._start + due - self._clock_ns()
        if ahead > 0:
            self._sleep(ahead / 1e9)
        return self._wall_start + max(due, self._clock_ns() - self._start)


class SensorDriver:
    """A live source of sensor records for a vendor's driver (see the module notes)."""

    def __init__(self, bus: Bus, announce: Iterable[str] = (), lateness_ms: int = 200,
                 watermark_interval_ms: int = 100, outage_frames: int = 1000, outage_bytes: int = 64 << 20,
                 consumers: Mapping[str, list[str]] | None = None, retain_s: float = 300.0,
                 stall_hold_ms: int = 2000):
        """``consumers`` (key -> the services that read it, the recorder included): a supervised
        deployment, where the driver keeps each key's frames for a restarted consumer until every
        consumer checkpointed past them, at most ``retain_s`` of event time and ``outage_bytes``
        per key (:meth:`common.live.LiveSource.serve_replays`).  ``stall_hold_ms``: how long a
        stalled key's watermark is held back at most (:mod:`common.live`: Stalls)."""
        self.bus = bus
        if consumers is None:
            self.source = LiveSource(bus, lateness_ms * 1_000_000, announce, outage_frames, outage_bytes,
                                     stall_hold_ns=stall_hold_ms * 1_000_000)
        else:
            self.source = LiveSource(bus, lateness_ms * 1_000_000, announce, 1 << 62, outage_bytes,
                                     int(retain_s * 1e9), stall_hold_ms * 1_000_000)
            self.source.serve_replays({k: list(v) for k, v in consumers.items()})
        self.source.start_watermarks(watermark_interval_ms / 1000)
        self._seq: dict[str, int] = {}

    @property
    def published(self) -> dict[str, int]:
        return dict(self.source.published)

    @property
    def late(self) -> dict[str, int]:
        return dict(self.source.late)

    def header(self, key: str, stamp_ns: int | None, frame_id: str) -> Header:
        """The next header of ``key``: its own seq, ``stamp_ns`` (None: now)."""
        seq = self._seq.get(key, 0)
        self._seq[key] = seq + 1
        return Header(seq=seq, stamp=time.time_ns() if stamp_ns is None else int(stamp_ns), frame_id=frame_id)

    def publish(self, key: str, msg: Message) -> bool:
        """Publish any of our messages on ``key`` now; True when it was late (published anyway)."""
        return self.source.publish(key, msg)

    def camera_frame(self, image: np.ndarray, stamp_ns: int | None = None, key: str = "camera/image_raw",
                     frame_id: str = "camera", encoding: str | None = None) -> bool:
        """One frame: (h, w) mono8, (h, w, 3) rgb8 or (h, w, 4) rgba8 uint8 (``encoding`` overrides,
        e.g. bgr8, mono16 for uint16)."""
        data = np.ascontiguousarray(image)
        channels = 1 if data.ndim == 2 else int(data.shape[2]) if data.ndim == 3 else 0
        enc = encoding or ("mono16" if data.dtype == np.uint16 and channels == 1 else _ENCODING.get(channels))
        if enc is None or data.ndim not in (2, 3):
            raise ValueError(f"camera frame on {key}: image of shape {data.shape} is not (h, w[, 1|3|4])")
        return self.publish(key, Image(header=self.header(key, stamp_ns, frame_id), height=int(data.shape[0]),
                                       width=int(data.shape[1]), encoding=enc, data=data))

    def sonar_beam(self, angle_rad: float, intensities: Sequence[int] | np.ndarray, max_range_m: int,
                   stamp_ns: int | None = None, key: str = "sonar_micron", frame_id: str = "sonar") -> bool:
        """One beam of a mechanically scanned sonar: echo intensities from 0 to ``max_range_m``."""
        beam = np.asarray(intensities, dtype=np.int32)
        return self.publish(key, RangeImageBeam(header=self.header(key, stamp_ns, frame_id),
                                                angle_rad=float(angle_rad), angle_grad=float(np.degrees(angle_rad)),
                                                nbins=int(beam.size), max_range=int(max_range_m), beam_data=beam))

    def dvl(self, velocity: Sequence[float], altitude: float, stamp_ns: int | None = None, valid: bool = True,
            key: str = "dvl_linkquest", frame_id: str = "dvl", **fields: Any) -> bool:
        """A DVL record: bottom ``velocity`` (m/s, instrument frame) and ``altitude`` (m); ``valid``
        False flags a dropout.  Other LinkquestDvl fields (``heading``, ``datagood``...) as keywords;
        those not given are zero (beams flagged good when ``valid``)."""
        good = 1 if valid else 0
        values: dict[str, Any] = {
            "datagood": [good] * 4, "altitudebeam": [float(altitude)] * 4, "bottomvelocitybeam": [0.0] * 4,
            "watervelocitybeam": [0.0] * 4, "watervelocitycredit": [0.0] * 4,
            "velocityinst": [float(v) for v in velocity], "velocityinstflag": good, "velocityearth": [0.0] * 3,
            "velocityearthflag": 0, "watervelocityinst": [0.0] * 3, "watervelocityinstflag": 0,
            "watervelocityearth": [0.0] * 3, "watervelocityearthflag": 0, "roll": 0.0, "pitch": 0.0,
            "heading": 0.0, "altitude": float(altitude), "temperature": 0.0, "pressure": 0.0, "salinity": 0.0,
            "soundspeed": 0.0}
        values.update(fields)
        return self.publish(key, LinkquestDvl(header=self.header(key, stamp_ns, frame_id), **values))

    def imu(self, roll: float, pitch: float, yaw: float, gyro: Sequence[float] = (0.0, 0.0, 0.0),
            accel: Sequence[float] = (0.0, 0.0, 0.0), stamp_ns: int | None = None, key: str = "imu_adis_ros",
            frame_id: str = "imu") -> bool:
        """An IMU record: attitude (rad, ZYX), angular rate (rad/s), acceleration (m/s^2)."""
        qx, qy, qz, qw = _quaternion(roll, pitch, yaw)
        return self.publish(key, Imu(header=self.header(key, stamp_ns, frame_id), roll=roll, pitch=pitch, yaw=yaw,
                                     qx=qx, qy=qy, qz=qz, qw=qw, gx=float(gyro[0]), gy=float(gyro[1]),
                                     gz=float(gyro[2]), ax=float(accel[0]), ay=float(accel[1]), az=float(accel[2])))

    def close(self) -> None:
        """End-of-stream on every key published or announced; nothing is published after."""
        self.source.end()

    def __enter__(self) -> SensorDriver:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()
