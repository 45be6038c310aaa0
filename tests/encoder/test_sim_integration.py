"""EncoderNode on a short simulated mission (camera + Micron sonar), both sonar message forms."""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from common.mcap_io import read_messages
from common.node import run_offline
from services.encoder.encoder import MultimodalEncoder
from system.config import PoseidonConfig
from system.services import build_node

sim = pytest.importorskip("missions.sim.mission")


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("sim") / "short.mcap"
    sim.generate(path, sim.SimParams(minutes=0.1, seed=3), progress=False)
    return path


def test_sim_mission_every_frame_encoded_and_ros_form_identical(recording: Path, tmp_path: Path) -> None:
    base = {"lsbh": {"matrix_path": str(tmp_path / "p_{backbone}_{modality}.npy")}, "pool_grid": 2, "torch_threads": 1}
    outs: dict[str, list[Any]] = {}
    encoder = None
    for topic in ("sonar_micron", "sonar_micron_ros"):
        cfg = PoseidonConfig.model_validate({"encoder": {**base, "sonar": {"topic": topic}}})
        # a fresh encoder per run (the running embedding statistics are state), sharing the backbone
        encoder = MultimodalEncoder(cfg.encoder, backbone=encoder.backbone if encoder else None)
        msgs = [(m.key, m.message()) for m in read_messages(recording, keys=["camera/image_raw", topic])]
        frames = [m for k, m in msgs if k == "camera/image_raw"]
        out: list[Any] = [m for _, m in run_offline(build_node("encoder", cfg, encoder=encoder), msgs)]
        assert [o.header.stamp for o in out] == [f.header.stamp for f in frames]
        # after the first beams, every frame carries both modalities
        assert sum(len(o.modalities) == 2 for o in out) >= len(out) - 1
        outs[topic] = out
    for a, b in zip(outs["sonar_micron"], outs["sonar_micron_ros"]):
        assert all(np.array_equal(x.active, y.active) for x, y in zip(a.modalities, b.modalities))
        assert np.array_equal(a.fused.active, b.fused.active)
