"""``poseidon vpr --mission``: one MCAP recording through :class:`EncoderNode` (camera and
sonar in event order), then the matchers and :class:`NeocortexHtm` over its frames against
the true revisits (:mod:`eval.vpr` states the definitions and the JSON keys)."""
from __future__ import annotations

import json
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypedDict

import numpy as np
from tqdm import tqdm

from common.messages import Image, Odometry, RevisitTruth
from eval.baselines import SEQ_LENGTH, patch_normalise, sad_similarity, sequence_similarity
from eval.results import LvcRevisitScores, LvcScores, MatcherMetrics, MissionScores, ModalityScores
from eval.vpr_htm import DECISION_KINDS, _htm_row, decision_kind, run_length_stats
from eval.vpr_metrics import VprInputError, cosine_similarity, overlap_similarity, overlap_stats, vpr_metrics
from system.services import build_node

if TYPE_CHECKING:
    from services.encoder.config import EncoderConfig
    from services.htm.config import HtmConfig
    from system.config import PoseidonConfig


def _travelled(stamps: np.ndarray, pose_stamps: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """Distance travelled (m) along the true trajectory at each of ``stamps``."""
    seg = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(positions, axis=0), axis=1))]
    return np.interp(stamps.astype(np.float64), pose_stamps.astype(np.float64), seg)


def lvc_revisit_scores(ids: np.ndarray, gt: Sequence[Sequence[int]], eligible: np.ndarray) -> LvcRevisitScores:
    """LVC-id recall and precision on a mission (see the module doc, ``--mission``), by the one
    definition of :func:`eval.frontend.lvc_revisit_metrics`.  ``eligible[i]`` is a prefix of
    the earlier frames (those at least the revisit gap of travel back)."""
    from eval.frontend import lvc_pair_metrics, lvc_revisit_metrics
    before = np.asarray(eligible, bool).sum(axis=1)
    m = lvc_revisit_metrics(ids, gt, eligible_before=before)
    pm = lvc_pair_metrics(ids, gt, eligible_before=before)
    return {"lvc_recall": m["recall"] or 0.0, "lvc_precision": m["precision"] or 0.0,
            "n_revisit_frames": m["revisit_frames"], "n_claimed_revisits": m["claimed"],
            "n_correct_claims": m["correct_claims"],
            "lvc_pair_precision": pm["pair_precision"] or 0.0, "lvc_pair_recall": pm["pair_recall"] or 0.0}


@dataclass
class MissionStreams:
    """What the encoder made of one mission, per camera frame (input of :func:`score_mission`)."""

    y: np.ndarray                 # camera embeddings (n, d)
    z: np.ndarray                 # standardised camera embeddings (n, d)
    thumbs: np.ndarray            # patch-normalised 32x16 grey thumbnails (n, 512)
    sdrs: dict[str, list[np.ndarray]]  # "camera", "sonar" (empty when absent), "fused" active bits per frame
    gt: list[list[int]]
    eligible: np.ndarray          # (n, n) bool: j is a candidate earlier frame of i
    min_gap_m: float
    counters: dict[str, int]
    weights: str
    dim: int
    fusion_mode: str
    seconds_embed: float
    dr_positions: list[np.ndarray | None] | None = None   # robot_state's position at each frame (m; None: none yet)


def run_mission(path: str | Path, cfg: PoseidonConfig, enc_cfg: EncoderConfig, min_gap_m: float | None,
                use_htm: bool, chains: Sequence[str] = ()) -> MissionScores:
    """The front-end (EncoderNode, then NeocortexHtm storing LVCs online) over one MCAP mission.

    Returns the figures of the ``--mission`` JSON (see the module doc); ``chains`` names the
    chains of :mod:`services.htm.chains` also run on the fused stream.
    """
    return score_mission(encode_mission(path, cfg, enc_cfg, min_gap_m), cfg, enc_cfg, use_htm, chains)


def _revisit_gap(path: Path, min_gap_m: float | None) -> float:
    """``min_gap_m``, or the recording's ``params.revisit_min_gap_m`` when None; checks that the
    recording has the channels ``--mission`` needs."""
    from common.mcap_io import RecordingError, read_metadata, recording_keys

    try:
        keys = recording_keys(path)
    except RecordingError as exc:
        raise VprInputError(str(exc)) from None
    for k in ("camera/image_raw", "truth/revisits", "truth/pose"):
        if k not in keys:
            raise VprInputError(f"{path}: no {k!r} channel (needed by --mission; a `poseidon sim` recording has it)")
    if min_gap_m is None:
        meta = read_metadata(path).get("poseidon", {})
        try:
            if "params" not in meta and "source_metadata" in meta:  # poseidon transform: the source's record
                meta = json.loads(meta["source_metadata"])
            params = meta["params"]
            min_gap_m = float((json.loads(params) if isinstance(params, str) else params)["revisit_min_gap_m"])
        except (KeyError, ValueError, TypeError) as exc:
            raise VprInputError(f"{path}: no params.revisit_min_gap_m in the 'poseidon' metadata ({exc}); "
                                f"pass --min-gap-m") from None
    return min_gap_m


def _camera_recorder(enc_cfg: Any) -> Any:
    """A :class:`MultimodalEncoder` that also keeps (y, z, bits) of every camera frame in ``camera``."""
    from services.encoder.encoder import MultimodalEncoder

    class _Recorder(MultimodalEncoder):
        def __init__(self, c: Any) -> None:
            super().__init__(c)
            self.camera: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
            self._index: dict[int, int] = {}   # id of a camera embedding -> its row in ``camera``

        def sdr(self, modality: str, embedding: np.ndarray, update: bool = True) -> np.ndarray:
            z = self.standardize(modality, embedding, update)
            bits = self.lsbh(modality).encode(z)
            if modality == "camera":
                row = (np.asarray(embedding, np.float32), z.astype(np.float32), bits)
                i = self._index.get(id(embedding))
                if not update and i is not None:   # a frame held by the warm-up hold, hashed anew
                    self.camera[i] = row
                else:
                    self._index[id(embedding)] = len(self.camera)
                    self.camera.append(row)
            return bits

    return _Recorder(enc_cfg)


@dataclass
class _MissionRead:
    """The raw streams of one mission pass: per camera frame, and the truth channels."""

    frames: list[tuple[int, np.ndarray]] = field(default_factory=list)  # (stamp, fused bits) per camera frame
    mod_bits: dict[str, list[np.ndarray]] = field(default_factory=lambda: {"camera": [], "sonar": []})
    thumbs: list[np.ndarray] = field(default_factory=list)
    truth: dict[int, np.ndarray] = field(default_factory=dict)
    pose_t: list[Any] = field(default_factory=list)
    pose_p: list[Any] = field(default_factory=list)
    cam_stamps: list[int] = field(default_factory=list)
    odom_t: list[int] = field(default_factory=list)     # the robot_state node's Odometry (dead reckoning)
    odom_p: list[list[float]] = field(default_factory=list)


def _read_mission(path: Path, node: Any, sonar_key: str, robot_state: Any = None) -> _MissionRead:
    """Every camera, sonar and truth message of the recording, the sensors through ``node`` and
    (when given) the navigation sensors through the ``robot_state`` node (its ``Odometry``)."""
    from common.codec import DecodeError
    from common.mcap_io import RecordingError, read_messages
    from services.encoder.images import image_to_rgb

    rd = _MissionRead()
    nav = set(robot_state.inputs) if robot_state is not None else set()
    wanted = ["camera/image_raw", sonar_key, "truth/revisits", "truth/pose", *sorted(nav)]
    bar = tqdm(desc="mission frames", unit="frame", file=sys.stderr, leave=False)
    try:
        for rec in read_messages(path, keys=wanted):
            msg = rec.message()
            if rec.key in nav:
                robot_state.process(rec.key, msg)
                for key, odo in robot_state.take_outbox():
                    if key == "Odometry":
                        rd.odom_t.append(odo.header.stamp)
                        rd.odom_p.append(list(odo.position))
                continue
            if rec.key == "truth/revisits":
                assert isinstance(msg, RevisitTruth)
                rd.truth[int(msg.frame_index)] = np.asarray(msg.same_place, np.int64)
            elif rec.key == "truth/pose":
                assert isinstance(msg, Odometry)
                rd.pose_t.append(msg.header.stamp)
                rd.pose_p.append(msg.position)
            else:
                if rec.key == "camera/image_raw":
                    assert isinstance(msg, Image)
                    rd.cam_stamps.append(msg.header.stamp)
                    rd.thumbs.append(patch_normalise(image_to_rgb(msg)))
                    bar.update(1)
                node.process(rec.key, msg)
                _take_sdrs(node, rd)
    except (RecordingError, DecodeError) as exc:
        raise VprInputError(f"{path}: {exc}") from None
    finally:
        bar.close()
    return rd


def _take_sdrs(node: Any, rd: _MissionRead) -> None:
    """The camera-clocked SDRs the encoder node released, into ``rd`` (frames, per-modality bits)."""
    for _, out in node.take_outbox():
        present = {m.modality: np.asarray(m.active, np.uint32) for m in out.modalities}
        if "camera" in present:
            rd.frames.append((out.header.stamp, np.asarray(out.fused.active, np.uint32)))
            for m in rd.mod_bits:
                rd.mod_bits[m].append(present.get(m, np.zeros(0, np.uint32)))


def encode_mission(path: str | Path, cfg: Any, enc_cfg: Any, min_gap_m: float | None) -> MissionStreams:
    """Camera and sonar of one MCAP mission through :class:`EncoderNode`, in event order."""

    path = Path(path)
    min_gap_m = _revisit_gap(path, min_gap_m)
    run_cfg = cfg.model_copy(update={"encoder": enc_cfg})
    encoder = _camera_recorder(enc_cfg)
    node = build_node("encoder", run_cfg, encoder=encoder)
    t0 = time.perf_counter()
    robot_state = build_node("robot_state", run_cfg)
    rd = _read_mission(path, node, enc_cfg.sonar.topic, robot_state)
    node.finish()
    _take_sdrs(node, rd)      # what the warm-up hold still held at the end
    robot_state.finish()
    for key, odo in robot_state.take_outbox():
        if key == "Odometry":
            assert isinstance(odo, Odometry)
            rd.odom_t.append(odo.header.stamp)
            rd.odom_p.append(list(odo.position))
    t_embed = time.perf_counter() - t0
    n = len(rd.cam_stamps)
    if len(rd.frames) != n or len(encoder.camera) != n:
        raise VprInputError(f"{path}: {n} camera frames but {len(rd.frames)} camera-clocked SDRs")
    gt = [[int(j) for j in rd.truth.get(i, []) if 0 <= j < i] for i in range(n)]
    dist = _travelled(np.asarray(rd.cam_stamps), np.asarray(rd.pose_t), np.asarray(rd.pose_p, np.float64))
    idx = np.arange(n)
    eligible = (idx[None, :] < idx[:, None]) & (dist[:, None] - dist[None, :] >= min_gap_m)
    dr = None
    if rd.odom_t:   # the latest dead-reckoned position at or before each frame (the htm node's rule)
        k = np.searchsorted(np.asarray(rd.odom_t), np.asarray(rd.cam_stamps), side="right") - 1
        p = np.asarray(rd.odom_p, np.float64)
        dr = [p[i] if i >= 0 else None for i in k]

    return MissionStreams(
        y=np.stack([c[0] for c in encoder.camera]), z=np.stack([c[1] for c in encoder.camera]),
        thumbs=np.stack(rd.thumbs), sdrs={**rd.mod_bits, "fused": [f[1] for f in rd.frames]}, gt=gt,
        eligible=eligible, min_gap_m=float(min_gap_m), counters=dict(node.counters), weights=encoder.weights,
        dim=encoder.dim, fusion_mode=enc_cfg.fusion_mode, seconds_embed=t_embed, dr_positions=dr)


class MissionHtm(TypedDict):
    """One HTM over a mission's stream (:func:`mission_htm`): its LVC figures, its ``htm_lvc`` and
    ``htm_descriptor`` similarities (frame x earlier frame, -inf off the candidates) and the LVC id
    of every frame."""

    scores: LvcScores
    htm_lvc: np.ndarray
    htm_descriptor: np.ndarray
    ids: np.ndarray


def mission_htm(htm_cfg: HtmConfig, length: int, bits: Sequence[np.ndarray], gt: Sequence[Sequence[int]],
                eligible: np.ndarray, positions: Sequence[np.ndarray | None] | None = None) -> MissionHtm:
    """One NeocortexHtm storing LVCs online over one SDR stream: LVC scores and similarity matrices.

    ``positions``: the dead-reckoned position of each frame, for ``htm.dr_gate.enabled``."""
    from services.htm.pipeline import NeocortexHtm

    htm = NeocortexHtm(htm_cfg.model_copy(update={"input_size": length}))
    out = []
    cols_used: set[int] = set()
    kinds = {k: 0 for k in DECISION_KINDS}
    for t, b in enumerate(tqdm(bits, desc="htm", file=sys.stderr, leave=False)):
        r = htm.step(np.asarray(b, np.uint32), position=None if positions is None else positions[t])
        cols_used.update(htm.last_columns.tolist())
        out.append((*_htm_row(htm, r), float(r.anomaly)))
        kinds[decision_kind(r)] += 1
    n = len(out)
    ids = np.array([o[0] for o in out])
    desc = overlap_similarity([o[2] for o in out], [o[2] for o in out]).astype(np.float64)
    lvc = np.full(desc.shape, -np.inf)
    for i in range(n):
        frame = out[i][3]   # the memory index is the frame index: every frame is stored in order
        if 0 <= frame < n and eligible[i, frame]:
            lvc[i, frame] = out[i][1]
            continue
        same = np.flatnonzero(eligible[i] & (ids == ids[i]))
        if same.size:
            lvc[i, same[np.argmax(desc[i, same])]] = out[i][1]
    res: LvcScores = {
        **lvc_revisit_scores(ids, gt, eligible), "n_lvc": len(htm.lvc), "lvc_run_length": run_length_stats(ids),
        "tm_anomaly_mean": round(float(np.mean([o[4] for o in out])), 4) if out else 0.0,
        "sp_columns_used": len(cols_used), "decisions": kinds,
        "frames_stored": len(htm.seqmem) if htm.seqmem is not None else 0,
        "tm_decision_share": round(kinds["tm"] / max(n - kinds["new"], 1), 4)}
    return {"scores": res, "htm_lvc": lvc, "htm_descriptor": np.where(eligible, desc, -np.inf), "ids": ids}



def score_mission(st: MissionStreams, cfg: PoseidonConfig, enc_cfg: EncoderConfig, use_htm: bool,
                  chains: Sequence[str] = ()) -> MissionScores:
    """The ``--mission`` figures (see the module doc) from the encoded streams."""
    gt, eligible, n = st.gt, st.eligible, len(st.gt)

    def masked(sim: np.ndarray) -> np.ndarray:
        return np.where(eligible, sim, -np.inf)

    cam_bits, fused = st.sdrs["camera"], st.sdrs["fused"]
    lsbh_cam = overlap_similarity(cam_bits, cam_bits)
    cos = cosine_similarity(st.y, st.y)
    sims = {"cnn_cosine": masked(cos),
            "seq_cosine": sequence_similarity(masked(cos), SEQ_LENGTH),
            "patchnorm_sad": masked(sad_similarity(st.thumbs, st.thumbs)),
            "lsbh_overlap": masked(lsbh_cam),
            "lsbh_fused_overlap": masked(overlap_similarity(fused, fused))}
    if enc_cfg.embedding_norm.mode != "none":
        sims["cnn_cosine_standardized"] = masked(cosine_similarity(st.z, st.z))
    fused_scores: LvcScores | None = None
    modalities: dict[str, ModalityScores] = {}
    chain_scores: dict[str, LvcScores] = {}
    t_htm = 0.0
    if use_htm:
        t1 = time.perf_counter()
        streams = {f"fused_{st.fusion_mode}": fused}
        for m in ("camera", "sonar"):
            if st.fusion_mode != m:
                streams[m] = st.sdrs[m]
        for name, bits in streams.items():
            h = mission_htm(cfg.htm, enc_cfg.sp_columns, bits, gt, eligible, st.dr_positions)
            modalities[name] = {**h["scores"], "htm_lvc": vpr_metrics(h["htm_lvc"], gt)}
            if name.startswith("fused"):
                sims["htm_lvc"], sims["htm_descriptor"] = h["htm_lvc"], h["htm_descriptor"]
                fused_scores = h["scores"]
        if chains:
            from services.htm.chains import chain_config
            for cname in chains:
                h = mission_htm(chain_config(cfg.htm, cname), enc_cfg.sp_columns, fused, gt, eligible, st.dr_positions)
                sims[cname] = h["htm_lvc"]
                chain_scores[cname] = h["scores"]
        t_htm = time.perf_counter() - t1
    matchers: dict[str, MatcherMetrics] = {name: vpr_metrics(s, gt) for name, s in sims.items()}
    result: MissionScores = {
        "n_frames": n, "n_revisit_frames": sum(1 for g in gt if g), "min_gap_m": st.min_gap_m,
        "dr_positions": sum(1 for p in (st.dr_positions or []) if p is not None),
        "sdr_overlap": overlap_stats(lsbh_cam, gt, eligible),
        "fused_bits_mean": round(float(np.mean([f.size for f in fused])), 1),
        "encoder_counters": st.counters, "matchers": matchers,
        "seconds": {"embed": round(st.seconds_embed, 2), "htm": round(t_htm, 2)},
        "weights": st.weights, "embedding_dim": st.dim}
    if fused_scores is None:
        return result
    # the fused code's LVC figures at the top level
    with_htm: MissionScores = {**result, **fused_scores, "modalities": modalities}
    if chains:
        with_htm["chains"] = chain_scores
    return with_htm


# --------------------------------------------------------------------------- CLI
