"""The RatSLAM local-view baseline's configuration section (``ratslam_lv:``).

Validated at start-up as part of the whole configuration (``system/config.py``); a
wrong value fails naming its dotted field.
"""
from __future__ import annotations

from pydantic import Field

from common.config import ConfigSection

__all__ = ["RatSlamLvConfig"]


class RatSlamLvConfig(ConfigSection):
    """RatSLAM local-view front-end (Table 3.1; values of the dissertation's ratslam_irataus.yaml,
    Section 5.4.2, where it gives them; see services/ratslam_lv/matcher.py for the rest)."""

    image_topic: str = Field("camera/image_raw", description="camera key the templates are made from")
    image_crop_x_min: int = Field(0, ge=0, description="crop: left edge [pixels]")
    image_crop_x_max: int | None = Field(None, ge=1, description="crop: right edge (exclusive); null: image width [pixels]")
    image_crop_y_min: int = Field(120, ge=0, description="crop: top edge (dissertation: 120) [pixels]")
    image_crop_y_max: int | None = Field(None, ge=1, description="crop: bottom edge (exclusive); null: image height [pixels]")
    template_x_size: int = Field(60, ge=1, description="template width [pixels]")
    template_y_size: int = Field(20, ge=1, description="template height [pixels]")
    vt_shift_match: int = Field(5, ge=0, description="horizontal shift range [template pixels]")
    vt_shift_match_y: int = Field(2, ge=0, description="vertical shift range (ours) [template pixels]")
    vt_step_match: int = Field(1, ge=1, description="shift increment [template pixels]")
    vt_match_threshold: float = Field(0.018, gt=0, description="mean absolute difference below which a "
                                      "template matches (dissertation: 0.018) [intensity]")
    vt_normalisation: float = Field(0.4, ge=0, le=1, description="template mean scaled to this; 0: off "
                                    "(dissertation: 0.4) [intensity]")
    vt_patch_normalise: int = Field(3, ge=0, description="patch normalisation radius; 0: off "
                                    "(dissertation: 3) [template pixels]")
    vt_min_overlap: float = Field(0.5, gt=0, le=1, description="a shift is compared only where at least this "
                                  "fraction of the template overlaps [fraction]")
