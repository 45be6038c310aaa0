"""Embedding standardisation before LSBH (``encoder.embedding_norm.mode``; an addition to Eq. 4.2).

Eq. 4.2 hashes v = P^T y of the raw embedding.  Untrained (seeded) or simply uncentred CNN
features are post-ReLU and positive: every embedding carries a large common-mode component
mu, so v = P^T mu + P^T (y - mu) is dominated by the fixed P^T mu and the top/bottom-k
indices hardly change from place to place (measured: ~85 % shared bits between SDRs of
different places, where independent SDRs share s = 25 %).  Hashing z = (y - mu) / sigma
instead (per-dimension mean and standard deviation) restores the locality the hash needs.
Scaling z by any positive number (L2 normalisation) does not change the top/bottom-k
indices, so an L2 step would be a no-op for LSBH and is not offered.

Modes:

* ``none``: z = y (the dissertation's Eq. 4.2 exactly).
* ``running``: mu, sigma estimated online, in event order, per modality (Welford).  A frame
  is standardised with the statistics of the frames *before* it (the first frame: z = y;
  until two frames have been seen, sigma = 1), then added to them, for the first
  ``embedding_norm.warmup`` frames.  After the warm-up the statistics are frozen
  (``embedding_norm.rate`` 0, default: the SDR of a place stays the same for the rest of the
  mission, so its LVC id can be found again) or follow an exponential moving average with
  that rate per frame.
* ``fixed``: mu, sigma fitted beforehand on a reference sequence (:meth:`fit`; ``poseidon
  vpr`` fits them on its reference set, ``--save-norm`` writes them) and loaded from
  ``embedding_norm.path``; never updated.

``embedding_norm.scale`` false (default) only centres, z = y - mu: measured better than
full standardisation on the corridor set and the simulated missions (dividing by sigma
amplified near-constant dimensions, notably of the sparse sonar rasters; fused-SDR PR AUC on
a 5-minute sim mission 0.17 centred vs 0.02 scaled).  With scaling sigma is floored at
``1e-3 x mean(sigma)`` so constant (dead) dimensions do not amplify rounding noise.
The state (count, mu, M2 = sum of squared deviations, frozen flag) is stored per modality
in ``embedding_norm.path`` when set (``{backbone}`` and ``{modality}`` substituted, e.g.
``state/embnorm_{backbone}_{modality}.npz`` next to the LSBH projection): loaded at start
when the file exists, written when the warm-up completes and when the encoder closes.  The
default is empty (in memory): the statistics describe the data they were estimated on, so
a run must not silently pick up another mission's; set the path together with
``htm.state_path`` when a map is carried across sessions (the stored LVC prototypes are
only valid with the statistics their SDRs were made with).  Everything is float64
arithmetic in frame order: deterministic.
"""
from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np

__all__ = ["NORM_MODES", "EmbeddingStandardizer", "StandardizerError", "norm_path"]

log = logging.getLogger(__name__)

NORM_MODES = ("none", "running", "fixed")
STATE_VERSION = 1
SIGMA_FLOOR = 1e-3


class StandardizerError(ValueError):
    """A statistics file that does not fit, or a mode that cannot run."""


def norm_path(template: str, backbone: str, modality: str) -> Path:
    """``embedding_norm.path`` with ``{backbone}`` and ``{modality}`` substituted."""
    try:
        return Path(template.format(backbone=backbone, modality=modality))
    except (KeyError, IndexError) as exc:
        raise StandardizerError(f"encoder.embedding_norm.path {template!r}: only {{backbone}} and {{modality}} "
                                f"may be substituted ({exc})") from None


class EmbeddingStandardizer:
    """Per-dimension z = (y - mu) / sigma of one modality's embeddings (see module doc)."""

    def __init__(self, dim: int, mode: str = "running", warmup: int = 50, rate: float = 0.0,
                 scale: bool = False, path: Path | None = None):
        if mode not in NORM_MODES:
            raise StandardizerError(f"encoder.embedding_norm.mode must be one of {NORM_MODES}, got {mode!r}")
        if warmup < 1:
            raise StandardizerError(f"encoder.embedding_norm.warmup must be >= 1, got {warmup}")
        if not 0.0 <= rate < 1.0:
            raise StandardizerError(f"encoder.embedding_norm.rate must be in [0, 1), got {rate}")
        self.dim = int(dim)
        self.mode = mode
        self.warmup = int(warmup)
        self.rate = float(rate)
        self.scale = bool(scale)
        self.path = path
        self.count = 0
        self.mean = np.zeros(self.dim, np.float64)
        self.m2 = np.zeros(self.dim, np.float64)
        self.frozen = mode == "fixed"
        self._dirty = False
        if path is not None and mode != "none" and path.exists():
            self.load(path)
        elif mode == "fixed":
            where = f"{path}" if path is not None else "no encoder.embedding_norm.path"
            raise StandardizerError(f"encoder.embedding_norm.mode fixed needs fitted statistics: {where} does not exist "
                                    f"(fit them with `poseidon vpr --save-norm FILE` on a reference set)")

    # ------------------------------------------------------------------ statistics
    @property
    def sigma(self) -> np.ndarray:
        """Per-dimension standard deviation (population), floored; ones before two frames."""
        if self.count < 2:
            return np.ones(self.dim)
        sd = np.sqrt(np.maximum(self.m2 / self.count, 0.0))
        floor = SIGMA_FLOOR * float(sd.mean()) if sd.mean() > 0 else 1.0
        return np.maximum(sd, floor)

    def settled(self, frames: int) -> bool:
        """The statistics hold at least ``frames`` embeddings, or are not estimated online
        (``none``, ``fixed``, frozen): the encoder's warm-up hold may end (:mod:`services.encoder.core`)."""
        return self.mode != "running" or self.frozen or self.count >= frames

    def _apply(self, y: np.ndarray) -> np.ndarray:
        if self.count == 0:
            return y.copy()
        z = y - self.mean
        if self.scale:
            z = z / self.sigma
        return z

    def _update(self, y: np.ndarray) -> None:
        if not self.frozen:  # Welford, in frame order
            self.count += 1
            d = y - self.mean
            self.mean += d / self.count
            self.m2 += d * (y - self.mean)
            if self.mode == "running" and self.count >= self.warmup:
                self.frozen = True
                log.debug("encoder: embedding statistics frozen after %d frames", self.count)
                self.save()
            self._dirty = True
        elif self.mode == "running" and self.rate > 0.0:  # slow EMA after the warm-up
            a = self.rate
            d = y - self.mean
            self.mean += a * d
            var = self.m2 / max(self.count, 1)
            self.m2 = ((1 - a) * (var + a * d * d)) * self.count
            self._dirty = True

    def transform(self, y: np.ndarray, update: bool = True) -> np.ndarray:
        """z of one embedding (d,); in ``running`` mode the frame then updates the statistics."""
        y = np.asarray(y, dtype=np.float64).reshape(-1)
        if y.size != self.dim:
            raise StandardizerError(f"embedding has {y.size} dimensions, the standardiser expects {self.dim}")
        if self.mode == "none":
            return y
        z = self._apply(y)
        if update and self.mode == "running":
            self._update(y)
        return z

    def transform_batch(self, y: np.ndarray, update: bool = True) -> np.ndarray:
        """:meth:`transform` for each row of (N, d), in row order."""
        return np.stack([self.transform(r, update) for r in np.atleast_2d(y)])

    @classmethod
    def fitted(cls, y: np.ndarray, scale: bool = False, path: Path | None = None) -> EmbeddingStandardizer:
        """A ``fixed`` standardiser with mu, sigma fitted on the rows of ``y`` (a reference sequence)."""
        y = np.atleast_2d(np.asarray(y, dtype=np.float64))
        st = cls(y.shape[1], "none", scale=scale, path=None)
        st.fit(y)
        st.mode, st.path = "fixed", path
        return st

    def fit(self, y: np.ndarray) -> None:
        """Set mu, sigma from the rows of ``y`` (a reference sequence) and freeze them."""
        y = np.atleast_2d(np.asarray(y, dtype=np.float64))
        if y.shape[1] != self.dim or y.shape[0] < 2:
            raise StandardizerError(f"fit needs >= 2 embeddings of {self.dim} dimensions, got shape {y.shape}")
        self.count = int(y.shape[0])
        self.mean = y.mean(axis=0)
        self.m2 = ((y - self.mean) ** 2).sum(axis=0)
        self.frozen = True
        self._dirty = True

    # ------------------------------------------------------------------ persistence
    def state(self) -> dict[str, np.ndarray]:
        meta = {"version": STATE_VERSION, "dim": self.dim, "count": self.count, "frozen": self.frozen}
        return {"mean": self.mean, "m2": self.m2, "meta_json": np.frombuffer(json.dumps(meta).encode(), np.uint8)}

    def save(self, path: Path | None = None) -> None:
        """Write the statistics to ``path`` (default: the configured one; nothing if none)."""
        path = path if path is not None else self.path
        if path is None:
            return
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.name + ".tmp.npz")
        # numpy's savez stub types **kwds against its allow_pickle: bool keyword
        np.savez(tmp, **self.state())  # type: ignore[arg-type]
        tmp.replace(path)
        self._dirty = False
        log.info("encoder: embedding statistics (%d frames) saved to %s", self.count, path)

    def close(self) -> None:
        """Save if the statistics changed since the last save."""
        if self._dirty:
            self.save()

    def load(self, path: Path) -> None:
        try:
            with np.load(path, allow_pickle=False) as z:
                data = {k: z[k] for k in z.files}
        except (OSError, ValueError) as exc:
            raise StandardizerError(f"embedding statistics {path} are not a readable .npz: {exc}") from exc
        if not {"mean", "m2", "meta_json"} <= set(data):
            raise StandardizerError(f"embedding statistics {path}: missing mean/m2/meta_json")
        meta = json.loads(bytes(data["meta_json"]).decode())
        if meta.get("version") != STATE_VERSION:
            raise StandardizerError(f"embedding statistics {path}: version {meta.get('version')}, "
                                    f"expected {STATE_VERSION}")
        if meta["dim"] != self.dim or data["mean"].shape != (self.dim,):
            raise StandardizerError(f"embedding statistics {path} are for {meta['dim']} dimensions, the encoder "
                                    f"has {self.dim}; delete the file or point encoder.embedding_norm.path elsewhere")
        if not (np.all(np.isfinite(data["mean"])) and np.all(np.isfinite(data["m2"]))):
            raise StandardizerError(f"embedding statistics {path} contain non-finite values")
        self.mean = data["mean"].astype(np.float64)
        self.m2 = data["m2"].astype(np.float64)
        self.count = int(meta["count"])
        self.frozen = bool(meta["frozen"]) or self.mode == "fixed"
        if self.mode == "fixed" and self.count < 2:
            raise StandardizerError(f"embedding statistics {path} hold {self.count} frames; fixed needs >= 2")
        log.info("encoder: embedding statistics (%d frames) loaded from %s", self.count, path)
