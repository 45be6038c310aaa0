"""Our messages -> ROS message objects (rosbags typestores): the exporters' and the live
bridge's side of the one mapping.  What maps to which ROS type, and what each loses, is the
"Ours -> ROS" table of :mod:`common.ros_convert` (the ROS -> ours side).
"""
from __future__ import annotations

from collections.abc import Callable
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
    PoseCellActivity,
    PoseStamped,
    PoseWithCovarianceStamped,
    RangeImageBeam,
    RevisitTruth,
    Sdr,
    Temperature,
    TFMessage,
    TwistStamped,
)

__all__ = ["ros_type_of", "to_ros"]


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

    def activity(self, m: PoseCellActivity) -> Any:
        (nx, ny), (nz, n_yaw) = m.xy.shape, m.zyaw.shape
        return self.T["poseidon_msgs/msg/PoseCellActivity"](
            header=self.header(m.header), nx=nx, ny=ny, xy=np.ascontiguousarray(m.xy, np.uint8).reshape(-1),
            xy_scale=m.xy_scale, nz=nz, n_yaw=n_yaw, zyaw=np.ascontiguousarray(m.zyaw, np.uint8).reshape(-1),
            zyaw_scale=m.zyaw_scale, centroid=self.f64(m.centroid), spacing=self.f64(m.spacing), steps=m.steps)

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
    (PoseCellActivity, "poseidon_msgs/msg/PoseCellActivity", _Build.activity),
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
