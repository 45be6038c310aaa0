"""encoder.runtime: the backbone on ONNX Runtime / OpenVINO gives torch's embedding (torch is the reference)."""
from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

from common.config import ConfigError
from services.encoder.config import EncoderConfig
from services.encoder.encoder import MultimodalEncoder
from services.encoder.runtime import RuntimeUnavailable, export_onnx, make_features
from system.config import load_config

NORDLAND = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "nordland_trimmed"
EXPORTED = ["onnxruntime", "openvino"]
REL_TOL = 1e-4  # relative L2 difference of an embedding from torch's (measured ~1e-6)


def _need(runtime: str) -> None:
    if importlib.util.find_spec(runtime) is None:
        pytest.skip(f"{runtime} is not installed (pip install -e . installs it)")


def _images() -> list[np.ndarray]:
    """Random noise, a float image, a grey one and smooth 'scenes' (gradients, blobs, an edge)."""
    rng = np.random.default_rng(5)
    out: list[np.ndarray] = [rng.integers(0, 256, (288, 384, 3), dtype=np.uint8),
                             rng.random((224, 224, 3), dtype=np.float32),
                             rng.integers(0, 256, (120, 160), dtype=np.uint8)]
    yy, xx = np.mgrid[0:288, 0:384].astype(np.float32)
    for k in range(3):
        img = np.stack([(xx / 384) * (k + 1) % 1.0, yy / 288, 0.5 + 0.5 * np.sin(xx / (20 + 10 * k))], axis=2)
        for _ in range(6):  # dark rocks on a bright wall
            cy, cx, r = rng.uniform(0, 288), rng.uniform(0, 384), rng.uniform(10, 60)
            img[(yy - cy) ** 2 + (xx - cx) ** 2 < r * r] *= 0.3
        img[:, : 384 // (k + 2)] *= 0.6
        out.append((img * 255).astype(np.uint8))
    return out


def _rel(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


@pytest.fixture(scope="module")
def reference() -> MultimodalEncoder:
    return MultimodalEncoder(EncoderConfig(runtime="torch", lsbh={"matrix_path": ""}, embedding_norm={"mode": "none"}))


@pytest.mark.parametrize("runtime", EXPORTED)
def test_runtime_gives_torchs_embedding_and_sdr(runtime: str, reference: MultimodalEncoder) -> None:
    _need(runtime)
    enc = MultimodalEncoder(EncoderConfig(runtime=runtime, precision="f32", lsbh={"matrix_path": ""}, embedding_norm={"mode": "none"}))
    assert enc.runtime == runtime and reference.runtime == "torch"
    imgs = _images()
    want, got = reference.embed(imgs), enc.embed(imgs)
    assert len(got) == len(imgs)
    for i, (a, b) in enumerate(zip(got, want)):
        assert a.dtype == np.float32 and a.shape == b.shape == (1792,)
        assert _rel(a, b) < REL_TOL, (i, _rel(a, b))
        assert np.array_equal(enc.sdr("camera", a), reference.sdr("camera", b)), i
    # a batch (encoder.batch_max) is the images one by one
    one_by_one = [enc.embed([im])[0] for im in imgs[:3]]
    assert all(np.array_equal(x, y) for x, y in zip(one_by_one, got[:3]))


@pytest.mark.parametrize("runtime", EXPORTED)
def test_runtime_changes_the_embedding_when_the_image_changes(runtime: str) -> None:
    """Not a constant: the exported graph runs on its input (a stale or zero graph would pass equality on one image)."""
    _need(runtime)
    enc = MultimodalEncoder(EncoderConfig(runtime=runtime, lsbh={"matrix_path": ""}, embedding_norm={"mode": "none"}))
    a, b = enc.embed(_images()[3:5])
    assert _rel(a, b) > 0.05


@pytest.mark.parametrize("runtime", EXPORTED)
@pytest.mark.parametrize("backbone,size", [("shufflenetv2", 224), ("alexnet_conv3", 160),
                                           ("efficientnet_lite0", 128)])
def test_other_backbones_and_sizes(runtime: str, backbone: str, size: int) -> None:
    _need(runtime)
    cfg = dict(cnn_backbone=backbone, input_size=size, untrained=True, lsbh={"matrix_path": ""},
               embedding_norm={"mode": "none"})
    ref = MultimodalEncoder(EncoderConfig(**cfg, runtime="torch"))
    enc = MultimodalEncoder(EncoderConfig(**cfg, runtime=runtime, precision="f32"))
    imgs = _images()[::2]
    for a, b in zip(enc.embed(imgs), ref.embed(imgs)):
        assert a.shape == b.shape == (ref.dim,)
        assert _rel(a, b) < REL_TOL


@pytest.mark.skipif(not (NORDLAND / "summer").is_dir(), reason=f"real images absent: {NORDLAND}")
@pytest.mark.parametrize("runtime", EXPORTED)
def test_runtime_on_real_images(runtime: str, reference: MultimodalEncoder) -> None:
    from PIL import Image

    _need(runtime)
    enc = MultimodalEncoder(EncoderConfig(runtime=runtime, precision="f32", lsbh={"matrix_path": ""}, embedding_norm={"mode": "none"}))
    names = sorted(p.name for p in (NORDLAND / "summer").glob("*.png"))[400:1000:60]
    imgs = [np.asarray(Image.open(NORDLAND / s / n).convert("RGB")) for n in names for s in ("summer", "winter")]
    for a, b in zip(enc.embed(imgs), reference.embed(imgs)):
        assert _rel(a, b) < REL_TOL
        assert np.array_equal(enc.sdr("camera", a), reference.sdr("camera", b))


def test_export_is_deterministic_and_one_image() -> None:
    pytest.importorskip("onnx", reason="onnx is not installed (pip install -e . installs it)")
    import onnx

    enc = MultimodalEncoder(EncoderConfig(runtime="torch", lsbh={"matrix_path": ""}, embedding_norm={"mode": "none"}))
    data = export_onnx(enc.backbone, 160)
    assert data == export_onnx(enc.backbone, 160)
    graph = onnx.load_from_string(data).graph
    dims = [d.dim_value for d in graph.input[0].type.tensor_type.shape.dim]
    assert dims == [1, 3, 160, 160]
    assert not any(n.op_type == "BatchNormalization" for n in graph.node)  # exported after folding


def test_missing_runtime_package_is_a_clear_error(monkeypatch: pytest.MonkeyPatch) -> None:
    for name in EXPORTED:
        monkeypatch.setitem(sys.modules, name, None)  # import fails as if not installed
        with pytest.raises(RuntimeUnavailable, match=f"encoder.runtime {name}.*not installed"):
            MultimodalEncoder(EncoderConfig(input_size=32, runtime=name, lsbh={"matrix_path": ""}))


def test_runtime_field_is_validated(tmp_path: Path) -> None:
    assert EncoderConfig().runtime == "openvino"  # the default: docs/DECISIONS.md, encoder.runtime
    assert load_config(overrides=["encoder.runtime=onnxruntime"]).encoder.runtime == "onnxruntime"
    with pytest.raises(ConfigError, match="encoder.runtime"):
        load_config(overrides=["encoder.runtime=tensorrt"])


def test_precision_field_is_validated_and_applies_to_openvino_only() -> None:
    assert EncoderConfig().precision == "bf16"  # the default: docs/DECISIONS.md, encoder.precision
    assert load_config(overrides=["encoder.precision=f32"]).encoder.precision == "f32"
    with pytest.raises(ConfigError, match="encoder.precision"):
        load_config(overrides=["encoder.precision=int8"])
    enc = MultimodalEncoder(EncoderConfig(input_size=32, runtime="onnxruntime", lsbh={"matrix_path": ""}))
    assert enc.precision == "f32"  # bf16 (the default) does not apply to onnxruntime
    with pytest.raises(ValueError, match="bf16 runs on openvino only"):
        make_features(enc.backbone, "onnxruntime", 32, 1, "bf16")


def test_bf16_openvino_stays_close_to_torch(reference: MultimodalEncoder) -> None:
    """encoder.precision bf16: the plugin computes in bfloat16 where the CPU has it (else f32);
    either way the embedding stays within a few % of torch's and the SDR keeps most bits."""
    _need("openvino")
    enc = MultimodalEncoder(EncoderConfig(precision="bf16", lsbh={"matrix_path": ""}, embedding_norm={"mode": "none"}))
    assert enc.runtime == "openvino" and enc.precision == "bf16"
    torch_rt = MultimodalEncoder(EncoderConfig(precision="bf16", lsbh={"matrix_path": ""}, embedding_norm={"mode": "none"}),
                                 runtime="torch")
    assert torch_rt.precision == "f32"  # a runtime override away from openvino runs f32
    import openvino as ov

    has_bf16 = "BF16" in ov.Core().get_property("CPU", "OPTIMIZATION_CAPABILITIES")
    imgs = _images()[3:]
    for i, (a, b) in enumerate(zip(enc.embed(imgs), reference.embed(imgs))):
        assert _rel(a, b) < 0.1, (i, _rel(a, b))
        if has_bf16:  # bf16 really ran (f32 is within ~1e-6)
            assert _rel(a, b) > 1e-3, (i, _rel(a, b))
        sa, sb = enc.sdr("camera", a), reference.sdr("camera", b)
        assert len(np.intersect1d(sa, sb)) >= 0.85 * len(sb), i
