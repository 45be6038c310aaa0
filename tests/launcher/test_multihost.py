"""Two vehicle computers on one machine: network namespaces joined by a veth pair.

Host A (10.77.0.1) runs the hub (a Zenoh router) and the player; host B (10.77.0.2) runs
the recorder, connected to A's router across the link.  Every message must arrive.  The
secured profile runs the whole pipeline across the two hosts under default-deny access
control, with intruders.  Needs root and iproute2 (as on the build machines); skipped otherwise.
"""
import json
import os
import shutil
import subprocess
import sys
import time
import uuid

import pytest

from tests.common.recordings import six_stream_recording
from tests.conftest import REPO

pytestmark = [pytest.mark.timeout(180), pytest.mark.slow]


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


@pytest.fixture(scope="module")
def short_mission(tmp_path_factory):
    from missions.sim.cli import main as sim_main
    path = tmp_path_factory.mktemp("mission") / "cave.mcap"
    assert sim_main(["--minutes", "0.1", "--seed", "3", "--out", str(path)]) == 0
    return path


@pytest.mark.timeout(480)
def test_secured_pipeline_on_two_hosts(two_hosts, tmp_path, short_mission):
    """The secured profile (deploy/zenoh/secured-*.json5, ``poseidon certs``): mutual TLS,
    user/password, and default-deny access control generated from the services' keys.

    Host A (sensor computer): hub, player, robot_state; host B: hub (connected to A's as user
    ``router``; A's recognises it by its hub certificate), encoder, htm, posecells, expmap,
    recorder; each service joins its own host's hub.  Every service runs with its own credentials and the recording equals
    an unsecured run's, message for message.  Meanwhile intruders try: the right certificate
    without credentials and a certificate of another CA cannot join; the player's credentials
    can neither put Odometry nor read the camera; the encoder's can neither put the camera nor
    read Odometry; the expmap's (allowed to read the camera) do receive it, which shows the
    intruders' subscriptions would see a leak.
    """
    pytest.importorskip("cryptography")
    from launcher.run import plan_run, run_embedded
    from system.config import load_config

    host_a, host_b = two_hosts
    py = [sys.executable, "-m", "launcher.cli"]
    tls, rogue = tmp_path / "tls", tmp_path / "rogue"
    for out, hosts in ((tls, "10.77.0.1,10.77.0.2"), (rogue, "10.77.0.2")):
        subprocess.run([*py, "certs", "--out", str(out), "--hosts", hosts], cwd=REPO, check=True, timeout=60)
    sets = [f"encoder.lsbh.matrix_path={tmp_path}/lsbh_{{backbone}}_{{modality}}.npy"]
    config = load_config(overrides=sets)
    plan = plan_run(config, short_mission)
    t0 = time.monotonic()
    baseline = run_embedded(config, short_mission, tmp_path / "unsecured.mcap", progress=False, timeout_s=300)
    t_baseline = time.monotonic() - t0

    hosts = _SecuredHosts(host_a, host_b, tmp_path, tls, sets)
    router_a, router_b = hosts.routers()
    out = tmp_path / "secured.mcap"
    hub, run_service, intruder = hosts.hub, hosts.service, hosts.intruder

    procs: dict[str, subprocess.Popen] = {}
    intruders: dict[str, subprocess.Popen] = {}
    t0 = time.monotonic()
    try:
        procs["hub_a"] = hub(host_a, router_a)
        procs["hub_b"] = hub(host_b, router_b)
        time.sleep(1.0)
        intruders = {
            "no_credentials": intruder(host_b, tls, None, "--put", "Odometry", "--subscribe", "camera/image_raw"),
            "wrong_certificate": intruder(host_b, rogue, "recorder", "--subscribe", "camera/image_raw"),
            "player": intruder(host_a, tls, "player", "--put", "Odometry", "--subscribe", "camera/image_raw"),
            "encoder": intruder(host_b, tls, "encoder", "--put", "camera/image_raw", "--subscribe", "Odometry"),
            "expmap": intruder(host_b, tls, "expmap", "--subscribe", "camera/image_raw"),
        }
        first = {name: p.stdout.readline().strip() for name, p in intruders.items()}  # "ready", or its report
        copy = ["--copy-from", str(short_mission), "--copy-keys", ",".join(plan.copy_keys)] if plan.copy_keys else []
        procs["recorder"] = run_service(host_b, "recorder", "--out", str(out), "--expect", ",".join(plan.expect),
                                        *copy)
        for name in plan.services:
            procs[name] = run_service(host_a if name == "robot_state" else host_b, name)
        procs["player"] = run_service(host_a, "player", "--input", str(short_mission), "--keys",
                                      ",".join(plan.player_keys), "--wait-for", ",".join(["recorder", *plan.services]),
                                      "--no-progress")
        assert procs["recorder"].wait(timeout=300) == 0
        for p in intruders.values():  # their subscriptions end before the player drains
            if p.poll() is None:
                p.terminate()
        reports = {name: json.loads(first[name] if first[name].startswith("{")
                                    else intruders[name].communicate(timeout=30)[0])
                   for name in intruders}
        for name in ("player", *plan.services):
            assert procs[name].wait(timeout=120) == 0, name
    finally:
        for p in [*intruders.values(), *procs.values()]:
            if p.poll() is None:
                p.terminate()
                p.wait(timeout=15)
    t_secured = time.monotonic() - t0
    recorded = json.loads((tmp_path / "recorder.json").read_text())
    print(f"\n[secured] {sum(recorded['recorded'].values())} messages recorded in {t_secured:.0f} s over TLS with "
          f"access control (unsecured embedded baseline: {sum(baseline.recording['counts'].values())} in "
          f"{t_baseline:.0f} s); intruders: {reports}")
    _check_secured_run(recorded, baseline, out, tmp_path, reports)


class _SecuredHosts:
    """Commands of the secured two-host run: each host's hub, a service joining its own
    host's hub with its own credentials, and intruders (tests/launcher/intruder.py)."""

    PY = [sys.executable, "-m", "launcher.cli"]

    def __init__(self, host_a, host_b, tmp_path, tls, sets):
        self.host_a = host_a
        self.IP = {host_a: "10.77.0.1", host_b: "10.77.0.2"}
        self.ENDPOINT = {host_a: "tls/10.77.0.1:7447", host_b: "tls/10.77.0.2:7447"}  # each host's own hub
        self.tmp_path, self.tls, self.sets = tmp_path, tls, sets

    def routers(self):
        """A's hub configuration, and B's: the same, connecting to A's hub."""
        router_a = REPO / "deploy" / "zenoh" / "secured-router.json5"
        router_b = self.tmp_path / "secured-router-b.json5"
        text = router_a.read_text()
        assert text.count("endpoints: [],  // the other computers' routers") == 1
        router_b.write_text(text.replace("endpoints: [],  // the other computers' routers",
                                         f'endpoints: ["{self.ENDPOINT[self.host_a]}"],  // A'))
        return router_a, router_b

    @staticmethod
    def in_ns(ns, *cmd):
        return ["ip", "netns", "exec", ns, *cmd]

    def hub(self, ns, config):
        tls = self.tls
        return subprocess.Popen(self.in_ns(ns, *self.PY, "hub", "--listen", self.ENDPOINT[ns], "--zenoh-config",
                                           str(config), "--tls-dir", str(tls), "--tls-host", f"hub.{self.IP[ns]}",
                                           "--zenoh-user", "router", "--zenoh-password-file",
                                           str(tls / "router.password")), cwd=REPO)

    def service(self, ns, name, *extra):
        tls = self.tls
        cmd = self.in_ns(ns, *self.PY, "service", name, "--connect", self.ENDPOINT[ns], "--zenoh-config",
                         str(REPO / "deploy" / "zenoh" / "secured-service.json5"), "--tls-dir", str(tls),
                         "--tls-host", self.IP[ns], "--zenoh-user", name, "--zenoh-password-file",
                         str(tls / f"{name}.password"), *[a for s in self.sets for a in ("--set", s)],
                         "--stats", str(self.tmp_path / f"{name}.json"), *extra)
        return subprocess.Popen(cmd, cwd=REPO)

    def intruder(self, ns, tls_dir, user, *args):
        cred = ["--user", user, "--password-file", str(self.tls / f"{user}.password")] if user else []
        return subprocess.Popen(self.in_ns(ns, sys.executable, "-m", "tests.launcher.intruder", self.ENDPOINT[ns],
                                           str(tls_dir), self.IP[ns], *cred, *args), cwd=REPO,
                                stdout=subprocess.PIPE, text=True)


def _check_secured_run(recorded, baseline, out, tmp_path, reports):
    from tests.common.recordings import payloads_by_key

    # every service with its own credentials: the whole pipeline flowed, exactly as without security
    assert recorded["recorded"] == baseline.recording["counts"] and recorded["invalid"] == {}
    assert payloads_by_key(out) == payloads_by_key(tmp_path / "unsecured.mcap")  # nothing forged got in
    assert {"Odometry", "neocortex/sdr", "local_view_cells", "experience_event", "map"} <= set(recorded["recorded"])
    # no session at all without credentials, or with a certificate of another CA
    for name in ("no_credentials", "wrong_certificate"):
        assert reports[name]["joined"] is False and "error" in reports[name], reports[name]
    # credentials used beyond their rights: joined, tried for the whole run, got nothing through
    assert reports["player"]["joined"] and reports["player"]["put"]["Odometry"] > 20
    assert reports["player"]["received"]["camera/image_raw"] == 0
    assert reports["encoder"]["joined"] and reports["encoder"]["put"]["camera/image_raw"] > 20
    assert reports["encoder"]["received"]["Odometry"] == 0
    # ... while a subscription within its rights receives every camera frame
    assert reports["expmap"]["data"]["camera/image_raw"] == recorded["recorded"]["camera/image_raw"]


#: the recorder's Zenoh lease across the link (ms): how soon a cut is noticed (measured: about
#: 6 s after the cut with 3 s, about 9 s with Zenoh's default 10 s -- too close to a 10 s cut)
OUTAGE_LEASE_MS = 3000


@pytest.mark.timeout(120)
def test_a_live_source_rides_out_a_10_s_cut_between_hosts(two_hosts, tmp_path):
    """Host A: hub and a live source (``tests/launcher/outage_source.py``: a SensorDriver, IMU
    and DVL at 100 Hz each, 24 s, wall-clock stamps); host B: the recorder.  7 s in, the link
    between the hosts goes down for 10 s, then back.  The outage rule (:mod:`common.live`): the
    IMU keeps 2000 frames -- enough for the whole outage: every message is recorded, those held
    during the outage counted ``delivered_late``; the DVL keeps 100 -- not enough: held frames
    pushed out are counted ``dropped_outage`` by the source, and the recorder counts every
    frame that never arrived (``missing``, from the frame numbers): recorded + missing ==
    published, exactly, for both keys."""
    host_a, host_b = two_hosts
    dev = "va" + host_a[2:]
    endpoint = "tcp/10.77.0.1:7447"
    lease = tmp_path / "lease.json5"
    lease.write_text(f"{{transport: {{link: {{tx: {{lease: {OUTAGE_LEASE_MS}}}}}}}}}")
    out = tmp_path / "outage.mcap"
    py = [sys.executable, "-m", "launcher.cli"]
    keys = ["dvl_linkquest", "imu_adis_ros"]
    hub = subprocess.Popen(["ip", "netns", "exec", host_a, *py, "hub", "--listen", endpoint], cwd=REPO)
    rec = src = None
    try:
        time.sleep(1.0)
        rec = subprocess.Popen(["ip", "netns", "exec", host_b, *py, "service", "recorder", "--connect", endpoint,
                                "--zenoh-config", str(lease), "--out", str(out), "--expect", ",".join(keys),
                                "--stats", str(tmp_path / "rec.json")], cwd=REPO)
        src = subprocess.Popen(["ip", "netns", "exec", host_a, sys.executable, "-m", "tests.launcher.outage_source",
                                endpoint, "--rate", "100", "--seconds", "24", "--buffer", "2000,100"], cwd=REPO,
                               stdout=subprocess.PIPE, text=True)
        assert src.stdout is not None and src.stdout.readline().strip() == "ready"
        time.sleep(7.0)
        _ip("-n", host_a, "link", "set", dev, "down")
        time.sleep(10.0)
        _ip("-n", host_a, "link", "set", dev, "up")
        stdout, _ = src.communicate(timeout=60)
        assert src.returncode == 0
        assert rec.wait(timeout=60) == 0
    finally:
        for p in (src, rec, hub):
            if p is not None and p.poll() is None:
                p.terminate()
                p.wait(timeout=10)
    sent = json.loads(stdout.strip().splitlines()[-1])
    recorded = json.loads((tmp_path / "rec.json").read_text())
    print(f"\n[10 s cut] source: {sent}\n[10 s cut] recorder: recorded {recorded['recorded']}, missing "
          f"{recorded['missing']}, duplicates dropped {recorded['duplicates']}")
    imu, dvl = "imu_adis_ros", "dvl_linkquest"
    published = sent["published"]
    assert published == {imu: 2400, dvl: 2400}
    assert sorted(recorded["ended"]) == keys  # the run went on to a complete recording
    assert sent["outages"] == {imu: 1, dvl: 1}
    for key in keys:  # nothing silently lost
        assert recorded["recorded"][key] + recorded["missing"].get(key, 0) == published[key], key
    # the IMU's buffer covered the outage: everything arrived, the held frames late
    assert recorded["recorded"][imu] == published[imu] and imu not in recorded["missing"]
    assert sent["delivered_late"][imu] > 0 and imu not in sent["dropped_outage"]
    # the DVL's did not: the held frames beyond 100 were dropped and counted by the source; the
    # recorder also misses those lost in flight before the outage was noticed (not known at the source)
    assert sent["delivered_late"][dvl] == 100
    assert 0 < sent["dropped_outage"][dvl] <= recorded["missing"][dvl]
    from common.mcap_io import read_messages
    assert sum(1 for _ in read_messages(out, keys=[imu])) == published[imu]
