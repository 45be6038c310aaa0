"""``poseidon config``: --explain prints a key's documentation, a section's fields, a renamed
key's new name; an unknown key is exit 2 naming close matches; --show prints the effective
configuration."""
from __future__ import annotations

import pytest
import yaml

from launcher.cli import main


def test_explain_a_field_prints_its_name_description_type_default_unit_and_range(capsys):
    assert main(["config", "--explain", "htm.sp.num_active_columns"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("htm.sp.num_active_columns\n")
    for line in ("type:    int", "default: 800", "unit:    columns", "range:   >= 1", "global inhibition"):
        assert line in out


def test_explain_a_section_lists_its_fields(capsys):
    assert main(["config", "--explain", "expmap.loops"]) == 0
    out = capsys.readouterr().out
    assert "expmap.loops.confirmations = 2" in out and "expmap.loops.place_radius_m = 0.0 [m]" in out


def test_explain_an_old_key_says_it_was_renamed_and_to_what(capsys):
    assert main(["config", "--explain", "htm.sp_numActiveColumns"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("htm.sp_numActiveColumns was renamed htm.sp.num_active_columns")


def test_explain_an_unknown_key_is_exit_2_naming_close_matches(capsys):
    assert main(["config", "--explain", "htm.seqmem.lenght"]) == 2
    err = capsys.readouterr().err
    assert "htm.seqmem.lenght" in err and "htm.seqmem.length" in err


def test_show_prints_the_effective_configuration(tmp_path, capsys):
    f = tmp_path / "mine.yaml"
    f.write_text("htm:\n  seqmem:\n    length: 7\n")
    assert main(["config", "--show", "--config", str(f), "--set", "debug.slow_ms=5"]) == 0
    shown = yaml.safe_load(capsys.readouterr().out)
    assert shown["htm"]["seqmem"]["length"] == 7 and shown["debug"]["slow_ms"] == 5.0
    assert shown["expmap"]["loops"]["scan_matching"] is True


@pytest.mark.parametrize("override", ["htm.sv_seqmem_length=7", "expmap.loop_scan_matching=false"])
def test_show_refuses_an_old_key_naming_the_new_one(override, capsys):
    assert main(["config", "--show", "--set", override]) == 2
    assert "was renamed" in capsys.readouterr().err
