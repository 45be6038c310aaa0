"""The ROS 1 bridge's configuration section (``bridge_ros1:`` in ``deploy/poseidon.yaml``).

``topics`` maps a ROS topic to our key (and optionally the ROS type it must have); by default
it is the importer's mapping (:data:`common.ros_convert.DEFAULT_TOPIC_MAP`), and with
``discover`` every other published topic is bridged too, on the topic without its leading
slash (the importer's rule).  Validated at start-up as part of the whole configuration
(``system/config.py``); a wrong value fails naming its dotted field.
"""
from __future__ import annotations

from pydantic import Field

from common.config import ConfigSection
from common.ros_convert import DEFAULT_TOPIC_MAP

__all__ = ["BridgeRos1Config", "TopicRoute"]


class TopicRoute(ConfigSection):
    """Where one ROS topic goes."""

    key: str | None = Field(description="our key (no leading slash); null: the topic is not bridged")
    type: str = Field("", description="the ROS type the topic must have, e.g. sensor_msgs/Imu ('' any); "
                      "another type is carried raw and counted as type_mismatch")
    raw: bool = Field(False, description="carry the topic raw (raw/<key>) even when a model exists")


def _default_topics() -> dict[str, TopicRoute]:
    return {topic: TopicRoute(key=key) for topic, key in DEFAULT_TOPIC_MAP.items()}


class BridgeRos1Config(ConfigSection):
    """The ROS 1 bridge: ROS topics in, our outputs back to ROS (services/bridge_ros1)."""

    master_uri: str = Field("", description="ROS master; '' = the ROS_MASTER_URI environment variable, "
                            "else http://localhost:11311")
    node_name: str = Field("poseidon_bridge", pattern=r"^[A-Za-z][A-Za-z0-9_]*$", description="ROS node name")
    ros_python_path: str = Field("/usr/lib/python3/dist-packages",
                                 description="where rospy is (appended to sys.path, never prepended)")
    master_timeout_s: float = Field(10.0, gt=0, description="wait this long for the ROS master at start [s]")
    topics: dict[str, TopicRoute] = Field(default_factory=_default_topics,
                                          description="ROS topic -> our key (default: the importer's mapping)")
    ros_queue_size: int = Field(10000, ge=1, description="rospy's queue per subscribed topic: if the bridge "
                                "falls this far behind a topic, rospy drops its oldest messages (a loaded machine at "
                                "rosbag play -r 8 needs more than a few hundred) [messages]")
    discover: bool = Field(True, description="also bridge every other published topic (key: the topic "
                           "without its leading slash)")
    bridge_unread: bool = Field(False, description="also bridge the topics whose key no service of the run reads "
                                "(the recording then holds every topic of the ROS graph); off: when the launcher names "
                                "the keys its services read (poseidon run --live ros1, or --read), only those, the "
                                "grid's returns and keep_keys are subscribed to; the others are listed in the stats' "
                                "unread")
    keep_keys: list[str] = Field(default_factory=lambda: ["truth/pose", "truth/revisits"],
                                 description="keys bridged (and recorded) even when no service reads them: the "
                                 "ground truth a run is scored against (poseidon eval)")
    discover_interval_s: float = Field(1.0, gt=0, description="how often the master is asked for new topics [s]")
    ignore_topics: list[str] = Field(default_factory=lambda: ["/rosout", "/rosout_agg", "/clock"],
                                     description="never bridged in (our own output topics never are)")
    lateness_ms: int = Field(200, ge=0, description="live watermarks: a stream promises nothing older than "
                             "its wall-clock-mapped time minus this; see bridge.py [ms]")
    stall_hold_ms: int = Field(2000, ge=0, description="a topic silent for over 4 of its mean gaps and half "
                               "lateness_ms is taken to be held up (rosbag play or a rospy thread starved): its "
                               "watermark stops advancing for at most this long, so its messages after the stall "
                               "are not late; 0: watermarks follow the wall clock throughout (common/live.py: "
                               "Stalls) [ms]")
    outage_buffer_frames: int = Field(1000, ge=1, description="per key, the last frames kept to send again "
                                      "after its consumers were unreachable (common/live.py: the outage rule); "
                                      "held frames beyond it are dropped oldest first, counted dropped_outage [frames]")
    outage_buffer_mb: float = Field(64.0, gt=0, description="per key, at most this much kept for an outage [MB]")
    watermark_interval_ms: int = Field(100, ge=10, description="wall-clock watermarks on every source key this "
                                       "often [ms]")
    odometry_key: str = Field("Odometry", description="our key published as nav_msgs/Odometry")
    odometry_topic: str = Field("/poseidon/odom", description="ROS topic of odometry_key")
    dead_reckoning_key: str = Field("dead_reckoning", description="our key published as geometry_msgs/PoseStamped")
    dead_reckoning_topic: str = Field("/poseidon/dead_reckoning", description="ROS topic of dead_reckoning_key")
    map_key: str = Field("map", description="our key published as nav_msgs/Path + visualization_msgs/MarkerArray")
    path_topic: str = Field("/poseidon/path", description="experience map as nav_msgs/Path (latched)")
    markers_topic: str = Field("/poseidon/map_markers",
                               description="experience map as visualization_msgs/MarkerArray (latched)")
    map_period_s: float = Field(1.0, ge=0, description="publish the map to ROS at most this often (wall clock) [s]")
    grid_topic: str = Field("/map", description="the occupancy grid of the horizontal returns (laser scan, else "
                            "sonar_micron) at the map-corrected poses, as nav_msgs/OccupancyGrid (latched); "
                            "services/bridge_ros1/grid.py")
    grid_period_s: float = Field(5.0, ge=0, description="rebuild and publish the grid at most this often, in event "
                                 "time (the stamps of the returns, Odometry and map); 0 = no grid [s]")
    grid_wall_period_s: float = Field(2.0, ge=0, description="and at most this often in wall time: a bag played "
                                      "at 16x would otherwise be rebuilt 3 times a wall second, each build over every "
                                      "return so far (at 1x, grid_period_s is the bound) [s]")
    grid_resolution_m: float = Field(0.05, gt=0, description="the grid's cell size, as poseidon export --grid's "
                                     "default [m]")
    grid_max_returns: int = Field(2_000_000, ge=1000, description="returns kept for the grid; beyond it they are "
                                  "thinned to one per experience and cell (services/bridge_ros1/grid.py) [returns]")
    grid_max_poses: int = Field(500_000, ge=1000, description="Odometry samples kept for the grid; beyond it every "
                                "other sample of the older half that its neighbours interpolate within half a cell "
                                "is dropped (services/bridge_ros1/grid.py) [samples]")
    grid_max_cells: int = Field(16_000_000, ge=1, description="a larger grid is not built (logged): about 200 m x "
                                "200 m at 0.05 m [cells]")
    lvc_key: str = Field("local_view_cells", description="our key published as std_msgs/Int32 (the LVC id)")
    lvc_topic: str = Field("/poseidon/lvc_id", description="ROS topic of lvc_key")
    event_key: str = Field("experience_event", description="our key published as std_msgs/String (JSON)")
    event_topic: str = Field("/poseidon/experience_event", description="ROS topic of event_key")
    diagnostics_topic: str = Field("/diagnostics", description="a live run's health (live/health, one status "
                                   "per service) as diagnostic_msgs/DiagnosticArray, the topic rqt_robot_monitor "
                                   "reads")

    def output_stages(self) -> dict[str, str]:
        """Our output key -> its latency stage (:class:`common.live.LatencyTracker`): the outputs
        published back to ROS, also those the live player times (``system.services.latency_stages``)."""
        return {self.odometry_key: "odometry", self.dead_reckoning_key: "dead_reckoning", self.map_key: "map",
                self.lvc_key: "lvc", self.event_key: "event"}
