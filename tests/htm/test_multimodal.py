"""htm.lvc.require_multimodal (Table 4.1): per-modality validation of an accepted LVC match."""
import numpy as np

from common.messages import Header, NeocortexSdr, Sdr
from common.node import run_offline
from services.htm.config import HtmConfig
from services.htm.pipeline import NeocortexHtm
from system.config import PoseidonConfig
from system.services import build_node

L = 2048


def _cfg(require: bool) -> HtmConfig:
    # descriptor = the fused SDR itself, so the LVC decision depends only on the bits given
    return HtmConfig(descriptor={"source": "sdr", "interval_mode": False}, lvc={"require_multimodal": require})


def _sets():
    rng = np.random.default_rng(11)
    cam_a = np.sort(rng.choice(L, 200, replace=False))
    cam_b = np.sort(rng.choice(L, 200, replace=False))  # another camera view, ~10% overlap with cam_a
    sonar = np.sort(rng.choice(L, 200, replace=False))
    return cam_a, cam_b, sonar


def test_match_needs_every_shared_modality_to_agree():
    cam_a, cam_b, sonar = _sets()
    fused = np.union1d(cam_a, sonar)
    for require, expected in ((False, [0, 0, 0, 0]), (True, [0, 1, 0, 0])):
        h = NeocortexHtm(_cfg(require))
        ids = [h.step(fused, modalities={"camera": cam_a, "sonar": sonar}).lvc_id,
               # same fused bits, but the camera saw something else: vetoed when required
               h.step(fused, modalities={"camera": cam_b, "sonar": sonar}).lvc_id,
               # camera missing: only the sonar is checked, and it agrees
               h.step(fused, modalities={"sonar": sonar}).lvc_id,
               # no per-modality evidence at all: nothing to check
               h.step(fused).lvc_id]
        assert ids == expected, (require, ids)
    assert h.multimodal.rejections == 1


def test_modality_prototypes_survive_save_and_load(tmp_path):
    cam_a, cam_b, sonar = _sets()
    fused = np.union1d(cam_a, sonar)
    h = NeocortexHtm(_cfg(True))
    h.step(fused, modalities={"camera": cam_a, "sonar": sonar})
    h.save(tmp_path / "s.npz")
    g = NeocortexHtm.load(tmp_path / "s.npz", _cfg(True))
    assert g.step(fused, modalities={"camera": cam_b, "sonar": sonar}).is_new
    assert g.step(fused, modalities={"camera": cam_a}).lvc_id == 0


def test_node_counts_multimodal_rejections():
    cam_a, cam_b, sonar = _sets()
    msgs = []
    for i, cam in enumerate((cam_a, cam_b)):
        h = Header(seq=i, stamp=10 + i, frame_id="cam")
        mods = [Sdr(header=h, modality="camera", size=L, active=cam.astype(np.uint32)),
                Sdr(header=h, modality="sonar", size=L, active=sonar.astype(np.uint32))]
        fused = Sdr(header=h, modality="fused", size=L, active=np.union1d(cam_a, sonar).astype(np.uint32))
        msgs.append(("neocortex/sdr", NeocortexSdr(header=h, modalities=mods, fused=fused, fusion_mode="union")))
    node = build_node("htm", PoseidonConfig(htm=_cfg(True)))
    out = run_offline(node, msgs)
    assert [m.most_active_cell for _, m in out] == [0, 1]
    # no Odometry in this stream: the dead-reckoning gate checks nothing and says so
    assert node.counters == {"lvc_created": 2, "multimodal_rejections": 1, "frames_without_odometry": 2}
