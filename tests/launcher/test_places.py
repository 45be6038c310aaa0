"""A folder of frames through place recognition in two commands (poseidon import FOLDER; poseidon
run --config deploy/presets/images.yaml): the run ends with how many places and which frames
return to which (launcher/places.py)."""
import json
import subprocess
import sys

import numpy as np
import pytest
from PIL import Image as PILImage

from common.mcap_io import RecordingWriter
from common.messages import Header, LocalViewCells
from launcher.places import format_places, places_summary
from tests.conftest import REPO

pytestmark = pytest.mark.timeout(600)


def test_a_revisit_is_a_return_to_an_earlier_frames_place_not_the_same_view_held(tmp_path):
    run = tmp_path / "run.mcap"
    ids = [0, 1, 1, 2, 0, 0, 3, 1]           # frame 2 keeps frame 1's view; 4 and 7 return; 5 holds 4's view
    with RecordingWriter(run) as w:
        for i, lvc in enumerate(ids):
            w.write("local_view_cells", LocalViewCells(header=Header(seq=i, stamp=i * 10**9), most_active_cell=lvc,
                                                       active_cells=[], is_new=lvc not in ids[:i], intersection=0))
    p = places_summary(run)
    assert p == {"frames": 8, "places": 4, "revisits": [[4, 0, 0], [7, 1, 1]], "names": []}
    assert format_places(p) == ["places: 8 frames -> 4 places (LVC ids); 2 frames return to an earlier place:",
                                "  frame 4 -> place 0, first seen at frame 0",
                                "  frame 7 -> place 1, first seen at frame 1"]
    assert format_places(p, shown=1)[-1] == "  ... 1 more (--json key 'places')"
    empty = tmp_path / "none.mcap"
    with RecordingWriter(empty) as w:
        w.add_metadata("poseidon", {"tool": "test"})
    assert places_summary(empty) is None and format_places(None) == []


def test_a_folder_of_frames_seen_twice_gives_each_frame_of_the_second_pass_its_first_frames_place(tmp_path):
    rng = np.random.default_rng(0)
    scenes = [rng.integers(0, 256, (12, 16, 3), dtype=np.uint8) for _ in range(12)]
    frames = tmp_path / "frames"
    frames.mkdir()
    for i, k in enumerate(list(range(12)) * 2):     # the same 12 views, twice
        PILImage.fromarray(scenes[k]).resize((160, 120), PILImage.NEAREST).save(frames / f"f{i:03d}.png")
    rec, run = tmp_path / "frames.mcap", tmp_path / "places.mcap"
    poseidon = [sys.executable, "-m", "launcher.cli"]
    done = subprocess.run([*poseidon, "import", str(frames), "--out", str(rec), "--no-progress"], cwd=REPO,
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    done = subprocess.run([*poseidon, "run", "--embedded", "--input", str(rec), "--out", str(run), "--config",
                           str(REPO / "deploy" / "presets" / "images.yaml"), "--json"], cwd=REPO,
                          capture_output=True, text=True, timeout=500)
    assert done.returncode == 0, done.stderr
    result = json.loads(done.stdout)
    places = result["places"]
    assert places["frames"] == 24 and places["names"][13] == "f013.png"
    assert places["places"] == 12
    assert [r[:2] for r in places["revisits"]] == [[12 + k, k] for k in range(12)]
    assert result["inputs"]["encoder"]["missing"] == []       # no sonar: not needed when fusing the camera alone
    lines = format_places(places)
    assert lines[0] == "places: 24 frames -> 12 places (LVC ids); 12 frames return to an earlier place:"
    assert lines[1].startswith("  frame 12 (f012.png) -> place ") and lines[1].endswith("first seen at frame 0 (f000.png)")
