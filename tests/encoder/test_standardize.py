"""Embedding standardisation before LSBH: cross-place overlap, determinism, freezing, persistence."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from services.encoder.config import EncoderConfig
from services.encoder.lsbh import LsbhEncoder, make_projection
from services.encoder.standardize import EmbeddingStandardizer, StandardizerError, norm_path
from system.services import build_node

D, L = 256, 512


def places(n_places: int = 40, frames: int = 3, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Post-ReLU-like embeddings: a large common component + a place pattern + frame noise."""
    rng = np.random.default_rng(seed)
    common = 5.0 + rng.random(D) * 3.0
    pattern = rng.standard_normal((n_places, D))
    y = [common + pattern[p] + 0.3 * rng.standard_normal(D) for p in range(n_places) for _ in range(frames)]
    return np.maximum(np.array(y), 0.0), np.repeat(np.arange(n_places), frames)


def overlap(a: np.ndarray, b: np.ndarray) -> float:
    return np.intersect1d(a, b).size / a.size


def mean_overlaps(sdrs: list[np.ndarray], place: np.ndarray) -> tuple[float, float]:
    same: list[float] = []
    diff: list[float] = []
    for i in range(len(sdrs)):
        for j in range(i + 1, len(sdrs)):
            (same if place[i] == place[j] else diff).append(overlap(sdrs[i], sdrs[j]))
    return float(np.mean(same)), float(np.mean(diff))


@pytest.fixture(scope="module")
def lsbh() -> LsbhEncoder:
    return LsbhEncoder(make_projection(D, L // 2, 42, "camera"), L, 0.25)


def test_standardisation_lowers_cross_place_overlap(lsbh: LsbhEncoder) -> None:
    y, place = places()
    raw = [lsbh.encode(v) for v in y]
    st = EmbeddingStandardizer(D, "running", warmup=30, scale=False)
    std = [lsbh.encode(st.transform(v)) for v in y]
    same_raw, diff_raw = mean_overlaps(raw, place)
    # after the warm-up, only frames standardised with the frozen statistics
    same_std, diff_std = mean_overlaps(std[30:], place[30:])
    assert diff_raw > 0.6  # the common component dominates P^T y: different places share most bits
    assert 0.2 < diff_std < 0.32  # independent SDRs share s = 25 %
    assert same_std > diff_std + 0.3  # the same place still overlaps strongly
    # fitted statistics (fixed mode), with scaling, do the same
    fx = EmbeddingStandardizer.fitted(y, scale=True)
    z = fx.transform_batch(y)
    np.testing.assert_allclose(z.mean(axis=0), 0.0, atol=1e-9)
    np.testing.assert_allclose(z.std(axis=0), 1.0, rtol=1e-6)
    assert fx.mode == "fixed" and fx.count == len(y)
    _, diff_fix = mean_overlaps([lsbh.encode(v) for v in z], place)
    assert 0.2 < diff_fix < 0.32


def test_running_warmup_freezes_and_is_deterministic() -> None:
    y, _ = places(10, 2, seed=1)
    a = EmbeddingStandardizer(D, "running", warmup=5)
    b = EmbeddingStandardizer(D, "running", warmup=5)
    za = a.transform_batch(y)
    zb = b.transform_batch(y)
    assert np.array_equal(za, zb)
    assert np.array_equal(za[0], y[0])  # the first frame has no statistics yet
    np.testing.assert_allclose(za[1], y[1] - y[0])  # centred by the frames before it; sigma 1 until two frames
    assert a.frozen and a.count == 5
    np.testing.assert_allclose(a.mean, y[:5].mean(axis=0))
    np.testing.assert_allclose(a.sigma, np.maximum(y[:5].std(axis=0), 1e-3 * y[:5].std(axis=0).mean()))
    mean = a.mean.copy()
    a.transform(y[7])
    assert np.array_equal(a.mean, mean)  # frozen: later frames do not move the statistics
    # the same later frame gives the same z every time (a revisit keeps its SDR)
    assert np.array_equal(a.transform(y[12]), a.transform(y[12]))
    # with a rate the mean follows slowly
    c = EmbeddingStandardizer(D, "running", warmup=5, rate=0.1)
    c.transform_batch(y[:5])
    m5 = c.mean.copy()
    c.transform(y[6])
    np.testing.assert_allclose(c.mean, m5 + 0.1 * (y[6] - m5))
    # default centres only; scale=True also divides by sigma
    np.testing.assert_allclose(a.transform(y[8]), y[8] - a.mean)
    s = EmbeddingStandardizer(D, "running", warmup=5, scale=True)
    s.transform_batch(y[:5])
    np.testing.assert_allclose(s.transform(y[8]), (y[8] - a.mean) / a.sigma)
    # none is the identity (Eq. 4.2 exactly)
    assert np.array_equal(EmbeddingStandardizer(D, "none").transform(y[3]), y[3])


def test_statistics_persist_and_reload(tmp_path: Path) -> None:
    y, _ = places(10, 2, seed=2)
    path = norm_path(str(tmp_path / "n_{backbone}_{modality}.npz"), "shufflenetv2", "camera")
    assert path.name == "n_shufflenetv2_camera.npz"
    a = EmbeddingStandardizer(D, "running", warmup=6, path=path)
    a.transform_batch(y[:5])
    assert not path.exists()
    a.transform(y[5])  # the warm-up completes: saved
    assert path.exists()
    b = EmbeddingStandardizer(D, "running", warmup=6, path=path)
    assert b.frozen and b.count == 6
    assert np.array_equal(a.transform_batch(y[6:]), b.transform_batch(y[6:]))
    # fixed mode loads the same file
    f = EmbeddingStandardizer(D, "fixed", path=path)
    assert np.array_equal(f.transform(y[9]), a.transform(y[9]))
    with pytest.raises(StandardizerError, match="for 256 dimensions, the encoder has 100"):
        EmbeddingStandardizer(100, "running", path=path)
    with pytest.raises(StandardizerError, match="fixed needs fitted statistics"):
        EmbeddingStandardizer(D, "fixed", path=tmp_path / "absent.npz")
    with pytest.raises(StandardizerError, match="embedding_norm.warmup"):
        EmbeddingStandardizer(D, "running", warmup=0)
    with pytest.raises(StandardizerError, match="expects 256"):
        a.transform(np.zeros(3))


def test_encoder_node_saves_statistics_on_finish(tmp_path: Path) -> None:
    from common.messages import Header, Image
    from common.node import run_offline
    from services.encoder.encoder import MultimodalEncoder
    from system.config import PoseidonConfig

    enc = {"lsbh": {"matrix_path": str(tmp_path / "p_{backbone}_{modality}.npy")}, "sp_columns": 256, "pool_grid": 1,
           "torch_threads": 1,
           "embedding_norm": {"warmup": 100, "path": str(tmp_path / "n_{backbone}_{modality}.npz")}}
    cfg = PoseidonConfig.model_validate({"encoder": enc})
    rng = np.random.default_rng(0)
    msgs = [("camera/image_raw", Image(header=Header(seq=i, stamp=i * 200_000_000, frame_id="cam"), height=16,
                                       width=16, encoding="rgb8",
                                       data=rng.integers(0, 256, (16, 16, 3), dtype=np.uint8)))
            for i in range(4)]
    out = run_offline(build_node("encoder", cfg, encoder=MultimodalEncoder(cfg.encoder)), msgs)
    assert len(out) == 4
    st = EmbeddingStandardizer(112, "running", warmup=100, path=tmp_path / "n_efficientnet_lite0_camera.npz")
    assert st.count == 4 and not st.frozen  # mid warm-up state saved at the end, continued next time
    assert EncoderConfig().embedding_norm.mode == "running" and EncoderConfig().torch_threads == 1


def test_standardize_sequence_gives_the_held_frames_the_statistics_of_the_hold(tmp_path: Path) -> None:
    from services.encoder.encoder import MultimodalEncoder

    base = {"lsbh": {"matrix_path": str(tmp_path / "p_{backbone}_{modality}.npy")}, "sp_columns": 256, "pool_grid": 1,
            "torch_threads": 1}
    held = MultimodalEncoder(EncoderConfig.model_validate({**base, "embedding_norm": {"warmup": 20, "hold": 4}}))
    plain = MultimodalEncoder(EncoderConfig.model_validate({**base, "embedding_norm": {"warmup": 20, "hold": 0}}),
                              backbone=held.backbone)
    y = np.random.default_rng(3).random((8, held.dim)) + 5.0
    zh = held.standardize_sequence("camera", list(y))
    zp = plain.standardize_sequence("camera", list(y))
    for i in range(4):                     # held: centred by the mean of the four held frames
        np.testing.assert_allclose(zh[i], y[i] - y[:4].mean(axis=0))
    np.testing.assert_allclose(zp[0], y[0])   # unheld: the first frame has no statistics
    for i in range(4, 8):                  # afterwards both centre by the frames before
        np.testing.assert_allclose(zh[i], zp[i])
        np.testing.assert_allclose(zh[i], y[i] - y[:i].mean(axis=0))



def test_the_hold_ends_inside_the_replay_flow_window() -> None:
    from system.config import PoseidonConfig

    cfg = PoseidonConfig.model_validate({"encoder": {"lsbh": {"matrix_path": ""}, "embedding_norm": {"hold_max_s": 5.0},
                                                     "pool_grid": 1, "sp_columns": 256}})
    node = build_node("encoder", cfg)
    assert node.core.hold == 10 and node.core.hold_max_ns == 2_000_000_000   # 3 s window - 1 s
    cfg.bus.flow_window_ms = 200
    assert build_node("encoder", cfg).core.hold == 0                         # no room for a hold
