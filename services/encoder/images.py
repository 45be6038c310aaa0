"""Camera frames as arrays, without torch: what the encoder's core needs of an :class:`Image`
before the backbone (so that planning a run, which reads each service's keys, never imports
torch)."""
from __future__ import annotations

import numpy as np

from common.messages import Image

__all__ = ["image_to_rgb"]


def image_to_rgb(msg: Image) -> np.ndarray:
    """An :class:`Image` message as an (H, W, 3) RGB array: uint8 for the 8-bit encodings,
    float32 in [0, 1] for ``mono16``."""
    data = np.asarray(msg.data)
    enc = msg.encoding
    channels = {"rgb8": 3, "bgr8": 3, "rgba8": 4, "bgra8": 4, "mono8": 1, "mono16": 1}[enc]
    expected = (msg.height, msg.width) if channels == 1 else (msg.height, msg.width, channels)
    if data.shape != expected and not (channels == 1 and data.shape == (msg.height, msg.width, 1)):
        raise ValueError(f"Image seq {msg.header.seq}: data shape {data.shape} does not match "
                         f"{msg.height}x{msg.width} {enc} (expected {expected})")
    if enc == "mono16":
        img = data.astype(np.float32).reshape(msg.height, msg.width, 1) / 65535.0
    else:
        img = data.astype(np.uint8, copy=False)
    if channels == 1:
        img = img.reshape(msg.height, msg.width, 1).repeat(3, axis=2)
    elif enc in ("bgr8", "bgra8"):
        img = img[:, :, 2::-1]
    else:
        img = img[:, :, :3]
    return np.ascontiguousarray(img)
