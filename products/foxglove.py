"""A PoseidonSLAM recording -> an MCAP file Foxglove opens with its well-known schemas.

Our recordings store msgpack payloads with JSON schemas, which no viewer understands.  The
export writes every message again, encoded for Foxglove:

============================= ================================ ====================================
our key / type                channel (topic)                  schema (encoding)
============================= ================================ ====================================
Image, ExperienceImage        ``/<key>``                       ``foxglove.RawImage`` (protobuf)
RangeImageBeam (sonar beam)   ``/<key>``                       ``foxglove.PointCloud``: one point per
                                                               range bin along the beam (x, y, z,
                                                               intensity float32)
LaserScan                     ``/<key>``                       ``foxglove.LaserScan``
Odometry, PoseStamped         ``/<key>``                       ``foxglove.PoseInFrame``
  (trajectories)              ``/<key>/path``                  ``foxglove.PosesInFrame``: the path so
                                                               far (one pose per second of event
                                                               time), once per ``path_period_s``
                                                               (5 s) and at the last pose
ExperienceMap                 ``/<key>``                       ``foxglove.SceneUpdate``: entity
                                                               ``experience_map`` (a sphere per node,
                                                               a line list of links, loop closures
                                                               red)
LocalViewCells                ``/<key>``                       ``foxglove.Log`` ("LVC 12 new R=0.43 ...")
ExperienceEvent               ``/<key>``                       ``foxglove.Log``
NavSatFix                     ``/<key>``                       ``foxglove.LocationFix``
any other type of ours        ``/<key>``                       its ROS 2 type (``ros2msg``, CDR), as
                                                               ``poseidon export --ros2`` writes it
RawMessage (``raw/...``)      original ROS topic (``/<key>``   original type, bytes unchanged
                              when the topic also has mapped   (``ros1msg``/ROS 1 or ``ros2msg``/CDR)
                              messages under another schema)
============================= ================================ ====================================

Protobuf schemas are the official ones (package ``foxglove-schemas-protobuf``), stored as
a serialised ``FileDescriptorSet`` with their dependencies, as Foxglove expects.  Log time
= publish time = event time (ns).
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import IO, Any

import numpy as np

from common.geometry import quaternion_of_yaw
from common.mcap_io import read_messages
from common.messages import (
    ExperienceEvent,
    ExperienceMap,
    Image,
    LaserScan,
    LocalViewCells,
    Message,
    NavSatFix,
    Odometry,
    PoseStamped,
    RangeImageBeam,
    RawMessage,
)
from common.ros_encode import to_ros
from products.ros_types import make_export_typestore
from products.rosbag import ExportError

__all__ = ["export_foxglove", "file_descriptor_set"]


def file_descriptor_set(desc: Any) -> bytes:
    """Serialised FileDescriptorSet of a protobuf message descriptor and every file it imports."""
    from google.protobuf import descriptor_pb2

    fset = descriptor_pb2.FileDescriptorSet()
    seen: set[str] = set()

    def add(fd: Any) -> None:
        if fd.name in seen:
            return
        seen.add(fd.name)
        for dep in fd.dependencies:
            add(dep)
        proto = descriptor_pb2.FileDescriptorProto()
        fd.CopyToProto(proto)
        fset.file.append(proto)

    add(desc.file)
    data: bytes = fset.SerializeToString()
    return data


class _Pb:
    """The foxglove protobuf classes used here (imported lazily)."""

    def __init__(self) -> None:
        from foxglove_schemas_protobuf import (
            Color_pb2,
            LaserScan_pb2,
            LinePrimitive_pb2,
            LocationFix_pb2,
            Log_pb2,
            PackedElementField_pb2,
            Point3_pb2,
            PointCloud_pb2,
            Pose_pb2,
            PoseInFrame_pb2,
            PosesInFrame_pb2,
            Quaternion_pb2,
            RawImage_pb2,
            SceneEntity_pb2,
            SceneUpdate_pb2,
            SpherePrimitive_pb2,
            Vector3_pb2,
        )

        self.RawImage = RawImage_pb2.RawImage
        self.PointCloud = PointCloud_pb2.PointCloud
        self.PackedElementField = PackedElementField_pb2.PackedElementField
        self.LaserScan = LaserScan_pb2.LaserScan
        self.PoseInFrame = PoseInFrame_pb2.PoseInFrame
        self.PosesInFrame = PosesInFrame_pb2.PosesInFrame
        self.Pose = Pose_pb2.Pose
        self.Vector3 = Vector3_pb2.Vector3
        self.Quaternion = Quaternion_pb2.Quaternion
        self.Point3 = Point3_pb2.Point3
        self.Color = Color_pb2.Color
        self.SceneUpdate = SceneUpdate_pb2.SceneUpdate
        self.SceneEntity = SceneEntity_pb2.SceneEntity
        self.SpherePrimitive = SpherePrimitive_pb2.SpherePrimitive
        self.LinePrimitive = LinePrimitive_pb2.LinePrimitive
        self.Log = Log_pb2.Log
        self.LocationFix = LocationFix_pb2.LocationFix


def _ts(target: Any, ns: int) -> None:
    target.seconds = int(ns) // 1_000_000_000
    target.nanos = int(ns) % 1_000_000_000


class _FoxgloveWriter:
    def __init__(self, f: IO[bytes]):
        from mcap.writer import CompressionType, Writer

        self.w = Writer(f, compression=CompressionType.ZSTD)
        self.w.start(profile="", library="poseidonslam export")
        self.schemas: dict[tuple[str, str], int] = {}
        self.channels: dict[str, int] = {}
        self.channel_schema: dict[str, str] = {}
        self.counts: dict[str, dict[str, Any]] = {}

    def channel(self, topic: str, schema_name: str, schema_encoding: str, schema_data: bytes,
                message_encoding: str) -> int:
        cid = self.channels.get(topic)
        if cid is not None:
            if self.channel_schema[topic] != schema_name:
                raise ExportError(f"topic {topic}: carries {self.channel_schema[topic]}, cannot also carry "
                                  f"{schema_name}")
            return cid
        sid = self.schemas.get((schema_name, schema_encoding))
        if sid is None:
            sid = self.w.register_schema(schema_name, schema_encoding, schema_data)
            self.schemas[(schema_name, schema_encoding)] = sid
        cid = self.w.register_channel(topic, message_encoding, sid)
        self.channels[topic] = cid
        self.channel_schema[topic] = schema_name
        return cid

    def write(self, cid: int, topic: str, stamp: int, data: bytes) -> None:
        self.w.add_message(cid, log_time=stamp, publish_time=stamp, data=data)
        c = self.counts.setdefault(topic, {"schema": self.channel_schema[topic], "count": 0})
        c["count"] += 1

    def finish(self) -> None:
        self.w.finish()  # type: ignore[no-untyped-call]  # mcap leaves Writer.finish() unannotated


class FoxgloveExporter:
    """Converts our messages one by one (trajectory paths keep state per key)."""

    #: event time between two poses kept in a path (ns): bounds the size of the path messages
    PATH_SPACING_NS = 1_000_000_000

    def __init__(self, writer: _FoxgloveWriter, path_period_s: float = 5.0):
        self.pb = _Pb()
        self.out = writer
        self.store = make_export_typestore(ros2=True)
        self.path_period_ns = int(path_period_s * 1e9)
        # key -> frame, poses kept, last path message stamp, last pose stamp, last kept pose stamp
        self.paths: dict[str, tuple[str, list[Any], int, int, int]] = {}
        self.last_pose: dict[str, Any] = {}
        self._fds: dict[str, bytes] = {}

    # ------------------------------------------------------------------ channels
    def _pb_write(self, topic: str, msg: Any, stamp: int) -> None:
        desc = msg.DESCRIPTOR
        if desc.full_name not in self._fds:
            self._fds[desc.full_name] = file_descriptor_set(desc)
        cid = self.out.channel(topic, desc.full_name, "protobuf", self._fds[desc.full_name], "protobuf")
        self.out.write(cid, topic, stamp, msg.SerializeToString())

    def _cdr_write(self, topic: str, msg: Message, stamp: int) -> None:
        msgtype, ros = to_ros(self.store, True, msg)
        text, _ = self.store.generate_msgdef(msgtype, ros_version=2)
        cid = self.out.channel(topic, msgtype, "ros2msg", text.encode(), "cdr")
        self.out.write(cid, topic, stamp, bytes(self.store.serialize_cdr(ros, msgtype)))

    def _raw_write(self, key: str, m: RawMessage, stamp: int) -> None:
        if m.serialization == "ros1":
            enc, menc = "ros1msg", "ros1"
        else:
            enc, menc = ("ros2idl" if m.definition_format == "idl" else "ros2msg"), "cdr"
        topic = m.topic
        if self.out.channel_schema.get(topic, m.ros_type) != m.ros_type:
            topic = "/" + key  # the original topic already carries the mapped messages of that topic
        cid = self.out.channel(topic, m.ros_type, enc, m.definition.encode(), menc)
        self.out.write(cid, topic, stamp, m.data)

    # ------------------------------------------------------------------ conversions
    def _pose(self, position: list[float], q: list[float]) -> Any:
        pb = self.pb
        return pb.Pose(position=pb.Vector3(x=position[0], y=position[1], z=position[2]),
                       orientation=pb.Quaternion(x=q[0], y=q[1], z=q[2], w=q[3]))

    def _image(self, m: Image) -> Any:
        data = np.ascontiguousarray(np.asarray(m.data))
        ch = 1 if data.ndim == 2 else data.shape[2]
        img = self.pb.RawImage(frame_id=m.header.frame_id, width=m.width, height=m.height, encoding=m.encoding,
                               step=m.width * ch * data.dtype.itemsize,
                               data=data.astype(data.dtype.newbyteorder("<")).tobytes())
        _ts(img.timestamp, m.header.stamp)
        return img

    def _beam(self, m: RangeImageBeam) -> Any:
        pb = self.pb
        echo = np.asarray(m.beam_data, np.float32)
        n = echo.shape[0]
        r = (np.arange(n, dtype=np.float64) + 0.5) * (float(m.max_range) / max(n, 1))
        pts = np.zeros((n, 4), np.float32)
        pts[:, 0] = r * math.cos(m.angle_rad)
        pts[:, 1] = r * math.sin(m.angle_rad)
        pts[:, 3] = echo
        f32 = pb.PackedElementField.NumericType.Value("FLOAT32")
        cloud = pb.PointCloud(frame_id=m.header.frame_id, pose=self._pose([0, 0, 0], [0, 0, 0, 1]), point_stride=16,
                              fields=[pb.PackedElementField(name=name, offset=4 * i, type=f32)
                                      for i, name in enumerate(("x", "y", "z", "intensity"))],
                              data=pts.astype("<f4").tobytes())
        _ts(cloud.timestamp, m.header.stamp)
        return cloud

    def _laser(self, m: LaserScan) -> Any:
        scan = self.pb.LaserScan(frame_id=m.header.frame_id, pose=self._pose([0, 0, 0], [0, 0, 0, 1]),
                                 start_angle=m.angle_min, end_angle=m.angle_max,
                                 ranges=np.asarray(m.ranges, np.float64).tolist(),
                                 intensities=np.asarray(m.intensities, np.float64).tolist())
        _ts(scan.timestamp, m.header.stamp)
        return scan

    def _trajectory(self, key: str, m: Odometry | PoseStamped) -> None:
        frame = m.header.frame_id or "world"
        q = m.orientation if isinstance(m, Odometry) else quaternion_of_yaw(m.yaw)
        pose = self._pose(m.position, q)
        pif = self.pb.PoseInFrame(frame_id=frame, pose=pose)
        _ts(pif.timestamp, m.header.stamp)
        self._pb_write("/" + key, pif, m.header.stamp)
        _, poses, last_path, _, last_kept = self.paths.get(key, (frame, [], -1, 0, -1))
        if last_kept < 0 or m.header.stamp - last_kept >= self.PATH_SPACING_NS:
            poses.append(pose)
            last_kept = m.header.stamp
        if last_path < 0 or m.header.stamp - last_path >= self.path_period_ns:
            self._path(key, frame, poses, m.header.stamp)
            last_path = m.header.stamp
        self.paths[key] = (frame, poses, last_path, m.header.stamp, last_kept)
        self.last_pose[key] = pose

    def _path(self, key: str, frame: str, poses: list[Any], stamp: int) -> None:
        p = self.pb.PosesInFrame(frame_id=frame, poses=poses)
        _ts(p.timestamp, stamp)
        self._pb_write(f"/{key}/path", p, stamp)

    def _map(self, m: ExperienceMap) -> Any:
        pb = self.pb
        frame = m.header.frame_id or "world"
        ent = pb.SceneEntity(frame_id=frame, id="experience_map", frame_locked=False)
        _ts(ent.timestamp, m.header.stamp)
        node_color = pb.Color(r=0.1, g=0.6, b=1.0, a=1.0)
        for n in m.nodes:
            ent.spheres.append(pb.SpherePrimitive(pose=self._pose(n.position, quaternion_of_yaw(n.yaw)),
                                                  size=pb.Vector3(x=0.4, y=0.4, z=0.4),
                                                  color=pb.Color(r=1.0, g=0.8, b=0.0, a=1.0) if n.id == m.current
                                                  else node_color))
        where = {n.id: n.position for n in m.nodes}
        list_type = pb.LinePrimitive.Type.Value("LINE_LIST")
        for closure, color in ((False, pb.Color(r=0.8, g=0.8, b=0.8, a=1.0)), (True, pb.Color(r=1.0, g=0.1, b=0.1, a=1.0))):
            pts = []
            for k in m.links:
                if k.loop_closure == closure and k.source in where and k.target in where:
                    pts += [where[k.source], where[k.target]]
            if pts:
                ent.lines.append(pb.LinePrimitive(type=list_type, pose=self._pose([0, 0, 0], [0, 0, 0, 1]),
                                                  thickness=0.1 if closure else 0.05, scale_invariant=False,
                                                  points=[pb.Point3(x=p[0], y=p[1], z=p[2]) for p in pts],
                                                  color=color))
        return pb.SceneUpdate(entities=[ent])

    def _log(self, name: str, text: str, stamp: int) -> Any:
        log = self.pb.Log(level=self.pb.Log.Level.Value("INFO"), message=text, name=name)
        _ts(log.timestamp, stamp)
        return log

    def _fix(self, m: NavSatFix) -> Any:
        fix = self.pb.LocationFix(frame_id=m.header.frame_id, latitude=m.latitude, longitude=m.longitude,
                                  altitude=m.altitude, position_covariance=m.position_covariance,
                                  # the generated stub wants the enum's NewType; the runtime takes the int
                                  position_covariance_type=m.position_covariance_type)  # type: ignore[arg-type]
        _ts(fix.timestamp, m.header.stamp)
        return fix

    def add(self, key: str, msg: Message, stamp: int) -> None:
        """Write one message of key ``key`` (see the module table)."""
        topic = "/" + key
        if isinstance(msg, RawMessage):
            self._raw_write(key, msg, stamp)
        elif isinstance(msg, Image):  # ExperienceImage too
            self._pb_write(topic, self._image(msg), stamp)
        elif isinstance(msg, RangeImageBeam):
            self._pb_write(topic, self._beam(msg), stamp)
        elif isinstance(msg, LaserScan):
            self._pb_write(topic, self._laser(msg), stamp)
        elif isinstance(msg, (Odometry, PoseStamped)):
            self._trajectory(key, msg)
        elif isinstance(msg, ExperienceMap):
            self._pb_write(topic, self._map(msg), stamp)
        elif isinstance(msg, LocalViewCells):
            cells = ", ".join(f"{c.id}:{c.rate:.2f}" for c in msg.active_cells[:5])
            text = (f"LVC {msg.most_active_cell}{' new' if msg.is_new else ''} I={msg.intersection} "
                    f"active [{cells}]")
            self._pb_write(topic, self._log(key, text, stamp), stamp)
        elif isinstance(msg, ExperienceEvent):
            x, y, z = msg.odom_position
            text = (f"experience event: LVC {msg.lvc_id} gate={msg.gate} C_t={msg.vpr_count} "
                    f"odom=({x:.2f}, {y:.2f}, {z:.2f}) m yaw={msg.odom_yaw:.3f} rad")
            self._pb_write(topic, self._log(key, text, stamp), stamp)
        elif isinstance(msg, NavSatFix):
            self._pb_write(topic, self._fix(msg), stamp)
        else:
            self._cdr_write(topic, msg, stamp)

    def finish(self) -> None:
        """The last pose of every trajectory is in its path."""
        for key, (frame, poses, last_path, last, last_kept) in self.paths.items():
            if last != last_path:
                self._path(key, frame, poses + ([self.last_pose[key]] if last != last_kept else []), last)


def export_foxglove(run: str | Path, out: str | Path, overwrite: bool = False,
                    path_period_s: float = 5.0) -> dict[str, Any]:
    """Write ``run`` as a Foxglove-ready MCAP ``out``; returns ``{"out", "format", "topics":
    {topic: {"schema", "count"}}}``."""
    run, out = Path(run), Path(out)
    if not run.is_file():
        raise ExportError(f"{run}: no such recording")
    if out.exists() and not overwrite:
        raise ExportError(f"{out}: exists (pass --overwrite to replace it)")
    if out.resolve() == run.resolve():
        raise ExportError(f"{out}: is the input recording")
    part = out.with_name(out.name + ".part")
    try:
        with open(part, "wb") as f:
            writer = _FoxgloveWriter(f)
            exp = FoxgloveExporter(writer, path_period_s)
            try:
                for rec in read_messages(run, strict=True):
                    exp.add(rec.key, rec.message(), rec.stamp)
                exp.finish()
            finally:
                writer.finish()
        part.replace(out)
    except BaseException:
        part.unlink(missing_ok=True)
        raise
    return {"out": str(out), "format": "foxglove", "topics": dict(sorted(writer.counts.items()))}
