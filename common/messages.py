"""Typed messages of PoseidonSLAM (pydantic models, msgpack on the wire).

(Over 500 lines because every wire message is here: the codec, the recorder's schemas and the
ROS mapping see one registry, and no service depends on another's message module.)

Every message carries a :class:`Header` (``seq`` per publisher, ``stamp`` event time in
integer nanoseconds, ``frame_id``).  Numpy arrays are fields of type :data:`NDArray`; the
codec (:mod:`common.codec`) carries them as raw bytes with dtype and shape.

Sensor inputs follow the fields of the real Cala Viuda dataset (package
``cirs_girona_cala_viuda``: Depth, Imu, LinkquestDvl, RangeImageBeam) and the standard
``sensor_msgs`` / ``nav_msgs`` types it also records (Image, LaserScan, Odometry).
SLAM outputs follow the dissertation, Section 4.2 (SDRs, LocalViewCells, ExperienceEvent,
ExperienceMap, ExperienceImage).  Other sensor types a vehicle records (NavSatFix,
FluidPressure, Temperature, MagneticField, PoseWithCovarianceStamped, TwistStamped,
TFMessage, DiagnosticArray) have lossless models for ``poseidon import``; any other ROS
message travels as :class:`RawMessage` (its serialised bytes and definition) on a
``raw/...`` key.

:data:`KEYS` maps every key of the architecture (relative to the vehicle namespace, e.g.
``poseidon/``) to its message type (every ``raw/...`` key carries RawMessage).
Conventions: positions in metres, angles in radians, velocities in m/s, world frame NED
unless a field says otherwise.
"""
from __future__ import annotations

from typing import Annotated, Any, ClassVar, Literal

import numpy as np
from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, PlainSerializer, WithJsonSchema, model_validator

__all__ = [
    "NDArray", "Header", "Message", "Image", "RangeImageBeam", "LaserScan", "LinkquestDvl",
    "Imu", "Depth", "Odometry", "Sdr", "NeocortexSdr", "LocalViewCell", "LocalViewCells",
    "ExperienceEvent", "PoseCellActivity", "ExperienceNode", "ExperienceLink", "ExperienceMap", "ExperienceImage", "ScanPose",
    "PoseStamped", "RevisitTruth", "NavSatFix", "FluidPressure", "Temperature", "MagneticField",
    "PoseWithCovarianceStamped", "TwistStamped", "TransformStamped", "TFMessage", "KeyValue", "DiagnosticStatus",
    "DiagnosticArray", "RawMessage", "LatencyReport", "LatencyStage", "RAW_KEY_PREFIX", "IMAGE_CHANNELS", "KEYS", "MESSAGE_TYPES", "message_type", "key_type",
]


def _to_array(value: Any) -> np.ndarray:
    """Any accepted form -> a numeric numpy array (bool, int, uint or float; never object or text)."""
    if isinstance(value, np.ndarray):
        arr = value
    elif isinstance(value, dict) and {"dtype", "shape", "data"} <= value.keys():
        try:
            arr = np.frombuffer(value["data"], dtype=np.dtype(value["dtype"])).reshape(value["shape"])
        except (TypeError, ValueError) as exc:  # a bad dtype string or a shape the bytes do not fill
            raise ValueError(f"array {value.get('dtype')!r} {value.get('shape')!r}: {exc}") from None
    elif isinstance(value, (list, tuple)):
        try:
            arr = np.asarray(value)
        except (TypeError, ValueError) as exc:  # ragged nesting
            raise ValueError(f"not a rectangular numeric array: {exc}") from None
    else:
        raise ValueError(f"expected a numpy array, got {type(value).__name__}")
    if arr.dtype.kind not in "biuf":
        raise ValueError(f"array of dtype {arr.dtype.str} is not numeric (bool, int, uint or float)")
    return arr


def _require(cond: bool, what: str) -> None:
    """A cross-field check of a model validator: ValueError (-> ValidationError) naming the contradiction."""
    if not cond:
        raise ValueError(what)


def _index_array(arr: np.ndarray, name: str) -> None:
    _require(arr.ndim == 1, f"{name} must be one-dimensional, got shape {arr.shape}")
    _require(arr.dtype.kind in "iu", f"{name} must hold integers, got dtype {arr.dtype.str}")


#: A numpy array field.  JSON schema: an object with dtype, shape and the raw bytes.
NDArray = Annotated[
    np.ndarray,
    BeforeValidator(_to_array),
    PlainSerializer(lambda a: a, return_type=Any, when_used="python"),
    PlainSerializer(lambda a: {"dtype": a.dtype.str, "shape": list(a.shape), "data": a.tobytes().hex()},
                    return_type=Any, when_used="json"),
    WithJsonSchema({
        "type": "object",
        "description": "numpy array: raw little-endian bytes (msgpack bin) with dtype and shape",
        "properties": {
            "dtype": {"type": "string"},
            "shape": {"type": "array", "items": {"type": "integer"}},
            "data": {"type": "string", "contentEncoding": "base64"},
        },
        "required": ["dtype", "shape", "data"],
    }),
]


class Header(BaseModel):
    """ROS-style header: ``seq`` (+1 per message of a publisher), ``stamp`` (event time, ns)."""

    model_config = ConfigDict(extra="forbid")
    seq: int = Field(ge=0)
    stamp: int = Field(ge=0, description="event time in nanoseconds since the epoch")
    frame_id: str = ""


class Message(BaseModel):
    """Base of every message: a header, arrays allowed, unknown fields rejected."""

    model_config = ConfigDict(extra="forbid", arbitrary_types_allowed=True)
    type_name: ClassVar[str] = ""
    header: Header

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        cls.type_name = f"poseidon_msgs/{cls.__name__}"


# --------------------------------------------------------------------------- sensors


#: channels per image encoding
IMAGE_CHANNELS = {"rgb8": 3, "bgr8": 3, "mono8": 1, "rgba8": 4, "bgra8": 4, "mono16": 1}


class Image(Message):
    """sensor_msgs/Image. ``data`` has shape (height, width, channels) or (height, width)."""

    height: int = Field(ge=1)
    width: int = Field(ge=1)
    encoding: Literal["rgb8", "bgr8", "mono8", "rgba8", "bgra8", "mono16"] = "rgb8"
    data: NDArray

    @model_validator(mode="after")
    def _data_matches_header(self) -> Image:
        """``data`` must be (height, width[, channels]) of the dtype and channel count of ``encoding``."""
        d = self.data
        _require(d.ndim in (2, 3), f"data must be (height, width[, channels]), got shape {d.shape}")
        _require(d.shape[:2] == (self.height, self.width),
                 f"data shape {d.shape} contradicts height {self.height} x width {self.width}")
        channels = d.shape[2] if d.ndim == 3 else 1
        _require(channels == IMAGE_CHANNELS[self.encoding],
                 f"data has {channels} channels, encoding {self.encoding} has {IMAGE_CHANNELS[self.encoding]}")
        want = np.dtype(np.uint16) if self.encoding == "mono16" else np.dtype(np.uint8)
        _require(d.dtype.kind == "u" and d.dtype.itemsize == want.itemsize,
                 f"data dtype {d.dtype.str} contradicts encoding {self.encoding} ({want.name})")
        return self


class RangeImageBeam(Message):
    """cirs_girona_cala_viuda/RangeImageBeam: one beam of a mechanically scanned sonar."""

    angle_grad: float
    angle_rad: float
    nbins: int = Field(ge=0)
    max_range: int = Field(ge=0, description="metres")
    beam_data: NDArray = Field(description="int32 echo intensities, nbins long")

    @model_validator(mode="after")
    def _nbins_matches_data(self) -> RangeImageBeam:
        _require(self.beam_data.ndim == 1, f"beam_data must be one-dimensional, got shape {self.beam_data.shape}")
        _require(len(self.beam_data) == self.nbins,
                 f"nbins {self.nbins} contradicts beam_data of {len(self.beam_data)} values")
        _require(self.beam_data.dtype.kind in "iu", f"beam_data must hold integers, got {self.beam_data.dtype.str}")
        return self


class LaserScan(Message):
    """sensor_msgs/LaserScan (the ``*_ros`` sonar topics of the dataset)."""

    angle_min: float
    angle_max: float
    angle_increment: float
    time_increment: float = 0.0
    scan_time: float = 0.0
    range_min: float
    range_max: float
    ranges: NDArray
    intensities: NDArray

    @model_validator(mode="after")
    def _arrays_agree(self) -> LaserScan:
        """ranges 1-D; intensities empty or one per range; the angle span not reversed."""
        _require(self.ranges.ndim == 1, f"ranges must be one-dimensional, got shape {self.ranges.shape}")
        _require(self.intensities.ndim == 1, f"intensities must be one-dimensional, got shape {self.intensities.shape}")
        _require(len(self.intensities) in (0, len(self.ranges)),
                 f"{len(self.intensities)} intensities for {len(self.ranges)} ranges")
        _require(self.angle_max >= self.angle_min, f"angle_max {self.angle_max} < angle_min {self.angle_min}")
        _require(self.range_max >= self.range_min, f"range_max {self.range_max} < range_min {self.range_min}")
        return self


class LinkquestDvl(Message):
    """cirs_girona_cala_viuda/LinkquestDvl (LinkQuest NavQuest 600 Micro).

    ``velocityinst`` is the bottom velocity in the instrument frame, valid when
    ``velocityinstflag`` is 1; ``datagood`` flags each of the four beams.  Attitude
    (roll, pitch, heading) is in degrees as the instrument reports it.
    """

    errcode: str = ""
    datagood: list[int] = Field(min_length=4, max_length=4)
    altitudebeam: list[float] = Field(min_length=4, max_length=4)
    bottomvelocitybeam: list[float] = Field(min_length=4, max_length=4)
    watervelocitybeam: list[float] = Field(min_length=4, max_length=4)
    watervelocitycredit: list[float] = Field(min_length=4, max_length=4)
    velocityinst: list[float] = Field(min_length=3, max_length=3)
    velocityinstflag: int
    velocityearth: list[float] = Field(min_length=3, max_length=3)
    velocityearthflag: int
    watervelocityinst: list[float] = Field(min_length=3, max_length=3)
    watervelocityinstflag: int
    watervelocityearth: list[float] = Field(min_length=3, max_length=3)
    watervelocityearthflag: int
    roll: float
    pitch: float
    heading: float
    altitude: float
    temperature: float
    pressure: float
    salinity: float
    soundspeed: float
    rawdata: str = ""


class Imu(Message):
    """cirs_girona_cala_viuda/Imu (ADIS16480): attitude (rad), quaternion, magnetometer,
    accelerometer (m/s^2), gyro (rad/s), gyro bias; also the target of sensor_msgs/Imu."""

    roll: float
    pitch: float
    yaw: float
    qx: float
    qy: float
    qz: float
    qw: float
    temp: float = 0.0
    mx: float = 0.0
    my: float = 0.0
    mz: float = 0.0
    ax: float = 0.0
    ay: float = 0.0
    az: float = 0.0
    gx: float = 0.0
    gy: float = 0.0
    gz: float = 0.0
    bx: float = 0.0
    by: float = 0.0
    bz: float = 0.0


class Depth(Message):
    """cirs_girona_cala_viuda/Depth: depth below the surface from pressure, metres (down +)."""

    depth: float


class Odometry(Message):
    """nav_msgs/Odometry: pose (position m, orientation quaternion xyzw) and twist.

    ``pose_covariance`` and ``twist_covariance`` are row-major 6x6 (x y z roll pitch yaw).
    ``status`` carries flags of the producer (e.g. ``dvl_dropout``) for the audit.
    """

    child_frame_id: str = ""
    position: list[float] = Field(min_length=3, max_length=3)
    orientation: list[float] = Field(min_length=4, max_length=4, description="quaternion x y z w")
    linear_velocity: list[float] = Field(default_factory=lambda: [0.0, 0.0, 0.0], min_length=3, max_length=3)
    angular_velocity: list[float] = Field(default_factory=lambda: [0.0, 0.0, 0.0], min_length=3, max_length=3)
    pose_covariance: list[float] = Field(default_factory=lambda: [0.0] * 36, min_length=36, max_length=36)
    twist_covariance: list[float] = Field(default_factory=lambda: [0.0] * 36, min_length=36, max_length=36)
    status: list[str] = Field(default_factory=list)


class PoseStamped(Message):
    """A 3D position (m) with yaw (rad): one sample of a trajectory (``dead_reckoning``)."""

    position: list[float] = Field(min_length=3, max_length=3)
    yaw: float = 0.0


# --------------------------------------------------------------------------- SLAM outputs


class Sdr(Message):
    """A sparse distributed representation: sorted active bit indices (0-based) of ``size`` bits."""

    modality: str = Field(description="camera | sonar | fused")
    size: int = Field(ge=1)
    active: NDArray = Field(description="uint32 sorted active indices")

    @model_validator(mode="after")
    def _active_within_size(self) -> Sdr:
        """Active indices: integers, strictly increasing (sorted, no repeats), in [0, size)."""
        a = self.active
        _index_array(a, "active")
        if len(a):
            increasing = bool((a[1:] > a[:-1]).all())
            # strictly increasing: the ends are the extremes (one pass over the array, not three)
            lo, hi = (int(a[0]), int(a[-1])) if increasing else (int(a.min()), int(a.max()))
            _require(lo >= 0 and hi < self.size, f"active indices span [{lo}, {hi}], outside [0, size {self.size})")
            _require(increasing, "active indices are not sorted strictly increasing")
        return self


class NeocortexSdr(Message):
    """Encoder output per frame (Eqs. 4.1-4.3): per-modality SDRs and their fusion."""

    modalities: list[Sdr]
    fused: Sdr
    fusion_mode: str

    @model_validator(mode="after")
    def _one_bit_space(self) -> NeocortexSdr:
        sizes = {m.size for m in self.modalities}
        _require(sizes <= {self.fused.size}, f"modality SDR sizes {sorted(sizes)} differ from the fused size "
                 f"{self.fused.size}")
        return self


class LocalViewCell(BaseModel):
    model_config = ConfigDict(extra="forbid")
    id: int = Field(ge=0)
    rate: float = Field(ge=0.0, le=1.0, description="overlap-recall R of Eq. 4.7")


class LocalViewCells(Message):
    """``local_view_cells`` (Section 4.2.2): most active LVC id, R as rate, every frame."""

    most_active_cell: int = Field(ge=0)
    active_cells: list[LocalViewCell]
    is_new: bool = Field(description="true when Eq. 4.10 created the id on this frame")
    intersection: int = Field(ge=0, description="I of Eq. 4.6 for the winner (0 if new)")


class ExperienceEvent(Message):
    """``experience_event``: an accepted identity with its pose evidence (Section 4.2.3)."""

    lvc_id: int = Field(ge=0)
    pc_centroid: list[float] = Field(min_length=4, max_length=4, description="x y z (m) and yaw (rad)")
    odom_position: list[float] = Field(min_length=3, max_length=3)
    odom_yaw: float
    gate: str = Field(description="vpr | leak | off: which rule authorised the event")
    vpr_count: int = Field(ge=0, description="C_t of Eq. 4.11")


class PoseCellActivity(Message):
    """``posecells/activity``: the pose-cell activity summed over (z, yaw) and over (x, y), as
    uint8 images (activity of a pixel = value * scale), with the centroid (Section 4.2.4)."""

    xy: NDArray = Field(description="uint8 (nx, ny): activity summed over z and yaw, times 1 / xy_scale")
    xy_scale: float = Field(ge=0, allow_inf_nan=False, description="activity per unit of xy")
    zyaw: NDArray = Field(description="uint8 (nz, n_yaw): activity summed over x and y, times 1 / zyaw_scale")
    zyaw_scale: float = Field(ge=0, allow_inf_nan=False, description="activity per unit of zyaw")
    centroid: list[float] = Field(min_length=4, max_length=4, description="x y z (m, in [0, n * spacing)) and "
                                  "yaw (rad, in [-pi, pi))")
    spacing: list[float] = Field(min_length=3, max_length=3, description="cell spacing along x, y, z (m); a "
                                 "yaw cell is 2 pi / n_yaw rad")
    steps: int = Field(ge=0, description="pose-cell steps (LVC frames) so far")

    @model_validator(mode="after")
    def _images(self) -> PoseCellActivity:
        for name, img in (("xy", self.xy), ("zyaw", self.zyaw)):
            _require(img.ndim == 2 and img.dtype == np.uint8, f"{name} must be a 2-D uint8 image, got "
                     f"{img.dtype.str} {img.shape}")
        return self


class ExperienceNode(BaseModel):
    model_config = ConfigDict(extra="forbid")
    id: int = Field(ge=0)
    lvc_id: int = Field(ge=0)
    position: list[float] = Field(min_length=3, max_length=3)
    yaw: float
    stamp: int


class ExperienceLink(BaseModel):
    model_config = ConfigDict(extra="forbid")
    source: int
    target: int
    delta: list[float] = Field(min_length=3, max_length=3)
    duration_s: float
    weight: float
    loop_closure: bool = False


class ExperienceMap(Message):
    """``map``: the 3D experience graph (Eqs. 4.20-4.21)."""

    nodes: list[ExperienceNode]
    links: list[ExperienceLink]
    current: int = -1
    corrections: int = 0


class ScanPose(Message):
    """``scan_pose``: where one range scan was taken, registered against the local map of an
    experience (laser map, services/expmap/scan_poses.py); stamp = the scan's."""

    experience_id: int = Field(ge=0, description="the map node whose frame ``pose`` is in")
    pose: list[float] = Field(min_length=3, max_length=3, description="x m forward, y m left, yaw rad of the "
                              "robot at the scan, in the experience's frame")
    score: float = Field(ge=0, le=1, description="the registration's mean likelihood (0..1)")


class SessionLinkInfo(BaseModel):
    """One link between two sessions of the map (see ``MapSessions``)."""

    model_config = ConfigDict(extra="forbid")
    session: int = Field(ge=0, description="the session of target (the newer component)")
    to_session: int = Field(ge=0, description="the session of source")
    source: int = Field(ge=0, description="node id of the older experience")
    target: int = Field(ge=0, description="node id of the newer experience")
    stamp: int = Field(description="event stamp of the link (ns)")
    delta: list[float] = Field(min_length=3, max_length=3, description="p_target - p_source asked (m)")
    shift: list[float] = Field(min_length=3, max_length=3, description="how far the newer component moved (m)")
    rotation_deg: float = Field(description="heading disagreement of the two sweeps (the registration's, deg)")
    inlier_fraction: float
    applied_deg: float = Field(0.0, description="rotation applied to the newer session (deg; 0: translation "
                               "only, expmap.sessions.link_rotate off)")


class MapSessions(Message):
    """``map_sessions``: the sessions of the ``map`` published with the same stamp;
    published only by a map with more than one session."""

    node_session: list[int] = Field(description="session id per node of that map")
    loaded_nodes: int = Field(ge=0, description="nodes loaded from the map file at start (earlier missions)")
    links: list[SessionLinkInfo]
    rejections: dict[str, int] = Field(default_factory=dict, description="link candidates refused, per reason")


class ExperienceImage(Image):
    """``experience_image``: the camera frame closest to an event, header = event header."""

    source_stamp: int = Field(description="stamp of the camera frame used as evidence (ns)")


# --------------------------------------------------------------------------- other ROS sensor types
# Lossless models of the common sensor_msgs / geometry_msgs / tf2_msgs / diagnostic_msgs types a
# vehicle records besides the SLAM inputs (``poseidon import`` maps them; ``poseidon export``
# writes them back as the same ROS types).  Field names and units as in ROS.


class NavSatFix(Message):
    """sensor_msgs/NavSatFix: a GNSS fix (surface fixes of an AUV), WGS 84."""

    status: int = Field(description="NavSatStatus.status: -1 no fix, 0 fix, 1 SBAS, 2 GBAS")
    service: int = Field(0, description="NavSatStatus.service bit mask (1 GPS, 2 GLONASS, 4 COMPASS, 8 GALILEO)")
    latitude: float = Field(description="degrees, + north")
    longitude: float = Field(description="degrees, + east")
    altitude: float = Field(description="metres above the WGS 84 ellipsoid")
    position_covariance: list[float] = Field(default_factory=lambda: [0.0] * 9, min_length=9, max_length=9,
                                             description="m^2, row-major 3x3 in ENU")
    position_covariance_type: int = Field(0, description="0 unknown, 1 approximated, 2 diagonal known, 3 known")


class FluidPressure(Message):
    """sensor_msgs/FluidPressure: pressure in pascals and its variance (Pa^2)."""

    fluid_pressure: float
    variance: float = 0.0


class Temperature(Message):
    """sensor_msgs/Temperature: degrees Celsius and variance."""

    temperature: float
    variance: float = 0.0


class MagneticField(Message):
    """sensor_msgs/MagneticField: field vector in tesla, row-major 3x3 covariance."""

    magnetic_field: list[float] = Field(min_length=3, max_length=3)
    magnetic_field_covariance: list[float] = Field(default_factory=lambda: [0.0] * 9, min_length=9, max_length=9)


class PoseWithCovarianceStamped(Message):
    """geometry_msgs/PoseWithCovarianceStamped: position (m), quaternion xyzw, 6x6 covariance."""

    position: list[float] = Field(min_length=3, max_length=3)
    orientation: list[float] = Field(min_length=4, max_length=4, description="quaternion x y z w")
    covariance: list[float] = Field(default_factory=lambda: [0.0] * 36, min_length=36, max_length=36)


class TwistStamped(Message):
    """geometry_msgs/TwistStamped: linear (m/s) and angular (rad/s) velocity."""

    linear: list[float] = Field(min_length=3, max_length=3)
    angular: list[float] = Field(min_length=3, max_length=3)


class TransformStamped(BaseModel):
    """geometry_msgs/TransformStamped: ``header.frame_id`` -> ``child_frame_id``."""

    model_config = ConfigDict(extra="forbid")
    header: Header
    child_frame_id: str
    translation: list[float] = Field(min_length=3, max_length=3, description="metres")
    rotation: list[float] = Field(min_length=4, max_length=4, description="quaternion x y z w")


class TFMessage(Message):
    """tf2_msgs/TFMessage (and ROS1 tf/tfMessage).  ROS has no header on it: ours carries the
    stamp of the first transform (or the bag's record time) and an empty frame_id."""

    transforms: list[TransformStamped]


class KeyValue(BaseModel):
    model_config = ConfigDict(extra="forbid")
    key: str
    value: str


class DiagnosticStatus(BaseModel):
    """diagnostic_msgs/DiagnosticStatus: level 0 OK, 1 WARN, 2 ERROR, 3 STALE."""

    model_config = ConfigDict(extra="forbid")
    level: int
    name: str
    message: str = ""
    hardware_id: str = ""
    values: list[KeyValue] = Field(default_factory=list)


class DiagnosticArray(Message):
    """diagnostic_msgs/DiagnosticArray."""

    status: list[DiagnosticStatus]


#: keys of raw-carried messages: ``raw/<key the topic would have>`` (``/vendor/status`` -> ``raw/vendor/status``)
RAW_KEY_PREFIX = "raw/"


class RawMessage(Message):
    """A ROS message whose type has no model here, carried through unchanged (``poseidon import``
    records it on ``raw/<key>``; the player replays it; ``poseidon export`` writes the bytes back).

    ``data`` is the message exactly as serialised in the source bag; ``definition`` is the
    message definition text as the bag stored it (ROS1: the full ``.msg`` text with its
    dependencies after ``MSG:`` separators; ROS2: ``.msg`` or ``.idl`` text, or the definition
    rosbags generated when the bag had none).  ``header`` stamp is the ROS header stamp when the
    message has one, else the bag's record time.
    """

    topic: str = Field(description="the original ROS topic, e.g. /vendor/status")
    ros_type: str = Field(description="ROS type in rosbags form, e.g. vendor_msgs/msg/Status")
    serialization: Literal["ros1", "cdr"]
    definition: str
    definition_format: Literal["msg", "idl"] = "msg"
    digest: str = Field("", description="ROS1 md5sum or ROS2 RIHS01 type hash of the definition, if known")
    data: bytes


class LatencyStage(BaseModel):
    """One stage of a :class:`LatencyReport`: wall time from a sensor message's arrival at the
    live source to the output it caused arriving back there (ms)."""

    model_config = ConfigDict(extra="forbid")
    n: int = Field(ge=0, description="outputs matched to an input by stamp")
    unmatched: int = Field(0, ge=0, description="outputs whose stamp no remembered input had")
    p50_ms: float | None = None
    p95_ms: float | None = None
    p99_ms: float | None = None
    max_ms: float | None = None


class LatencyReport(Message):
    """``live/latency``: a live run's latency per stage, published once by its source after the
    services' outputs ended (recorded with the run; ``poseidon eval`` reads it).  Stages:
    ``lvc``, ``event``, ``map``, ``odometry``, ``dead_reckoning`` (:mod:`common.live`)."""

    source: str = Field(description="the live source that measured it: bridge_ros1 | live_player")
    rate: float = Field(0.0, ge=0, description="the live player's pace (x real time); 0 for a sensor source")
    stages: dict[str, LatencyStage]


# --------------------------------------------------------------------------- ground truth


class RevisitTruth(Message):
    """Ground truth for one camera frame (simulated or transformed missions): the indices
    (0-based, in camera-frame order) of earlier frames that show the same place."""

    frame_index: int = Field(ge=0)
    same_place: NDArray = Field(description="int32 indices of earlier frames of the same place")

    @model_validator(mode="after")
    def _earlier_frames(self) -> RevisitTruth:
        _index_array(self.same_place, "same_place")
        if len(self.same_place):
            _require(int(self.same_place.min()) >= 0 and int(self.same_place.max()) < self.frame_index,
                     f"same_place indices must be earlier frames in [0, {self.frame_index})")
        return self


#: key (relative to the vehicle namespace) -> message type
KEYS: dict[str, type[Message]] = {
    "camera/image_raw": Image,
    "sonar_micron": RangeImageBeam,
    "sonar_seaking": RangeImageBeam,
    "sonar_micron_ros": LaserScan,
    "sonar_seaking_ros": LaserScan,
    "dvl_linkquest": LinkquestDvl,
    "imu_adis": Imu,
    "imu_adis_ros": Imu,
    "depth_sensor": Depth,
    "odometry": Odometry,
    "wheel_odometry": Odometry,
    "scan": LaserScan,
    "scan_rear": LaserScan,
    "neocortex/sdr": NeocortexSdr,
    "local_view_cells": LocalViewCells,
    "Odometry": Odometry,
    "ground_truth": Odometry,
    "experience_event": ExperienceEvent,
    "posecells/activity": PoseCellActivity,
    "map": ExperienceMap,
    "dead_reckoning": PoseStamped,
    "experience_image": ExperienceImage,
    "map_sessions": MapSessions,
    "scan_pose": ScanPose,
    "truth/pose": Odometry,
    "truth/revisits": RevisitTruth,
    "live/latency": LatencyReport,
}

MESSAGE_TYPES: dict[str, type[Message]] = {
    t.type_name: t
    for t in (Image, RangeImageBeam, LaserScan, LinkquestDvl, Imu, Depth, Odometry, PoseStamped, Sdr,
              NeocortexSdr, LocalViewCells, ExperienceEvent, PoseCellActivity, ExperienceMap, ExperienceImage,
              MapSessions, ScanPose, RevisitTruth,
              NavSatFix, FluidPressure, Temperature, MagneticField, PoseWithCovarianceStamped, TwistStamped,
              TFMessage, DiagnosticArray, RawMessage, LatencyReport)
}


def message_type(type_name: str) -> type[Message]:
    """The message class registered under ``type_name`` (e.g. ``poseidon_msgs/Image``)."""
    try:
        return MESSAGE_TYPES[type_name]
    except KeyError:
        raise KeyError(f"unknown message type {type_name!r}; known: {sorted(MESSAGE_TYPES)}") from None


def key_type(key: str) -> type[Message]:
    """The message class of a namespace-relative key (e.g. ``camera/image_raw``); every
    ``raw/...`` key carries :class:`RawMessage`."""
    if key.startswith(RAW_KEY_PREFIX):
        return RawMessage
    try:
        return KEYS[key]
    except KeyError:
        raise KeyError(f"unknown key {key!r}; known keys: {sorted(KEYS)}") from None
