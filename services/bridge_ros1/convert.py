"""ROS bytes <-> our messages for the bridge, through :mod:`common.ros_convert` (the importer's
mapping: one implementation) with a ROS 1 (Noetic) rosbags typestore.

In (:class:`Incoming`): a topic's route (``bridge_ros1.topics``, else with ``discover`` the
topic without its leading slash) gives the key; the bytes are deserialised with the typestore
(a type it does not know is registered from the definition the publisher sent) and converted
as the importer converts a bag message; a type without a model, a payload that does not decode,
content with no lossless conversion, a ``raw: true`` route or a type other than the route's
``type`` is carried raw on ``raw/<key>`` with the reason counted, as ``poseidon import`` does.

Out (:class:`Outgoing`), what ROS tools see of our outputs:

=================== ============================== =====================================================
our key (default)   ROS topic (default)            ROS type
=================== ============================== =====================================================
``Odometry``        ``/poseidon/odom``             nav_msgs/Odometry (:func:`common.ros_encode.to_ros`)
``dead_reckoning``  ``/poseidon/dead_reckoning``   geometry_msgs/PoseStamped (same)
``map``             ``/poseidon/path``             nav_msgs/Path: the experiences in id order, latched
``map``             ``/poseidon/map_markers``      visualization_msgs/MarkerArray, latched: DELETEALL, then
                                                   ``experiences`` (SPHERE_LIST), ``links`` (LINE_LIST, grey),
                                                   ``loop_closures`` (LINE_LIST, red), ``current`` (SPHERE)
``scan``            ``/map``                       nav_msgs/OccupancyGrid, latched: the grid of the laser
``sonar_micron``                                   (else sonar) returns at the poses ``Odometry`` and ``map``
                                                   give (:mod:`services.bridge_ros1.grid`)
``local_view_cells`` ``/poseidon/lvc_id``          std_msgs/Int32: the frame's LVC id (``most_active_cell``)
``experience_event`` ``/poseidon/experience_event`` std_msgs/String: JSON ``{"stamp", "lvc_id", "gate",
                                                   "vpr_count", "odom_position", "odom_yaw", "pc_centroid"}``
=================== ============================== =====================================================

Headers keep our stamp (the input that caused the output) and frame id; Path and markers use the
map message's frame id, ``odom`` when it has none; the grid the same (before the first map,
``Odometry``'s), stamped with the newest input stamp it has seen.
"""
from __future__ import annotations

import json
from typing import Any

import numpy as np

from common.geometry import quaternion_of_yaw
from common.messages import (
    RAW_KEY_PREFIX,
    DiagnosticArray,
    ExperienceEvent,
    ExperienceMap,
    LocalViewCells,
    Message,
    Odometry,
    PoseStamped,
)
from common.ros_convert import (
    CONVERTERS,
    ConversionError,
    key_of,
    make_typestore,
    normalise_type,
    raw_message,
    rosbags_type,
    stamped_header,
)
from common.ros_encode import to_ros
from services.bridge_ros1.config import TopicRoute
from services.bridge_ros1.grid import GridUpdate

__all__ = ["Incoming", "Outgoing", "Converted"]

#: (key, message, why it was carried raw: "" when converted)
Converted = tuple[str, Message, str]


class Incoming:
    """ROS topic + bytes -> (key, our message); see the module notes."""

    def __init__(self, routes: dict[str, TopicRoute], discover: bool):
        self.routes = routes
        self.discover = discover
        self.store = make_typestore(ros2=False)
        self._seqs: dict[str, int] = {}
        self._bad_types: dict[str, str] = {}

    def key(self, topic: str) -> str | None:
        """Our key of ``topic`` (None: not bridged)."""
        if topic in self.routes:
            return self.routes[topic].key
        if not self.discover:
            return None
        return key_of(topic, {})

    def _known(self, ros_type: str, definition: str) -> str:
        """rosbags name of ``ros_type``, registered from ``definition`` when the store lacks it;
        raises ValueError naming the type when it cannot be."""
        name = rosbags_type(ros_type)
        if name in self.store.types:
            return name
        if ros_type in self._bad_types:
            raise ValueError(self._bad_types[ros_type])
        from rosbags.typesys import get_types_from_msg

        try:
            types = get_types_from_msg(definition, name)
            types.pop("std_msgs/msg/Header", None)
            self.store.register({k: v for k, v in types.items() if k not in self.store.fielddefs})
        except Exception as exc:  # any parser error: the definition is unusable
            self._bad_types[ros_type] = f"definition of {ros_type} unusable: {type(exc).__name__}: {exc}"
            raise ValueError(self._bad_types[ros_type]) from None
        return name

    def convert(self, topic: str, ros_type: str, md5: str, definition: str, data: bytes,
                arrival_ns: int) -> Converted | None:
        """Our message of one ROS message (None when the topic is not bridged)."""
        key = self.key(topic)
        if key is None:
            return None
        route = self.routes.get(topic)
        msgtype = normalise_type(ros_type)
        ros: Any = None
        conv = CONVERTERS.get(msgtype)
        why = f"no model for {msgtype}"
        if route is not None and route.raw:
            conv, why = None, "carried raw on request (bridge_ros1.topics raw)"
        elif route is not None and route.type and normalise_type(route.type) != msgtype:
            conv, why = None, f"type_mismatch: {msgtype}, configured {route.type}"
        try:
            ros = self.store.deserialize_ros1(data, self._known(ros_type, definition))
        except Exception as exc:  # a payload or definition that does not decode: carried raw
            conv, why = None, f"payload does not decode against its definition: {type(exc).__name__}: {exc}"
        if conv is not None:
            header = stamped_header(ros, msgtype, arrival_ns, self._seqs, key)
            try:
                return key, conv(ros, header), ""
            except (ConversionError, TypeError, ValueError) as exc:
                why = f"no lossless conversion to our model: {str(exc).splitlines()[0]}"
        raw_key = RAW_KEY_PREFIX + key
        seq = self._seqs.get(raw_key, 0)
        self._seqs[raw_key] = seq + 1
        msg = raw_message(topic, rosbags_type(ros_type), data, ros, (definition, "msg", md5), False, arrival_ns, seq)
        return raw_key, msg, why


class Outgoing:
    """Our outputs -> (ROS type, serialised ROS 1 bytes); see the module notes."""

    def __init__(self) -> None:
        self.store = make_typestore(ros2=False)
        self.T = self.store.types

    def definition(self, ros_type: str) -> tuple[str, str]:
        """(md5, full definition text) of ``ros_type`` (e.g. ``nav_msgs/Odometry``)."""
        text, md5 = self.store.generate_msgdef(rosbags_type(ros_type), ros_version=1)
        return str(md5), str(text)

    def _ser(self, obj: Any, ros_type: str) -> bytes:
        return bytes(self.store.serialize_ros1(obj, rosbags_type(ros_type)))

    def standard(self, msg: Odometry | PoseStamped | DiagnosticArray) -> tuple[str, bytes]:
        """Odometry / PoseStamped / DiagnosticArray as the exporter writes them."""
        name, obj = to_ros(self.store, False, msg)
        return normalise_type(name), self._ser(obj, name)

    def _header(self, stamp: int, frame: str, seq: int = 0) -> Any:
        return self.T["std_msgs/msg/Header"](seq=seq & 0xFFFFFFFF, stamp=self._time(stamp), frame_id=frame)

    def _time(self, ns: int) -> Any:
        return self.T["builtin_interfaces/msg/Time"](sec=int(ns) // 1_000_000_000, nanosec=int(ns) % 1_000_000_000)

    def _pose(self, p: list[float], yaw: float) -> Any:
        T = self.T
        q = quaternion_of_yaw(yaw)
        return T["geometry_msgs/msg/Pose"](
            position=T["geometry_msgs/msg/Point"](x=float(p[0]), y=float(p[1]), z=float(p[2])),
            orientation=T["geometry_msgs/msg/Quaternion"](x=float(q[0]), y=float(q[1]), z=float(q[2]),
                                                          w=float(q[3])))

    def path(self, m: ExperienceMap) -> bytes:
        frame = m.header.frame_id or "odom"
        ps = self.T["geometry_msgs/msg/PoseStamped"]
        poses = [ps(header=self._header(n.stamp, frame), pose=self._pose(n.position, n.yaw))
                 for n in sorted(m.nodes, key=lambda n: n.id)]
        return self._ser(self.T["nav_msgs/msg/Path"](header=self._header(m.header.stamp, frame, m.header.seq),
                                                     poses=poses), "nav_msgs/Path")

    def markers(self, m: ExperienceMap) -> bytes:
        T = self.T
        frame = m.header.frame_id or "odom"
        point, color, vec = T["geometry_msgs/msg/Point"], T["std_msgs/msg/ColorRGBA"], T["geometry_msgs/msg/Vector3"]
        dur = T["builtin_interfaces/msg/Duration"](sec=0, nanosec=0)
        mk = T["visualization_msgs/msg/Marker"]
        pos = {n.id: n.position for n in m.nodes}

        def marker(ns: str, id_: int, kind: int, action: int, pts: list[list[float]], rgba: tuple[float, ...],
                   scale: float) -> Any:
            return mk(header=self._header(m.header.stamp, frame), ns=ns, id=id_, type=kind, action=action,
                      pose=self._pose([0.0, 0.0, 0.0], 0.0), scale=vec(x=scale, y=scale, z=scale),
                      color=color(r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3]), lifetime=dur, frame_locked=False,
                      points=[point(x=float(p[0]), y=float(p[1]), z=float(p[2])) for p in pts], colors=[],
                      text="", mesh_resource="", mesh_use_embedded_materials=False)

        def lines(loop: bool) -> list[list[float]]:
            out: list[list[float]] = []
            for k in m.links:
                if k.loop_closure == loop and k.source in pos and k.target in pos:
                    out += [pos[k.source], pos[k.target]]
            return out

        items = [marker("", 0, 0, 3, [], (0, 0, 0, 0), 1.0),  # DELETEALL
                 marker("experiences", 0, 7, 0, [n.position for n in m.nodes], (0.1, 0.5, 1.0, 1.0), 0.2),
                 marker("links", 0, 5, 0, lines(False), (0.6, 0.6, 0.6, 1.0), 0.03),
                 marker("loop_closures", 0, 5, 0, lines(True), (1.0, 0.1, 0.1, 1.0), 0.06)]
        if m.current in pos:
            items.append(marker("current", 0, 2, 0, [], (1.0, 0.8, 0.0, 1.0), 0.4))
            cur = items[-1]
            cur.pose.position.x, cur.pose.position.y, cur.pose.position.z = (float(v) for v in pos[m.current])
        return self._ser(T["visualization_msgs/msg/MarkerArray"](markers=items), "visualization_msgs/MarkerArray")

    def occupancy_grid(self, g: GridUpdate) -> bytes:
        """nav_msgs/OccupancyGrid of ``g``: origin = lower-left corner of cell (0, 0), yaw 0, map_load_time = stamp."""
        T, f = self.T, g.frame
        info = T["nav_msgs/msg/MapMetaData"](map_load_time=self._time(g.stamp), resolution=float(f.resolution),
                                             width=f.width, height=f.height,
                                             origin=self._pose([f.origin[0], f.origin[1], 0.0], 0.0))
        msg = T["nav_msgs/msg/OccupancyGrid"](header=self._header(g.stamp, g.frame_id), info=info,
                                             data=np.ascontiguousarray(g.data, dtype=np.int8))
        return self._ser(msg, "nav_msgs/OccupancyGrid")

    def lvc_id(self, m: LocalViewCells) -> bytes:
        return self._ser(self.T["std_msgs/msg/Int32"](data=int(m.most_active_cell)), "std_msgs/Int32")

    def event(self, m: ExperienceEvent) -> bytes:
        text = json.dumps({"stamp": m.header.stamp, "lvc_id": m.lvc_id, "gate": m.gate, "vpr_count": m.vpr_count,
                           "odom_position": m.odom_position, "odom_yaw": m.odom_yaw, "pc_centroid": m.pc_centroid},
                          separators=(",", ":"))
        return self._ser(self.T["std_msgs/msg/String"](data=text), "std_msgs/String")

