"""The whole pipeline on a short simulated cave mission: every service, both modes."""
import pytest

from common.mcap_io import file_sha256, read_metadata
from launcher.run import run_distributed, run_embedded
from missions.sim.cli import main as sim_main
from system.config import load_config
from system.services import available_services
from tests.common.recordings import payloads_by_key

pytestmark = [pytest.mark.timeout(600), pytest.mark.slow]

OUTPUT_KEYS = ("neocortex/sdr", "local_view_cells", "Odometry", "ground_truth", "experience_event", "map",
               "experience_image", "dead_reckoning")


@pytest.fixture(scope="module")
def mission(tmp_path_factory):
    path = tmp_path_factory.mktemp("mission") / "cave.mcap"
    assert sim_main(["--minutes", "0.3", "--seed", "3", "--out", str(path)]) == 0
    return path


def test_every_service_runs_and_modes_agree_byte_for_byte(mission, tmp_path):
    cfg = load_config(overrides=[f"encoder.lsbh.matrix_path={tmp_path}/lsbh_{{backbone}}_{{modality}}.npy"])
    assert {"encoder", "htm", "robot_state", "posecells", "expmap"} <= set(available_services())
    a = run_distributed(cfg, mission, tmp_path / "dist.mcap", progress=False, timeout_s=400)
    b = run_embedded(cfg, mission, tmp_path / "emb.mcap", progress=False, timeout_s=400)
    counts = a.recording["counts"]
    frames = counts["camera/image_raw"]
    assert frames > 50
    # one SDR and one LVC id per camera frame, odometry on its grid, the reference relayed
    assert counts["neocortex/sdr"] == frames and counts["local_view_cells"] == frames
    assert counts["Odometry"] > 0 and counts["ground_truth"] == counts["odometry"]
    # the back-end made experiences, each with its evidence image, and published the map
    assert counts["experience_event"] > 0 and counts["experience_image"] == counts["experience_event"]
    assert counts["map"] > 0 and counts["dead_reckoning"] > 0
    assert b.recording["counts"] == counts
    pa, pb = payloads_by_key(tmp_path / "dist.mcap"), payloads_by_key(tmp_path / "emb.mcap")
    for key in OUTPUT_KEYS:
        assert pa[key] == pb[key], f"{key} differs between distributed and embedded runs"
    # both name their input by its SHA-256 (hashed while the services start)
    digest = file_sha256(mission)
    for run in ("dist", "emb"):
        assert read_metadata(tmp_path / f"{run}.mcap")["poseidon"]["input_sha256"] == digest


def test_guard_off_on_the_on_runs_front_end_equals_the_full_pipeline(mission, tmp_path):
    """`poseidon demo`'s Guard OFF run: only the services the guard changes, on the ON run's
    recording, give the events and map a full Guard OFF pipeline gives."""
    from launcher.demo import GUARDED_SERVICES
    lsbh = f"encoder.lsbh.matrix_path={tmp_path}/lsbh_{{backbone}}_{{modality}}.npy"
    on_cfg = load_config(overrides=[lsbh, "vpr_guard.require_vpr_for_event=true"])
    off_cfg = load_config(overrides=[lsbh, "vpr_guard.require_vpr_for_event=false"])
    run_embedded(on_cfg, mission, tmp_path / "on.mcap", progress=False, timeout_s=400)
    run_embedded(off_cfg, mission, tmp_path / "off_full.mcap", progress=False, timeout_s=400)
    res = run_embedded(off_cfg, tmp_path / "on.mcap", tmp_path / "off.mcap", services=list(GUARDED_SERVICES),
                       progress=False, timeout_s=400)
    assert set(GUARDED_SERVICES) <= set(res.services) and not {"encoder", "htm", "robot_state"} & set(res.services)
    full, replay, on = (payloads_by_key(tmp_path / f"{n}.mcap") for n in ("off_full", "off", "on"))
    for key in ("experience_event", "map", "experience_image", "dead_reckoning", "local_view_cells", "Odometry"):
        assert replay[key] == full[key], f"{key} differs from the full Guard OFF pipeline"
    assert len(full["experience_event"]) > len(on["experience_event"])   # the guard really was off
