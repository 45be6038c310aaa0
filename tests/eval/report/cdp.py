"""A minimal Chrome DevTools Protocol client over ``--remote-debugging-pipe``.

Chromium reads NUL-terminated JSON commands on file descriptor 3 and writes replies and
events on descriptor 4; no websocket, no port, nothing to install.  Used by the report's
browser test to load the page headless, collect console messages, exceptions and network
requests, wait until every figure has rendered and take a screenshot.
"""
from __future__ import annotations

import fcntl
import json
import os
import select
import subprocess
import time
from pathlib import Path
from typing import Any

CHROMIUM = Path("/usr/bin/chromium")

#: flags of a quiet, offline, throw-away headless browser (software rendering)
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--disable-default-apps", "--disable-extensions", "--mute-audio",
         # trusted local content: software WebGL for the 3D figure without the deprecated silent fallback
         "--enable-unsafe-swiftshader"]


class CdpError(RuntimeError):
    """The browser answered a command with an error, or did not answer in time."""


class Browser:
    """One headless Chromium process driven through the DevTools pipe."""

    def __init__(self, user_data_dir: Path, executable: Path = CHROMIUM, extra_flags: list[str] | None = None,
                 idle: bool = False):
        """``idle``: Chromium runs under Linux's SCHED_IDLE policy from its first instruction, so
        every process and thread it ever starts inherits it (it only takes CPU nothing else wants)."""
        to_child_r, self._to_child_w = os.pipe()
        self._from_child_r, from_child_w = os.pipe()

        def wire() -> None:  # in the child: the pipe ends become fds 3 (in) and 4 (out)
            if idle:
                os.sched_setscheduler(0, os.SCHED_IDLE, os.sched_param(0))
            high_r = fcntl.fcntl(to_child_r, fcntl.F_DUPFD, 10)  # out of the way of 3 and 4 first
            high_w = fcntl.fcntl(from_child_w, fcntl.F_DUPFD, 10)
            os.dup2(high_r, 3)  # dup2 makes them inheritable; every other fd of ours is not
            os.dup2(high_w, 4)

        user_data_dir.mkdir(parents=True, exist_ok=True)
        self._stderr_path = user_data_dir.parent / f"{user_data_dir.name}-chromium-stderr.log"
        self._stderr = open(self._stderr_path, "wb")
        self.proc = subprocess.Popen(
            [str(executable), *FLAGS, *(extra_flags or []), f"--user-data-dir={user_data_dir}",
             "--remote-debugging-pipe", "about:blank"],
            stdin=subprocess.DEVNULL, stdout=self._stderr, stderr=self._stderr,
            preexec_fn=wire, close_fds=False)
        os.close(to_child_r)
        os.close(from_child_w)
        self._buf = b""
        self._next_id = 0
        self.events: list[dict[str, Any]] = []

    # ------------------------------------------------------------------ protocol
    def _send(self, method: str, params: dict[str, Any] | None, session: str | None) -> int:
        self._next_id += 1
        msg: dict[str, Any] = {"id": self._next_id, "method": method, "params": params or {}}
        if session:
            msg["sessionId"] = session
        os.write(self._to_child_w, json.dumps(msg).encode() + b"\0")
        return self._next_id

    def _read_one(self, deadline: float) -> dict[str, Any] | None:
        while b"\0" not in self._buf:
            left = deadline - time.monotonic()
            if left <= 0:
                return None
            ready, _, _ = select.select([self._from_child_r], [], [], left)
            if not ready:
                return None
            chunk = os.read(self._from_child_r, 1 << 20)
            if not chunk:
                raise CdpError(f"chromium closed the DevTools pipe (exit {self.proc.poll()}); "
                               f"stderr: {self.stderr_tail()}")
            self._buf += chunk
        raw, self._buf = self._buf.split(b"\0", 1)
        return json.loads(raw)

    def call(self, method: str, params: dict[str, Any] | None = None, session: str | None = None,
             timeout_s: float = 30.0) -> dict[str, Any]:
        """Send one command and return its result; events that arrive meanwhile are kept."""
        cid = self._send(method, params, session)
        deadline = time.monotonic() + timeout_s
        while True:
            msg = self._read_one(deadline)
            if msg is None:
                raise CdpError(f"{method}: no answer within {timeout_s} s")
            if msg.get("id") == cid:
                if "error" in msg:
                    raise CdpError(f"{method}: {msg['error']}")
                return msg.get("result", {})
            if "method" in msg:
                self.events.append(msg)

    def pump(self, seconds: float) -> None:
        """Collect events for ``seconds``."""
        deadline = time.monotonic() + seconds
        while (msg := self._read_one(deadline)) is not None:
            if "method" in msg:
                self.events.append(msg)

    def stderr_tail(self, n: int = 2000) -> str:
        self._stderr.flush()
        return self._stderr_path.read_bytes()[-n:].decode(errors="replace")

    def close(self) -> None:
        if self.proc.poll() is None:
            try:
                self._send("Browser.close", None, None)
                self.proc.wait(timeout=10)
            except (OSError, subprocess.TimeoutExpired):
                self.proc.kill()
                self.proc.wait(timeout=10)
        os.close(self._to_child_w)
        os.close(self._from_child_r)
        self._stderr.close()

    def __enter__(self) -> Browser:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
