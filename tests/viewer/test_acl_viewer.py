"""In the secured profile the view is a declared read-only identity: it may subscribe, never put."""
from __future__ import annotations

from launcher.acl import access_control, identity_grants


def test_the_viewer_identity_may_subscribe_and_put_nothing() -> None:
    grants = identity_grants()["viewer"]
    assert {g.verb for g in grants} == {"subscribe", "watch"}
    acl = access_control()
    policy = next(p for p in acl["policies"] if p["subjects"] == ["viewer"])
    rules = [r for r in acl["rules"] if r["id"] in policy["rules"]]
    ingress = {m for r in rules if "ingress" in r["flows"] for m in r["messages"]}
    assert ingress == {"declare_subscriber", "declare_liveliness_subscriber"}  # no put, no token, no query
