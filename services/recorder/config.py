"""The recorder's configuration section (``recorder:``).

Validated at start-up as part of the whole configuration (``system/config.py``); a
wrong value fails naming its dotted field.
"""
from __future__ import annotations

from typing import Literal

from pydantic import Field

from common.config import ConfigSection

__all__ = ["RecorderConfig"]


class RecorderConfig(ConfigSection):
    """The run's MCAP recording (services/recorder)."""

    chunk_size: int = Field(1 << 20, ge=1024, description="MCAP chunk size [bytes]")
    compression: Literal["zstd", "lz4", "none"] = Field("zstd", description="compression of the MCAP chunks")
    zstd_level: int = Field(-1, ge=-7, le=22, description="zstd level of the chunks: -1 compresses a simulated "
                            "run in ~0.9 ns per byte to 1/1.14 of its size, 1 in ~1.7 ns to 1/1.35 (19 % less "
                            "disk for about twice the recorder's compression CPU)")
