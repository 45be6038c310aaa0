"""Per-modality prototypes of the LVCs for ``htm.lvc.require_multimodal`` (Table 4.1): the camera
(sonar) SDR of the frame that created each LVC, and the check that a match's frame overlaps it
by R = |A & B| / |A| >= ``lvc.min_camera_score`` (``lvc.min_sonar_score``) in every modality present
on both sides (:mod:`services.htm.pipeline`)."""
from __future__ import annotations

import numpy as np

from services.htm.lvc import overlap_scores

__all__ = ["ModalityPrototypes"]


class ModalityPrototypes:
    """Per-modality SDRs of the frame that created each LVC (for ``lvc.require_multimodal``)."""

    def __init__(self, thresholds: dict[str, float]):
        self.thresholds = thresholds
        self.protos: list[dict[str, np.ndarray]] = []
        self.rejections = 0

    def store(self, lvc_id: int, modalities: dict[str, np.ndarray] | None) -> None:
        while len(self.protos) <= lvc_id:
            self.protos.append({})
        self.protos[lvc_id] = {m: np.asarray(v, np.int64).copy() for m, v in (modalities or {}).items()
                               if m in self.thresholds}

    def disagree(self, lvc_id: int, modalities: dict[str, np.ndarray] | None) -> bool:
        """True when a modality present in the frame and the prototype overlaps too little."""
        stored = self.protos[lvc_id] if lvc_id < len(self.protos) else {}
        for m, threshold in self.thresholds.items():
            cur = None if modalities is None else modalities.get(m)
            if cur is None or len(cur) == 0 or m not in stored or len(stored[m]) == 0:
                continue
            if overlap_scores(cur, stored[m])["R"] < threshold:
                self.rejections += 1
                return True
        return False

    def state(self) -> dict[str, np.ndarray]:
        out: dict[str, np.ndarray] = {}
        for m in self.thresholds:
            arrays = [p.get(m, np.zeros(0, np.int64)) for p in self.protos]
            present = np.array([m in p for p in self.protos], bool)
            out[f"{m}.bits"] = np.concatenate(arrays) if arrays else np.zeros(0, np.int64)
            out[f"{m}.start"] = np.concatenate([[0], np.cumsum([a.size for a in arrays])]).astype(np.int64)
            out[f"{m}.present"] = present
        return out

    def set_state(self, st: dict[str, np.ndarray]) -> None:
        self.protos = []
        for m in self.thresholds:
            if f"{m}.bits" not in st:
                continue
            bits, start, present = st[f"{m}.bits"], st[f"{m}.start"], st[f"{m}.present"]
            while len(self.protos) < present.size:
                self.protos.append({})
            for k in np.flatnonzero(present):
                self.protos[k][m] = bits[start[k]:start[k + 1]].copy()
