"""``encoder`` service: camera frames + MSIS sonar beams -> ``neocortex/sdr`` (Eqs. 4.1-4.3).

Inputs: ``camera/image_raw`` (:class:`Image`) and the sonar key ``encoder.sonar_topic``
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
Embeddings are standardised per modality before LSBH (``encoder.embedding_norm``, in
event order; the statistics are saved at the end, see :mod:`services.encoder.standardize`).
Messages are processed one at a time (a frame plus the sonar raster go through the CNN as
one batch of two).  Sonar encoding rule: the raster is re-encoded when the beams have swept
at least ``encoder.sonar_encode_sweep_deg`` (45 deg: a fifth of a Micron turn, ~1 s at
42 deg/s, i.e. about every 5th camera frame at 5 Hz) since its last encoding, or when there
is no sonar SDR yet (start, after a ring reset); otherwise the last sonar SDR is reused
(counted as ``sonar_sdr_reused``).  A raster changes little within a few degrees of sweep
while the CNN costs as much as a camera frame, so this keeps the sonar cost per camera
frame at about a fifth of a CNN pass (``benchmarks/bench_encoder.py``).
"""
from __future__ import annotations

import hashlib
import logging
import math

import numpy as np

from common.config import PoseidonConfig
from common.messages import Header, Image, LaserScan, NeocortexSdr, RangeImageBeam, Sdr
from common.node import ServiceNode

from .encoder import MultimodalEncoder, image_to_rgb
from .sonar import SonarRaster

__all__ = ["EncoderNode"]

log = logging.getLogger(__name__)

TWO_PI = 2.0 * math.pi
OUT = "neocortex/sdr"


class EncoderNode(ServiceNode):
    """Thin transport wrapper around :class:`MultimodalEncoder` and :class:`SonarRaster`."""

    name = "encoder"
    outputs = (OUT,)

    @classmethod
    def io_keys(cls, config: PoseidonConfig) -> tuple[tuple[str, ...], tuple[str, ...]]:
        return ("camera/image_raw", config.encoder.sonar_topic), (OUT,)

    def __init__(self, config: PoseidonConfig, encoder: MultimodalEncoder | None = None):
        super().__init__(config)
        cfg = config.encoder
        self.sonar_key = cfg.sonar_topic
        self.encoder = encoder if encoder is not None else MultimodalEncoder(cfg)
        self.raster = SonarRaster(cfg.sonar_polar_width, cfg.sonar_polar_height, cfg.sonar_rmax,
                                  cfg.sonar_use_intensities)
        self.mode = cfg.fusion_mode
        if config.htm.state_path and cfg.embedding_norm == "running" and not cfg.embedding_norm_path:
            log.warning("encoder: htm.state_path keeps the LVC map across runs but encoder.embedding_norm_path is "
                        "empty: the running embedding statistics restart every run, so the SDRs of known places "
                        "change; set encoder.embedding_norm_path (e.g. state/embnorm_{backbone}_{modality}.npz)")
            self.count("embedding_norm_not_persisted")
        self.stale_ns = int(round(config.sync.sync_stale_sec * 1e9))
        self.length = cfg.sp_columns
        self._last_camera: int | None = None
        self._sweep_rad = 0.0
        self._sonar_cache: np.ndarray | None = None  # the last sonar SDR
        self._since_sonar_rad = 0.0  # bearing swept since the sonar raster was last encoded
        self._reencode_rad = math.radians(cfg.sonar_encode_sweep_deg)

    # ------------------------------------------------------------------ inputs
    def process(self, key: str, msg) -> None:
        if key == "camera/image_raw":
            self._on_camera(msg)
        elif key == self.sonar_key:
            self._on_sonar(msg)
        else:
            raise KeyError(f"encoder: unexpected input key {key!r}")

    def _on_sonar(self, msg: RangeImageBeam | LaserScan) -> None:
        stamp = msg.header.stamp
        if self.raster.last_stamp is not None and stamp - self.raster.last_stamp > self.stale_ns:
            self.raster.reset()
            self._sweep_rad = 0.0
            self._sonar_cache = None
            self.count("sonar_ring_reset")
        prev = self.raster.last_angle
        if isinstance(msg, RangeImageBeam):
            self.raster.add_beam(msg)
            angles = [msg.angle_rad]
        elif isinstance(msg, LaserScan):
            angles = self.raster.add_scan(msg)
        else:
            raise TypeError(f"encoder: {self.sonar_key} carries {type(msg).__name__}, "
                            "expected RangeImageBeam or LaserScan")
        for a in angles:
            if prev is not None:
                step = abs((a - prev + math.pi) % TWO_PI - math.pi)
                self._sweep_rad += step
                self._since_sonar_rad += step
            prev = a
        self.count("sonar_beams", len(angles))
        camera_silent = self._last_camera is None or stamp - self._last_camera > self.stale_ns
        sonar_clock = self.mode == "sonar" or (self.mode in ("union", "and") and camera_silent)
        if sonar_clock and self._sweep_rad >= TWO_PI:
            self._emit(stamp, msg.header.frame_id, {"sonar": self._sonar_sdr()})
            self.count("sonar_clocked_outputs")

    def _on_camera(self, msg: Image) -> None:
        self._last_camera = msg.header.stamp
        if self.mode == "sonar":
            self.count("camera_frames_unused")
            return
        stamp = msg.header.stamp
        rgb = image_to_rgb(msg)
        sonar_fresh = (self.mode != "camera" and self.raster.has_data and self.raster.last_stamp is not None
                       and stamp - self.raster.last_stamp <= self.stale_ns)
        sdrs: dict[str, np.ndarray] = {}
        if sonar_fresh and self._sonar_due():
            y_cam, y_son = self.encoder.embed([rgb, self.raster.image3()])
            self._set_sonar(y_son)
        else:
            (y_cam,) = self.encoder.embed([rgb])
            if sonar_fresh:
                self.count("sonar_sdr_reused")
        sdrs["camera"] = self.encoder.sdr("camera", y_cam)
        if sonar_fresh:
            sdrs["sonar"] = self._sonar_cache  # type: ignore[assignment]
        else:
            self.count("frames_without_sonar")
        self._emit(stamp, msg.header.frame_id, sdrs)

    def _sonar_due(self) -> bool:
        """The encoding rule of the module doc: no sonar SDR yet, or swept far enough since the last."""
        return self._sonar_cache is None or self._since_sonar_rad >= self._reencode_rad

    def _set_sonar(self, y: np.ndarray) -> None:
        self._sonar_cache = self.encoder.sdr("sonar", y)
        self._since_sonar_rad = 0.0
        self.count("sonar_encodings")

    def _sonar_sdr(self) -> np.ndarray:
        if self._sonar_due():
            (y,) = self.encoder.embed([self.raster.image3()])
            self._set_sonar(y)
        return self._sonar_cache  # type: ignore[return-value]

    # ------------------------------------------------------------------ checkpoints
    checkpoint_exclude = ("encoder", "_digests")  # the CNN is rebuilt from the configuration

    def _lsbh_digests(self) -> dict[str, str]:
        digests = self.__dict__.setdefault("_digests", {})
        for m, e in self.encoder._lsbh.items():
            if m not in digests:
                digests[m] = hashlib.sha256(np.ascontiguousarray(e.projection).tobytes()).hexdigest()
        return dict(digests)

    def checkpoint_state(self) -> dict:
        """Node state plus the encoder's standardisation statistics and a digest of each LSBH
        projection (the projections are rebuilt from the seed or their file, then checked)."""
        state = super().checkpoint_state()
        state["_standardizers"] = dict(self.encoder._norm)
        state["_lsbh_digest"] = self._lsbh_digests()
        return state

    def restore_checkpoint(self, state: dict) -> None:
        state = dict(state)
        for modality, st in state.pop("_standardizers").items():
            self.encoder.set_standardizer(modality, st)
        for modality, digest in state.pop("_lsbh_digest").items():
            self.encoder.lsbh(modality)
            if self._lsbh_digests()[modality] != digest:
                raise ValueError(f"encoder: the LSBH projection of {modality} differs from the checkpoint's "
                                 "(encoder.lsbh_seed or encoder.lsbh_matrix_path changed)")
        super().restore_checkpoint(state)

    def finish(self) -> None:
        self.encoder.close()

    def close(self) -> None:
        self.encoder.close()

    # ------------------------------------------------------------------ output
    def _emit(self, stamp: int, frame_id: str, sdrs: dict[str, np.ndarray]) -> None:
        self._sweep_rad = 0.0  # the sonar clock counts travel since the last output
        header = self.header(OUT, stamp, frame_id)
        fused = self.encoder.fuse(sdrs, self.mode)

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
