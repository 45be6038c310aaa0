"""Two vehicle computers on one machine: network namespaces joined by a veth pair.

Host A (10.77.0.1) runs the hub (a Zenoh router) and the player; host B (10.77.0.2) runs
the recorder, connected to A's router across the link.  Every message must arrive.
Needs root and iproute2 (as on the build machines); skipped otherwise.
"""
import json
import os
import shutil
import subprocess
import sys
import time
import uuid

import pytest

from tests.conftest import REPO
from tests.foundation.recordings import six_stream_recording

pytestmark = pytest.mark.timeout(180)


def _ip(*args: str) -> None:
    subprocess.run(["ip", *args], check=True, capture_output=True, text=True)


@pytest.fixture
def two_hosts():
    if os.geteuid() != 0 or shutil.which("ip") is None:
        pytest.skip("needs root and iproute2 to create network namespaces")
    tag = uuid.uuid4().hex[:6]
    a, b = f"pa{tag}", f"pb{tag}"
    try:
        _ip("netns", "add", a)
        _ip("netns", "add", b)
    except subprocess.CalledProcessError as exc:
        pytest.skip(f"cannot create network namespaces here: {exc.stderr.strip()}")
    try:
        _ip("link", "add", f"va{tag}", "type", "veth", "peer", "name", f"vb{tag}")
        _ip("link", "set", f"va{tag}", "netns", a)
        _ip("link", "set", f"vb{tag}", "netns", b)
        for ns, dev, addr in ((a, f"va{tag}", "10.77.0.1/24"), (b, f"vb{tag}", "10.77.0.2/24")):
            _ip("-n", ns, "addr", "add", addr, "dev", dev)
            _ip("-n", ns, "link", "set", dev, "up")
            _ip("-n", ns, "link", "set", "lo", "up")
        yield a, b
    finally:
        _ip("netns", "del", a)
        _ip("netns", "del", b)


def test_services_on_two_hosts_through_a_router(two_hosts, tmp_path):
    host_a, host_b = two_hosts
    src = tmp_path / "mission.mcap"
    counts = six_stream_recording(src, 1500, image_every=10)
    endpoint = "tcp/10.77.0.1:7447"
    out = tmp_path / "recorded_on_b.mcap"
    py = [sys.executable, "-m", "launcher.cli"]
    hub = subprocess.Popen(["ip", "netns", "exec", host_a, *py, "hub", "--listen", endpoint, "--zenoh-config",
                            str(REPO / "deploy" / "zenoh" / "router-multi-host.json5")], cwd=REPO)
    rec = subprocess.Popen(["ip", "netns", "exec", host_b, *py, "service", "recorder", "--connect", endpoint,
                            "--out", str(out), "--expect", ",".join(sorted(counts)),
                            "--stats", str(tmp_path / "rec.json")], cwd=REPO)
    try:
        time.sleep(1.0)
        player = subprocess.run(["ip", "netns", "exec", host_a, *py, "service", "player", "--connect", endpoint,
                                 "--input", str(src), "--wait-for", "recorder", "--no-progress",
                                 "--stats", str(tmp_path / "player.json")], cwd=REPO, timeout=120)
        assert player.returncode == 0
        assert rec.wait(timeout=60) == 0
    finally:
        for p in (rec, hub):
            if p.poll() is None:
                p.terminate()
                p.wait(timeout=10)
    assert json.loads((tmp_path / "player.json").read_text())["published"] == counts
    assert json.loads((tmp_path / "rec.json").read_text())["recorded"] == counts
