"""The live view's configuration section (``view:``).

Validated at start-up as part of the whole configuration (``system/config.py``); a wrong
value fails naming its dotted field.
"""
from __future__ import annotations

from pydantic import Field

from common.config import ConfigSection

__all__ = ["ViewConfig"]


class ViewConfig(ConfigSection):
    """The live browser view and Foxglove server (``poseidon view``, ``poseidon run --view``; services/viewer)."""

    listen: str = Field("127.0.0.1:8080", description="HOST:PORT the page is served on; loopback unless told "
                        "otherwise (port 0: any free port)")
    update_hz: float = Field(2.0, ge=0.5, le=20.0, description="the view's state is rebuilt from the latest "
                             "samples this often; the page polls at the same rate (each poll costs the browser "
                             "a request and the view a snapshot, see docs/DECISIONS.md, Live view) [Hz]")
    image_width: int = Field(320, ge=32, le=1280, description="camera frames are shrunk to at most this width "
                             "before JPEG encoding [px]")
    jpeg_quality: int = Field(70, ge=10, le=95, description="JPEG quality of the camera frame sent to the page")
    trajectory_points: int = Field(4000, ge=100, description="a trajectory keeps at most this many points "
                                   "(every other point is dropped when full) [points]")
    timeline_points: int = Field(4000, ge=100, description="the LVC timeline keeps at most this many frames "
                                 "(every other one dropped when full; revisits are always kept) [frames]")
    sonar_bins: int = Field(64, ge=8, le=512, description="range bins kept per sonar beam in the sweep [bins]")
    sample_bytes: int = Field(65536, ge=1024, description="a key whose data frames are larger (camera images) "
                              "is sampled, not followed frame by frame: the hub copies only about sample_hz "
                              "of its frames a second to the view [bytes]")
    sample_hz: float = Field(2.0, gt=0, le=20.0, description="frames a second taken of each sampled key (the "
                             "camera panel's refresh rate in a live view) [Hz]")
    linger_s: float = Field(0.0, ge=0.0, description="poseidon run --view: keep serving the final state this "
                            "long after the run ended (0: stop with the run) [s]")
    idle_priority: bool = Field(True, description="poseidon view of a running deployment: the view runs at the "
                                "lowest CPU priority (Linux SCHED_IDLE), so on a vehicle computer it only uses "
                                "time the SLAM leaves (false: the default scheduling)")
    nice: int = Field(10, ge=0, le=19, description="poseidon view of a running deployment: the view process, "
                      "Zenoh's threads included, runs at least at this niceness, so the SLAM's processes preempt "
                      "it on a vehicle computer (0: the niceness it was started with)")
    connect_timeout_s: float = Field(5.0, gt=0, description="poseidon view --connect: give up (exit 2) when no "
                                     "hub answers at the address within this time [s]")
    foxglove_backlog: int = Field(64, ge=1, description="Foxglove server: messages buffered per client; beyond, "
                                  "the oldest are dropped for that client only [messages]")
    camera_key: str = Field("camera/image_raw", description="key of the camera frames shown")
    sonar_key: str = Field("sonar_micron", description="key of the sonar beams (RangeImageBeam) drawn as a sweep")
    scan_key: str = Field("scan", description="key of the laser scans (LaserScan) drawn as points")
    truth_keys: list[str] = Field(default_factory=lambda: ["truth/pose", "ground_truth"], description="keys of "
                                  "the true trajectory, first present wins (Odometry)")
