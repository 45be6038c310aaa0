"""Named front-end chains (issue 17): htm overrides that ``poseidon vpr`` runs beside the configured default.

- ``sdr_seqmem`` -- the chain that is the default today: the fused SDR is the descriptor (no SP,
  no TM: ``sp_columns_used`` 0), Eq. 4.9 gates at 0.72, the place-sequence prior and the
  SeqSLAM-like sequence memory (:mod:`services.htm.sequence`).
- ``sp_tm`` -- the neocortical chain: a spatial pooler that keeps the place (4096 columns, 800
  active, potential pool over the whole input, inhibition on each column's overlap
  standardised by its own running mean and deviation over the first 1000 frames, then
  frozen; no boosting), its active columns are the descriptor (gates 0.66 / prior 0.62, chosen
  on the seed-1234 and seed-77 missions); the temporal memory runs over the 40 most strongly
  driven active columns and its predictions decide a revisit (:mod:`services.htm.tm_match`,
  share >= 0.2) before the sequence memory, which stays (without it the chain recognises
  almost nothing on Nordland).  Measured (README, "Defaults that are ours"): it does not beat
  ``sdr_seqmem`` on the missions, so it is an option, not the default.

- ``sdr_seqmem_f1`` -- ``sdr_seqmem`` with a sequence match that needs less margin (1.25) but the
  frame's own F1 with the stored frame j* >= 0.68 (``htm.sv_seqmem_min_f1``, a fixed constant),
  and a sequence match may override an Eq. 4.9 match to an id the current pass created in its
  last 50 frames (``htm.sv_seqmem_override``).  Chosen on seeds 1234, 77, 2101-2105; the fixed
  F1 floor rejects every cross-season match (Nordland AP ~0): a mission-only chain.
- ``sdr_seqmem_cal`` -- the same with a *self-calibrated* F1 check in place of the constant
  (``htm.sv_seqmem_f1_quantile`` 0.2 of the F1 of the traversal's confident sequence matches,
  margin >= 1.75; :mod:`services.htm.calibrate`), sequence margin 1.5.

``chain_config(htm_cfg, name)`` returns the configured ``HtmConfig`` with the chain's overrides.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from services.htm.config import HtmConfig

__all__ = ["CHAINS", "chain_config"]

CHAINS: dict[str, dict[str, Any]] = {
    "sdr_seqmem": {"sv_descriptor_source": "sdr", "sv_tm_decide": False, "sp_overlap_norm_steps": 0,
                   "tm_input_columns": 0, "sv_match_threshold": 0.72, "min_f1": 0.72,
                   "sv_seq_match_threshold": 0.68},
    "sp_tm": {"sv_descriptor_source": "sp", "sv_tm_decide": True, "sp_columns": 4096,
              "sp_potentialRadius": 2048, "sp_numActiveColumns": 800, "sp_overlap_norm_steps": 1000,
              "sp_boostStrength": 0.0, "tm_input_columns": 40, "tm_cellsPerColumn": 16,
              "tm_maxNewSynapseCount": 16, "tm_activationThreshold": 4, "tm_minThreshold": 3,
              "sv_tm_share": 0.2, "sv_match_threshold": 0.66, "min_f1": 0.66, "sv_seq_match_threshold": 0.62},
    "sdr_seqmem_f1": {"sv_descriptor_source": "sdr", "sv_tm_decide": False, "sp_overlap_norm_steps": 0,
                      "tm_input_columns": 0, "sv_match_threshold": 0.72, "min_f1": 0.72,
                      "sv_seq_match_threshold": 0.68, "sv_seqmem_override": True, "sv_seqmem_margin": 1.25,
                      "sv_seqmem_min_f1": 0.68, "sv_seqmem_f1_quantile": 0.0},
    "sdr_seqmem_cal": {"sv_descriptor_source": "sdr", "sv_tm_decide": False, "sp_overlap_norm_steps": 0,
                       "tm_input_columns": 0, "sv_match_threshold": 0.72, "min_f1": 0.72,
                       "sv_seq_match_threshold": 0.68, "sv_seqmem_override": True, "sv_seqmem_margin": 1.5,
                       "sv_seqmem_min_f1": 0.0, "sv_seqmem_f1_quantile": 0.2, "sv_seqmem_confident_margin": 1.75,
                       "sv_seqmem_calib_warmup": 20},
}


def chain_config(htm_cfg: HtmConfig, name: str) -> HtmConfig:
    """``htm_cfg`` (an ``HtmConfig``) with the overrides of chain ``name``."""
    if name not in CHAINS:
        raise ValueError(f"unknown front-end chain {name!r}; known: {sorted(CHAINS)}")
    return htm_cfg.model_copy(update=CHAINS[name])
