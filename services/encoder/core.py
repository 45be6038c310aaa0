"""When the encoder produces an output: camera frames and sonar messages -> SDRs (no transport).

:class:`EncoderCore` drives a :class:`~services.encoder.encoder.MultimodalEncoder` with
the sonar clock (:class:`~services.encoder.clock.SonarClock`): one call per camera frame or
sonar message, returning the per-modality SDRs of an output (or None).  Core and clock are plain classes: a notebook or a test feeds them messages
directly.  What happened is tallied in order in :attr:`EncoderCore.events` (counter name,
increment), which the node drains into its counters.

The warm-up hold (``encoder.embedding_norm.hold`` H > 0, running statistics): the SDR of a
frame is the hash of its embedding centred by the mean of the embeddings before it, so the
first frames of a mission are hashed with a mean of a handful of frames (the very first with
none) and do not match their own place seen later (corridor: the first 8 of 111 queries
lost).  So from the start the core *holds* its outputs (their embeddings, with the
statistics still taking every embedding in) until the modality that clocks them (the camera;
the sonar in ``sonar`` mode) has H embeddings, ``hold_max`` outputs are held, or the inputs
are ``hold_max_ns`` of event time past the oldest held output (2 s: a replay keeps only
``bus.flow_window_ms`` of event time in flight, and the services downstream wait for the held
outputs; a laser log's scan clock deadlocked the replay without this bound), and then
hashes the held outputs with the statistics as they stand, in order (the sonar, embedded
about once per 5 frames, joins with the embeddings it has by then).  The hold happens once,
at the start; afterwards every output is hashed at once.  Its cost is a start-up delay of H
camera frames (2 s at 5 Hz for H = 10), which the node announces through its output
watermark, so downstream services see the same event-time order as without the hold.
H = 10 is the smallest hold that recovers the corridor's first queries (AP with the first
frames hashed with the mean of 1 / 5 / 10 / 20 / 50 frames: 0.927 / 0.937 / 1.000 / 1.000 /
1.000); on seven development missions (seeds 1234, 77, 2101-2105, camera modality) it moved
revisit recall / precision from 0.476 / 0.978 to 0.475 / 0.980.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from common.messages import Image, LaserScan, RangeImageBeam

from .clock import SonarClock
from .images import image_to_rgb

__all__ = ["EncoderCore", "EncoderOutput", "SdrEncoder"]


@dataclass
class EncoderOutput:
    """One output of the encoder: its stamp and frame id, the SDRs per modality (sorted active
    bits) and the embeddings they were hashed from; ``sonar_clocked``: produced by the sonar
    sweep clock (no camera frame)."""

    stamp: int
    frame_id: str
    sdrs: dict[str, np.ndarray]
    embeddings: dict[str, np.ndarray]
    sonar_clocked: bool = False


class SdrEncoder(Protocol):
    """What :class:`EncoderCore` uses of its encoder (a :class:`MultimodalEncoder`, or a stand-in)."""

    def embed(self, images: Sequence[np.ndarray]) -> list[np.ndarray]: ...

    def sdr(self, modality: str, embedding: np.ndarray, update: bool = True) -> np.ndarray: ...

    def settled(self, modality: str, frames: int) -> bool: ...

    def fuse(self, sdrs: Mapping[str, np.ndarray | None], mode: str | None = None) -> np.ndarray: ...


class EncoderCore:
    """Camera frames and sonar messages -> the encoder's outputs (:class:`EncoderOutput`).

    :meth:`on_camera` and :meth:`on_sonar` return the outputs released by the message (none,
    one, or the held ones at the end of the warm-up hold, in order); fuse an output's SDRs
    with :meth:`fuse`.  A fresh sonar that is due is embedded in one batch with the frame
    (camera first).  ``hold``/``hold_max``: the warm-up hold (module doc; 0: none).
    """

    def __init__(self, encoder: SdrEncoder, clock: SonarClock, hold: int = 0, hold_max: int = 50,
                 hold_max_ns: int = 2_000_000_000):
        if hold < 0 or hold_max < 1 or hold_max_ns <= 0:
            raise ValueError(f"hold must be >= 0, hold_max >= 1 and hold_max_ns > 0, got {hold}, {hold_max}, "
                             f"{hold_max_ns}")
        self.hold_max_ns = int(hold_max_ns)
        self.encoder = encoder
        self.clock = clock
        self.events: list[tuple[str, int]] = []
        self.hold = int(hold)
        self.hold_max = int(hold_max)
        self.holding = self.hold > 0       # the warm-up hold is still on
        self.held: list[EncoderOutput] = []
        self.sonar_y: np.ndarray | None = None   # the embedding behind clock.sonar_sdr

    @property
    def mode(self) -> str:
        return self.clock.mode

    def _count(self, what: str, n: int = 1) -> None:
        self.events.append((what, n))

    def take_events(self) -> list[tuple[str, int]]:
        """The (counter, increment) pairs since the last call, in order."""
        out, self.events = self.events, []
        return out

    @property
    def oldest_held_stamp(self) -> int | None:
        """Stamp of the oldest held output (None: nothing held)."""
        return self.held[0].stamp if self.held else None

    def on_sonar(self, msg: RangeImageBeam | LaserScan) -> list[EncoderOutput]:
        """Add the message; a sonar-only output when the sweep clock fires."""
        up = self.clock.add(msg)
        if up.reset:
            self._count("sonar_ring_reset")
            self.sonar_y = None
        self._count("sonar_beams", up.beams)
        if not up.clocked:
            return []
        sdrs = {"sonar": self._sonar_sdr()}
        self.clock.emitted()
        assert self.sonar_y is not None
        out = EncoderOutput(msg.header.stamp, msg.header.frame_id, sdrs, {"sonar": self.sonar_y}, True)
        return self._release(out)

    def on_camera(self, msg: Image) -> list[EncoderOutput]:
        """The frame's output (camera, and sonar when fresh); nothing in ``sonar`` mode."""
        stamp = msg.header.stamp
        self.clock.camera_seen(stamp)
        if self.mode == "sonar":
            self._count("camera_frames_unused")
            return []
        rgb = image_to_rgb(msg)
        sonar_fresh = self.clock.fresh(stamp)
        if sonar_fresh and self.clock.due:
            y_cam, y_son = self.encoder.embed([rgb, self.clock.raster.image3()])
            self._encoded(y_son)
        else:
            (y_cam,) = self.encoder.embed([rgb])
            if sonar_fresh:
                self._count("sonar_sdr_reused")
        sdrs = {"camera": self.encoder.sdr("camera", y_cam)}
        ys = {"camera": y_cam}
        if sonar_fresh:
            assert self.clock.sonar_sdr is not None and self.sonar_y is not None
            sdrs["sonar"], ys["sonar"] = self.clock.sonar_sdr, self.sonar_y
        else:
            self._count("frames_without_sonar")
        self.clock.emitted()
        return self._release(EncoderOutput(stamp, msg.header.frame_id, sdrs, ys))

    def _encoded(self, y: np.ndarray) -> None:
        self.sonar_y = y
        self.clock.encoded(self.encoder.sdr("sonar", y))
        self._count("sonar_encodings")

    def _sonar_sdr(self) -> np.ndarray:
        if self.clock.due:
            (y,) = self.encoder.embed([self.clock.raster.image3()])
            self._encoded(y)
        assert self.clock.sonar_sdr is not None
        return self.clock.sonar_sdr

    # ------------------------------------------------------------------ warm-up hold
    def _release(self, out: EncoderOutput) -> list[EncoderOutput]:
        """The outputs due after ``out``: itself, nothing (held), or every held output."""
        if not self.holding:
            return [out]
        settled = self.encoder.settled("sonar" if self.mode == "sonar" else "camera", self.hold)
        if not self.held and settled:
            self.holding = False     # statistics loaded, fixed or already warm: nothing to hold
            return [out]
        self.held.append(out)
        if len(self.held) < self.hold_max and not settled:
            return []
        return self.flush()

    def expire(self, stamp: int) -> list[EncoderOutput]:
        """The inputs reached event time ``stamp`` (ns): the hold ends (:meth:`flush`) once that is
        ``hold_max_ns`` past the oldest held output, even if no output came since (a sonar sweep
        clock outputs every few seconds; a replay's flow window must not wait on the hold)."""
        if self.held and stamp - self.held[0].stamp >= self.hold_max_ns:
            return self.flush()
        return []

    def flush(self) -> list[EncoderOutput]:
        """End the hold: every held output hashed anew with the statistics as they stand
        (``update`` False: each embedding is in them once already), in order; the last sonar
        SDR too, so a later frame reusing it matches."""
        self.holding = False
        held, self.held = self.held, []
        for h in held:
            h.sdrs = {m: self.encoder.sdr(m, y, update=False) for m, y in h.embeddings.items()}
        if held and self.sonar_y is not None and self.clock.sonar_sdr is not None:
            self.clock.sonar_sdr = self.encoder.sdr("sonar", self.sonar_y, update=False)
        if held:
            self._count("outputs_held", len(held))
        return held

    def fuse(self, sdrs: dict[str, np.ndarray]) -> np.ndarray:
        """Fused active bits of the output (Eq. 4.3, the clock's fusion mode)."""
        return self.encoder.fuse(sdrs, self.mode)
