"""The player's configuration section (``player:`` in ``deploy/poseidon.yaml``).

Validated at start-up as part of the whole configuration (``system/config.py``); a
wrong value fails naming its dotted field.
"""
from __future__ import annotations

from typing import Literal

from pydantic import Field

from common.config import ConfigSection

__all__ = ["PlayerConfig"]


class PlayerConfig(ConfigSection):
    """Replay of a recording onto the bus (services/player)."""

    rate: float = Field(0.0, ge=0, description="replay speed: 1 = real time, N = N x, 0 = as fast as taken [x real time]")
    keys: list[str] = Field(default_factory=list, description="keys to publish (empty: every key)")
    replay: Literal["copied", "all", "consumed"] = Field(
        "copied", description="what a poseidon run replays from its input: copied = the keys a started service "
        "subscribes to, plus the ground truth evaluation reads (truth/pose, truth/revisits), go over the bus; the "
        "recorder copies the other input keys (e.g. the sim's sonar_seaking, sonar_*_ros, imu_adis, 2/3 of its "
        "messages) from the input recording itself, so the run's recording holds the whole input again; all = "
        "every key over the bus (what a live run does: there copied means all); consumed = as copied, but the "
        "other keys stay in the input recording only. player.keys still narrows each")
    bundle_frames: int = Field(
        16, ge=0, le=1024, description="a replay as fast as taken (rate 0) sends up to this many consecutive data frames "
        "of a key (each at most 16 KiB: not camera images) in one bus sample (a bundle), which the receiver splits again: "
        "the same frames in the same order, about a tenth as many deliveries of the frequent keys; once flow control "
        "held it, the player waits for room for bundle_ms of event time before it goes on (0 or 1: one sample "
        "per frame; paced and live runs always send one per frame) [frames]")
    bundle_ms: int = Field(
        1000, ge=1, le=60000, description="a bundle goes out at the latest when the replay has moved this much "
        "event time past it, and whenever the player waits for its consumers (flow control) [ms]")
