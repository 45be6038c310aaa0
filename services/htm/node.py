"""HTM service node: ``neocortex/sdr`` -> ``local_view_cells`` (Section 4.2.2).

Every valid NeocortexSdr frame yields exactly one LocalViewCells message with the frame's stamp
and frame_id (never suppressed; gating happens downstream in the VPR Guard). With
``htm.state_path`` set, the SP/TM/LVC state is loaded at start when the file exists and
saved when the inputs end and when the node closes.  A frame whose fused SDR has the wrong
size is logged with its key and seq, counted (``sdr_wrong_size``) and skipped.  With
``htm.lvc.require_multimodal`` the per-modality SDRs of the frame validate each match.

With ``htm.dr_gate.enabled`` (the dead-reckoning gate, :mod:`services.htm.geometry`) the node also
subscribes to ``Odometry``, first in priority, so a frame is checked against the latest
dead-reckoned position at or before its stamp (the posecells rule); a frame before any
``Odometry`` is not checked (``frames_without_odometry``), a non-finite position is logged,
counted (``odometry_non_finite``) and skipped, and ``dr_gate_rejections`` counts the claims
the gate turned down.  ``tm_segments_evicted`` counts the segments the temporal memory's
synapse budget (``htm.tm.max_synapses``) evicted.
"""
from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from common.messages import LocalViewCell, LocalViewCells, Message, NeocortexSdr, Odometry
from common.node import ServiceNode
from services.htm.config import HtmConfig
from services.htm.pipeline import NeocortexHtm

__all__ = ["HtmNode", "warm_up_kernels"]

log = logging.getLogger(__name__)


def warm_up_kernels(cfg: HtmConfig, places: int = 10) -> None:
    """Run a throwaway :class:`NeocortexHtm` of ``cfg`` (no state file; the sequence memory's
    exclusion window shortened to 2 frames so that it has candidates at once) over two passes of
    ``places`` synthetic places with positions, so the spatial pooler, the temporal memory, the
    LVC search and the sequence memory have each run and numba has compiled (or loaded) their
    kernels (the same argument types as the real core's)."""
    core = NeocortexHtm(cfg.updated({"state_path": "", "seqmem.exclude": 2}))
    rng = np.random.default_rng(0)
    k = max(1, cfg.input_size // 20)
    sdrs = [np.sort(rng.choice(cfg.input_size, k, replace=False)).astype(np.uint32) for _ in range(places)]
    for i in range(2 * places):
        j = i % places
        core.step(sdrs[j], position=np.array([float(j), 0.0, 0.0]))


class HtmNode(ServiceNode[HtmConfig]):
    """Runs :class:`NeocortexHtm` on the fused SDR of every encoder frame."""

    name = "htm"
    inputs = ("neocortex/sdr",)
    outputs = ("local_view_cells",)

    @classmethod
    def io_keys(cls, config: HtmConfig) -> tuple[tuple[str, ...], tuple[str, ...]]:
        """``Odometry`` first (the dead-reckoning gate's positions) when ``dr_gate.enabled``, then the SDRs."""
        gate = config.dr_gate.enabled and config.seqmem.length > 0
        return (("Odometry",) if gate else ()) + cls.inputs, cls.outputs

    def __init__(self, config: HtmConfig):
        super().__init__(config)
        self.position: np.ndarray | None = None     # latest dead-reckoned position (dr_gate.enabled)
        self.cfg = config
        self.state_path = Path(self.cfg.state_path) if self.cfg.state_path else None
        if self.state_path is not None and self.state_path.exists():
            self.htm = NeocortexHtm.load(self.state_path, self.cfg)
            log.info("htm: loaded state from %s (%d LVCs)", self.state_path, len(self.htm.lvc))
        else:
            self.htm = NeocortexHtm(self.cfg)
            if self.state_path is not None:
                log.info("htm: no state at %s yet, starting fresh", self.state_path)
        self._dirty = False

    def warm_up(self) -> None:
        """Compile the kernels on a throwaway core (:func:`warm_up_kernels`); the node's own is untouched."""
        warm_up_kernels(self.cfg)

    def process(self, key: str, msg: Message) -> None:
        if key == "Odometry" and isinstance(msg, Odometry):
            p = np.asarray(msg.position, np.float64)
            if not np.all(np.isfinite(p)):
                log.error("htm: %s seq %d skipped: non-finite position %s", key, msg.header.seq, msg.position)
                self.count("odometry_non_finite")
                return
            self.position = p
            return
        if not isinstance(msg, NeocortexSdr):
            raise TypeError(f"htm: {key!r} carries {type(msg).__name__}, expected NeocortexSdr")
        fused = msg.fused
        if fused.size != self.cfg.input_size:
            log.error("htm: %s seq %d skipped: fused.size %d differs from htm.input_size %d", key,
                      msg.header.seq, fused.size, self.cfg.input_size)
            self.count("sdr_wrong_size")
            return
        modalities = {s.modality: s.active for s in msg.modalities} if self.htm.multimodal is not None else None
        before = self.htm.multimodal.rejections if self.htm.multimodal is not None else 0
        if self.htm.dr_gate is not None and self.position is None:
            self.count("frames_without_odometry")
        rejected, kept_out = self.htm.dr_rejections, self.htm.frames_not_stored
        evicted = self.htm.tm.evicted if self.htm.tm is not None else 0
        res = self.htm.step(fused.active, modalities=modalities, position=self.position)
        if self.htm.tm is not None and self.htm.tm.evicted > evicted:
            self.count("tm_segments_evicted", self.htm.tm.evicted - evicted)
        if self.htm.frames_not_stored > kept_out:
            self.count("frames_not_stored")
        if self.htm.dr_rejections > rejected:
            self.count("dr_gate_rejections", self.htm.dr_rejections - rejected)
        self._dirty = True
        if res.is_new:
            self.count("lvc_created")
        if self.htm.multimodal is not None and self.htm.multimodal.rejections > before:
            self.count("multimodal_rejections")
        self.publish("local_view_cells", LocalViewCells(
            header=self.header("local_view_cells", msg.header.stamp, msg.header.frame_id),
            most_active_cell=res.lvc_id,
            active_cells=[LocalViewCell(id=res.lvc_id, rate=min(max(res.rate, 0.0), 1.0))],
            is_new=res.is_new,
            intersection=res.intersection,
        ))

    def _save(self) -> None:
        if self.state_path is not None and self._dirty:
            self.htm.save(self.state_path)
            self._dirty = False
            log.info("htm: saved state to %s (%d LVCs)", self.state_path, len(self.htm.lvc))

    def finish(self) -> None:
        self._save()

    def close(self) -> None:
        self._save()
