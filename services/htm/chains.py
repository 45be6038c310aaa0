"""Named front-end chains: htm overrides that ``poseidon vpr`` runs beside the configured default.

The default (``htm`` section as shipped): the fused SDR is the descriptor of the Eq. 4.9 gates
(0.72) and the sequence memory; a spatial pooler (4096 columns, 800 active, potential pool over
the whole input, inhibition on standardised overlaps, no boosting) feeds its 20 most strongly
driven columns to a temporal memory whose correct predictions decide a revisit
(:mod:`services.htm.tm_match`, share >= ``tm.decide_share``), before the sequence memory; every
revisit claim must pass the dead-reckoning gate (:mod:`services.htm.geometry`), which lets the
sequence memory decide at margin 0.75 / score 1.0.  Each chain below is the default with one
part changed, so the rows say what each part adds:

- ``sdr_seqmem`` -- the fused-SDR chain: no SP, no TM, no dead-reckoning
  gate, sequence margin 1.75 / score 1.5 (``sp_columns_used`` 0).
- ``no_tm`` -- the default without the TM's decisions (and so without the SP).
- ``no_dr_gate`` -- the default without the dead-reckoning gate (the appearance-only chain).
- ``no_seqmem`` -- the default without the sequence memory (and so without the gate, which keeps
  its stored frames): Eq. 4.9, the TM and the place-sequence prior only.
- ``sp_tm`` -- the SP's active columns are the descriptor (gates 0.66, prior 0.62), the rest as
  the default.
- ``sdr_seqmem_f1`` / ``sdr_seqmem_cal`` -- ``sdr_seqmem`` whose sequence match also checks the
  frame's own F1 with j*: a constant 0.68 (margin 1.25), or self-calibrated (0.2-quantile of the
  traversal's confident matches, margin 1.5; :mod:`services.htm.calibrate`); both let a sequence
  match override an Eq. 4.9 id the pass created in its last 50 frames.
- ``new_places`` -- the default whose sequence memory and TM frame index keep only the frames that
  are no revisit of an older place (``seqmem.store``): the cost per frame then
  grows with the places seen, not with the mission's length.

``chain_config(htm_cfg, name)`` returns the configured ``HtmConfig`` with the chain's overrides.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from services.htm.config import HtmConfig

__all__ = ["CHAINS", "chain_config"]

_SDR_SEQMEM: dict[str, Any] = {"descriptor.source": "sdr", "tm.decide": False, "dr_gate.enabled": False,
                               "lvc.match_threshold": 0.72, "lvc.min_f1": 0.72, "lvc.successor_threshold": 0.68,
                               "seqmem.margin": 1.75, "seqmem.threshold": 1.5}

#: chain name -> changes to the ``htm`` section (dotted field -> value)
CHAINS: dict[str, dict[str, Any]] = {
    "sdr_seqmem": _SDR_SEQMEM,
    "no_tm": {"tm.decide": False},
    "no_dr_gate": {"dr_gate.enabled": False},
    "no_seqmem": {"seqmem.length": 0, "dr_gate.enabled": False},
    "sp_tm": {"descriptor.source": "sp", "lvc.match_threshold": 0.66, "lvc.min_f1": 0.66,
              "lvc.successor_threshold": 0.62},
    "sdr_seqmem_f1": {**_SDR_SEQMEM, "seqmem.override": True, "seqmem.margin": 1.25, "seqmem.min_f1": 0.68,
                      "seqmem.f1_quantile": 0.0},
    "sdr_seqmem_cal": {**_SDR_SEQMEM, "seqmem.override": True, "seqmem.margin": 1.5, "seqmem.min_f1": 0.0,
                       "seqmem.f1_quantile": 0.2, "seqmem.confident_margin": 1.75, "seqmem.calib_warmup": 20},
    "new_places": {"seqmem.store": "new_places"},
}


def chain_config(htm_cfg: HtmConfig, name: str) -> HtmConfig:
    """``htm_cfg`` (an ``HtmConfig``) with the overrides of chain ``name``."""
    if name not in CHAINS:
        raise ValueError(f"unknown front-end chain {name!r}; known: {sorted(CHAINS)}")
    return htm_cfg.updated(CHAINS[name])
