"""Backbones: torchvision-named state dicts round-trip, clear errors, seeded init, hub cache."""
from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest
import torch

from services.encoder.backbones import (
    AlexNetConv3,
    EfficientNetLite0,
    ShuffleNetV2,
    WeightsError,
    build_backbone,
    hub_checkpoint,
    load_backbone,
)
from services.encoder.config import EncoderConfig
from services.encoder.encoder import MultimodalEncoder

# a few names of torchvision's shufflenet_v2_x1_0 / alexnet state dicts
TORCHVISION_SHUFFLENET_KEYS = [
    "conv1.0.weight", "conv1.1.running_var", "stage2.0.branch1.0.weight", "stage2.0.branch1.2.weight",
    "stage2.0.branch2.3.weight", "stage2.1.branch2.6.num_batches_tracked", "stage3.7.branch2.5.weight",
    "stage4.0.branch1.3.bias", "conv5.0.weight", "conv5.1.running_mean", "fc.weight", "fc.bias",
]


def _perturbed(model: torch.nn.Module, seed: int) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    sd = {}
    for k, v in model.state_dict().items():
        if v.is_floating_point():
            noise = torch.rand(v.shape, generator=g) if "running_var" in k else torch.randn(v.shape, generator=g)
            sd[k] = noise * 0.5 + (1.0 if "running_var" in k else 0.0)
        else:
            sd[k] = v.clone()
    return sd


def test_shufflenet_has_torchvision_names_and_size() -> None:
    m = ShuffleNetV2()
    keys = m.state_dict().keys()
    for k in TORCHVISION_SHUFFLENET_KEYS:
        assert k in keys
    assert sum(p.numel() for p in m.parameters()) == 2_278_604  # torchvision shufflenet_v2_x1_0
    x = torch.zeros(1, 3, 224, 224)
    assert m.eval().features(x).shape == (1, 232, 14, 14)
    assert AlexNetConv3().eval()(x).shape == (1, 384, 13, 13)


def test_weights_round_trip_shufflenet(tmp_path: Path) -> None:
    a = build_backbone("shufflenetv2")
    assert isinstance(a, ShuffleNetV2)
    a.load_state_dict(_perturbed(a, 1))
    path = tmp_path / "shufflenetv2_x1-deadbeef.pth"
    torch.save(a.state_dict(), path)
    b = load_backbone("shufflenetv2", str(path))
    assert b.trained and b.weights == str(path)
    x = torch.randn(2, 3, 224, 224, generator=torch.Generator().manual_seed(0))
    with torch.inference_mode():
        assert torch.equal(a.eval()(x), b.model(x))
        assert torch.equal(a.features(x), b.features(x))


def test_weights_round_trip_full_alexnet_state_dict(tmp_path: Path) -> None:
    a = AlexNetConv3()
    sd = _perturbed(a, 2)
    # a full torchvision AlexNet also has conv4, conv5 and the classifier: accepted and dropped
    sd["features.8.weight"] = torch.zeros(256, 384, 3, 3)
    sd["features.10.bias"] = torch.zeros(256)
    sd["classifier.6.weight"] = torch.zeros(10, 4096)
    path = tmp_path / "alexnet-owt-0000.pth"
    torch.save(sd, path)
    b = load_backbone("alexnet_conv3", str(path))
    a.load_state_dict({k: v for k, v in sd.items() if k in a.state_dict()})
    x = torch.randn(1, 3, 224, 224, generator=torch.Generator().manual_seed(0))
    with torch.inference_mode():
        assert torch.equal(a.eval()(x), b.model(x))


def test_incompatible_and_missing_weights_give_clear_errors(tmp_path: Path) -> None:
    alex = tmp_path / "alexnet.pth"
    torch.save(AlexNetConv3().state_dict(), alex)
    with pytest.raises(WeightsError) as err:
        load_backbone("shufflenetv2", str(alex))
    msg = str(err.value)
    assert str(alex) in msg and "missing keys" in msg and "conv1.0.weight" in msg
    assert "unexpected keys" in msg and "features.0.weight" in msg
    sd = ShuffleNetV2().state_dict()
    sd["fc.weight"] = torch.zeros(10, 1024)
    sd["fc.bias"] = torch.zeros(10)
    bad = tmp_path / "shuffle10.pth"
    torch.save(sd, bad)
    with pytest.raises(WeightsError, match=r"shape mismatches.*fc\.(bias|weight)"):
        load_backbone("shufflenetv2", str(bad))
    with pytest.raises(WeightsError, match="weights file not found: .*nope.pth"):
        load_backbone("shufflenetv2", str(tmp_path / "nope.pth"))
    junk = tmp_path / "junk.pth"
    junk.write_bytes(b"not a torch file")
    with pytest.raises(WeightsError, match="junk.pth is not a readable"):
        load_backbone("alexnet_conv3", str(junk))
    with pytest.raises(ValueError, match="unknown backbone 'vgg'"):
        load_backbone("vgg")


def test_seeded_init_is_deterministic_and_warns(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture) -> None:
    monkeypatch.setenv("TORCH_HOME", str(tmp_path / "empty_hub"))
    torch.manual_seed(123)
    before = torch.rand(1)
    torch.manual_seed(123)
    with caplog.at_level(logging.WARNING):
        a = load_backbone("shufflenetv2", seed=42, untrained=True)
    assert "UNTRAINED" in caplog.text
    assert torch.equal(torch.rand(1), before)  # global RNG untouched
    b = load_backbone("shufflenetv2", seed=42, untrained=True)
    c = load_backbone("shufflenetv2", seed=7, untrained=True)
    assert a.weights == "seeded" and not a.trained
    sa, sb, sc = a.model.state_dict(), b.model.state_dict(), c.model.state_dict()
    assert all(torch.equal(sa[k], sb[k]) for k in sa)
    assert not torch.equal(sa["conv1.0.weight"], sc["conv1.0.weight"])


def test_missing_weights_is_an_error_saying_how_to_fix(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("TORCH_HOME", str(tmp_path / "empty_hub"))
    with pytest.raises(WeightsError, match=r"no weights for backbone shufflenetv2.*weights_path.*untrained: true"):
        load_backbone("shufflenetv2")
    with pytest.raises(WeightsError, match="choose one"):
        load_backbone("shufflenetv2", str(tmp_path / "x.pth"), untrained=True)
    # a wrong file for the packaged backbone names the keys and the fix
    alex = tmp_path / "alex.pth"
    torch.save(AlexNetConv3().state_dict(), alex)
    with pytest.raises(WeightsError, match=r"(?s)missing keys.*_blocks.*fix: install the weights package"):
        load_backbone("efficientnet_lite0", str(alex))


def test_hub_cache_is_used(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    ckpt = tmp_path / "hub" / "checkpoints"
    ckpt.mkdir(parents=True)
    monkeypatch.setenv("TORCH_HOME", str(tmp_path))
    assert hub_checkpoint("alexnet_conv3") is None
    a = AlexNetConv3()
    a.load_state_dict(_perturbed(a, 5))
    torch.save(a.state_dict(), ckpt / "alexnet-owt-7be5be79.pth")
    assert hub_checkpoint("alexnet_conv3") == ckpt / "alexnet-owt-7be5be79.pth"
    b = load_backbone("alexnet_conv3")
    assert b.trained and b.weights.endswith("alexnet-owt-7be5be79.pth")
    assert isinstance(b.model, AlexNetConv3)
    conv_b, conv_a = b.model.features[0], a.features[0]
    assert isinstance(conv_b, torch.nn.Conv2d) and isinstance(conv_a, torch.nn.Conv2d)
    assert torch.equal(conv_b.weight, conv_a.weight)


def test_encoder_embedding_dims_and_batching(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("TORCH_HOME", str(tmp_path))
    cfg = EncoderConfig(batch_max=3, pool_grid=2, torch_threads=1, cnn_backbone="shufflenetv2", untrained=True, lsbh={"matrix_path": str(tmp_path / "p_{backbone}_{modality}.npy")}, embedding_norm={"path": str(tmp_path / "n_{backbone}_{modality}.npz")})
    enc = MultimodalEncoder(cfg)
    rng = np.random.default_rng(0)
    imgs = [rng.integers(0, 256, (48, 64, 3), dtype=np.uint8) for _ in range(5)]
    ys = enc.encode_camera(imgs)
    assert len(ys) == 5 and ys[0].shape == (232 * 4,) and enc.dim == 928
    single = enc.encode_camera(imgs[4:5])[0]
    np.testing.assert_allclose(ys[4], single, rtol=1e-4, atol=1e-5)
    bits = enc.sdr("camera", ys[0])
    assert bits.size == 2 * (cfg.sp_columns // 2 // 4)
    assert (tmp_path / "p_shufflenetv2_camera.npy").exists()
    grey = enc.encode_camera([rng.random((300, 400)).astype(np.float32)])[0]
    assert grey.shape == (928,)
    with pytest.raises(ValueError, match="shape"):
        enc.encode_camera([np.zeros((4, 4, 2))])
    alex = MultimodalEncoder(cfg.model_copy(update={"cnn_backbone": "alexnet_conv3"}))
    assert alex.encode_camera(imgs[:1])[0].shape == (384 * 4,)


@pytest.mark.parametrize("name", ["efficientnet_lite0", "shufflenetv2", "alexnet_conv3"])
def test_fold_batchnorm_keeps_the_function_and_removes_every_batch_norm(name: str) -> None:
    from services.encoder.backbones import fold_batchnorm
    model = build_backbone(name)
    model.load_state_dict(_perturbed(model, 3))  # non-trivial running statistics and affine terms
    model.eval()
    folded = fold_batchnorm(model)
    assert not any(isinstance(m, torch.nn.BatchNorm2d) for m in folded.modules())
    assert any(isinstance(m, torch.nn.BatchNorm2d) for m in model.modules()) == (name != "alexnet_conv3")
    x = torch.randn(2, 3, 96, 96, generator=torch.Generator().manual_seed(0))
    def feats(m: torch.nn.Module) -> torch.Tensor:
        if name != "alexnet_conv3":
            assert isinstance(m, (ShuffleNetV2, EfficientNetLite0))
            return m.features(x)
        out: torch.Tensor = m(x)
        return out

    with torch.inference_mode():
        a, b = feats(model), feats(folded)
    scale = float(a.abs().max())
    assert scale > 0
    assert float((a - b).abs().max()) <= 1e-4 * scale
    # the original is untouched
    assert any(isinstance(m, torch.nn.BatchNorm2d) for m in model.modules()) == (name != "alexnet_conv3")


def test_encoder_folds_batch_norm_by_default_with_the_same_embedding() -> None:
    cfg = EncoderConfig(untrained=True)
    rng = np.random.default_rng(1)
    frames = [rng.integers(0, 255, (72, 96, 3), dtype=np.uint8) for _ in range(3)]
    folded = MultimodalEncoder(cfg)
    eager = MultimodalEncoder(cfg.model_copy(update={"fold_batchnorm": False}))
    assert not any(isinstance(m, torch.nn.BatchNorm2d) for m in folded.model.modules())
    assert any(isinstance(m, torch.nn.BatchNorm2d) for m in eager.model.modules())
    a, b = np.stack(eager.embed(frames)), np.stack(folded.embed(frames))
    assert np.abs(a - b).max() <= 1e-4 * np.abs(a).max()
