"""The rospy side of the bridge: the only module that imports rospy.

rospy comes from the system (Debian ``ros-core``, ``python3-*-msgs``): its folder is
*appended* to ``sys.path`` (our venv's numpy, yaml... stay first; ``site.addsitedir`` would run
that folder's ``.pth`` files).  Subscriptions are ``rospy.AnyMsg`` (bytes + the publisher's
type, md5 and definition from the connection header: nothing is deserialised by rospy);
publications write bytes we serialised with rosbags (:mod:`common.ros_encode`) through a
class per ROS type that carries the type's md5 and definition, so numpy never meets rospy's
generated code (its ``serialize_numpy`` fails under NumPy 2).

Embedding rules (verified against rospy): wait for the master with
``rosgraph.is_master_online`` *before* ``init_node`` (which otherwise blocks forever);
``init_node(disable_signals=True)`` (the launcher owns SIGINT/SIGTERM, and it may run off the
main thread); one node per process; callbacks run on rospy's threads.
"""
from __future__ import annotations

import io
import logging
import os
import sys
import threading
import time
from collections.abc import Callable
from typing import Any

__all__ = ["import_rospy", "RosLink", "RosUnavailable", "DEFAULT_MASTER_URI"]

log = logging.getLogger(__name__)

DEFAULT_MASTER_URI = "http://localhost:11311"

#: (topic, ROS type, md5, definition, serialised bytes, arrival wall time ns)
OnMessage = Callable[[str, str, str, str, bytes, int], None]


class RosUnavailable(RuntimeError):
    """rospy cannot be imported, or the ROS master does not answer (the message says which)."""


def import_rospy(path: str) -> Any:
    """rospy, with ``path`` appended to ``sys.path`` when needed; RosUnavailable naming ``path``."""
    if path and path not in sys.path:
        sys.path.append(path)
    try:
        import rospy
    except ImportError as exc:
        raise RosUnavailable(f"rospy cannot be imported ({exc}); install ROS 1 (deploy/setup.sh: ros-core and the "
                             f"python3-*-msgs packages) or set bridge_ros1.ros_python_path (now {path!r})") from None
    return rospy


class RosLink:
    """One ROS node: AnyMsg subscriptions handed to ``on_message``, raw publishers."""

    def __init__(self, master_uri: str, node_name: str, python_path: str, on_message: OnMessage,
                 queue_size: int = 10000):
        self.rospy = import_rospy(python_path)
        self.master_uri = master_uri or os.environ.get("ROS_MASTER_URI") or DEFAULT_MASTER_URI
        self.node_name = node_name
        self.on_message = on_message
        self.queue_size = queue_size
        self._subs: dict[str, Any] = {}
        self._pubs: dict[str, Any] = {}
        self._classes: dict[str, type] = {}

    def connect(self, timeout_s: float) -> None:
        """Wait for the master (at most ``timeout_s``), then start the node."""
        import rosgraph

        os.environ["ROS_MASTER_URI"] = self.master_uri  # rospy reads it at init_node
        deadline = time.monotonic() + timeout_s
        while not rosgraph.is_master_online(master_uri=self.master_uri):
            if time.monotonic() > deadline:
                raise RosUnavailable(f"no ROS master at {self.master_uri} after {timeout_s:.0f} s "
                                     f"(bridge_ros1.master_uri / ROS_MASTER_URI; is roscore running?)")
            time.sleep(0.1)
        self.rospy.init_node(self.node_name, anonymous=False, disable_signals=True)
        log.info("bridge_ros1: node /%s on master %s", self.node_name, self.master_uri)

    # ---- in -------------------------------------------------------------------------------
    def subscribe(self, topic: str) -> None:
        if topic not in self._subs:
            self._subs[topic] = self.rospy.Subscriber(topic, self.rospy.AnyMsg, self._callback, callback_args=topic,
                                                      queue_size=self.queue_size, tcp_nodelay=True)

    def subscribed(self) -> set[str]:
        return set(self._subs)

    def _callback(self, msg: Any, topic: str) -> None:
        arrival = time.time_ns()
        hdr = getattr(msg, "_connection_header", None) or {}
        if isinstance(msg, self.rospy.AnyMsg):
            data = bytes(msg._buff)
        else:  # rospy shares one connection per topic: a typed subscriber elsewhere in the process
            buff = io.BytesIO()
            msg.serialize(buff)
            data = buff.getvalue()
        self.on_message(topic, str(hdr.get("type", getattr(msg, "_type", ""))), str(hdr.get("md5sum", "")),
                        str(hdr.get("message_definition", "")), data, arrival)

    def published_topics(self) -> list[tuple[str, str]]:
        """(topic, type) of every topic published on the master now."""
        return [(str(t), str(ty)) for t, ty in self.rospy.get_published_topics()]

    # ---- out ------------------------------------------------------------------------------
    def _raw_class(self, ros_type: str, md5: str, definition: str) -> type:
        cls = self._classes.get(ros_type)
        if cls is None:
            name = "Raw_" + ros_type.replace("/", "_")
            cls = self._classes[ros_type] = type(name, (self.rospy.AnyMsg,),
                                                 {"_type": ros_type, "_md5sum": md5, "_full_text": definition,
                                                  "__slots__": []})
        return cls

    def advertise(self, topic: str, ros_type: str, md5: str, definition: str, latch: bool = False) -> None:
        cls = self._raw_class(ros_type, md5, definition)
        self._pubs[topic] = (self.rospy.Publisher(topic, cls, queue_size=100, latch=latch), cls)

    def publish(self, topic: str, data: bytes) -> None:
        pub, cls = self._pubs[topic]
        msg = cls()
        msg._buff = data
        pub.publish(msg)

    #: seconds :meth:`close` waits for the node's shutdown (unregistering at the master, joining
    #: rospy's threads: each XML-RPC call and join can wait on a slow or stuck master)
    CLOSE_TIMEOUT_S = 5.0

    def close(self, reason: str = "bridge stopped") -> bool:
        """Unregister every topic and shut the node down, waiting at most ``CLOSE_TIMEOUT_S``;
        False (logged) when it did not finish in time: the bridge goes on ending its run and the
        rest of rospy's shutdown is left to its daemon thread."""
        subs, pubs = list(self._subs.values()), [pub for pub, _cls in self._pubs.values()]
        self._subs.clear()
        self._pubs.clear()

        failed: list[BaseException] = []

        def shut_down() -> None:
            try:
                for topic in (*subs, *pubs):
                    topic.unregister()
                self.rospy.signal_shutdown(reason)
            except BaseException as exc:  # handed to the caller below
                failed.append(exc)

        worker = threading.Thread(target=shut_down, name="ros-shutdown", daemon=True)
        worker.start()
        worker.join(self.CLOSE_TIMEOUT_S)
        if worker.is_alive():
            log.warning("bridge_ros1: the ROS node's shutdown (master %s) did not finish within %.0f s; "
                        "leaving it", self.master_uri, self.CLOSE_TIMEOUT_S)
            return False
        if failed:
            raise failed[0]
        return True
