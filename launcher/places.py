"""The places a run's front-end recognised: ``poseidon run --json`` key ``places`` and the
lines at the end of a run that has ``local_view_cells``.

Each camera frame gets one LVC id (``local_view_cells``, :mod:`services.htm`): a new id is a
new place, an id given before is a place seen again.  ``places`` counts the ids; a *revisit*
is a frame that took an id first given to a frame other than the one just before it (a
frame that keeps its predecessor's id is the same view, not a return); each revisit is
``[frame, first frame of its place, LVC id]`` with frames numbered from 0 in event order.
When the run's input was imported from a folder of frames (``poseidon import FOLDER``), the
frames' file names are given too (``names``, index = frame number).
"""
from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from common.mcap_io import read_messages, read_metadata
from common.messages import LocalViewCells

__all__ = ["places_summary", "format_places", "SHOWN"]

#: revisits listed in the readable summary (all of them are in the JSON)
SHOWN = 20


def _frame_names(run_path: str | Path) -> list[str]:
    """File names of the input's frames (``poseidon import`` of a folder), or []."""
    try:
        input_path = read_metadata(run_path).get("poseidon", {}).get("input", "")
        if not input_path or not Path(input_path).is_file():
            return []
        names = json.loads(read_metadata(input_path).get("poseidon", {}).get("frames", "[]"))
    except (OSError, ValueError):
        return []
    return [str(n) for n in names] if isinstance(names, list) else []


def places_summary(run_path: str | Path) -> dict[str, Any] | None:
    """``{"frames", "places", "revisits": [[frame, first_frame, lvc_id]], "names"}`` of a run's
    recording; None when it has no ``local_view_cells``."""
    ids = [m.message() for m in read_messages(run_path, keys=["local_view_cells"])]
    lvcs = [m for m in ids if isinstance(m, LocalViewCells)]
    if not lvcs:
        return None
    first: dict[int, int] = {}
    revisits: list[list[int]] = []
    for i, m in enumerate(lvcs):
        lvc = m.most_active_cell
        if lvc not in first:
            first[lvc] = i
        elif lvcs[i - 1].most_active_cell != lvc:
            revisits.append([i, first[lvc], lvc])
    names = _frame_names(run_path)
    return {"frames": len(lvcs), "places": len(first), "revisits": revisits,
            "names": names if len(names) == len(lvcs) else []}


def format_places(p: Mapping[str, Any] | None, shown: int = SHOWN) -> list[str]:
    """Readable lines of :func:`places_summary`: the count, then the revisits (the first ``shown``)."""
    if not p:
        return []
    names = p.get("names") or []

    def frame(i: int) -> str:
        return f"{i} ({names[i]})" if names else str(i)

    revisits = p["revisits"]
    lines = [f"places: {p['frames']} frames -> {p['places']} places (LVC ids); {len(revisits)} frames return to "
             f"an earlier place" + (":" if revisits else "")]
    lines += [f"  frame {frame(i)} -> place {lvc}, first seen at frame {frame(j)}" for i, j, lvc in revisits[:shown]]
    if len(revisits) > shown:
        lines.append(f"  ... {len(revisits) - shown} more (--json key 'places')")
    return lines
