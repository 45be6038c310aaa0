"""No input can kill a service; contradictory messages are rejected at
validation; a service that fails ends the run quickly, even without the launcher."""
import json
import subprocess
import sys
import time

import numpy as np
import pytest

from common.bus import open_hub
from common.codec import DecodeError, decode, decode_frame, encode, encode_frame
from common.mcap_io import read_messages
from common.messages import Depth, Header, Image, LaserScan, NeocortexSdr, RangeImageBeam, RevisitTruth, Sdr
from launcher.run import run_embedded
from system.config import PoseidonConfig
from tests.common.nodes import SlowEcho, start_local_runner
from tests.common.recordings import HOSTILE, inconsistent_image, six_stream_recording, with_inconsistent_image
from tests.conftest import REPO

pytestmark = pytest.mark.timeout(120)

H = Header(seq=0, stamp=10)


@pytest.mark.parametrize("frame", HOSTILE)
def test_malformed_frames_raise_only_decode_error(frame):
    with pytest.raises(DecodeError):
        f = decode_frame(frame)
        f.message()


def test_contradictory_messages_are_rejected_at_validation():
    def bad(fn, match):
        with pytest.raises(ValueError, match=match):
            fn()
    bad(lambda: Image(header=H, height=4000, width=4000, data=np.zeros((2, 2, 3), np.uint8)), "contradicts height")
    bad(lambda: Image(header=H, height=2, width=2, encoding="mono8", data=np.zeros((2, 2, 3), np.uint8)), "channels")
    bad(lambda: Image(header=H, height=2, width=2, data=np.zeros((2, 2, 3), np.float64)), "dtype")
    bad(lambda: Image(header=H, height=2, width=2, encoding="mono16", data=np.zeros((2, 2), np.uint8)), "dtype")
    bad(lambda: RangeImageBeam(header=H, angle_grad=0, angle_rad=0, nbins=50, max_range=20,
                               beam_data=np.zeros(3, np.int32)), "nbins 50")
    bad(lambda: LaserScan(header=H, angle_min=0, angle_max=0, angle_increment=0.1, range_min=0, range_max=5,
                          ranges=np.zeros(10, np.float32), intensities=np.zeros(7, np.float32)), "7 intensities")
    bad(lambda: Sdr(header=H, modality="camera", size=16, active=np.array([1, 16], np.uint32)), "outside")
    bad(lambda: Sdr(header=H, modality="camera", size=16, active=np.array([5, 3], np.uint32)), "sorted")
    bad(lambda: Sdr(header=H, modality="camera", size=16, active=np.array([3, 3], np.uint32)), "sorted")
    bad(lambda: Sdr(header=H, modality="camera", size=16, active=np.array([0.5], np.float32)), "integers")
    sdr = Sdr(header=H, modality="camera", size=16, active=np.array([1], np.uint32))
    bad(lambda: NeocortexSdr(header=H, modalities=[sdr], fused=sdr.model_copy(update={"size": 32}),
                             fusion_mode="union"), "differ")
    bad(lambda: RevisitTruth(header=H, frame_index=3, same_place=np.array([5], np.int32)), "earlier")
    bad(lambda: RangeImageBeam(header=H, angle_grad=0, angle_rad=0, nbins=1, max_range=20,
                               beam_data=np.array(["x"])), "not numeric")
    # the wire form of the image: a DecodeError naming the field, never a crash in a service
    with pytest.raises(DecodeError, match="Image: field"):
        decode(encode(inconsistent_image(H)), Image)
    # consistent messages still pass
    Image(header=H, height=2, width=3, encoding="mono8", data=np.zeros((2, 3), np.uint8))
    Image(header=H, height=2, width=3, encoding="mono16", data=np.zeros((2, 3, 1), np.uint16))
    Image(header=H, height=2, width=3, encoding="bgra8", data=np.zeros((2, 3, 4), np.uint8))


def test_runner_counts_and_logs_every_hostile_frame_and_keeps_going(caplog):
    session, bus, t, result = start_local_runner(SlowEcho(PoseidonConfig()))
    depth, camera = bus.publisher("depth_sensor"), bus.publisher("camera/image_raw")
    depth.send(Depth(header=Header(seq=0, stamp=10), depth=1.0))
    for frame in HOSTILE:
        camera.send_raw(frame)
        depth.send_raw(frame)
    camera.send_raw(encode_frame(inconsistent_image(Header(seq=7, stamp=11))))
    depth.send(Depth(header=Header(seq=1, stamp=5), depth=9.0))  # older than its own stream: late
    depth.send(Depth(header=Header(seq=2, stamp=20), depth=2.0))
    camera.send_eos()
    camera.send(Image(header=Header(seq=8, stamp=30), height=1, width=1, encoding="mono8",
                      data=np.zeros((1, 1), np.uint8)))  # after its end-of-stream
    time.sleep(0.5)  # two publishers: let the camera frames arrive before the last end-of-stream
    depth.send_eos()
    t.join(timeout=30)
    bus.close()
    session.close()
    stats = result["stats"]
    assert not t.is_alive()
    assert stats.published == {"echo/depth": 2}
    assert stats.invalid == {"camera/image_raw": len(HOSTILE) + 2, "depth_sensor": len(HOSTILE) + 1}
    # one hostile frame is well framed with a payload that is not msgpack: an invalid message
    assert stats.rejected == {"bad_frame": 2 * (len(HOSTILE) - 1), "invalid_message": 3, "late": 1,
                              "after_end_of_stream": 1}
    text = " ".join(r.getMessage() for r in caplog.records)
    assert "invalid message on camera/image_raw seq 7 skipped: poseidon_msgs/Image: field" in text
    assert "late message on depth_sensor seq 1" in text
    assert "camera/image_raw seq 8 after its end-of-stream" in text


def test_inconsistent_image_is_skipped_and_the_run_completes(tmp_path):
    src, bad = tmp_path / "six.mcap", tmp_path / "bad.mcap"
    counts = six_stream_recording(src, 600, image_every=10)
    bad_seq = with_inconsistent_image(src, bad)
    cfg = PoseidonConfig(service_classes={"image_rows": "tests.common.nodes:ImageRows"})
    result = run_embedded(cfg, bad, tmp_path / "out.mcap", services=["image_rows"], progress=False, timeout_s=60)
    st = result.services["image_rows"]
    assert st["invalid"] == {"camera/image_raw": 1} and st["rejected"] == {"invalid_message": 1}
    assert result.recording["counts"]["image_rows/mean"] == counts["camera/image_raw"] - 1
    assert result.recording["counts"]["camera/image_raw"] == counts["camera/image_raw"]  # the audit keeps it
    assert bad_seq == 3


def test_a_dying_service_aborts_a_run_without_launcher(tmp_path):
    """hub + recorder + a failing service + player as separate `poseidon service` processes:
    the failure ends every process within seconds (exit 4: aborted) and the recording is whole."""
    import socket
    src = tmp_path / "small.mcap"
    counts = six_stream_recording(src, 1500, image_every=10)
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        endpoint = f"tcp/127.0.0.1:{s.getsockname()[1]}"
    cfg = tmp_path / "cfg.yaml"
    cfg.write_text(json.dumps({"service_classes": {"boom": "tests.common.nodes:Boom"}}))
    py = [sys.executable, "-m", "launcher.cli", "service"]
    common = ["--connect", endpoint, "--config", str(cfg)]
    out = tmp_path / "rec.mcap"
    hub = open_hub(endpoint)
    procs = {}
    try:
        procs["recorder"] = subprocess.Popen(py + ["recorder", *common, "--out", str(out), "--expect",
                                                   ",".join(sorted(counts) + ["boom/depth"])], cwd=REPO)
        procs["boom"] = subprocess.Popen(py + ["boom", *common], cwd=REPO)
        procs["player"] = subprocess.Popen(py + ["player", *common, "--input", str(src), "--wait-for",
                                                 "recorder,boom", "--no-progress"], cwd=REPO)
        t0 = time.monotonic()
        rcs = {n: p.wait(timeout=60) for n, p in procs.items()}
        elapsed = time.monotonic() - t0
    finally:
        for p in procs.values():
            if p.poll() is None:
                p.kill()
        hub.close()
    assert rcs == {"recorder": 4, "boom": 1, "player": 4}, rcs
    assert elapsed < 45
    got = list(read_messages(out, strict=True))  # closed with its summary
    assert 0 < len(got) < sum(counts.values())
