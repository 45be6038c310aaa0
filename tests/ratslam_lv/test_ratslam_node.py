"""The ratslam_lv service: one local_view_cells per frame, offline and through the launcher."""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from common.mcap_io import RecordingWriter, read_messages
from common.messages import Header, Image, LocalViewCells
from common.node import run_offline
from services.ratslam_lv.node import RatSlamViewNode
from system.config import load_config
from system.services import available_services, build_node, node_class

T0 = 1_700_000_000_000_000_000
NS = 1_000_000_000


def _scene(seed: int, h: int = 288, w: int = 384) -> np.ndarray:
    rng = np.random.default_rng(seed)
    img = np.kron(rng.random((h // 8 + 1, w // 8 + 1)), np.ones((8, 8)))[:h, :w]
    return np.repeat((img * 255).astype(np.uint8)[..., None], 3, axis=2)


def _frames(scenes: list[int], key: str = "camera/image_raw") -> list[tuple[str, Image]]:
    out = []
    for k, s in enumerate(scenes):
        img = _scene(s) if s >= 0 else np.zeros((8, 8, 3), np.uint8)  # -1: a frame too small for the crop
        out.append((key, Image(header=Header(seq=k, stamp=T0 + k * NS // 5, frame_id="camera"),
                               height=img.shape[0], width=img.shape[1], encoding="rgb8", data=img)))
    return out


def test_one_message_per_frame_with_the_frame_header() -> None:
    node = build_node("ratslam_lv", load_config())
    frames = _frames([1, 2, 1, 3, 2])
    out = run_offline(node, frames)
    assert [k for k, _ in out] == ["local_view_cells"] * 5
    msgs: list[Any] = [m for _, m in out]
    assert all(isinstance(m, LocalViewCells) for m in msgs)
    assert [m.most_active_cell for m in msgs] == [0, 1, 0, 2, 1]
    assert [m.is_new for m in msgs] == [True, True, False, True, False]
    assert [m.header.stamp for m in msgs] == [f.header.stamp for _, f in frames]
    assert [m.header.seq for m in msgs] == [0, 1, 2, 3, 4] and {m.header.frame_id for m in msgs} == {"camera"}
    for m in msgs:
        assert len(m.active_cells) == 1 and m.active_cells[0].id == m.most_active_cell
        assert 0.0 <= m.active_cells[0].rate <= 1.0 and m.intersection == 0
    assert msgs[2].active_cells[0].rate == 1.0  # exact revisit: difference 0
    assert node.counters == {"templates_created": 3, "templates_matched": 2}


def test_unusable_frame_is_counted_and_skipped() -> None:
    node = build_node("ratslam_lv", load_config())
    out = run_offline(node, _frames([1, -1, 1]))
    lvcs: list[Any] = [m for _, m in out]
    assert [m.most_active_cell for m in lvcs] == [0, 0]
    assert node.counters["frame_rejected"] == 1


def test_image_topic_is_configurable() -> None:
    cfg = load_config(overrides=["ratslam_lv.image_topic=camera/left"])
    assert RatSlamViewNode.io_keys(cfg.ratslam_lv) == (("camera/left",), ("local_view_cells",))
    node = build_node("ratslam_lv", cfg)
    assert len(run_offline(node, _frames([1, 2], key="camera/left"))) == 2


def test_registered_as_an_optional_front_end() -> None:
    assert node_class("ratslam_lv") is RatSlamViewNode
    assert "ratslam_lv" not in available_services()  # never started beside htm by default


@pytest.mark.timeout(300)
def test_poseidon_run_with_services_ratslam_lv(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``poseidon run --services ratslam_lv`` replaces the neocortical front-end end to end."""
    from launcher.cli import main

    rec = tmp_path / "cam.mcap"
    with RecordingWriter(rec) as w:
        for key, img in _frames([1, 2, 1, 2, 3]):
            w.write(key, img)
    out = tmp_path / "run.mcap"
    assert main(["run", "--input", str(rec), "--out", str(out), "--services", "ratslam_lv", "--embedded",
                 "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert set(summary["services"]) == {"player", "recorder", "ratslam_lv"}  # no encoder, no htm
    assert summary["services"]["ratslam_lv"]["counters"] == {"templates_created": 3, "templates_matched": 2}
    lvc: list[Any] = [r.message() for r in read_messages(out, keys=["local_view_cells"])]
    assert [m.most_active_cell for m in lvc] == [0, 1, 0, 1, 2]
