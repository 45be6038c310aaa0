"""``poseidon audit RUN.mcap [--json] [--slop S] [--config FILE] [--set K=V]``: is every experience traced to its frame?

Event-evidence association (Section 5.4.4, "Audit of Event-Evidence Correspondence"):
``experience_event`` and ``experience_image`` are joined by header ``(seq, stamp)`` (the
expmap gives each image its event's header).  A joined pair is an *association* when its
evidence lag dt = |source_stamp - event stamp| is at most ``slop_s`` (default: the run's
``expmap.image.sync_slop``, 0.75 s, the dissertation's ``slop_sec``).

``--json`` keys:

- ``recording``, ``config_source``, ``slop_s``;
- ``events``, ``images`` (message counts), ``associated`` (pairs within the slop);
- ``precision`` = associated / images, ``recall`` = associated / events, ``f1`` = their
  harmonic mean (null when a denominator is 0);
- ``missing_images`` = events with no image of the same header, ``missing_events`` =
  images with no event of the same header, ``duplicate_images`` = images beyond the first
  for one header, ``late_images`` = joined pairs with dt > ``slop_s``;
- ``dt_mean_s``, ``dt_max_s``: dt over every joined pair (s; Table 5.4's dt_real);
- ``keys``: per recorded key ``{"messages", "first_seq", "last_seq", "gaps", "missing",
  "duplicates", "out_of_order"}`` from the header seq (the MCAP sequence): ``gaps`` =
  jumps between consecutive distinct seqs (sorted), ``missing`` = seqs absent between
  first and last, ``duplicates`` = messages repeating a seq, ``out_of_order`` = times the
  seq decreased in event-time order;
- ``messages_missing`` (sum of ``missing`` over keys), ``keys_with_gaps`` (sorted names).

Exit status: 0, or 2 when the recording cannot be read.
"""
from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from eval.rundata import RunData, add_config_args, config_from_args, load_run, report_cli
from system.config import PoseidonConfig

__all__ = ["audit_run", "association", "sequence_gaps", "format_audit", "main"]


def sequence_gaps(seqs: Sequence[int]) -> dict[str, int | None]:
    """Gaps, missing, duplicate and out-of-order header seqs of one key (module docstring)."""
    if not len(seqs):
        return {"messages": 0, "first_seq": None, "last_seq": None, "gaps": 0, "missing": 0, "duplicates": 0,
                "out_of_order": 0}
    a = np.asarray(seqs, dtype=np.int64)
    u = np.unique(a)
    steps = np.diff(u)
    return {"messages": int(len(a)), "first_seq": int(u[0]), "last_seq": int(u[-1]),
            "gaps": int(np.count_nonzero(steps > 1)), "missing": int((steps - 1).sum()),
            "duplicates": int(len(a) - len(u)), "out_of_order": int(np.count_nonzero(np.diff(a) < 0))}


def association(events: Sequence[tuple[int, int]], images: Sequence[tuple[int, int, int]],
                slop_s: float) -> dict[str, Any]:
    """Association figures of events ``(seq, stamp)`` and images ``(seq, stamp, source_stamp)``."""
    ev = set(events)
    seen: set[tuple[int, int]] = set()
    dts: list[float] = []
    associated = late = duplicates = missing_events = 0
    for seq, stamp, source in images:
        key = (seq, stamp)
        if key in seen:
            duplicates += 1
            continue
        seen.add(key)
        if key not in ev:
            missing_events += 1
            continue
        dt = abs(source - stamp) / 1e9
        dts.append(dt)
        if dt <= slop_s:
            associated += 1
        else:
            late += 1
    n_ev, n_im = len(events), len(images)
    precision = associated / n_im if n_im else None
    recall = associated / n_ev if n_ev else None
    f1 = (2 * precision * recall / (precision + recall) if precision and recall else
          (0.0 if precision is not None and recall is not None else None))
    return {"events": n_ev, "images": n_im, "associated": associated, "precision": precision, "recall": recall,
            "f1": f1, "missing_images": len(ev - seen), "missing_events": missing_events,
            "duplicate_images": duplicates, "late_images": late,
            "dt_mean_s": float(np.mean(dts)) if dts else None, "dt_max_s": float(np.max(dts)) if dts else None}


def audit_run(path: str | Path | RunData, slop_s: float | None = None,
              config: PoseidonConfig | None = None) -> dict[str, Any]:
    """Audit a run recording (``path`` or a loaded :class:`RunData`); keys in the module docstring."""
    run = path if isinstance(path, RunData) else load_run(path, config)
    slop = run.config.expmap.image.sync_slop if slop_s is None else slop_s
    out: dict[str, Any] = {"recording": str(run.path), "config_source": run.config_source, "slop_s": slop}
    assoc = association([(e.header.seq, e.header.stamp) for e in run.events],
                        [(i.seq, i.stamp, i.source_stamp) for i in run.images], slop)
    out.update({k: (round(v, 6) if isinstance(v, float) else v) for k, v in assoc.items()})
    keys = {k: sequence_gaps(v) for k, v in sorted(run.seqs.items())}
    out["keys"] = keys
    out["messages_missing"] = sum(int(k["missing"] or 0) for k in keys.values())
    out["keys_with_gaps"] = sorted(k for k, v in keys.items() if v["gaps"])
    return out


def _f(v: Any, fmt: str = ".3f") -> str:
    return "n/a" if v is None else format(v, fmt)


def format_audit(a: dict[str, Any]) -> list[str]:
    """Human-readable lines of an :func:`audit_run` result."""
    lines = [f"recording          {a['recording']}",
             f"event-evidence     {a['events']} events, {a['images']} images, {a['associated']} associated "
             f"(dt <= {a['slop_s']:g} s): precision {_f(a['precision'])}, recall {_f(a['recall'])}, F1 {_f(a['f1'])}",
             f"missing            {a['missing_images']} images, {a['missing_events']} events; "
             f"{a['duplicate_images']} duplicate and {a['late_images']} late images",
             f"evidence lag dt    mean {_f(a['dt_mean_s'])} s, max {_f(a['dt_max_s'])} s",
             f"sequence gaps      {a['messages_missing']} messages missing over {len(a['keys_with_gaps'])} keys"]
    lines.append(f"  {'key':<24} {'messages':>9} {'gaps':>6} {'missing':>8} {'dup':>5} {'reorder':>8}")
    for k, v in a["keys"].items():
        lines.append(f"  {k:<24} {v['messages']:>9} {v['gaps']:>6} {v['missing']:>8} {v['duplicates']:>5} "
                     f"{v['out_of_order']:>8}")
    return lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="poseidon audit",
                                 description="event-evidence association and per-key sequence gaps of a run recording")
    ap.add_argument("recording", type=Path)
    ap.add_argument("--json", action="store_true", help="print the result as JSON (keys: see the module docstring)")
    ap.add_argument("--slop", type=float, default=None,
                    help="largest evidence lag of an association (s; default expmap.image.sync_slop of the run)")
    add_config_args(ap)
    args = ap.parse_args(argv)
    return report_cli("audit", lambda: audit_run(args.recording, slop_s=args.slop, config=config_from_args(args)), format_audit, args.json)


if __name__ == "__main__":
    sys.exit(main())
