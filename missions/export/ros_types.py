"""Our messages -> ROS messages (rosbags typestores), for ROS 1/ROS 2 bags and Foxglove.

Standard types where ROS has one; the Cala Viuda types for the dataset's own sensors; our
SLAM outputs as ``poseidon_msgs`` types registered from the ``.msg`` files in ``msg/``:

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
ExperienceMap               poseidon_msgs/msg/ExperienceMap (+ Node, Link)         -
RevisitTruth                poseidon_msgs/msg/RevisitTruth                         -
RawMessage                  its original type, bytes unchanged (converted         -
                            between ROS 1 and CDR only when the bag kind differs)
=========================== ====================================================== =====================
"""
from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from common.geometry import quaternion_of_yaw
from common.messages import (
    Depth,
    DiagnosticArray,
    ExperienceEvent,
    ExperienceImage,
    ExperienceMap,
    FluidPressure,
    Header,
    Image,
    Imu,
    LaserScan,
    LinkquestDvl,
    LocalViewCells,
    MagneticField,
    Message,
    NavSatFix,
    NeocortexSdr,
    Odometry,
    PoseStamped,
    PoseWithCovarianceStamped,
    RangeImageBeam,
    RawMessage,
    RevisitTruth,
    Sdr,
    Temperature,
    TFMessage,
    TwistStamped,
)
from missions.importers.rosbags_io import CALA_VIUDA_MSGS

__all__ = ["MSG_DIR", "POSEIDON_MSGS", "make_export_typestore", "ros_type_of", "to_ros", "RawConverter"]

#: the .msg files of poseidon_msgs
MSG_DIR = Path(__file__).resolve().parent / "msg"


def _load_msgs() -> dict[str, str]:
    out = {}
    for f in sorted((MSG_DIR / "poseidon_msgs").glob("*.msg")):
        out[f"poseidon_msgs/msg/{f.stem}"] = f.read_text()
    if not out:
        raise FileNotFoundError(f"{MSG_DIR}: no poseidon_msgs .msg definitions (broken installation?)")
    return out


POSEIDON_MSGS: dict[str, str] = _load_msgs()


def make_export_typestore(ros2: bool) -> Any:
    """ROS 2 Humble or ROS 1 Noetic types + Cala Viuda + poseidon_msgs."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE if ros2 else Stores.ROS1_NOETIC)
    types: dict[str, Any] = {}
    extra = {} if "tf2_msgs/msg/TFMessage" in store.types else {  # absent from rosbags' Noetic store
        "tf2_msgs/msg/TFMessage": "geometry_msgs/TransformStamped[] transforms\n"}
    for name, text in {**CALA_VIUDA_MSGS, **POSEIDON_MSGS, **extra}.items():
        types.update(get_types_from_msg(text, name))
    store.register(types)
    return store


class _Build:
    """Builds ROS message objects of one typestore (ROS 1 headers carry ``seq``)."""

    def __init__(self, store: Any, ros2: bool):
        self.T = store.types
        self.ros2 = ros2

    def time(self, ns: int) -> Any:
        return self.T["builtin_interfaces/msg/Time"](sec=int(ns) // 1_000_000_000, nanosec=int(ns) % 1_000_000_000)

    def header(self, h: Header) -> Any:
        H = self.T["std_msgs/msg/Header"]
        if self.ros2:
            return H(stamp=self.time(h.stamp), frame_id=h.frame_id)
        return H(seq=h.seq & 0xFFFFFFFF, stamp=self.time(h.stamp), frame_id=h.frame_id)

    def vec3(self, v: list[float]) -> Any:
        return self.T["geometry_msgs/msg/Vector3"](x=float(v[0]), y=float(v[1]), z=float(v[2]))

    def point(self, v: list[float]) -> Any:
        return self.T["geometry_msgs/msg/Point"](x=float(v[0]), y=float(v[1]), z=float(v[2]))

    def quat(self, q: list[float]) -> Any:
        return self.T["geometry_msgs/msg/Quaternion"](x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3]))

    def pose(self, p: list[float], q: list[float]) -> Any:
        return self.T["geometry_msgs/msg/Pose"](position=self.point(p), orientation=self.quat(q))

    @staticmethod
    def f64(a: Any) -> np.ndarray:
        return np.asarray(a, dtype=np.float64)

    # ------------------------------------------------------------------ per type
    def image(self, m: Image, h: Header | None = None) -> Any:
        data = np.ascontiguousarray(np.asarray(m.data))
        ch = 1 if data.ndim == 2 else data.shape[2]
        step = m.width * ch * data.dtype.itemsize
        return self.T["sensor_msgs/msg/Image"](header=self.header(h or m.header), height=m.height, width=m.width,
                                               encoding=m.encoding, is_bigendian=0, step=step,
                                               data=np.frombuffer(data.astype(data.dtype.newbyteorder("<")).tobytes(),
                                                                  np.uint8))

    def experience_image(self, m: ExperienceImage) -> Any:
        return self.T["poseidon_msgs/msg/ExperienceImage"](header=self.header(m.header), image=self.image(m),
                                                           source_stamp=m.source_stamp)

    def beam(self, m: RangeImageBeam) -> Any:
        return self.T["cirs_girona_cala_viuda/msg/RangeImageBeam"](
            header=self.header(m.header), angle_grad=m.angle_grad, angle_rad=m.angle_rad, nbins=m.nbins,
            max_range=m.max_range, beam_data=np.asarray(m.beam_data, np.int32))

    def laser(self, m: LaserScan) -> Any:
        return self.T["sensor_msgs/msg/LaserScan"](
            header=self.header(m.header), angle_min=m.angle_min, angle_max=m.angle_max,
            angle_increment=m.angle_increment, time_increment=m.time_increment, scan_time=m.scan_time,
            range_min=m.range_min, range_max=m.range_max, ranges=np.asarray(m.ranges, np.float32),
            intensities=np.asarray(m.intensities, np.float32))

    def dvl(self, m: LinkquestDvl) -> Any:
        kw = m.model_dump(exclude={"header"})
        for k, v in kw.items():
            if isinstance(v, list):
                kw[k] = np.asarray(v, np.int32 if k == "datagood" else np.float64)
        return self.T["cirs_girona_cala_viuda/msg/LinkquestDvl"](header=self.header(m.header), **kw)

    def depth(self, m: Depth) -> Any:
        return self.T["cirs_girona_cala_viuda/msg/Depth"](header=self.header(m.header), depth=m.depth)

    def imu(self, m: Imu) -> Any:
        zeros9 = np.zeros(9)
        return self.T["sensor_msgs/msg/Imu"](
            header=self.header(m.header), orientation=self.quat([m.qx, m.qy, m.qz, m.qw]),
            orientation_covariance=zeros9, angular_velocity=self.vec3([m.gx, m.gy, m.gz]),
            angular_velocity_covariance=zeros9, linear_acceleration=self.vec3([m.ax, m.ay, m.az]),
            linear_acceleration_covariance=zeros9)

    def odometry(self, m: Odometry) -> Any:
        T = self.T
        return T["nav_msgs/msg/Odometry"](
            header=self.header(m.header), child_frame_id=m.child_frame_id,
            pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=self.pose(m.position, m.orientation),
                                                           covariance=self.f64(m.pose_covariance)),
            twist=T["geometry_msgs/msg/TwistWithCovariance"](
                twist=T["geometry_msgs/msg/Twist"](linear=self.vec3(m.linear_velocity),
                                                   angular=self.vec3(m.angular_velocity)),
                covariance=self.f64(m.twist_covariance)))

    def pose_stamped(self, m: PoseStamped) -> Any:
        return self.T["geometry_msgs/msg/PoseStamped"](header=self.header(m.header),
                                                       pose=self.pose(m.position, quaternion_of_yaw(m.yaw)))

    def navsatfix(self, m: NavSatFix) -> Any:
        return self.T["sensor_msgs/msg/NavSatFix"](
            header=self.header(m.header), status=self.T["sensor_msgs/msg/NavSatStatus"](status=m.status, service=m.service),
            latitude=m.latitude, longitude=m.longitude, altitude=m.altitude,
            position_covariance=self.f64(m.position_covariance), position_covariance_type=m.position_covariance_type)

    def pressure(self, m: FluidPressure) -> Any:
        return self.T["sensor_msgs/msg/FluidPressure"](header=self.header(m.header), fluid_pressure=m.fluid_pressure,
                                                       variance=m.variance)

    def temperature(self, m: Temperature) -> Any:
        return self.T["sensor_msgs/msg/Temperature"](header=self.header(m.header), temperature=m.temperature,
                                                     variance=m.variance)

    def magnetic(self, m: MagneticField) -> Any:
        return self.T["sensor_msgs/msg/MagneticField"](header=self.header(m.header),
                                                       magnetic_field=self.vec3(m.magnetic_field),
                                                       magnetic_field_covariance=self.f64(m.magnetic_field_covariance))

    def pose_cov(self, m: PoseWithCovarianceStamped) -> Any:
        T = self.T
        return T["geometry_msgs/msg/PoseWithCovarianceStamped"](
            header=self.header(m.header),
            pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=self.pose(m.position, m.orientation),
                                                           covariance=self.f64(m.covariance)))

    def twist(self, m: TwistStamped) -> Any:
        T = self.T
        return T["geometry_msgs/msg/TwistStamped"](header=self.header(m.header), twist=T["geometry_msgs/msg/Twist"](
            linear=self.vec3(m.linear), angular=self.vec3(m.angular)))

    def tf(self, m: TFMessage) -> Any:
        T = self.T
        return T["tf2_msgs/msg/TFMessage"](transforms=[
            T["geometry_msgs/msg/TransformStamped"](
                header=self.header(t.header), child_frame_id=t.child_frame_id,
                transform=T["geometry_msgs/msg/Transform"](translation=self.vec3(t.translation),
                                                           rotation=self.quat(t.rotation)))
            for t in m.transforms])

    def diagnostics(self, m: DiagnosticArray) -> Any:
        T = self.T
        return T["diagnostic_msgs/msg/DiagnosticArray"](header=self.header(m.header), status=[
            T["diagnostic_msgs/msg/DiagnosticStatus"](
                level=s.level, name=s.name, message=s.message, hardware_id=s.hardware_id,
                values=[T["diagnostic_msgs/msg/KeyValue"](key=kv.key, value=kv.value) for kv in s.values])
            for s in m.status])

    def sdr(self, s: Sdr) -> Any:
        return self.T["poseidon_msgs/msg/Sdr"](header=self.header(s.header), modality=s.modality, size=s.size,
                                               active=np.asarray(s.active, np.uint32))

    def neocortex(self, m: NeocortexSdr) -> Any:
        return self.T["poseidon_msgs/msg/NeocortexSdr"](header=self.header(m.header),
                                                        modalities=[self.sdr(s) for s in m.modalities],
                                                        fused=self.sdr(m.fused), fusion_mode=m.fusion_mode)

    def lvc(self, m: LocalViewCells) -> Any:
        C = self.T["poseidon_msgs/msg/LocalViewCell"]
        return self.T["poseidon_msgs/msg/LocalViewCells"](
            header=self.header(m.header), most_active_cell=m.most_active_cell,
            active_cells=[C(id=c.id, rate=c.rate) for c in m.active_cells], is_new=m.is_new,
            intersection=m.intersection)

    def event(self, m: ExperienceEvent) -> Any:
        return self.T["poseidon_msgs/msg/ExperienceEvent"](
            header=self.header(m.header), lvc_id=m.lvc_id, pc_centroid=self.f64(m.pc_centroid),
            odom_position=self.f64(m.odom_position), odom_yaw=m.odom_yaw, gate=m.gate, vpr_count=m.vpr_count)

    def exp_map(self, m: ExperienceMap) -> Any:
        N, L = self.T["poseidon_msgs/msg/ExperienceNode"], self.T["poseidon_msgs/msg/ExperienceLink"]
        return self.T["poseidon_msgs/msg/ExperienceMap"](
            header=self.header(m.header),
            nodes=[N(id=n.id, lvc_id=n.lvc_id, position=self.f64(n.position), yaw=n.yaw, stamp=n.stamp)
                   for n in m.nodes],
            links=[L(source=k.source, target=k.target, delta=self.f64(k.delta), duration_s=k.duration_s,
                     weight=k.weight, loop_closure=k.loop_closure) for k in m.links],
            current=m.current, corrections=m.corrections)

    def revisits(self, m: RevisitTruth) -> Any:
        return self.T["poseidon_msgs/msg/RevisitTruth"](header=self.header(m.header), frame_index=m.frame_index,
                                                        same_place=np.asarray(m.same_place, np.int32))


#: our type -> (ROS type, builder method name); ExperienceImage before Image (subclass)
_TABLE: list[tuple[type[Message], str, Callable[[_Build, Any], Any]]] = [
    (ExperienceImage, "poseidon_msgs/msg/ExperienceImage", _Build.experience_image),
    (Image, "sensor_msgs/msg/Image", _Build.image),
    (RangeImageBeam, "cirs_girona_cala_viuda/msg/RangeImageBeam", _Build.beam),
    (LaserScan, "sensor_msgs/msg/LaserScan", _Build.laser),
    (LinkquestDvl, "cirs_girona_cala_viuda/msg/LinkquestDvl", _Build.dvl),
    (Depth, "cirs_girona_cala_viuda/msg/Depth", _Build.depth),
    (Imu, "sensor_msgs/msg/Imu", _Build.imu),
    (Odometry, "nav_msgs/msg/Odometry", _Build.odometry),
    (PoseStamped, "geometry_msgs/msg/PoseStamped", _Build.pose_stamped),
    (NavSatFix, "sensor_msgs/msg/NavSatFix", _Build.navsatfix),
    (FluidPressure, "sensor_msgs/msg/FluidPressure", _Build.pressure),
    (Temperature, "sensor_msgs/msg/Temperature", _Build.temperature),
    (MagneticField, "sensor_msgs/msg/MagneticField", _Build.magnetic),
    (PoseWithCovarianceStamped, "geometry_msgs/msg/PoseWithCovarianceStamped", _Build.pose_cov),
    (TwistStamped, "geometry_msgs/msg/TwistStamped", _Build.twist),
    (TFMessage, "tf2_msgs/msg/TFMessage", _Build.tf),
    (DiagnosticArray, "diagnostic_msgs/msg/DiagnosticArray", _Build.diagnostics),
    (NeocortexSdr, "poseidon_msgs/msg/NeocortexSdr", _Build.neocortex),
    (LocalViewCells, "poseidon_msgs/msg/LocalViewCells", _Build.lvc),
    (ExperienceEvent, "poseidon_msgs/msg/ExperienceEvent", _Build.event),
    (ExperienceMap, "poseidon_msgs/msg/ExperienceMap", _Build.exp_map),
    (RevisitTruth, "poseidon_msgs/msg/RevisitTruth", _Build.revisits),
]
_BY_TYPE = {t: (name, fn) for t, name, fn in _TABLE}


def ros_type_of(cls: type[Message]) -> str:
    """The ROS type our message class is exported as (KeyError naming the class if none)."""
    try:
        return _BY_TYPE[cls][0]
    except KeyError:
        raise KeyError(f"no ROS type for {cls.type_name}; exportable: {sorted(t.type_name for t in _BY_TYPE)}") from None


def to_ros(store: Any, ros2: bool, msg: Message) -> tuple[str, Any]:
    """(ROS type, ROS message object of ``store``) of one of our messages."""
    ros_type_of(type(msg))
    name, fn = _BY_TYPE[type(msg)]
    return name, fn(_Build(store, ros2), msg)


class RawConverter:
    """Raw-carried ROS messages into a bag of kind ``ros2`` (CDR) or ROS 1.

    Same kind as the source: the bytes go out unchanged with the source's definition.  Other
    kind: the type is registered from the carried definition and the payload converted with
    rosbags (ROS 1 <-> CDR; ``std_msgs/Header`` gains or loses ``seq``).
    """

    def __init__(self, dst_store: Any, ros2: bool):
        from rosbags.typesys import Stores, get_typestore

        self.dst = dst_store
        self.ros2 = ros2
        self._src: dict[bool, Any] = {}
        self._get_typestore, self._stores = get_typestore, Stores
        self._fn: dict[tuple[str, str], Callable[[bytes], bytes]] = {}

    def same_kind(self, rm: RawMessage) -> bool:
        return (rm.serialization == "cdr") == self.ros2

    def _src_store(self, is2: bool) -> Any:
        if is2 not in self._src:
            self._src[is2] = self._get_typestore(self._stores.ROS2_HUMBLE if is2 else self._stores.ROS1_NOETIC)
        return self._src[is2]

    @staticmethod
    def _register(store: Any, definition: str, fmt: str, msgtype: str) -> None:
        from rosbags.typesys import get_types_from_idl, get_types_from_msg

        types = get_types_from_idl(definition) if fmt == "idl" else get_types_from_msg(definition, msgtype)
        types.pop("std_msgs/msg/Header", None)
        store.register({k: v for k, v in types.items() if k not in store.fielddefs})

    def register_for_writer(self, rm: RawMessage) -> None:
        """Make ``rm.ros_type`` known to the destination store (for the connection's definition)."""
        if rm.ros_type not in self.dst.fielddefs:
            self._register(self.dst, rm.definition, rm.definition_format, rm.ros_type)

    def convert(self, rm: RawMessage) -> bytes:
        """The payload for the destination bag kind."""
        if self.same_kind(rm):
            return rm.data
        key = (rm.ros_type, rm.serialization)
        fn = self._fn.get(key)
        if fn is None:
            from rosbags.convert.converter import is_same_wireformat, migrate_message

            src_is2 = rm.serialization == "cdr"
            src = self._src_store(src_is2)
            if rm.ros_type not in src.fielddefs:
                self._register(src, rm.definition, rm.definition_format, rm.ros_type)
            self.register_for_writer(rm)
            t = rm.ros_type
            if is_same_wireformat(src, self.dst, t, t):
                fn = ((lambda b, t=t: bytes(src.cdr_to_ros1(b, t))) if src_is2
                      else (lambda b, t=t: bytes(self.dst.ros1_to_cdr(b, t))))
            else:
                cache: dict[str, object] = {}

                def fn(b: bytes, t: str = t) -> bytes:
                    m = src.deserialize_cdr(b, t) if src_is2 else src.deserialize_ros1(b, t)
                    d = migrate_message(src, self.dst, t, t, cache, m)
                    return bytes(self.dst.serialize_cdr(d, t) if self.ros2 else self.dst.serialize_ros1(d, t))
            self._fn[key] = fn
        return fn(rm.data)
