"""ROS messages <-> our messages: the one mapping, shared by the bag importer
(``missions/importers``), the bag exporters (``products``) and the live ROS 1 bridge
(``services/bridge_ros1``).  ROS -> ours is here, ours -> ROS in :mod:`common.ros_encode`;
both tables are here.  Both directions work on rosbags message objects (the pure-Python
``rosbags`` typestores: no ROS installation needed); the bridge deserialises the bytes it
receives from rospy with the same typestore, so a live message and a bagged one convert
identically.

ROS -> ours (:data:`CONVERTERS`, :func:`stamped_header`, :func:`raw_message`):

===================================== ==================================================
ROS type                              our message
===================================== ==================================================
sensor_msgs/Image                     Image (rgb8, bgr8, mono8, rgba8, bgra8, mono16; 8UC1/3/4, 16UC1)
sensor_msgs/CompressedImage           Image rgb8 / mono8 (JPEG or PNG decoded by Pillow)
sensor_msgs/Imu                       Imu (roll, pitch, yaw from the quaternion, ZYX)
sensor_msgs/LaserScan                 LaserScan
nav_msgs/Odometry                     Odometry (pose, twist, covariances)
sensor_msgs/NavSatFix                 NavSatFix
sensor_msgs/FluidPressure             FluidPressure
sensor_msgs/Temperature               Temperature
sensor_msgs/MagneticField             MagneticField
geometry_msgs/PoseWithCovarianceStamped PoseWithCovarianceStamped
geometry_msgs/TwistStamped            TwistStamped
tf2_msgs/TFMessage, tf/tfMessage      TFMessage
diagnostic_msgs/DiagnosticArray       DiagnosticArray
cirs_girona_cala_viuda/Depth          Depth
cirs_girona_cala_viuda/Imu            Imu
cirs_girona_cala_viuda/LinkquestDvl   LinkquestDvl
cirs_girona_cala_viuda/RangeImageBeam RangeImageBeam
===================================== ==================================================

Any other type (vendor types, ``sensor_msgs/PointCloud2``, ...) is carried through unchanged
as :class:`~common.messages.RawMessage` (serialised bytes + definition, :func:`raw_message`) on
``raw/<key>``.  Values are copied without frame conversion (``frame_id`` is kept).  Stamp =
header stamp (ns), or the record/arrival time when the header stamp is zero or the type has no
header (:func:`stamped_header`); seq = the ROS1 header seq, or a per-key counter (ROS2 headers
have no seq).  Topics map to keys by :data:`DEFAULT_TOPIC_MAP`, other topics to the topic
without its leading slash (:func:`key_of`).

The Cala Viuda custom types are registered from their ``.msg`` definitions (below, as in the
ROS2 port of ``cirs_girona_cala_viuda``), so ROS2 bags that do not embed definitions read
too; ROS1 bags embed their own, and the original 2013 bags spell the DVL fields in
camelCase (``dataGood``, ``velocityInst``): fields are matched case-insensitively.

Ours -> ROS (:func:`common.ros_encode.to_ros`, :func:`common.ros_encode.ros_type_of`): standard
types where ROS has one; the Cala Viuda types for the dataset's own sensors; our SLAM outputs as
``poseidon_msgs`` types (the exporter registers them from ``products/msg``):

=========================== ====================================================== =====================
key type (ours)             ROS type                                               loses
=========================== ====================================================== =====================
Image                       sensor_msgs/msg/Image                                  -
ExperienceImage             poseidon_msgs/msg/ExperienceImage (Image + source)     -
RangeImageBeam              cirs_girona_cala_viuda/msg/RangeImageBeam              -
LaserScan                   sensor_msgs/msg/LaserScan                              -
LinkquestDvl                cirs_girona_cala_viuda/msg/LinkquestDvl                -
Depth                       cirs_girona_cala_viuda/msg/Depth                       -
Imu                         sensor_msgs/msg/Imu                                    temp, mag, gyro bias
Odometry                    nav_msgs/msg/Odometry                                  ``status`` flags
PoseStamped                 geometry_msgs/msg/PoseStamped (yaw as quaternion)      -
NavSatFix, FluidPressure,   sensor_msgs/msg/... (same name)                        -
Temperature, MagneticField
PoseWithCovarianceStamped,  geometry_msgs/msg/... (same name)                      -
TwistStamped
TFMessage                   tf2_msgs/msg/TFMessage                                 -
DiagnosticArray             diagnostic_msgs/msg/DiagnosticArray                    -
NeocortexSdr                poseidon_msgs/msg/NeocortexSdr (+ Sdr)                 -
LocalViewCells              poseidon_msgs/msg/LocalViewCells (+ LocalViewCell)     -
ExperienceEvent             poseidon_msgs/msg/ExperienceEvent                      -
PoseCellActivity            poseidon_msgs/msg/PoseCellActivity (images flattened)  -
ExperienceMap               poseidon_msgs/msg/ExperienceMap (+ Node, Link)         -
RevisitTruth                poseidon_msgs/msg/RevisitTruth                         -
=========================== ====================================================== =====================
"""
from __future__ import annotations

import io
import math
from collections.abc import Callable
from typing import Any

import numpy as np

from common.messages import (
    Depth,
    DiagnosticArray,
    DiagnosticStatus,
    FluidPressure,
    Header,
    Image,
    Imu,
    KeyValue,
    LaserScan,
    LinkquestDvl,
    MagneticField,
    Message,
    NavSatFix,
    Odometry,
    PoseWithCovarianceStamped,
    RangeImageBeam,
    RawMessage,
    Temperature,
    TFMessage,
    TransformStamped,
    TwistStamped,
)

__all__ = ["CALA_VIUDA_MSGS", "make_typestore", "CONVERTERS", "ConversionError", "normalise_type",
           "rpy_from_quaternion", "DEFAULT_TOPIC_MAP", "ros_header", "key_of", "stamped_header", "raw_message",
           "rosbags_type"]

#: .msg definitions of the package cirs_girona_cala_viuda (Cala Viuda caves dataset)
CALA_VIUDA_MSGS: dict[str, str] = {
    "cirs_girona_cala_viuda/msg/Depth": "std_msgs/Header header\nfloat64 depth\n",
    "cirs_girona_cala_viuda/msg/Imu": (
        "std_msgs/Header header\n" + "".join(f"float64 {f}\n" for f in
                                             "roll pitch yaw qx qy qz qw temp mx my mz ax ay az gx gy gz bx by bz".split())),
    "cirs_girona_cala_viuda/msg/RangeImageBeam": (
        "std_msgs/Header header\nfloat64 angle_grad\nfloat64 angle_rad\nint32 nbins\nint32 max_range\n"
        "int32[] beam_data\n"),
    "cirs_girona_cala_viuda/msg/LinkquestDvl": (
        "std_msgs/Header header\nstring errcode\nint32[4] datagood\nfloat64[4] altitudebeam\n"
        "float64[4] bottomvelocitybeam\nfloat64[4] watervelocitybeam\nfloat64[4] watervelocitycredit\n"
        "float64[3] velocityinst\nint32 velocityinstflag\nfloat64[3] velocityearth\nint32 velocityearthflag\n"
        "float64[3] watervelocityinst\nint32 watervelocityinstflag\nfloat64[3] watervelocityearth\n"
        "int32 watervelocityearthflag\nfloat64 roll\nfloat64 pitch\nfloat64 heading\nfloat64 altitude\n"
        "float64 temperature\nfloat64 pressure\nfloat64 salinity\nfloat64 soundspeed\nstring rawdata\n"),
}

#: ROS topic -> recording key (topics not listed map to the topic without its leading slash)
DEFAULT_TOPIC_MAP: dict[str, str] = {
    "/camera/image_raw": "camera/image_raw",
    "/sonar_micron": "sonar_micron",
    "/sonar_micron_ros": "sonar_micron_ros",
    "/sonar_seaking": "sonar_seaking",
    "/sonar_seaking_ros": "sonar_seaking_ros",
    "/dvl_linkquest": "dvl_linkquest",
    "/imu_adis": "imu_adis",
    "/imu_adis_ros": "imu_adis_ros",
    "/depth_sensor": "depth_sensor",
    "/odometry": "odometry",
}


def make_typestore(ros2: bool = False) -> Any:
    """A rosbags typestore (ROS1 Noetic or ROS2 Humble) with the Cala Viuda types registered."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE if ros2 else Stores.ROS1_NOETIC)
    types: dict[str, Any] = {}
    for name, text in CALA_VIUDA_MSGS.items():
        types.update(get_types_from_msg(text, name))
    store.register(types)
    return store


def normalise_type(msgtype: str) -> str:
    """``sensor_msgs/msg/Imu`` -> ``sensor_msgs/Imu``."""
    parts = msgtype.split("/")
    if len(parts) == 3 and parts[1] == "msg":
        return f"{parts[0]}/{parts[2]}"
    return msgtype


def rpy_from_quaternion(x: float, y: float, z: float, w: float) -> tuple[float, float, float]:
    """ZYX Euler angles (roll, pitch, yaw), rad, of a unit quaternion."""
    roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x))))
    yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return roll, pitch, yaw


class ConversionError(ValueError):
    """A message of a mapped type whose content cannot be represented (e.g. image encoding)."""


_CHANNELS = {"rgb8": 3, "bgr8": 3, "mono8": 1, "rgba8": 4, "bgra8": 4, "mono16": 1}
# OpenCV-style encodings as cv_bridge reads them
_ALIASES = {"8uc1": "mono8", "8uc3": "bgr8", "8uc4": "bgra8", "16uc1": "mono16"}


def _image(m: Any, h: Header) -> Image:
    enc = str(m.encoding).lower()
    enc = _ALIASES.get(enc, enc)
    if enc not in _CHANNELS:
        raise ConversionError(f"image encoding {m.encoding!r} not supported (supported: {sorted(_CHANNELS)})")
    ch = _CHANNELS[enc]
    dtype = np.dtype(">u2" if (enc == "mono16" and m.is_bigendian) else "<u2") if enc == "mono16" else np.dtype(np.uint8)
    raw = np.asarray(m.data, dtype=np.uint8)
    step = int(m.step)
    if raw.size < step * int(m.height):
        raise ConversionError(f"image data has {raw.size} bytes, expected step {step} x height {m.height}")
    rows = raw[: step * int(m.height)].reshape(int(m.height), step)[:, : int(m.width) * ch * dtype.itemsize]
    arr = np.ascontiguousarray(rows).view(dtype).reshape(int(m.height), int(m.width), ch)
    if enc == "mono16":
        arr = arr.astype("<u2")
    if ch == 1:
        arr = arr[:, :, 0]
    return Image(header=h, height=int(m.height), width=int(m.width), encoding=enc, data=np.ascontiguousarray(arr))


def _compressed(m: Any, h: Header) -> Image:
    from PIL import Image as PILImage
    from PIL import UnidentifiedImageError

    try:
        pil = PILImage.open(io.BytesIO(bytes(np.asarray(m.data, np.uint8))))
        pil.load()
    except (UnidentifiedImageError, OSError) as exc:
        raise ConversionError(f"compressed image ({m.format!r}) cannot be decoded: {exc}") from None
    if pil.mode in ("L", "I;16"):
        arr = np.asarray(pil.convert("L"))
        return Image(header=h, height=arr.shape[0], width=arr.shape[1], encoding="mono8", data=arr)
    arr = np.asarray(pil.convert("RGB"))
    return Image(header=h, height=arr.shape[0], width=arr.shape[1], encoding="rgb8", data=arr)


def _imu(m: Any, h: Header) -> Imu:
    q = m.orientation
    roll, pitch, yaw = rpy_from_quaternion(q.x, q.y, q.z, q.w)
    return Imu(header=h, roll=roll, pitch=pitch, yaw=yaw, qx=q.x, qy=q.y, qz=q.z, qw=q.w,
               ax=m.linear_acceleration.x, ay=m.linear_acceleration.y, az=m.linear_acceleration.z,
               gx=m.angular_velocity.x, gy=m.angular_velocity.y, gz=m.angular_velocity.z)


def _laser(m: Any, h: Header) -> LaserScan:
    return LaserScan(header=h, angle_min=m.angle_min, angle_max=m.angle_max, angle_increment=m.angle_increment,
                     time_increment=m.time_increment, scan_time=m.scan_time, range_min=m.range_min,
                     range_max=m.range_max, ranges=np.asarray(m.ranges, np.float32),
                     intensities=np.asarray(m.intensities, np.float32))


def _odometry(m: Any, h: Header) -> Odometry:
    p, o = m.pose.pose.position, m.pose.pose.orientation
    tl, ta = m.twist.twist.linear, m.twist.twist.angular
    return Odometry(header=h, child_frame_id=m.child_frame_id, position=[p.x, p.y, p.z], orientation=[o.x, o.y, o.z, o.w],
                    linear_velocity=[tl.x, tl.y, tl.z], angular_velocity=[ta.x, ta.y, ta.z],
                    pose_covariance=[float(v) for v in m.pose.covariance],
                    twist_covariance=[float(v) for v in m.twist.covariance])


_LOWER: dict[type, dict[str, str]] = {}


def _get(m: Any, name: str) -> Any:
    """Field ``name`` of a deserialised message, case-insensitively: the original ROS1 bags
    of the caves dataset use camelCase (``dataGood``, ``velocityInst``, ``soundSpeed``), the
    ROS2 port of cirs_girona_cala_viuda lower case (``datagood``)."""
    try:
        return getattr(m, name)
    except AttributeError:
        pass
    cls = type(m)
    lower = _LOWER.get(cls)
    if lower is None:
        names = getattr(cls, "__dataclass_fields__", None) or [a for a in dir(m) if not a.startswith("_")]
        lower = _LOWER[cls] = {n.lower(): n for n in names}
    real = lower.get(name.lower())
    if real is None:
        raise ConversionError(f"field {name!r} not in the message definition (fields: {sorted(lower.values())})")
    return getattr(m, real)


def _cv_depth(m: Any, h: Header) -> Depth:
    return Depth(header=h, depth=_get(m, "depth"))


def _copy_fields(model: type[Message], m: Any) -> dict[str, Any]:
    """Every field of ``model`` from ``m``; a field the source definition lacks keeps our
    default when it has one (the caves CSV/bags have no ``errCode``/``rawData``), else raises."""
    kw: dict[str, Any] = {}
    for name, info in model.model_fields.items():
        if name == "header":
            continue
        try:
            v = _get(m, name)
        except ConversionError:
            if info.is_required():
                raise
            continue
        kw[name] = v.tolist() if isinstance(v, np.ndarray) else v
    return kw


def _cv_imu(m: Any, h: Header) -> Imu:
    return Imu(header=h, **_copy_fields(Imu, m))


def _cv_beam(m: Any, h: Header) -> RangeImageBeam:
    return RangeImageBeam(header=h, angle_grad=_get(m, "angle_grad"), angle_rad=_get(m, "angle_rad"),
                          nbins=_get(m, "nbins"), max_range=_get(m, "max_range"),
                          beam_data=np.asarray(_get(m, "beam_data"), np.int32))


def _cv_dvl(m: Any, h: Header) -> LinkquestDvl:
    return LinkquestDvl(header=h, **_copy_fields(LinkquestDvl, m))


def _vec3(v: Any) -> list[float]:
    return [float(v.x), float(v.y), float(v.z)]


def _quat(q: Any) -> list[float]:
    return [float(q.x), float(q.y), float(q.z), float(q.w)]


def _floats(a: Any) -> list[float]:
    return [float(v) for v in a]


def _navsatfix(m: Any, h: Header) -> NavSatFix:
    return NavSatFix(header=h, status=int(m.status.status), service=int(m.status.service), latitude=m.latitude,
                     longitude=m.longitude, altitude=m.altitude, position_covariance=_floats(m.position_covariance),
                     position_covariance_type=int(m.position_covariance_type))


def _pressure(m: Any, h: Header) -> FluidPressure:
    return FluidPressure(header=h, fluid_pressure=m.fluid_pressure, variance=m.variance)


def _temperature(m: Any, h: Header) -> Temperature:
    return Temperature(header=h, temperature=m.temperature, variance=m.variance)


def _magnetic(m: Any, h: Header) -> MagneticField:
    return MagneticField(header=h, magnetic_field=_vec3(m.magnetic_field),
                         magnetic_field_covariance=_floats(m.magnetic_field_covariance))


def _pose_cov(m: Any, h: Header) -> PoseWithCovarianceStamped:
    return PoseWithCovarianceStamped(header=h, position=_vec3(m.pose.pose.position),
                                     orientation=_quat(m.pose.pose.orientation), covariance=_floats(m.pose.covariance))


def _twist(m: Any, h: Header) -> TwistStamped:
    return TwistStamped(header=h, linear=_vec3(m.twist.linear), angular=_vec3(m.twist.angular))


def ros_header(rh: Any, seq: int = 0) -> Header:
    """Our header from a ROS header (ROS1 seq when it has one)."""
    return Header(seq=int(getattr(rh, "seq", seq)), stamp=int(rh.stamp.sec) * 1_000_000_000 + int(rh.stamp.nanosec),
                  frame_id=str(rh.frame_id))


def _tf(m: Any, h: Header) -> TFMessage:
    return TFMessage(header=h, transforms=[
        TransformStamped(header=ros_header(t.header), child_frame_id=t.child_frame_id,
                         translation=_vec3(t.transform.translation), rotation=_quat(t.transform.rotation))
        for t in m.transforms])


def _diagnostics(m: Any, h: Header) -> DiagnosticArray:
    return DiagnosticArray(header=h, status=[
        DiagnosticStatus(level=int(s.level), name=s.name, message=s.message, hardware_id=s.hardware_id,
                         values=[KeyValue(key=kv.key, value=kv.value) for kv in s.values])
        for s in m.status])


#: normalised ROS type -> converter(ros message, header) -> our message
CONVERTERS: dict[str, Callable[[Any, Header], Message]] = {
    "sensor_msgs/Image": _image,
    "sensor_msgs/CompressedImage": _compressed,
    "sensor_msgs/Imu": _imu,
    "sensor_msgs/LaserScan": _laser,
    "nav_msgs/Odometry": _odometry,
    "sensor_msgs/NavSatFix": _navsatfix,
    "sensor_msgs/FluidPressure": _pressure,
    "sensor_msgs/Temperature": _temperature,
    "sensor_msgs/MagneticField": _magnetic,
    "geometry_msgs/PoseWithCovarianceStamped": _pose_cov,
    "geometry_msgs/TwistStamped": _twist,
    "tf2_msgs/TFMessage": _tf,
    "tf/tfMessage": _tf,
    "diagnostic_msgs/DiagnosticArray": _diagnostics,
    "cirs_girona_cala_viuda/Depth": _cv_depth,
    "cirs_girona_cala_viuda/Imu": _cv_imu,
    "cirs_girona_cala_viuda/LinkquestDvl": _cv_dvl,
    "cirs_girona_cala_viuda/RangeImageBeam": _cv_beam,
}


def key_of(topic: str, topic_map: dict[str, str | None]) -> str | None:
    """The recording key of ROS ``topic``: ``topic_map``'s entry (None: dropped), else the
    topic without its leading slash."""
    if topic in topic_map:
        return topic_map[topic]
    return topic.lstrip("/")


def rosbags_type(ros_type: str) -> str:
    """``sensor_msgs/Imu`` -> ``sensor_msgs/msg/Imu`` (rosbags' spelling; unchanged if already so)."""
    parts = ros_type.split("/")
    return f"{parts[0]}/msg/{parts[1]}" if len(parts) == 2 else ros_type


def _stamp_ns(t: Any) -> int:
    """ns of a rosbags ``builtin_interfaces/Time``."""
    return int(t.sec) * 1_000_000_000 + int(t.nanosec)


def stamped_header(ros: Any, msgtype: str, record_ns: int, seqs: dict[str, int], key: str) -> Header:
    """Our header of a deserialised ROS message: stamp = its header stamp, or ``record_ns``
    (the bag's record time, the bridge's arrival time) when that is zero or the type has no
    header (``tf2_msgs/TFMessage``: its first transform's stamp); seq = the ROS1 header seq,
    else the next of ``seqs[key]``."""
    h = getattr(ros, "header", None)
    stamp = record_ns
    if h is not None:
        hs = _stamp_ns(h.stamp)
        stamp = hs if hs > 0 else record_ns
    elif msgtype in ("tf2_msgs/TFMessage", "tf/tfMessage") and ros.transforms:
        stamp = _stamp_ns(ros.transforms[0].header.stamp) or record_ns
    if h is not None and hasattr(h, "seq"):
        seq = int(h.seq)
    else:
        seq = seqs.get(key, 0)
        seqs[key] = seq + 1
    return Header(seq=seq, stamp=stamp, frame_id=str(getattr(h, "frame_id", "")) if h is not None else "")


def raw_message(topic: str, ros_type: str, data: bytes, ros: Any, definition: tuple[str, str, str], is2: bool,
                record_ns: int, seq: int) -> RawMessage:
    """A ROS message carried as it is (bytes + ``definition``: text, format ``msg``/``idl``,
    digest); header from its ROS header when ``ros`` (the deserialised message, or None) has one."""
    h = getattr(ros, "header", None) if ros is not None else None
    stamp, frame = record_ns, ""
    if h is not None and hasattr(h, "stamp"):
        hs = _stamp_ns(h.stamp)
        stamp = hs if hs > 0 else record_ns
        frame = str(getattr(h, "frame_id", ""))
        seq = int(getattr(h, "seq", seq))
    text, fmt, digest = definition
    return RawMessage(header=Header(seq=seq, stamp=stamp, frame_id=frame), topic=topic, ros_type=ros_type,
                      serialization="cdr" if is2 else "ros1", definition=text,
                      definition_format="idl" if fmt == "idl" else "msg", digest=digest, data=bytes(data))
