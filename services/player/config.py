"""The player's configuration section (``player:`` in ``deploy/poseidon.yaml``).

Validated at start-up as part of the whole configuration (``launcher/config.py``); a
wrong value fails naming its dotted field.
"""
from __future__ import annotations

from pydantic import Field

from common.config import ConfigSection

__all__ = ["PlayerConfig"]


class PlayerConfig(ConfigSection):
    rate: float = Field(0.0, ge=0, description="replay speed: 1 = real time, N = N x, 0 = as fast as taken")
    keys: list[str] = Field(default_factory=list, description="keys to publish (empty: every key)")
