"""Zenoh sessions: explicit endpoints, the hub, and the ids reserved for viewers.

- Multicast scouting is off everywhere; sessions connect to explicit endpoints.  The
  launcher's hub is a session in ``router`` mode listening on loopback; services are
  ``client`` sessions connected to it (``peer``: multi-host set-ups, ``deploy/``).  A client
  retries its endpoints forever (services may start before the hub), every 0.25-1 s, not
  Zenoh's 1-4 s: a hub back after an outage is used again within a second.
- Every publisher blocks rather than drop (:mod:`common.bus`), except towards a viewer.
  :data:`VIEWER_IDS` are Zenoh ids reserved for read-only viewers (``poseidon view``); a hub
  or peer session forwards to them with congestion control DROP (:data:`VIEWER_QOS`, Zenoh's
  egress QoS overwrite).  A viewer whose link backs up (a suspended laptop, a stalled radio
  link, a view starved of CPU) then loses frames, which it counts from the transport indices,
  instead of holding every other consumer's frames on the hub until Zenoh gives up on its link
  (``block.wait_before_close``, 5 s).
"""
from __future__ import annotations

import json
import threading
from collections.abc import Iterable
from concurrent.futures import Future
from pathlib import Path
from typing import Any

import zenoh

__all__ = ["zenoh_config", "open_local_session", "open_hub", "CONNECT_RETRY", "VIEWER_IDS", "VIEWER_QOS"]

CONNECT_RETRY = {"period_init_ms": 250, "period_max_ms": 1000, "period_increase_factor": 2}
#: Zenoh ids reserved for read-only viewers, "view" and an index in hex; a viewer takes the first
#: one free (:func:`services.viewer.live.connect_bus`), so at most this many at once per hub
VIEWER_IDS: tuple[str, ...] = tuple(f"76696577{i:08x}" for i in range(1, 9))
#: the QoS overwrite every hub and peer session applies to what it sends to a viewer (see the module notes)
VIEWER_QOS: dict[str, Any] = {"id": "poseidon-viewers", "zids": list(VIEWER_IDS), "flows": ["egress"],
                              "messages": ["put", "delete"], "overwrite": {"congestion_control": "drop"}}


def zenoh_config(mode: str = "client", connect: Iterable[str] = (), listen: Iterable[str] = (),
                 config_file: str | None = None, tls_dir: str | None = None, tls_host: str | None = None,
                 user: str | None = None, password_file: str | None = None,
                 zenoh_id: str | None = None) -> zenoh.Config:
    """A Zenoh configuration with explicit endpoints and multicast scouting off; a router or
    peer forwards to viewers under :data:`VIEWER_QOS` (added to a ``config_file``'s own QoS
    overwrites); ``zenoh_id``: the session's Zenoh id (a viewer's, from :data:`VIEWER_IDS`).

    Secured profile (``deploy/zenoh/secured-*.json5``): ``tls_dir``/``tls_host`` point the
    mutual-TLS settings at ``DIR/ca.pem``, ``DIR/HOST.pem``, ``DIR/HOST.key`` (and a router's
    user dictionary at ``DIR/users.txt``), as written by ``poseidon certs``; ``user`` and
    ``password_file`` set the user/password authentication (the password never appears on a
    command line or in a configuration file).
    """
    if mode not in ("client", "peer", "router"):
        raise ValueError(f"zenoh mode must be client, peer or router, got {mode!r}")
    conf = zenoh.Config.from_file(config_file) if config_file else zenoh.Config()
    if tls_dir:
        d = Path(tls_dir)
        host = tls_host or "host"
        files = {"root_ca_certificate": d / "ca.pem", "connect_certificate": d / f"{host}.pem",
                 "connect_private_key": d / f"{host}.key"}
        if mode != "client":
            files.update(listen_certificate=d / f"{host}.pem", listen_private_key=d / f"{host}.key")
        for k, f in files.items():
            if not f.is_file():
                raise FileNotFoundError(f"TLS file {f} (for transport.link.tls.{k}) not found; see poseidon certs")
            conf.insert_json5(f"transport/link/tls/{k}", json.dumps(str(f)))
        conf.insert_json5("transport/link/tls/enable_mtls", "true")
        if mode == "router" and (d / "users.txt").is_file():
            conf.insert_json5("transport/auth/usrpwd/dictionary_file", json.dumps(str(d / "users.txt")))
    if user:
        if not password_file:
            raise ValueError("a zenoh user needs --zenoh-password-file")
        password = Path(password_file).read_text().strip()
        conf.insert_json5("transport/auth/usrpwd/user", json.dumps(user))
        conf.insert_json5("transport/auth/usrpwd/password", json.dumps(password))
    conf.insert_json5("mode", json.dumps(mode))
    connect, listen = list(connect), list(listen)
    if connect:
        conf.insert_json5("connect/endpoints", json.dumps(connect))
    if listen or mode == "router":
        conf.insert_json5("listen/endpoints", json.dumps(listen))
    conf.insert_json5("scouting/multicast/enabled", "false")
    if zenoh_id is not None:
        conf.insert_json5("id", json.dumps(zenoh_id))
    if mode != "client":
        overwrites = [q for q in json.loads(conf.get_json("qos/network")) if q.get("id") != VIEWER_QOS["id"]]
        conf.insert_json5("qos/network", json.dumps([*overwrites, VIEWER_QOS]))
    if mode != "router":
        conf.insert_json5("connect/timeout_ms", "-1")
        conf.insert_json5("connect/exit_on_failure", "false")
        conf.insert_json5("connect/retry", json.dumps(CONNECT_RETRY))
    return conf


def open_local_session() -> zenoh.Session:
    """A session for one process only (embedded runs, tests): no endpoints, no scouting."""
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("listen/endpoints", "[]")
    conf.insert_json5("scouting/multicast/enabled", "false")
    return zenoh.open(conf)


def open_hub(listen: str, config_file: str | None = None, **secure: str | None) -> zenoh.Session:
    """Open the hub: a router session listening on ``listen`` (e.g. ``tcp/127.0.0.1:7447``).
    ``secure``: ``tls_dir``, ``tls_host``, ``user``, ``password_file`` of :func:`zenoh_config`."""
    return zenoh.open(zenoh_config("router", connect=(), listen=[listen], config_file=config_file, **secure))


def open_hub_in_background(listen: str, **kwargs: Any) -> Future[zenoh.Session]:
    """:func:`open_hub` on a thread of its own (a launcher plans its run meanwhile); its error,
    if any, comes with ``result()``."""
    opening: Future[zenoh.Session] = Future()

    def work() -> None:
        opening.set_running_or_notify_cancel()
        try:
            opening.set_result(open_hub(listen, **kwargs))
        except BaseException as exc:  # handed to whoever calls result()
            opening.set_exception(exc)

    threading.Thread(target=work, name="poseidon-hub-open", daemon=True).start()
    return opening
