"""Recorder: every key of the namespace into one MCAP file per run.

Payloads are written byte for byte as received, one channel per key, one schema per
message type, log time = header stamp (event time).  The ``poseidon`` metadata record holds
the full configuration, the code revision and the input's hash.  The file is flushed to
disk at least every ``flush_interval_s`` (wall clock: this is transport, not algorithm), so
a recorder killed with SIGKILL leaves every complete chunk readable
(:func:`common.mcap_io.read_messages` recovers it).

The recorder stops when end-of-stream has arrived on every key in ``expect`` (the
launcher passes the player's keys and every service output), or when stopped.
Frames it cannot read (malformed, unknown type, no readable header, a key already
carrying another type) are logged with their key, counted and skipped: nothing a publisher
sends can stop the recorder.  An ``@abort`` on the bus (a service died, see
:mod:`common.bus`) stops it after writing what has arrived; the file is then closed with
its summary and ``RecorderStats.aborted`` says why.  On a normal end it reports progress
``END_OF_TIME`` so the player knows it finished.
"""
from __future__ import annotations

import logging
import queue
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable

from common.bus import Bus
from common.codec import DecodeError, decode_dict, decode_frame
from common.mcap_io import RecordingWriter
from common.ordering import END_OF_TIME

__all__ = ["Recorder", "RecorderStats"]

log = logging.getLogger(__name__)


@dataclass
class RecorderStats:
    recorded: dict[str, int] = field(default_factory=dict)
    invalid: dict[str, int] = field(default_factory=dict)
    ended: list[str] = field(default_factory=list)
    path: str = ""
    aborted: str = ""

    def as_dict(self) -> dict:
        return {"service": "recorder", "path": self.path, "recorded": self.recorded, "invalid": self.invalid,
                "ended": sorted(self.ended), "aborted": self.aborted}


class Recorder:
    def __init__(self, bus: Bus, out: str | Path, expect: Iterable[str] | None = None,
                 metadata: dict[str, Any] | None = None, compression: str = "zstd", chunk_size: int = 1 << 20,
                 flush_interval_s: float = 0.5, name: str = "recorder"):
        self.bus = bus
        self.out = Path(out)
        self.expect = set(expect) if expect is not None else None
        self.metadata = metadata or {}
        self.name = name
        self.queue: queue.SimpleQueue[tuple[str, bytes]] = queue.SimpleQueue()
        self.progress = bus.progress_publisher(name)
        self._seen = -1
        self.writer = RecordingWriter(self.out, compression=compression, chunk_size=chunk_size)
        self.flush_interval_s = flush_interval_s
        self.stop_event = threading.Event()
        self.stats = RecorderStats(path=str(self.out))
        bus.subscribe("**", self.queue)
        bus.on_abort(self._on_abort)

    def _on_abort(self, reason: str) -> None:
        if not self.stats.aborted:
            log.error("recorder: run aborted: %s", reason)
        self.stats.aborted = reason or "aborted"
        self.stop_event.set()

    def _done(self) -> bool:
        return self.expect is not None and self.expect <= set(self.stats.ended)

    def run(self) -> RecorderStats:
        self.writer.add_metadata("poseidon", self.metadata)
        self.writer.flush()
        self.bus.declare_alive(self.name)
        last_flush = time.monotonic()
        try:
            while not self._done():
                if self.stop_event.is_set() and self.queue.empty():
                    break
                try:
                    key, data = self.queue.get(timeout=0.2)
                except queue.Empty:
                    continue
                self._handle(key, data)
                if self._seen >= 0:
                    self.progress.report(self._seen, force=self.queue.empty())
                if time.monotonic() - last_flush > self.flush_interval_s:
                    self.writer.flush()
                    last_flush = time.monotonic()
        finally:
            self.writer.close()
        if self._done():
            self.progress.report(END_OF_TIME, force=True)  # finished normally (see common.bus)
        return self.stats

    def _handle(self, key: str, data: bytes) -> None:
        try:
            frame = decode_frame(data)
        except DecodeError as exc:
            self.stats.invalid[key] = self.stats.invalid.get(key, 0) + 1
            log.error("recorder: bad frame on %s skipped: %s", key, exc)
            return
        if frame.kind == "eos":
            self.stats.ended.append(key)
            return
        if frame.kind == "watermark":
            self._seen = max(self._seen, frame.stamp)
            return
        try:
            header = decode_dict(frame.payload).get("header")
            if not isinstance(header, dict):
                raise DecodeError("no header")
            stamp, seq = header.get("stamp"), header.get("seq")
            if not (isinstance(stamp, int) and 0 <= stamp <= END_OF_TIME and isinstance(seq, int) and seq >= 0):
                raise DecodeError(f"header stamp {stamp!r} / seq {seq!r} are not non-negative int64")
            self.writer.write_encoded(key, frame.type_name, frame.payload, stamp, seq)
        except (DecodeError, ValueError) as exc:
            self.stats.invalid[key] = self.stats.invalid.get(key, 0) + 1
            log.error("recorder: message on %s skipped: %s", key, exc)
            return
        self.stats.recorded[key] = self.stats.recorded.get(key, 0) + 1
        self._seen = max(self._seen, stamp)
