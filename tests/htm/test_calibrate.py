"""Self-calibrated gates: RunningQuantile, the sequence match's F1 checks, the override."""
import numpy as np

from services.htm.calibrate import RunningQuantile
from services.htm.config import HtmConfig
from services.htm.pipeline import NeocortexHtm

L = 2048


def test_running_quantile_is_exact_deterministic_and_persistent():
    rq = RunningQuantile(warmup=5)
    for x in [0.5, 0.1, 0.9, 0.3]:
        rq.add(x)
    assert rq.quantile(0.5) is None                       # fewer than warmup samples
    rq.add(0.7)
    assert rq.quantile(0.0) == 0.1 and rq.quantile(1.0) == 0.9
    assert rq.quantile(0.5) == 0.5 and rq.quantile(0.3) == 0.3   # rank floor(q (n - 1)), no interpolation
    clone = RunningQuantile(warmup=5)
    clone.set_state(rq.state())
    assert clone.quantile(0.5) == 0.5 and len(clone) == 5
    rq.reset()
    assert len(rq) == 0 and rq.quantile(0.5) is None


def _gate_precision(shift, calibrated):
    """Matches score ~0.70, non-matches ~U(0.40, 0.60); the null is the non-matches seen so far.
    Every score is shifted by ``shift`` (another mission's level)."""
    rng = np.random.default_rng(0)
    null = RunningQuantile(warmup=20)
    tp = fp = 0
    for t in range(2000):
        match = t % 10 == 0
        s = (0.70 + rng.normal(0, 0.01) if match else rng.uniform(0.40, 0.60)) + shift
        thr = 0.65 if not calibrated else (None if null.quantile(0.99) is None else null.quantile(0.99) + 0.02)
        if thr is not None and s >= thr:
            tp += match
            fp += not match
        if not match:
            null.add(s)
    return tp / max(tp + fp, 1), tp


def test_self_calibrated_gate_holds_precision_when_every_score_is_shifted():
    p0, tp0 = _gate_precision(0.0, calibrated=True)
    for shift in (-0.15, 0.15):
        p, tp = _gate_precision(shift, calibrated=True)
        assert p == p0 and tp == tp0                     # a constant shift moves the null quantile with it
    assert _gate_precision(0.0, calibrated=False)[0] == 1.0
    assert _gate_precision(0.15, calibrated=False)[0] < 0.5      # the fixed gate admits the shifted non-matches
    assert _gate_precision(-0.15, calibrated=False)[1] == 0      # ... or loses every match


def _loop(seed=0, n=150, keep=0.62):
    """Lap 1: n places, each seen in two identical frames; 60 novel frames; lap 2: the places again,
    each frame a noisy copy (too weak for Eq. 4.9 against lap 1), again two identical frames per place."""
    rng = np.random.default_rng(seed)
    places = [np.sort(rng.choice(L, 400, replace=False)) for _ in range(n)]
    novel = [np.sort(rng.choice(L, 400, replace=False)) for _ in range(60)]

    def noisy(p):
        k = int(keep * p.size)
        rest = np.setdiff1d(np.arange(L), p)
        return np.sort(np.concatenate([rng.choice(p, k, replace=False), rng.choice(rest, p.size - k, replace=False)]))

    lap2 = [noisy(p) for p in places]
    frames = [p for p in places for _ in range(2)] + novel + [q for q in lap2 for _ in range(2)]
    return frames, 2 * n + 60


def _run(frames, changes=None):
    cfg = HtmConfig(input_size=L, descriptor={"source": "sdr"}, lvc={"successor_threshold": 0.0},
                    seqmem={"length": 10, "velocities": [0.5, 1.0], "exclude": 20}).updated(changes or {})
    h = NeocortexHtm(cfg)
    return h, [h.step(f) for f in frames]


def test_override_lets_the_sequence_replace_a_recent_id():
    frames, start = _loop(keep=0.4)
    n_places = (len(frames) - start) // 2
    res = {}
    for override in (False, True):
        # a strict sequence gate: some lap-2 places get a new id first, their second frame then
        # passes Eq. 4.9 against that recent id
        h, out = _run(frames, {"seqmem.override": override, "seqmem.threshold": 8.0, "seqmem.margin": 1.0})
        lap1_ids = {r.lvc_id for r in out[:2 * n_places]}
        res[override] = (sum(r.lvc_id in lap1_ids for r in out[start:]),
                         sum(r.by_sequence and r.best_rate >= 0.72 for r in out[start:]))
        if override:   # every lap-1 id was created by lap 1's first frame of its place
            assert h.lvc_birth[:3] == [0, 2, 4]
    assert res[False][1] == 0            # without the override a passing Eq. 4.9 match always wins
    assert res[True][1] > 0              # with it the sequence takes over the recent id
    assert res[True][0] > res[False][0]  # ... and more lap-2 frames carry their lap-1 id


def test_f1_checks_of_the_sequence_match():
    frames, start = _loop()
    _, base = _run(frames)
    _, strict = _run(frames, {"seqmem.min_f1": 0.99})             # no lap-2 frame has F1 0.99 with lap 1
    _, calib = _run(frames, {"seqmem.f1_quantile": 0.5, "seqmem.calib_warmup": 5})
    assert sum(r.by_sequence for r in base[start:]) > 0
    assert sum(r.by_sequence for r in strict) == 0
    assert 0 < sum(r.by_sequence for r in calib[start:]) <= sum(r.by_sequence for r in base[start:])


def test_save_and_load_keep_the_calibration(tmp_path):
    frames, start = _loop()
    kw = {"seqmem.override": True, "seqmem.f1_quantile": 0.5, "seqmem.calib_warmup": 5}
    h, _ = _run(frames[:start + 100], kw)
    h.save(tmp_path / "s.npz")
    cfg = h.cfg
    g = NeocortexHtm.load(tmp_path / "s.npz", cfg)
    assert g.lvc_birth == h.lvc_birth and g.seq_calib.values == h.seq_calib.values
    a = [h.step(f).lvc_id for f in frames[start + 100:]]
    b = [g.step(f).lvc_id for f in frames[start + 100:]]
    assert a == b
