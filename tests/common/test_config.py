import pytest
import yaml

from common.config import ConfigError
from system.config import DEFAULT_CONFIG_PATH, PoseidonConfig, load_config
from system.write_defaults import render


def test_defaults_are_table_4_1():
    # the fields whose default is ours (docs/DECISIONS.md "Defaults that are ours") come from the dissertation preset
    from services.htm.presets import DISSERTATION_PRESET
    c = load_config(DISSERTATION_PRESET)
    assert (c.encoder.cnn_backbone, c.encoder.input_size, c.encoder.embedding_norm) == ("shufflenetv2", 224, "none")
    assert c.sync.sync_stale_sec == 0.75
    assert (c.encoder.fusion_mode, c.encoder.cnn_backbone, c.encoder.encoder_mode, c.encoder.lsbh_s) == \
        ("union", "shufflenetv2", "lsbh", 0.25)
    h = c.htm
    assert (h.sp_columns, h.sp_numActiveColumns, h.sp_potentialRadius) == (2048, 20, 600)
    assert (h.sp_synPermActiveInc, h.sp_synPermInactiveDec) == (0.006, 0.008)
    assert (h.tm_cellsPerColumn, h.tm_activationThreshold) == (40, 5)
    assert (h.tm_permanenceIncrement, h.tm_permanenceDecrement) == (0.008, 0.012)
    assert (h.sv_descriptor_source, h.sv_tm_window, h.sv_tm_topk, h.sv_tm_match_threshold) == ("tm", 7, 15, 0.30)
    assert (h.interval_mode, h.theta_alpha, h.theta_rho, h.sv_match_threshold) == (True, 0.65, 3, 0.38)
    assert (h.sv_min_intersection, h.sv_require_multimodal, h.sv_min_img_score, h.sv_min_sonar_score) == \
        (12, False, 0.45, 0.35)
    assert (h.sv_enable_f1_gate, h.min_f1, h.sv_use_iou_tiebreak, h.max_bits) == (True, 0.55, True, 0)
    assert (h.sv_tm_bits, h.sp_learn_steps, h.sv_seq_match_threshold) == ("cells", 0, 0.0)
    d = load_config()  # our defaults
    assert (d.encoder.cnn_backbone, d.htm.sv_descriptor_source, d.htm.sv_match_threshold) == \
        ("efficientnet_lite0", "sdr", 0.72)
    assert (c.encoder.sonar_polar_width, c.encoder.sonar_polar_height, c.encoder.sonar_rmax,
            c.encoder.sonar_use_intensities) == (224, 224, 30.0, True)
    p = c.posecells
    assert p.number_of_neurons == [15, 15, 15, 8] and p.distance_between_neurons == [0.1, 0.1, 0.1]
    assert (p.top_k, p.min_exc) == (4, 0.03)
    v = c.vpr_guard
    assert (v.require_vpr_for_event, v.vpr_window, v.vpr_min_rep, v.vpr_leak_rate) == (True, 26, 3, 20)
    assert (v.motion_gate_enable, v.min_event_trans_xy, v.min_event_dz) == (True, 0.12, 0.05)
    assert (c.robot_state.axis_remap, c.robot_state.axis_sign_z) == ("yxz", -1.0)
    e = c.expmap
    assert (e.match_threshold, e.lv_factor, e.pc_factor, e.min_experience_age, e.loop_confirmations) == \
        (0.98, 0.5, 0.5, 200, 2)
    assert (e.min_correction_route_len, e.max_correction_norm, e.max_correction_step,
            e.min_correction_interval_sec) == (250, 20.0, 0.05, 15.0)
    assert (e.image_topic, e.image_transport, e.publish_experience_image, e.image_buffer_size,
            e.image_sync_slop) == ("camera/image_raw", "raw", True, 400, 0.75)


def test_deploy_file_spells_out_every_default():
    assert DEFAULT_CONFIG_PATH.read_text() == render(), "run: python -m system.write_defaults"
    assert load_config(DEFAULT_CONFIG_PATH) == PoseidonConfig()


def test_errors_name_the_file_and_field(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump({"htm": {"sp_numActiveColumns": "many", "sp_colums": 10}}))
    with pytest.raises(ConfigError) as err:
        load_config(bad)
    text = str(err.value)
    assert str(bad) in text
    assert "htm.sp_numActiveColumns" in text and "htm.sp_colums: unknown field" in text
    with pytest.raises(ConfigError, match="vpr_guard.vpr_window"):
        load_config(overrides=["vpr_guard.vpr_window=0"])
    with pytest.raises(ConfigError, match="not found"):
        load_config(tmp_path / "missing.yaml")
    with pytest.raises(ConfigError, match="key.sub=value"):
        load_config(overrides=["novalue"])


def test_overrides_and_partial_files(tmp_path):
    f = tmp_path / "mine.yaml"
    f.write_text("vpr_guard:\n  require_vpr_for_event: false\n")
    c = load_config(f, ["htm.sv_tm_window=9", "bus.connect=[tcp/10.0.0.1:7447]"])
    assert c.vpr_guard.require_vpr_for_event is False and c.vpr_guard.vpr_window == 26
    assert c.htm.sv_tm_window == 9 and c.bus.connect == ["tcp/10.0.0.1:7447"]
