"""The secured profile's access control (launcher/acl.py): generated from the services' own
declaration of their keys, default deny, and the checked-in router configuration up to date.

The policy is evaluated here the way Zenoh's router does (tests/launcher/test_multihost.py
runs it for real): a message is allowed when a rule of the sender's subject for that flow and
message type has a key expression that *includes* the message's key expression.
"""
import pytest
import zenoh

from launcher import acl
from launcher.certs import USERS
from launcher.run import node_io
from services.player.player import SOURCE_KEYS
from system.config import load_config
from tests.conftest import REPO

ROUTER = REPO / "deploy" / "zenoh" / "secured-router.json5"


def allowed(policy: dict, user: str, flow: str, message: str, key: str) -> bool:
    """Zenoh 1.x's decision for ``user`` under a default-deny ``policy`` (allow rules only)."""
    assert policy["default_permission"] == "deny"
    subjects = {s["id"] for s in policy["subjects"] if user in s.get("usernames", [])}
    rule_ids = {r for p in policy["policies"] if subjects & set(p["subjects"]) for r in p["rules"]}
    ke = zenoh.KeyExpr(key)
    return any(r["permission"] == "allow" and flow in r["flows"] and message in r["messages"]
               and any(zenoh.KeyExpr(k).includes(ke) for k in r["key_exprs"])
               for r in policy["rules"] if r["id"] in rule_ids)


def may_put(policy: dict, user: str, key: str) -> bool:
    return allowed(policy, user, "ingress", "put", f"poseidon/{key}")


def may_read(policy: dict, user: str, key: str) -> bool:
    return (allowed(policy, user, "ingress", "declare_subscriber", f"poseidon/{key}")
            and allowed(policy, user, "egress", "put", f"poseidon/{key}"))


@pytest.fixture(scope="module")
def policy():
    return acl.access_control()


def test_the_checked_in_router_configuration_is_generated_from_the_code():
    assert acl.main(["--check", str(ROUTER)]) == 0, f"run: poseidon acl --write {ROUTER.relative_to(REPO)}"
    conf = zenoh.Config.from_file(str(ROUTER))  # Zenoh itself accepts it
    assert conf.get_json("access_control/default_permission") == '"deny"'


def test_check_reports_a_stale_or_unmarked_file(tmp_path):
    stale = tmp_path / "router.json5"
    stale.write_text(ROUTER.read_text().replace('"poseidon/Odometry"', '"poseidon/Odometry2"'))
    assert acl.main(["--check", str(stale)]) == 1
    assert acl.main(["--write", str(stale)]) == 0 and acl.main(["--check", str(stale)]) == 0
    assert stale.read_text() == ROUTER.read_text()
    unmarked = tmp_path / "plain.json5"
    unmarked.write_text("{ mode: 'router' }\n")
    assert acl.main(["--check", str(unmarked)]) == 2


def test_each_service_puts_exactly_its_outputs_and_reads_exactly_its_inputs(policy):
    config = load_config()
    data_keys = set(SOURCE_KEYS) | {k for n in acl.identities() if acl.identities()[n] == "service"
                                    for io in node_io(n, config) for k in io}
    for name, role in acl.identities().items():
        if role != "service":
            continue
        ins, outs = node_io(name, config)
        assert {k for k in data_keys if may_put(policy, name, k)} == set(outs), name
        assert {k for k in data_keys if may_read(policy, name, k)} == set(ins), name
    # who may put what the issue names
    assert [u for u in USERS if may_put(policy, u, "Odometry")] == ["router", "robot_state"]
    for key in SOURCE_KEYS:
        assert [u for u in USERS if may_put(policy, u, key)] == ["router", "player"], key
    assert not any(may_put(policy, "recorder", k) for k in data_keys)
    assert all(may_read(policy, "recorder", k) for k in data_keys)
    assert not any(may_read(policy, "player", k) for k in data_keys)
    camera_readers = {u for u in USERS if may_read(policy, u, "camera/image_raw")}
    assert camera_readers == {"router", "recorder", "viewer", "encoder", "expmap", "ratslam_lv"}
    assert not any(may_put(policy, "viewer", k) for k in data_keys)  # the view is read-only
    assert not may_put(policy, "nobody", "Odometry") and not may_read(policy, "nobody", "camera/image_raw")


def test_publishers_see_the_subscriptions_they_feed(policy):
    """The cause of the earlier failure: a client drops puts with no matching subscriber it
    was told of, so each publisher must receive (egress) the declarations of the allowed
    subscriptions that match its keys, the recorder's ``poseidon/**`` included."""
    for user, key in (("player", "camera/image_raw"), ("player", "truth/pose"), ("encoder", "neocortex/sdr"),
                      ("robot_state", "Odometry"), ("encoder", "@progress/encoder"), ("player", "@abort")):
        assert may_put(policy, user, key)
        assert allowed(policy, user, "egress", "declare_subscriber", f"poseidon/{key}"), (user, key)
    assert allowed(policy, "player", "egress", "declare_subscriber", "poseidon/**")
    assert allowed(policy, "encoder", "egress", "declare_subscriber", "poseidon/@progress/*")
    assert not allowed(policy, "recorder", "egress", "declare_subscriber", "poseidon/**")  # it publishes no data


def test_control_traffic(policy):
    for name, role in acl.identities().items():
        consumer = role in ("recorder", "service")
        assert allowed(policy, name, "ingress", "liveliness_token", f"poseidon/@alive/{name}") == consumer
        assert may_put(policy, name, f"@progress/{name}") == consumer
        assert may_read(policy, name, "@abort")
        assert may_put(policy, name, "@abort") == (role not in ("recorder", "viewer"))
        assert not allowed(policy, name, "ingress", "liveliness_token", "poseidon/@alive/someone_else")
        assert not may_put(policy, name, "@progress/someone_else")
    assert may_read(policy, "player", "@progress/*")
    assert allowed(policy, "player", "ingress", "declare_liveliness_subscriber", "poseidon/@alive/*")
    assert allowed(policy, "player", "egress", "liveliness_token", "poseidon/@alive/encoder")


def test_the_policy_follows_the_configuration():
    config = load_config(overrides=["encoder.sonar.topic=sonar_seaking", "bus.namespace=auv2"])
    policy = acl.access_control(config)
    assert allowed(policy, "encoder", "ingress", "declare_subscriber", "auv2/sonar_seaking")
    assert not allowed(policy, "encoder", "ingress", "declare_subscriber", "auv2/sonar_micron")
    assert not allowed(policy, "robot_state", "ingress", "put", "poseidon/Odometry")  # another namespace


def test_a_new_control_key_is_one_line(monkeypatch):
    monkeypatch.setattr(acl, "CONTROL_GRANTS", acl.CONTROL_GRANTS + (("put", "@replay/{name}", ("service",)),))
    policy = acl.access_control()
    assert may_put(policy, "htm", "@replay/htm") and not may_put(policy, "htm", "@replay/encoder")
    assert not may_put(policy, "player", "@replay/player")
    assert may_put(policy, "router", "@replay/htm")


def test_every_identity_has_credentials():
    assert set(acl.identities()) | {"router"} == set(USERS)


def test_replay_requests_go_from_a_key_s_consumers_to_its_publisher(policy):
    """Supervision (common.resume): a restarted consumer asks on @replay/<input key>, the
    publisher of that key listens there; checkpoint positions go on @ckpt/<service>."""
    config = load_config()
    ins, outs = node_io("htm", config)
    for k in ins:
        assert may_put(policy, "htm", f"@replay/{k}")
    assert not may_put(policy, "htm", "@replay/camera/image_raw")   # not an input of htm
    assert may_read(policy, "encoder", "@replay/neocortex/sdr") and not may_read(policy, "htm", "@replay/neocortex/sdr")
    assert may_read(policy, "player", "@replay/camera/image_raw") and may_put(policy, "recorder", "@replay/map")
    assert may_put(policy, "expmap", "@ckpt/expmap") and not may_put(policy, "expmap", "@ckpt/htm")
