"""``encoder`` service: camera frames + MSIS sonar beams -> ``neocortex/sdr`` (Eqs. 4.1-4.3).

Inputs: ``camera/image_raw`` (:class:`Image`) and the sonar key ``encoder.sonar.topic``
(``sonar_micron`` by default: :class:`RangeImageBeam`; the ``*_ros`` keys: :class:`LaserScan`).
Output: ``neocortex/sdr`` (:class:`NeocortexSdr`): per-modality SDRs and the fused SDR.

When an output is produced (the "clock"):

* ``fusion_mode`` union / and / camera: one output per camera frame, header stamp and
  frame_id = the frame's.  The camera SDR is always in it; the sonar SDR (not in ``camera``
  mode) when the sonar is *fresh*: the ring holds beams and the newest beam is at most
  ``sync.sync_stale_sec`` older than the frame.  A stale or absent sonar is simply a missing
  modality (Eq. 4.3 fuses what is present).
* Camera dropout (union / and): while the newest camera frame is more than
  ``sync.sync_stale_sec`` older than the sonar beams, the sonar takes over the clock: one
  sonar-only output each time the beams have swept a further 360 deg, stamped with the beam
  that completes the sweep.  Frames resume the clock as soon as they return.  So dropping
  either modality for a stretch still yields SDRs (a stretch with neither yields nothing).
* ``fusion_mode`` sonar: the sonar sweep clock only (camera frames are not encoded).

Beams accumulate in :class:`~services.encoder.sonar.SonarRaster` between outputs; a gap of
more than ``sync.sync_stale_sec`` between consecutive beams resets the ring (counted as
``sonar_ring_reset``), so an image never mixes sweeps from before and after a dropout.
Embeddings are standardised per modality before LSBH (``encoder.embedding_norm.mode``, in
event order; the statistics are saved at the end, see :mod:`services.encoder.standardize`).
With running statistics the first outputs are held until the camera has
``encoder.embedding_norm.hold`` embeddings (at most ``embedding_norm.hold_max_s`` of event
time), then hashed with them (the warm-up hold,
:mod:`services.encoder.core`); the output watermark stays at the oldest held stamp meanwhile,
and the end of the inputs releases what is still held.  Counter ``outputs_held``.
Messages are processed one at a time (a frame plus the sonar raster go through the CNN as
one batch of two).  Sonar encoding rule: the raster is re-encoded when the beams have swept
at least ``encoder.sonar.encode_sweep_deg`` (45 deg: a fifth of a Micron turn, ~1 s at
42 deg/s, i.e. about every 5th camera frame at 5 Hz) since its last encoding, or when there
is no sonar SDR yet (start, after a ring reset); otherwise the last sonar SDR is reused
(counted as ``sonar_sdr_reused``).  A raster changes little within a few degrees of sweep
while the CNN costs as much as a camera frame, so this keeps the sonar cost per camera
frame at about a fifth of a CNN pass (``benchmarks/bench_encoder.py``).

The rules live in :class:`services.encoder.core.EncoderCore` and
:class:`~services.encoder.clock.SonarClock`; the node subscribes, calls the core, publishes
and counts.
"""
from __future__ import annotations

import logging
import math
from typing import TYPE_CHECKING, Any

import numpy as np

from common.messages import Header, Image, LaserScan, Message, NeocortexSdr, RangeImageBeam, Sdr
from common.node import ServiceNode
from services.encoder.config import EncoderConfig

from .clock import SonarClock
from .core import EncoderCore, EncoderOutput
from .sonar import SonarRaster, warm_up_kernels

if TYPE_CHECKING:  # torch is imported only by a node that builds its encoder, not by run planning
    from .encoder import MultimodalEncoder

__all__ = ["EncoderNode"]

log = logging.getLogger(__name__)

OUT = "neocortex/sdr"


class EncoderNode(ServiceNode[EncoderConfig]):
    """Transport wrapper around :class:`EncoderCore` (a :class:`MultimodalEncoder` and a :class:`SonarClock`)."""

    name = "encoder"
    outputs = (OUT,)

    @classmethod
    def io_keys(cls, config: EncoderConfig) -> tuple[tuple[str, ...], tuple[str, ...]]:
        return ("camera/image_raw", config.sonar.topic), (OUT,)

    def __init__(self, config: EncoderConfig, *, sync_stale_sec: float, lvc_map_persisted: bool = False,
                 encoder: MultimodalEncoder | None = None, flow_window_s: float = 3.0):
        """``config``: the ``encoder`` section.  From other sections, explicitly: ``sync_stale_sec``
        (``sync``: how long a sonar raster stays fresh for a camera frame, s) and
        ``lvc_map_persisted`` (``htm.state_path`` set: the LVC map outlives the run) and
        ``flow_window_s`` (``bus.flow_window_ms``: the warm-up hold ends at the latest 1 s of event
        time before a replay's flow window is used up, and is off when the window is under 1 s)."""
        super().__init__(config)
        cfg = config
        self.sonar_key = cfg.sonar.topic
        if encoder is None:
            from .encoder import MultimodalEncoder
            encoder = MultimodalEncoder(cfg)
        self.encoder = encoder
        self.mode = cfg.fusion_mode
        if lvc_map_persisted and cfg.embedding_norm.mode == "running" and not cfg.embedding_norm.path:
            log.warning("encoder: htm.state_path keeps the LVC map across runs but encoder.embedding_norm.path is "
                        "empty: the running embedding statistics restart every run, so the SDRs of known places "
                        "change; set encoder.embedding_norm.path (e.g. state/embnorm_{backbone}_{modality}.npz)")
            self.count("embedding_norm_not_persisted")
        raster = SonarRaster(cfg.sonar.polar_width, cfg.sonar.polar_height, cfg.sonar.max_range_m, cfg.sonar.use_intensities)
        clock = SonarClock(raster, self.mode, int(round(sync_stale_sec * 1e9)),
                           math.radians(cfg.sonar.encode_sweep_deg))
        hold_max_s = min(cfg.embedding_norm.hold_max_s, flow_window_s - 1.0)
        hold = cfg.embedding_norm.hold if cfg.embedding_norm.mode == "running" and hold_max_s > 0 else 0
        self.core = EncoderCore(self.encoder, clock, hold, max(cfg.embedding_norm.warmup, 1),
                                int(round(max(hold_max_s, 1e-3) * 1e9)))
        self.length = cfg.sp_columns

    def warm_up(self) -> None:
        """The sonar beam kernel compiled before the first beam arrives."""
        warm_up_kernels()

    # ------------------------------------------------------------------ inputs
    def process(self, key: str, msg: Message) -> None:
        if key == "camera/image_raw":
            if not isinstance(msg, Image):
                raise TypeError(f"encoder: {key!r} carries {type(msg).__name__}, expected Image")
            outs = self.core.on_camera(msg)
        elif key == self.sonar_key:
            if not isinstance(msg, (RangeImageBeam, LaserScan)):
                raise TypeError(f"encoder: {key!r} carries {type(msg).__name__}, expected RangeImageBeam or LaserScan")
            outs = self.core.on_sonar(msg)
        else:
            raise KeyError(f"encoder: unexpected input key {key!r}")
        if self.core.holding:
            outs = outs + self.core.expire(msg.header.stamp)
        self._drain()
        self._emit_all(outs)

    def output_watermark(self, input_watermark: int) -> int:
        """While the warm-up hold keeps outputs back, nothing newer than the oldest held stamp is promised."""
        held = self.core.oldest_held_stamp
        return input_watermark if held is None else min(input_watermark, held)

    def _emit_all(self, outs: list[EncoderOutput]) -> None:
        for o in outs:
            self._emit(o.stamp, o.frame_id, o.sdrs)
            if o.sonar_clocked:
                self.count("sonar_clocked_outputs")

    def _drain(self) -> None:
        for what, n in self.core.take_events():
            self.count(what, n)

    # ------------------------------------------------------------------ checkpoints
    checkpoint_exclude = ("encoder", "core")  # the CNN is rebuilt from the configuration

    def checkpoint_state(self) -> dict[str, Any]:
        """Node state plus the sonar clock, the encoder's standardisation statistics and a digest
        of each LSBH projection (the projections are rebuilt from the seed or their file, then checked)."""
        state = super().checkpoint_state()
        state["_clock"] = self.core.clock
        state["_hold"] = (self.core.holding, self.core.held, self.core.sonar_y)
        state["_standardizers"] = self.encoder.standardizers
        state["_lsbh_digest"] = self.encoder.lsbh_digests()
        return state

    def restore_checkpoint(self, state: dict[str, Any]) -> None:
        state = dict(state)
        self.core.clock = state.pop("_clock")
        self.core.holding, self.core.held, self.core.sonar_y = state.pop("_hold")
        for modality, st in state.pop("_standardizers").items():
            self.encoder.set_standardizer(modality, st)
        for modality, digest in state.pop("_lsbh_digest").items():
            self.encoder.lsbh(modality)
            if self.encoder.lsbh_digests()[modality] != digest:
                raise ValueError(f"encoder: the LSBH projection of {modality} differs from the checkpoint's "
                                 "(encoder.lsbh.seed or encoder.lsbh.matrix_path changed)")
        super().restore_checkpoint(state)

    def finish(self) -> None:
        """The inputs ended: outputs still held by the warm-up hold go out, hashed with what was seen."""
        self._emit_all(self.core.flush())
        self._drain()
        self.encoder.close()

    def close(self) -> None:
        self.encoder.close()

    # ------------------------------------------------------------------ output
    def _emit(self, stamp: int, frame_id: str, sdrs: dict[str, np.ndarray]) -> None:
        header = self.header(OUT, stamp, frame_id)
        fused = self.core.fuse(sdrs)

        def sdr(modality: str, bits: np.ndarray) -> Sdr:
            return Sdr(header=Header(seq=header.seq, stamp=stamp, frame_id=frame_id), modality=modality,
                       size=self.length, active=np.asarray(bits, dtype=np.uint32))

        self.publish(OUT, NeocortexSdr(
            header=header,
            modalities=[sdr(m, sdrs[m]) for m in ("camera", "sonar") if m in sdrs],
            fused=sdr("fused", fused),
            fusion_mode=self.mode,
        ))
        self.count("outputs")
