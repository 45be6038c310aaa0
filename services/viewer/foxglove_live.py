"""The view's streams over Foxglove's WebSocket protocol (package ``foxglove-sdk``), so the
Foxglove app attaches to a running deployment (``poseidon view --foxglove PORT``).

Channels (Foxglove's well-known schemas; the same drawing as ``poseidon export --foxglove``,
:mod:`products.foxglove`, whose protobuf conversions sit above this layer):

=========================== =========================== =========================================
topic                       schema                      content
=========================== =========================== =========================================
``/map``                    ``foxglove.SceneUpdate``    entity ``experience_map``: a sphere per node,
                                                        a line list of links, loop closures red
``/trajectory/<trail>``     ``foxglove.PosesInFrame``   dead reckoning, odometry, truth, pose-cell
                                                        estimate (the trail so far, thinned)
``/pose``                   ``foxglove.PoseInFrame``    the latest dead-reckoning pose
``/camera``                 ``foxglove.CompressedImage`` the latest camera frame (small JPEG)
``/scan``                   ``foxglove.LaserScan``      the laser scan, or the sonar sweep (the
                                                        strongest echo per angle bin)
=========================== =========================== =========================================

:meth:`FoxgloveLive.update` runs after each update of the view (``view.update_hz``) and logs
only what changed since the last one; the server keeps at most ``view.foxglove_backlog``
messages per client and drops the oldest for a slow client (never anything of the SLAM).
Frame ``map`` throughout; log time = the view's newest event time.
"""
from __future__ import annotations

import math
from typing import Any

import foxglove
import numpy as np
from foxglove.channels import (
    CompressedImageChannel,
    LaserScanChannel,
    PoseInFrameChannel,
    PosesInFrameChannel,
    SceneUpdateChannel,
)
from foxglove.messages import (
    Color,
    CompressedImage,
    LaserScan,
    LinePrimitive,
    LinePrimitiveLineType,
    Point3,
    Pose,
    PoseInFrame,
    PosesInFrame,
    Quaternion,
    SceneEntity,
    SceneUpdate,
    SpherePrimitive,
    Timestamp,
    Vector3,
)

from services.viewer.model import SONAR_ANGLE_BINS, TRAILS, ViewModel

__all__ = ["FoxgloveLive"]

FRAME = "map"
_IDENTITY = Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)


def _ts(ns: int) -> Timestamp:
    return Timestamp(ns // 1_000_000_000, ns % 1_000_000_000)


def _pose(x: float, y: float, z: float, yaw: float = 0.0) -> Pose:
    return Pose(position=Vector3(x=x, y=y, z=z),
                orientation=Quaternion(x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2)))


class FoxgloveLive:
    """A Foxglove WebSocket server on ``host:port`` fed from a :class:`ViewModel` (see the module notes)."""

    def __init__(self, host: str = "127.0.0.1", port: int = 8765, backlog: int = 64):
        self.context = foxglove.Context()
        self.server = foxglove.start_server(name="PoseidonSLAM", host=host, port=port, context=self.context,
                                            message_backlog_size=backlog)
        ctx = self.context
        self.map = SceneUpdateChannel("/map", context=ctx)
        self.trails = {name: PosesInFrameChannel(f"/trajectory/{name}", context=ctx) for name in TRAILS}
        self.pose = PoseInFrameChannel("/pose", context=ctx)
        self.camera = CompressedImageChannel("/camera", context=ctx)
        self.scan = LaserScanChannel("/scan", context=ctx)
        self.sent: dict[str, int] = {}
        self._seen: dict[str, Any] = {}

    @property
    def port(self) -> int:
        port: int = self.server.port
        return port

    def _changed(self, what: str, version: Any) -> bool:
        if self._seen.get(what) == version:
            return False
        self._seen[what] = version
        self.sent[what] = self.sent.get(what, 0) + 1
        return True

    def update(self, model: ViewModel) -> None:
        """Log what changed in ``model`` since the last call."""
        ns = model.stamp
        t = _ts(ns)
        if model.map is not None and self._changed("map", model.map_version):
            self.map.log(self._scene(model, t), log_time=ns)
        for name, trail in model.trails.items():
            if trail.points and self._changed(f"trajectory/{name}", (trail.epoch, len(trail.points))):
                poses = [_pose(*p[:3]) for p in trail.points]
                self.trails[name].log(PosesInFrame(timestamp=t, frame_id=FRAME, poses=poses), log_time=ns)
        if model.pose is not None and self._changed("pose", tuple(model.pose)):
            self.pose.log(PoseInFrame(timestamp=t, frame_id=FRAME, pose=_pose(*model.pose)), log_time=ns)
        if model.camera is not None and self._changed("camera", model.camera_version):
            _v, jpeg = model.camera_jpeg()
            self.camera.log(CompressedImage(timestamp=_ts(model.camera.header.stamp), frame_id="camera", data=jpeg,
                                            format="jpeg"), log_time=ns)
        if (model.scan or model.sonar) and self._changed("scan", model.sonar_version):
            self.scan.log(self._scan(model, t), log_time=ns)

    @staticmethod
    def _scene(model: ViewModel, t: Timestamp) -> SceneUpdate:
        m = model.map
        assert m is not None
        spheres = [SpherePrimitive(pose=_pose(float(x), float(y), float(z)), size=Vector3(x=0.3, y=0.3, z=0.3),
                                   color=Color(r=0.2, g=0.5, b=1.0, a=1.0)) for x, y, z in m.xyz.tolist()]
        lines = []
        for loop, rgba in ((False, (0.6, 0.6, 0.6, 1.0)), (True, (1.0, 0.1, 0.1, 1.0))):
            pairs = m.links[m.loop == loop]
            if len(pairs):
                pts = [Point3(x=float(p[0]), y=float(p[1]), z=float(p[2])) for p in m.xyz[pairs.ravel()].tolist()]
                r, g, b, a = rgba
                lines.append(LinePrimitive(type=LinePrimitiveLineType.LineList, pose=_pose(0.0, 0.0, 0.0),
                                           thickness=0.08 if loop else 0.04, points=pts,
                                           color=Color(r=r, g=g, b=b, a=a)))
        entity = SceneEntity(timestamp=t, frame_id=FRAME, id="experience_map", spheres=spheres, lines=lines)
        return SceneUpdate(entities=[entity])

    @staticmethod
    def _scan(model: ViewModel, t: Timestamp) -> LaserScan:
        if model.scan:
            xy = np.asarray(model.scan, dtype=np.float64)
            angles = np.arctan2(xy[:, 1], xy[:, 0])
            order = np.argsort(angles)
            dist = np.hypot(xy[:, 0], xy[:, 1])[order]
            a0, a1 = float(angles[order[0]]), float(angles[order[-1]])
            return LaserScan(timestamp=t, frame_id=FRAME, pose=_pose(0.0, 0.0, 0.0), start_angle=a0, end_angle=a1,
                             ranges=[float(v) for v in dist], intensities=[])
        n = SONAR_ANGLE_BINS  # the sweep's angle bins, evenly spaced: a bin not swept yet has range 0
        ranges, strengths = [0.0] * n, [0.0] * n
        for k, (_angle, max_range, data) in model.sonar.items():
            echo = np.frombuffer(data, dtype=np.uint8)
            i = int(echo.argmax())
            ranges[k] = (i + 0.5) / echo.size * max_range
            strengths[k] = float(echo[i])
        return LaserScan(timestamp=t, frame_id=FRAME, pose=_pose(0.0, 0.0, 0.0), start_angle=0.0,
                         end_angle=2 * math.pi * (n - 1) / n, ranges=ranges, intensities=strengths)

    def stop(self) -> None:
        self.server.stop()
