"""The pose-cell activity as OpenRatSLAM's pose-cell view shows it: ``posecells/activity``.

:func:`activity_projections` sums the 4-D activity ``P[x, y, z, yaw]`` over (z, yaw) into an
x-y image and over (x, y) into a z-yaw image; both sum to the total activity (1 after each
attractor update).  :func:`activity_message` quantises each image to uint8 against its own
peak (``value * scale`` is the activity of a pixel, ``scale = peak / 255``) and adds the
network's centroid, so a message of the default 15 x 15 x 15 x 8 lattice carries 345 bytes of
pixels.  Everything is computed from the activity alone, in a fixed order: the same activity
gives the same bytes.

:class:`ActivityClock` bounds the rate in event time: at most one message per
``posecells.activity_period_s`` of input stamps (0: never).
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from common.messages import Header, PoseCellActivity

if TYPE_CHECKING:
    from services.posecells.network import PoseCellNetwork

__all__ = ["ACTIVITY_KEY", "ActivityClock", "activity_projections", "activity_message", "quantise"]

#: the key of the activity projections (``poseidon/posecells/activity`` on the bus)
ACTIVITY_KEY = "posecells/activity"


def activity_projections(activity: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(xy, zyaw)`` of a ``(nx, ny, nz, n_yaw)`` activity: the sums over (z, yaw) and over (x, y)."""
    p = np.asarray(activity, dtype=np.float64)
    if p.ndim != 4:
        raise ValueError(f"pose-cell activity must be 4-D (x, y, z, yaw), got shape {p.shape}")
    return p.sum(axis=(2, 3)), p.sum(axis=(0, 1))


def quantise(image: np.ndarray) -> tuple[np.ndarray, float]:
    """uint8 pixels and the activity per unit (``peak / 255``; 0 for an all-zero image)."""
    peak = float(image.max()) if image.size else 0.0
    if not peak > 0.0:
        return np.zeros(image.shape, np.uint8), 0.0
    scale = peak / 255.0
    return np.rint(np.clip(image, 0.0, None) / scale).astype(np.uint8), scale


def activity_message(net: PoseCellNetwork, header: Header) -> PoseCellActivity:
    """The network's current activity projections and centroid as a message."""
    xy, zyaw = activity_projections(net.P)
    qxy, sxy = quantise(xy)
    qzyaw, szyaw = quantise(zyaw)
    return PoseCellActivity(header=header, xy=qxy, xy_scale=sxy, zyaw=qzyaw, zyaw_scale=szyaw,
                            centroid=net.centroid(), spacing=[float(v) for v in net.spacing], steps=net.steps)


class ActivityClock:
    """When the next activity message is due, in event time (ns)."""

    def __init__(self, period_s: float):
        self.period_ns = int(round(float(period_s) * 1e9))
        self.last: int | None = None  # stamp of the last message (ns)

    def due(self, stamp: int) -> bool:
        """True (and the message counted as sent) when ``stamp`` is at least one period after the
        last message; always False when the period is 0."""
        if self.period_ns <= 0:
            return False
        if self.last is not None and stamp - self.last < self.period_ns:
            return False
        self.last = stamp
        return True
