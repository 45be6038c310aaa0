"""The pose cells' configuration sections: the attractor (``posecells:``, Eqs. 4.15-4.19) and the VPR Guard (``vpr_guard:``, Eqs. 4.11-4.14), both run by this service.

Validated at start-up as part of the whole configuration (``system/config.py``); a
wrong value fails naming its dotted field.
"""
from __future__ import annotations

from typing import Annotated

from pydantic import Field, model_validator

from common.config import ConfigSection, check

__all__ = ["PoseCellsConfig", "VprGuardConfig"]


class PoseCellsConfig(ConfigSection):
    """The 4-D pose-cell attractor network (Eqs. 4.15-4.19, services/posecells)."""

    number_of_neurons: list[Annotated[int, Field(ge=1, le=512)]] = Field(
        default_factory=lambda: [15, 15, 15, 8], min_length=4, max_length=4,
        description="cells along x, y, z and yaw (each 1..512) [cells]")
    distance_between_neurons: list[Annotated[float, Field(gt=0, allow_inf_nan=False)]] = Field(
        default_factory=lambda: [0.1, 0.1, 0.1], min_length=3, max_length=3, description="spacing of the cells along x, y, z, each > 0 [m]")
    top_k: int = Field(4, ge=1, description="at most this many LVCs of a local_view_cells message are active "
                       "(V_l = 1 in Eq. 4.19), by rate; the most active one always [LVCs]")
    min_exc: float = Field(0.03, ge=0, description="an LVC other than the most active needs rate >= this to be active [rate]")
    excitation_sigma_cells: float = Field(1.0, gt=0, description="std of the x/y/z excitation kernel (Eq. 4.16) "
                                          "[cells]")
    excitation_sigma_yaw_cells: float = Field(1.0, gt=0, description="std of the yaw excitation kernel (Eq. 4.16) "
                                              "[cells]")
    global_inhibition: float = Field(0.0005, ge=0, description="phi of Eq. 4.17 (activity sums to 1 over the "
                                     "lattice; RatSLAM's 0.00002 left the yaw axis uniform, see services/posecells) [activity]")
    lvc_learning_rate: float = Field(1.0, ge=0, description="lambda of Eq. 4.19")
    lvc_injection_gain: float = Field(0.1, ge=0, description="delta of Eq. 4.19")
    multiple_local_view_active: bool = Field(True, description="up to top_k LVCs of a message inject energy; "
                                             "false: the most active one only")
    # --- the pose-cell service's own parameters (services/posecells/)
    beta_min_fraction: float = Field(0.25, gt=0, le=1, description="Eq. 4.19 beta is stored on the cells with "
                                     "activity >= this fraction of the packet peak (sparse association) [fraction]")
    beta_max_cells: int = Field(64, ge=1, description="at most this many associated cells per LVC (the strongest) [cells]")
    lvc_maturity_steps: int = Field(10, ge=0, description="an LVC's association is injected only after the LVC has "
                                    "been absent this many frames (DolphinSLAM's L_mat; 0: literal Eq. 4.19) [frames]")
    max_odometry_step: float = Field(2.0, gt=0, description="an Odometry increment longer than this is a "
                                     "discontinuity (restarted odometry, later mission), not motion [m]")
    activity_period_s: float = Field(0.5, ge=0, allow_inf_nan=False, description="publish the activity's x-y and "
                                     "z-yaw projections and centroid on posecells/activity at most once per this "
                                     "much event time, after a pose-cell step (0: off) [s]")
    state_path: str = Field("", description="load pose cells, associations and gates from this .npz at start "
                            "and save at end (empty: off)")
    state_new_odometry_frame: bool = Field(False, description="the state loaded from state_path comes from another "
                                           "mission in its own odometry frame (poseidon run --map-dir sets it): its "
                                           "odometry reference and the event gates' memory (last event pose, VPR "
                                           "window) are not restored, so no event of this run carries the other "
                                           "mission's odometry; the activity and the LVC associations are")

    @model_validator(mode="after")
    def _consistent(self) -> PoseCellsConfig:
        cells = 1
        for n in self.number_of_neurons:
            cells *= n
        check(cells <= 50_000_000, f"posecells.number_of_neurons {self.number_of_neurons} is {cells} cells "
               "(at most 50 million)")
        check(self.top_k <= cells, f"posecells.top_k ({self.top_k}) must be <= the number of cells ({cells})")
        return self


class VprGuardConfig(ConfigSection):
    """The VPR Guard: when a frame may become an experience event (Eqs. 4.11-4.14)."""

    require_vpr_for_event: bool = Field(True, description="an event needs a repeated LVC in the window (Eqs. "
                                        "4.11-4.13); false: the motion gate alone")
    vpr_window: int = Field(26, ge=1, description="frames of the LVC repetition window (Eq. 4.11) [frames]")
    vpr_min_rep: int = Field(3, ge=1, description="repetitions of an LVC in the window an event needs (Eq. 4.12) "
                             "[frames]")
    vpr_leak_rate: int = Field(20, ge=0, description="leak of the repetition counts (Eq. 4.13) [frames]")
    motion_gate_enable: bool = Field(True, description="an event also needs motion since the last event (Eq. "
                                     "4.14)")
    min_event_trans_xy: float = Field(0.12, ge=0, description="horizontal motion since the last event that "
                                      "passes the motion gate [m]")
    min_event_dz: float = Field(0.05, ge=0, description="vertical motion since the last event that passes the "
                                "motion gate [m]")
    min_event_dyaw_deg: float = Field(0.0, ge=0, description="a turn of this many degrees since the last event also "
                                      "passes the motion gate (ours; 0: off, the dissertation's gate) [deg]")

    @model_validator(mode="after")
    def _consistent(self) -> VprGuardConfig:
        check(self.vpr_min_rep <= self.vpr_window,
               f"vpr_guard.vpr_min_rep ({self.vpr_min_rep}) must be <= vpr_guard.vpr_window ({self.vpr_window})")
        return self
