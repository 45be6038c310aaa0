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


def test_secured_profile_on_two_hosts(two_hosts, tmp_path):
    """deploy/zenoh/secured-*.json5 with `poseidon certs`: mutual TLS, user/password, access
    control.  With the right certificates and credentials every message flows; a session with
    the right certificate but no credentials cannot publish Odometry nor receive the camera;
    the player's credentials cannot put Odometry (only robot_state may); a certificate of
    another CA cannot join."""
    pytest.importorskip("cryptography")
    host_a, host_b = two_hosts
    py = [sys.executable, "-m", "launcher.cli"]
    tls, rogue = tmp_path / "tls", tmp_path / "rogue"
    for out, hosts in ((tls, "10.77.0.1,10.77.0.2"), (rogue, "10.77.0.2")):
        subprocess.run([*py, "certs", "--out", str(out), "--hosts", hosts], cwd=REPO, check=True, timeout=60)
    src = tmp_path / "mission.mcap"
    counts = six_stream_recording(src, 1500, image_every=10)
    endpoint = "tls/10.77.0.1:7447"
    out = tmp_path / "recorded_on_b.mcap"
    router = str(REPO / "deploy" / "zenoh" / "secured-router.json5")
    service = str(REPO / "deploy" / "zenoh" / "secured-service.json5")

    def secure(host, user):
        return ["--zenoh-config", service, "--tls-dir", str(tls), "--tls-host", host, "--zenoh-user", user,
                "--zenoh-password-file", str(tls / f"{user}.password")]

    hub = subprocess.Popen(["ip", "netns", "exec", host_a, *py, "hub", "--listen", endpoint, "--zenoh-config", router,
                            "--tls-dir", str(tls), "--tls-host", "10.77.0.1"], cwd=REPO)
    rec = subprocess.Popen(["ip", "netns", "exec", host_b, *py, "service", "recorder", "--connect", endpoint,
                            *secure("10.77.0.2", "recorder"), "--out", str(out), "--expect", ",".join(sorted(counts)),
                            "--stats", str(tmp_path / "rec.json")], cwd=REPO)
    intruder = [sys.executable, "-m", "tests.foundation.intruder", endpoint]
    intruders = {
        "no_credentials": subprocess.Popen(["ip", "netns", "exec", host_b, *intruder, str(tls), "10.77.0.2", "12"],
                                           cwd=REPO, stdout=subprocess.PIPE, text=True),
        "player_credentials": subprocess.Popen(["ip", "netns", "exec", host_b, *intruder, str(tls), "10.77.0.2",
                                                "player", str(tls / "player.password"), "12"],
                                               cwd=REPO, stdout=subprocess.PIPE, text=True),
        "wrong_certificate": subprocess.Popen(["ip", "netns", "exec", host_b, *intruder, str(rogue), "10.77.0.2",
                                               "recorder", str(tls / "recorder.password"), "12"],
                                              cwd=REPO, stdout=subprocess.PIPE, text=True),
    }
    try:
        time.sleep(2.0)
        player = subprocess.run(["ip", "netns", "exec", host_a, *py, "service", "player", "--connect", endpoint,
                                 *secure("10.77.0.1", "player"), "--input", str(src), "--wait-for", "recorder",
                                 "--no-progress", "--stats", str(tmp_path / "player.json")], cwd=REPO, timeout=120)
        assert player.returncode == 0
        assert rec.wait(timeout=60) == 0
        reports = {name: json.loads(p.communicate(timeout=60)[0].strip().splitlines()[-1])
                   for name, p in intruders.items()}
    finally:
        for p in (rec, hub, *intruders.values()):
            if p.poll() is None:
                p.terminate()
                p.wait(timeout=10)
    assert json.loads((tmp_path / "player.json").read_text())["published"] == counts
    recorded = json.loads((tmp_path / "rec.json").read_text())
    assert recorded["recorded"] == counts and recorded["invalid"] == {}  # no forged Odometry got in
    print("\n[secured] intruders:", reports)
    # a certificate of another CA, or the right certificate without credentials: no session at all,
    # so neither Odometry put nor camera received
    for name in ("wrong_certificate", "no_credentials"):
        assert reports[name]["joined"] is False and reports[name]["camera_received"] == 0, reports[name]
    # the player's own credentials joined and tried to put Odometry: the router dropped every one
    assert reports["player_credentials"]["joined"] is True and reports["player_credentials"]["odometry_put"] > 50
    assert "Odometry" not in recorded["recorded"]
