"""EncoderNode through common.node.run_offline with small synthetic camera and sonar streams."""
from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import pytest

from common.messages import Header, Image, Message, NeocortexSdr, RangeImageBeam
from common.node import run_offline
from services.encoder.encoder import MultimodalEncoder
from services.encoder.node import EncoderNode
from system.config import PoseidonConfig
from system.services import build_node

S = 1_000_000_000


@pytest.fixture(scope="module")
def config(tmp_path_factory: pytest.TempPathFactory) -> PoseidonConfig:
    tmp = tmp_path_factory.mktemp("enc")
    return PoseidonConfig.model_validate({"encoder": {
        "lsbh": {"matrix_path": str(tmp / "lsbh_{backbone}_{modality}.npy")}, "sp_columns": 256, "pool_grid": 2,
        "sonar": {"polar_width": 64, "polar_height": 64}, "embedding_norm": {"path": ""},
        "torch_threads": 1}})  # one thread: robust when the CI shares the cores


@pytest.fixture(scope="module")
def encoder(config: PoseidonConfig) -> MultimodalEncoder:
    return MultimodalEncoder(config.encoder)


def frame(t: float, seq: int) -> Image:
    rng = np.random.default_rng(int(t * 10) // 20)  # the scene changes every 2 s
    data = rng.integers(0, 256, (24, 32, 3), dtype=np.uint8)
    return Image(header=Header(seq=seq, stamp=int(round(t * S)), frame_id="cam"), height=24, width=32,
                 encoding="rgb8", data=data)


def ping(t: float, seq: int) -> RangeImageBeam:
    angle = (seq * math.radians(9.0)) % (2 * math.pi)  # 40 beams per 360 deg sweep
    data = np.zeros(100, dtype=np.int32)
    data[(seq * 7) % 100] = 180
    return RangeImageBeam(header=Header(seq=seq, stamp=int(round(t * S)), frame_id="sonar"),
                          angle_grad=math.degrees(angle), angle_rad=angle, nbins=100, max_range=30, beam_data=data)


def stream(cam_gaps: Sequence[tuple[float, float]] = (), sonar_gaps: Sequence[tuple[float, float]] = (),
           duration: float = 12.0) -> list[tuple[str, Message]]:
    """Camera 5 Hz, sonar 20 Hz (a 360 deg sweep every 2 s), each silent inside its gaps."""
    msgs: list[tuple[str, Message]] = []
    def inside(t: float, gaps: Sequence[tuple[float, float]]) -> bool:
        return any(a <= t < b for a, b in gaps)
    seq = 0
    for i in range(int(duration * 5)):
        t = i / 5
        if not inside(t, cam_gaps):
            msgs.append(("camera/image_raw", frame(t, seq)))
            seq += 1
    seq = 0
    for i in range(int(duration * 20)):
        t = i / 20 + 0.01
        if not inside(t, sonar_gaps):
            msgs.append(("sonar_micron", ping(t, seq)))
            seq += 1
    return msgs


def run(config: PoseidonConfig, encoder: MultimodalEncoder, mode: str = "union",
        **kw: Any) -> tuple[EncoderNode, list[NeocortexSdr]]:
    cfg = config.model_copy(update={"encoder": config.encoder.model_copy(update={"fusion_mode": mode})})
    # a fresh encoder per run (the running embedding statistics are state), sharing the backbone
    node = build_node("encoder", cfg, encoder=MultimodalEncoder(cfg.encoder, backbone=encoder.backbone))
    out = run_offline(node, stream(**kw))
    sdrs: list[NeocortexSdr] = []
    for k, m in out:
        assert k == "neocortex/sdr" and isinstance(m, NeocortexSdr)
        sdrs.append(m)
    return node, sdrs


def check_sdr(msg: NeocortexSdr, config: PoseidonConfig) -> None:
    k = config.encoder.sp_columns // 2 // 4
    mods = {s.modality: s.active for s in msg.modalities}
    for bits in mods.values():
        assert bits.dtype == np.uint32 and bits.size == 2 * k and np.all(np.diff(bits.astype(int)) > 0)
    expected = np.unique(np.concatenate(list(mods.values()))) if msg.fusion_mode == "union" else None
    if expected is not None:
        assert np.array_equal(msg.fused.active, expected)
    assert msg.fused.size == config.encoder.sp_columns
    assert msg.fused.header.stamp == msg.header.stamp


def test_one_output_per_frame_with_both_modalities(config: PoseidonConfig, encoder: MultimodalEncoder) -> None:
    node, out = run(config, encoder, duration=4.0)
    cams = [m for k, m in stream(duration=4.0) if k == "camera/image_raw"]
    assert [o.header.stamp for o in out] == [c.header.stamp for c in cams]
    assert [o.header.seq for o in out] == list(range(len(out)))
    assert out[0].header.frame_id == "cam"
    # first frame at t=0 precedes the first beam: camera only; afterwards both
    assert [s.modality for s in out[0].modalities] == ["camera"]
    assert all([s.modality for s in o.modalities] == ["camera", "sonar"] for o in out[1:])
    for o in out:
        check_sdr(o, config)
    # deterministic: same input, same output
    _, again = run(config, encoder, duration=4.0)
    assert all(np.array_equal(a.fused.active, b.fused.active) for a, b in zip(out, again))


def test_sonar_dropout_still_yields_camera_sdrs(config: PoseidonConfig, encoder: MultimodalEncoder) -> None:
    node, out = run(config, encoder, sonar_gaps=[(4.0, 8.0)], duration=10.0)
    assert len(out) == 50
    for o in out:
        t = o.header.stamp / S
        names = [s.modality for s in o.modalities]
        if 4.8 <= t < 8.0:
            assert names == ["camera"]
        elif t >= 8.2:
            assert names == ["camera", "sonar"]
        check_sdr(o, config)
    assert node.counters["sonar_ring_reset"] == 1


def test_camera_dropout_switches_to_sonar_sweep_clock(config: PoseidonConfig, encoder: MultimodalEncoder) -> None:
    node, out = run(config, encoder, cam_gaps=[(4.0, 10.0)], duration=12.0)
    sonar_only = [o for o in out if [s.modality for s in o.modalities] == ["sonar"]]
    stamps = [o.header.stamp / S for o in sonar_only]
    # last frame at 3.8 s; a 360 deg sweep takes 2 s -> sonar-clocked outputs about every 2 s
    assert 2 <= len(sonar_only) <= 3 and all(4.0 < t < 10.0 for t in stamps)
    assert np.all(np.diff([o.header.stamp for o in out]) > 0)
    for o in sonar_only:
        assert np.array_equal(o.fused.active, o.modalities[0].active)
        check_sdr(o, config)
    assert sum(1 for o in out if o.header.stamp / S >= 10.0) == 10  # frames resume the clock
    assert node.counters["sonar_clocked_outputs"] == len(sonar_only)


def test_single_modality_and_and_modes(config: PoseidonConfig, encoder: MultimodalEncoder) -> None:
    _, cam = run(config, encoder, mode="camera", duration=3.0)
    assert len(cam) == 15 and all([s.modality for s in o.modalities] == ["camera"] for o in cam)
    assert all(np.array_equal(o.fused.active, o.modalities[0].active) for o in cam)
    node, son = run(config, encoder, mode="sonar", duration=7.0)
    assert len(son) == 3 and node.counters["camera_frames_unused"] == 35
    assert all(o.header.frame_id == "sonar" for o in son)
    _, both = run(config, encoder, mode="and", duration=2.0)
    for o in both[1:]:
        a, b = (s.active for s in o.modalities)
        assert np.array_equal(o.fused.active, np.intersect1d(a, b))


def test_sonar_topic_from_config(config: PoseidonConfig, encoder: MultimodalEncoder) -> None:
    cfg = config.model_copy(update={"encoder": config.encoder.updated({"sonar.topic": "sonar_seaking"})})
    node = build_node("encoder", cfg, encoder=encoder)
    assert node.inputs == ("camera/image_raw", "sonar_seaking")
    out = run_offline(node, [("sonar_seaking", ping(0.0, 0)), ("camera/image_raw", frame(0.1, 0))])
    first = out[0][1]
    assert isinstance(first, NeocortexSdr) and [s.modality for s in first.modalities] == ["camera", "sonar"]


def test_image_to_rgb_encodings() -> None:
    from services.encoder.images import image_to_rgb
    rgb = np.arange(2 * 3 * 3, dtype=np.uint8).reshape(2, 3, 3)
    h = Header(seq=0, stamp=0)
    assert np.array_equal(image_to_rgb(Image(header=h, height=2, width=3, encoding="rgb8", data=rgb)), rgb)
    bgr = Image(header=h, height=2, width=3, encoding="bgr8", data=rgb[:, :, ::-1].copy())
    assert np.array_equal(image_to_rgb(bgr), rgb)
    mono = image_to_rgb(Image(header=h, height=2, width=3, encoding="mono16",
                              data=np.full((2, 3), 65535, dtype=np.uint16)))
    assert mono.shape == (2, 3, 3) and mono.dtype == np.float32 and np.all(mono == 1.0)
    with pytest.raises(ValueError, match="Image seq 0: data shape"):
        image_to_rgb(Image.model_construct(header=h, height=3, width=3, encoding="rgb8", data=rgb))


def test_warns_when_htm_map_persists_but_embedding_statistics_do_not(config: PoseidonConfig, encoder: MultimodalEncoder, caplog: pytest.LogCaptureFixture) -> None:
    cfg = config.model_copy(update={"htm": config.htm.model_copy(update={"state_path": "state/htm.npz"})})
    with caplog.at_level("WARNING", logger="services.encoder.node"):
        node = build_node("encoder", cfg, encoder=encoder)
    assert node.counters["embedding_norm_not_persisted"] == 1 and "embedding_norm.path" in caplog.text
    assert "embedding_norm_not_persisted" not in build_node("encoder", config, encoder=encoder).counters


def test_sonar_is_re_encoded_after_enough_sweep(config: PoseidonConfig, encoder: MultimodalEncoder) -> None:
    """45 deg rule: at 180 deg/s of sweep and 5 camera frames/s (36 deg per frame) the sonar raster goes
    through the CNN about every 2nd frame, the SDR in between is the last one; 0 deg: every frame."""
    node, out = run(config, encoder, duration=4.0)
    with_sonar = [o for o in out if any(s.modality == "sonar" for s in o.modalities)]
    enc = node.counters["sonar_encodings"]
    assert enc + node.counters["sonar_sdr_reused"] == len(with_sonar) == 19
    assert 8 <= enc <= 11
    sonar = [next(s.active for s in o.modalities if s.modality == "sonar") for o in with_sonar]
    assert sum(np.array_equal(a, b) for a, b in zip(sonar, sonar[1:])) >= node.counters["sonar_sdr_reused"]
    every = config.model_copy(update={"encoder": config.encoder.updated({"sonar.encode_sweep_deg": 0.0})})
    node0, out0 = run(every, encoder, duration=4.0)
    assert node0.counters["sonar_encodings"] == 19 and "sonar_sdr_reused" not in node0.counters


def test_warm_up_hold_delays_the_first_outputs_then_matches_the_unheld_stream(
        config: PoseidonConfig, encoder: MultimodalEncoder) -> None:
    def drive(hold: int) -> tuple[list[tuple[int, int, int]], list[NeocortexSdr], EncoderNode]:
        cfg = config.model_copy(update={"encoder": config.encoder.updated({"embedding_norm.hold": hold})})
        node = build_node("encoder", cfg, encoder=MultimodalEncoder(cfg.encoder, backbone=encoder.backbone))
        assert isinstance(node, EncoderNode)
        msgs = sorted(stream(duration=4.0), key=lambda km: (km[1].header.stamp, km[0] != "camera/image_raw"))
        trace, out = [], []
        for k, m in msgs:
            node.process(k, m)
            got = [o for _, o in node.take_outbox()]
            out += got
            if k == "camera/image_raw":
                trace.append((m.header.stamp, len(got), node.output_watermark(m.header.stamp)))
        node.finish()
        out += [o for _, o in node.take_outbox()]
        return trace, out, node

    trace, held, node = drive(10)
    _, plain, _ = drive(0)
    first = trace[0][0]
    released = next(i for i, (_, n, _) in enumerate(trace) if n)
    assert released == 9                                   # ten camera embeddings first
    assert all(wm == first for _, _, wm in trace[:released])   # the watermark waits at the oldest held frame
    assert trace[released][1] == released + 1 and trace[released][2] == trace[released][0]
    assert [o.header.stamp for o in held] == [o.header.stamp for o in plain]
    assert [o.header.seq for o in held] == list(range(len(held)))
    n = released + 1
    assert node.counters["outputs_held"] == n
    assert not np.array_equal(held[0].fused.active, plain[0].fused.active)   # re-hashed with ten frames' mean
    for a, b in zip(held[n:], plain[n:]):                  # afterwards the same statistics, the same SDRs
        assert np.array_equal(a.fused.active, b.fused.active)
    for o in held:
        check_sdr(o, config)


def test_the_end_of_the_inputs_releases_a_hold_that_never_filled(config: PoseidonConfig,
                                                                   encoder: MultimodalEncoder) -> None:
    node, out = run(config, encoder, duration=1.0)         # 5 frames < the hold of 10
    assert len(out) == 5 and node.counters["outputs_held"] == 5
