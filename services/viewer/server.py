"""The page's HTTP server (standard library ``ThreadingHTTPServer``).

Routes: ``/`` the page, ``/static/NAME`` its script and style (package files of
``services/viewer/static``: nothing from the network), ``/state.json`` the view's state as
JSON (query: what the page already holds -- ``map``, ``sonar``, ``camera``, each trail and
``lvc`` -- and, over a recording, ``t``: the slider's time in seconds; a camera frame the page
does not hold comes in it as ``camera_jpeg``, base64: one request per update, not two),
``/camera.jpg`` the current camera frame, ``/health``.

Why the page polls JSON snapshots rather than receiving Server-Sent Events or WebSocket
pushes: a poll asks for the newest state only, so a slow or hidden browser simply asks less
often and nothing queues anywhere -- no per-client buffer to bound, no writer thread blocked
on a slow socket, no backlog to drop.  The price is one request per update (a few hundred
bytes of headers at ``view.update_hz``, 2 Hz), and the deltas (map version, trail lengths, the
sonar bins written since the page's version) keep each answer small.
"""
from __future__ import annotations

import base64
import json
import logging
import re
import threading
from collections.abc import Mapping
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from typing import Any, Protocol
from urllib.parse import parse_qs, urlsplit

__all__ = ["ViewServer", "ViewSource", "parse_listen", "LOOPBACK"]

log = logging.getLogger(__name__)

LOOPBACK = ("127.0.0.1", "localhost", "::1")
_STATIC = {"index.html": "text/html; charset=utf-8", "view.js": "text/javascript; charset=utf-8",
           "view.css": "text/css; charset=utf-8"}
_HAVE = re.compile(r"^[0-9.]{1,24}$")


class ViewSource(Protocol):
    """What the server shows: a live feed or a recording."""

    def snapshot(self, have: Mapping[str, str], t_s: float) -> dict[str, Any]: ...

    def camera(self) -> tuple[int, bytes]: ...


def parse_listen(text: str, default_host: str = "127.0.0.1") -> tuple[str, int]:
    """``[HOST:]PORT`` -> (host, port); ValueError naming ``text`` when it is not one."""
    host, sep, port = text.rpartition(":")
    if not sep:
        host = default_host
    host = host.strip("[]") or default_host
    if not port.isdigit() or not 0 <= int(port) <= 65535:
        raise ValueError(f"{text!r} is not [HOST:]PORT (a port 0-65535, e.g. 8080 or 127.0.0.1:8080)")
    return host, int(port)


def _static(name: str) -> bytes:
    return resources.files("services.viewer").joinpath("static", name).read_bytes()


class ViewServer:
    """Serve ``source`` on ``host:port`` from a thread (:meth:`start`, :meth:`stop`)."""

    def __init__(self, source: ViewSource, host: str = "127.0.0.1", port: int = 8080):
        self.source = source
        self.bytes_sent = 0
        self.requests = 0
        self._lock = threading.Lock()
        if host not in LOOPBACK:
            log.warning("view: serving on %s, not loopback: anyone who can reach this address can watch the run",
                        host)
        server = self

        class Handler(BaseHTTPRequestHandler):
            protocol_version = "HTTP/1.1"

            def log_message(self, format: str, *args: Any) -> None:  # noqa: A002 - the stdlib's name
                log.debug("view: %s %s", self.address_string(), format % args)

            def do_GET(self) -> None:  # noqa: N802 - the stdlib's name
                url = urlsplit(self.path)
                query = {k: v[-1] for k, v in parse_qs(url.query).items()}
                path = url.path
                if path in ("/", "/index.html"):
                    self._send(200, _STATIC["index.html"], _static("index.html"))
                elif path.startswith("/static/") and path[len("/static/"):] in _STATIC:
                    name = path[len("/static/"):]
                    self._send(200, _STATIC[name], _static(name))
                elif path == "/state.json":
                    self._state(query)
                elif path == "/camera.jpg":
                    _version, jpeg = server.source.camera()
                    if jpeg:
                        self._send(200, "image/jpeg", jpeg)
                    else:
                        self._send(204, "image/jpeg", b"")
                elif path == "/health":
                    self._send(200, "text/plain", b"ok\n")
                else:
                    self._send(404, "text/plain", f"no such page: {path}\n".encode())

            def _state(self, query: Mapping[str, str]) -> None:
                have = {k: v for k, v in query.items() if k != "t" and _HAVE.match(v)}
                try:
                    t_s = float(query.get("t", "0"))
                except ValueError:
                    self._send(400, "text/plain", f"t={query.get('t')!r} is not a time in seconds\n".encode())
                    return
                snap = server.source.snapshot(have, t_s)
                if snap.get("camera_version", 0) > 0 and have.get("camera") != str(snap["camera_version"]):
                    version, jpeg = server.source.camera()
                    if jpeg:
                        snap["camera_version"] = version
                        snap["camera_jpeg"] = base64.b64encode(jpeg).decode()
                with server._lock:
                    snap.setdefault("view", {}).update(bytes_sent=server.bytes_sent, requests=server.requests)
                self._send(200, "application/json", json.dumps(snap, separators=(",", ":")).encode())

            def _send(self, code: int, ctype: str, body: bytes) -> None:
                self.send_response(code)
                self.send_header("Content-Type", ctype)
                self.send_header("Content-Length", str(len(body)))
                self.send_header("Cache-Control", "no-store")
                self.end_headers()
                try:
                    self.wfile.write(body)
                except (BrokenPipeError, ConnectionResetError) as exc:
                    log.debug("view: client %s left before its answer: %s", self.address_string(), exc)
                    return
                with server._lock:
                    server.bytes_sent += len(body)
                    server.requests += 1

        self.httpd = ThreadingHTTPServer((host, port), Handler)
        self.httpd.daemon_threads = True
        self._thread: threading.Thread | None = None

    @property
    def url(self) -> str:
        host, port = self.httpd.server_address[:2]
        name = host.decode() if isinstance(host, bytes) else str(host)
        shown = f"[{name}]" if ":" in name else name
        return f"http://{shown}:{port}/"

    def start(self) -> None:
        self._thread = threading.Thread(target=self.httpd.serve_forever, name="view-http", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self.httpd.shutdown()
        self.httpd.server_close()
        if self._thread is not None:
            self._thread.join(timeout=5)
