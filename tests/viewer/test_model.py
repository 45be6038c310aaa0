"""The view's model: the sonar sweep travels as a delta (only the angle bins written since the
version the page holds), the whole sweep to a page that held another model's."""
from __future__ import annotations

import numpy as np

from common.messages import Header, RangeImageBeam
from services.viewer.config import ViewConfig
from services.viewer.model import SONAR_ANGLE_BINS, ViewModel


def _beam(model: ViewModel, i: int, bin_: int) -> None:
    angle = (bin_ + 0.1) * 2 * np.pi / SONAR_ANGLE_BINS
    model.apply("sonar_micron", RangeImageBeam(header=Header(seq=i, stamp=1 + i), angle_grad=0.0, angle_rad=angle,
                                               nbins=8, max_range=10, beam_data=np.arange(8, dtype=np.int32) * i))


def test_a_page_gets_the_sonar_bins_written_since_the_version_it_holds() -> None:
    model = ViewModel(ViewConfig())
    for i, b in enumerate((3, 7, 11)):
        _beam(model, i, b)
    first = model.snapshot({})
    assert first["sonar"]["full"] and sorted(beam[0] for beam in first["sonar"]["beams"]) == [3, 7, 11]
    held = first["sonar_have"]
    assert "sonar" not in model.snapshot({"sonar": held})  # nothing new: no sweep at all
    _beam(model, 3, 7)   # bin 7 written again
    _beam(model, 4, 20)  # a new bin
    later = model.snapshot({"sonar": held})
    assert not later["sonar"]["full"]
    assert sorted(beam[0] for beam in later["sonar"]["beams"]) == [7, 20]


def test_a_page_holding_another_model_s_sweep_gets_all_of_it() -> None:
    old, new = ViewModel(ViewConfig()), ViewModel(ViewConfig())
    for model in (old, new):
        for i, b in enumerate((3, 7)):
            _beam(model, i, b)
    held = old.snapshot({})["sonar_have"]
    assert held != new.snapshot({})["sonar_have"]  # same version, another model
    again = new.snapshot({"sonar": held})
    assert again["sonar"]["full"] and len(again["sonar"]["beams"]) == 2
    ahead = f"{new.ident}.{new.sonar_version + 5}"  # a version this model never had
    assert new.snapshot({"sonar": ahead})["sonar"]["full"]
