import json

import pytest
import yaml

from common.config import ConfigError
from system.config import DEFAULT_CONFIG_PATH, PoseidonConfig, load_config
from system.write_defaults import render


def test_defaults_are_table_4_1():
    # the fields whose default is ours (docs/DECISIONS.md "Defaults that are ours") come from the dissertation preset
    from services.htm.presets import DISSERTATION_PRESET
    c = load_config(DISSERTATION_PRESET)
    assert (c.encoder.cnn_backbone, c.encoder.input_size, c.encoder.embedding_norm.mode) == ("shufflenetv2", 224, "none")
    assert c.sync.sync_stale_sec == 0.75
    assert (c.encoder.fusion_mode, c.encoder.cnn_backbone, c.encoder.encoder_mode, c.encoder.lsbh.s) == \
        ("union", "shufflenetv2", "lsbh", 0.25)
    h = c.htm
    assert (h.sp.columns, h.sp.num_active_columns, h.sp.potential_radius) == (2048, 20, 600)
    assert (h.sp.syn_perm_active_inc, h.sp.syn_perm_inactive_dec) == (0.006, 0.008)
    assert (h.tm.cells_per_column, h.tm.activation_threshold) == (40, 5)
    assert (h.tm.permanence_increment, h.tm.permanence_decrement) == (0.008, 0.012)
    assert (h.descriptor.source, h.descriptor.tm_window, h.descriptor.tm_topk, h.lvc.tm_match_threshold) == ("tm", 7, 15, 0.30)
    assert (h.descriptor.interval_mode, h.descriptor.theta_alpha, h.descriptor.theta_rho, h.lvc.match_threshold) == (True, 0.65, 3, 0.38)
    assert (h.lvc.min_intersection, h.lvc.require_multimodal, h.lvc.min_camera_score, h.lvc.min_sonar_score) == \
        (12, False, 0.45, 0.35)
    assert (h.lvc.f1_gate, h.lvc.min_f1, h.lvc.iou_tiebreak, h.descriptor.max_bits) == (True, 0.55, True, 0)
    assert (h.descriptor.tm_bits, h.sp.learn_steps, h.lvc.successor_threshold) == ("cells", 0, 0.0)
    d = load_config()  # our defaults
    assert (d.encoder.cnn_backbone, d.htm.descriptor.source, d.htm.lvc.match_threshold) == \
        ("efficientnet_lite0", "sdr", 0.72)
    assert (c.encoder.sonar.polar_width, c.encoder.sonar.polar_height, c.encoder.sonar.max_range_m,
            c.encoder.sonar.use_intensities) == (224, 224, 30.0, True)
    p = c.posecells
    assert p.number_of_neurons == [15, 15, 15, 8] and p.distance_between_neurons == [0.1, 0.1, 0.1]
    assert (p.top_k, p.min_exc) == (4, 0.03)
    v = c.vpr_guard
    assert (v.require_vpr_for_event, v.vpr_window, v.vpr_min_rep, v.vpr_leak_rate) == (True, 26, 3, 20)
    assert (v.motion_gate_enable, v.min_event_trans_xy, v.min_event_dz) == (True, 0.12, 0.05)
    assert (c.robot_state.axis_remap, c.robot_state.axis_sign_z) == ("yxz", -1.0)
    e = c.expmap
    assert (e.match_threshold, e.lv_factor, e.pc_factor, e.min_experience_age, e.loops.confirmations) == \
        (0.98, 0.5, 0.5, 200, 2)
    assert (e.corrections.min_route_len, e.corrections.max_norm, e.corrections.max_step,
            e.corrections.min_interval_sec) == (250, 20.0, 0.05, 15.0)
    assert (e.image.topic, e.image.transport, e.image.publish_experience, e.image.buffer_size,
            e.image.sync_slop) == ("camera/image_raw", "raw", True, 400, 0.75)


def test_deploy_file_spells_out_every_default():
    assert DEFAULT_CONFIG_PATH.read_text() == render(), "run: python -m system.write_defaults"
    assert load_config(DEFAULT_CONFIG_PATH) == PoseidonConfig()


def test_errors_name_the_file_and_field(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump({"htm": {"sp": {"num_active_columns": "many", "colums": 10}}}))
    with pytest.raises(ConfigError) as err:
        load_config(bad)
    text = str(err.value)
    assert str(bad) in text
    assert "htm.sp.num_active_columns" in text and "htm.sp.colums: unknown field" in text
    with pytest.raises(ConfigError, match="vpr_guard.vpr_window"):
        load_config(overrides=["vpr_guard.vpr_window=0"])
    with pytest.raises(ConfigError, match="not found"):
        load_config(tmp_path / "missing.yaml")
    with pytest.raises(ConfigError, match="key.sub=value"):
        load_config(overrides=["novalue"])


def test_overrides_and_partial_files(tmp_path):
    f = tmp_path / "mine.yaml"
    f.write_text("vpr_guard:\n  require_vpr_for_event: false\n")
    c = load_config(f, ["htm.descriptor.tm_window=9", "bus.connect=[tcp/10.0.0.1:7447]"])
    assert c.vpr_guard.require_vpr_for_event is False and c.vpr_guard.vpr_window == 26
    assert c.htm.descriptor.tm_window == 9 and c.bus.connect == ["tcp/10.0.0.1:7447"]


def test_a_renamed_key_in_a_file_is_refused_naming_the_new_key_and_the_file(tmp_path):
    old = tmp_path / "old.yaml"
    old.write_text(yaml.safe_dump({"htm": {"sp_numActiveColumns": 20, "sv_dr_gate": False},
                                   "live": {"slow_ms": 5}, "encoder": {"embedding_norm": "none"}}))
    with pytest.raises(ConfigError) as err:
        load_config(old)
    text = str(err.value)
    assert str(old) in text
    assert "htm.sp_numActiveColumns was renamed htm.sp.num_active_columns" in text
    assert "htm.sv_dr_gate was renamed htm.dr_gate.enabled" in text
    assert "live.slow_ms was renamed debug.slow_ms" in text
    assert "encoder.embedding_norm was renamed encoder.embedding_norm.mode" in text


def test_a_renamed_key_in_an_override_is_refused_naming_the_new_key():
    with pytest.raises(ConfigError, match=r"(?s)--set htm.sv_seqmem_length=0.*htm.sv_seqmem_length was renamed "
                                          r"htm.seqmem.length"):
        load_config(overrides=["htm.sv_seqmem_length=0"])
    with pytest.raises(ConfigError, match="robot_state.fault_jump_m was renamed debug.fault_jump_m"):
        load_config(overrides=["robot_state={fault_jump_m: [1, 0, 0]}"])
    # the new section of the same name as an old field is no old key
    assert load_config(overrides=["encoder.embedding_norm={mode: none}"]).encoder.embedding_norm.mode == "none"


def test_every_renamed_key_names_a_key_that_exists():
    from common.config import RENAMED_KEYS
    from system.config import FieldDoc, explain_key
    for old, new in RENAMED_KEYS.items():
        assert isinstance(explain_key(new), FieldDoc), (old, new)


def test_a_stored_configuration_of_an_older_version_reads_through_the_rename_table():
    from common.config import migrate_renamed
    old = {"htm": {"sp_columns": 1024, "seed": 7}, "robot_state": {"use_imu": False, "fault_jump_at_s": 3.0},
           "encoder": {"embedding_norm": "none", "lsbh_seed": 5}}
    c = PoseidonConfig.model_validate(migrate_renamed(old))
    assert (c.htm.sp.columns, c.htm.seed, c.robot_state.imu.enabled) == (1024, 7, False)
    assert (c.debug.fault_jump_at_s, c.encoder.embedding_norm.mode, c.encoder.lsbh.seed) == (3.0, "none", 5)
    assert migrate_renamed({"sp_columns": 1024}, "htm.") == {"sp": {"columns": 1024}}


def test_every_field_says_what_it_does_and_carries_no_work_history():
    import re

    from system.config import FieldDoc, SectionDoc, _all_keys, explain_key
    history = re.compile(r"\bissue \d|\bround \d|/" + "work/", re.IGNORECASE)  # split: this file is scanned too
    for key in _all_keys(PoseidonConfig):
        doc = explain_key(key)
        if isinstance(doc, FieldDoc):
            assert doc.description.strip(), f"{key}: no description"
            assert not history.search(doc.description), f"{key}: {doc.description}"
        else:
            assert isinstance(doc, SectionDoc) and doc.description, f"section {key}: no docstring"


def test_explain_a_field_a_section_an_old_key_and_an_unknown_one():
    from system.config import FieldDoc, RenamedDoc, SectionDoc, UnknownKey, explain_key
    f = explain_key("htm.sp.num_active_columns")
    assert isinstance(f, FieldDoc)
    assert (f.type, f.default, f.unit, f.range) == ("int", 800, "columns", ">= 1")
    assert "global inhibition" in f.description and "[" not in f.description
    d = explain_key("robot_state.dvl.velocity_sigma")
    assert isinstance(d, FieldDoc) and (d.unit, d.range) == ("m/s", "> 0")
    s = explain_key("htm.sp")
    assert isinstance(s, SectionDoc) and "htm.sp.columns" in [x.key for x in s.fields]
    assert "htm.seqmem" in explain_key("htm").sections  # type: ignore[union-attr]
    assert explain_key("htm.sp_numActiveColumns") == RenamedDoc("htm.sp_numActiveColumns", "htm.sp.num_active_columns")
    with pytest.raises(UnknownKey) as err:
        explain_key("htm.sp.num_active_colums")
    assert "htm.sp.num_active_columns" in err.value.matches
    with pytest.raises(UnknownKey) as err:
        explain_key("num_active_columns")
    assert err.value.matches == ["htm.sp.num_active_columns"]


def test_updated_applies_dotted_changes_and_validates():
    from services.htm.config import HtmConfig
    h = HtmConfig().updated({"seqmem.exclude": 2, "seed": 3})
    assert (h.seqmem.exclude, h.seed, h.seqmem.length) == (2, 3, HtmConfig().seqmem.length)
    with pytest.raises(ConfigError, match="htm.sp.num_active_columns"):
        HtmConfig().updated({"sp.columns": 16})
    with pytest.raises(ConfigError, match="unknown field"):
        HtmConfig().updated({"sp.colums": 16})


def test_a_recording_of_an_older_version_gives_its_configuration_under_the_new_names():
    from eval.rundata import _config_of_metadata
    old = {"htm": {"sv_seqmem_length": 12}, "expmap": {"loop_scan_matching": False}}
    c = _config_of_metadata("old.mcap", {"config": json.dumps(old)})
    assert c is not None and (c.htm.seqmem.length, c.expmap.loops.scan_matching) == (12, False)
