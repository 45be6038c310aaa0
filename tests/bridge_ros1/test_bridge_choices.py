"""What the ROS 1 bridge subscribes to and how often it rebuilds its grid, without ROS (a link
that records its subscriptions stands in for rospy; the bus is an in-process Zenoh session)."""
import threading

from services.bridge_ros1.bridge import Ros1Bridge
from services.bridge_ros1.config import BridgeRos1Config


class RecordingLink:
    """The part of :class:`services.bridge_ros1.ros_io.RosLink` that ``discover`` uses."""

    def __init__(self, published):
        self.published = published
        self.subs: list[str] = []

    def published_topics(self):
        return [(t, "any/Type") for t in self.published]

    def subscribed(self):
        return set(self.subs)

    def subscribe(self, topic):
        self.subs.append(topic)


PUBLISHED = ["/camera/image_raw", "/sonar_micron", "/sonar_seaking", "/sonar_seaking_ros", "/imu_adis",
             "/imu_adis_ros", "/truth/pose", "/vehicle/status"]


def test_only_the_topics_the_services_read_the_ground_truth_and_the_grid_returns_are_bridged(bus):
    bridge = Ros1Bridge(bus, BridgeRos1Config(), read=["camera/image_raw", "imu_adis_ros"])
    link = RecordingLink(PUBLISHED)
    bridge.discover(link)
    # sonar_micron: the /map grid's returns; truth/pose: bridge_ros1.keep_keys
    assert sorted(link.subs) == ["/camera/image_raw", "/imu_adis_ros", "/sonar_micron", "/truth/pose"]
    assert "/sonar_seaking" in bridge.stats.unread and "/vehicle/status" in bridge.stats.unread
    assert "/imu_adis_ros" not in bridge.stats.unread
    bridge.discover(link)  # polled again: nothing new, nothing twice
    assert len(link.subs) == 4 and len(bridge.stats.unread) == len(set(bridge.stats.unread))


def test_every_topic_is_bridged_when_asked_or_when_the_readers_are_not_known(bus):
    for bridge in (Ros1Bridge(bus, BridgeRos1Config(bridge_unread=True), read=["camera/image_raw"]),
                   Ros1Bridge(bus, BridgeRos1Config())):
        link = RecordingLink(PUBLISHED)
        bridge.discover(link)
        assert set(PUBLISHED) <= set(link.subs) and bridge.stats.unread == []


def test_the_grid_waits_its_wall_period_between_builds(bus):
    for wall_s, builds in ((3600.0, 1), (0.0, 3)):
        bridge = Ros1Bridge(bus, BridgeRos1Config(grid_wall_period_s=wall_s))
        bridge.link = RecordingLink([])  # any link: flush_grid only checks there is one
        done = threading.Semaphore(0)
        started: list[bool] = []

        def build(force, started=started, done=done):
            started.append(force)
            done.release()

        bridge._publish_grid = build
        bridge.grid.due = lambda: True  # event time says due every time
        for _ in range(3):
            bridge.flush_grid()
            if wall_s == 0.0:
                assert done.acquire(timeout=10)  # the build thread ended before the next try
                bridge._grid_thread.join()
        assert len(started) == builds, (wall_s, started)
        bridge.flush_grid(force=True)  # the end: always
        assert started[-1] is True
