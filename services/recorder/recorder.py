"""Recorder: every key of the namespace into one MCAP file per run.

Payloads are written byte for byte as received, one channel per key, one schema per
message type, log time = header stamp (event time).  The ``poseidon`` metadata record holds
the full configuration, the code revision and the input's hash.  The file is flushed to the
operating system at least every ``flush_interval_s`` (wall clock: this is transport, not
algorithm), so a recorder killed with SIGKILL leaves every complete chunk readable
(:func:`common.mcap_io.read_messages` recovers it), and synced to disk on a thread of its own
(the recorder's sync thread), so that receiving never waits for the disk.

The recorder stops when end-of-stream has arrived on every key in ``expect`` (the
launcher passes the player's keys and every service output), or when stopped.
Frames it cannot read (malformed, unknown type, no readable header, a key already
carrying another type) are logged with their key, counted and skipped: nothing a publisher
sends can stop the recorder.  Of a payload only the header is read
(:func:`common.codec.decode_header`): the services that decode the message check the rest.
An ``@abort`` on the bus (a service died, see
:mod:`common.bus`) stops it after writing what has arrived; the file is then closed with
its summary and ``RecorderStats.aborted`` says why.  On a normal end it reports progress
``END_OF_TIME`` so the player knows it finished.

Numbered frames it already has (a replay, a restarted publisher) are not recorded twice
(:class:`common.resume.SequenceGate`; ``RecorderStats.duplicates``); frames whose numbers were
skipped never arrived: counted ``missing`` per key (see :mod:`common.live`).  Supervised
(``supervision``), every ``supervise.recorder_checkpoint_interval_s`` of event time it ends the MCAP
chunk in progress; its sync thread then syncs the file and only after that saves per key the
messages recorded and the next transport index as they were at the chunk's end
(``<state_dir>/recorder.ckpt``) and reports those positions on ``@ckpt/recorder``, while the
recorder goes on receiving (the next checkpoint waits for the one in flight).  Restarted
(``supervision.resume``), it rewrites its partial file keeping, per key, exactly the messages
its checkpoint counted (anything written after the checkpoint is received again), continues it,
and asks every publisher for a replay from its checkpoint: the final file holds every message
exactly once.

Copied keys (``copy_from``, ``copy_keys``: ``player.replay: copied``, the default of a replay): the
input recording's keys that no service reads do not travel over the bus; the recorder reads them
from the input itself and writes each message once the event time it has received passes the
message's stamp, and the rest at the end of the run, so the run's recording holds them byte for byte
as the input does, without their publishing, routing and receiving (2/3 of the simulator's
messages).  Its checkpoint counts them with the rest; restarted, it continues them after its
checkpoint's event time.  An aborted or stopped run copies nothing more.

The input's digest (``input_digest``: a function returning a replay's input SHA-256, which the
launcher computes from the run's start on, while everything else starts): the metadata record is
written twice, at the start with ``input_sha256`` empty, so that a recording cut short still names
its configuration and code, and at a normal end again with the digest (waiting for it if need be).
Readers take a name's last record (:func:`common.mcap_io.read_metadata`).

The recorder is a :class:`common.worker.Sink` (receive loop, de-duplication, replay
requests, checkpoints and abort handling are shared with the services' runner).
"""
from __future__ import annotations

import logging
import os
import time
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from common.bus import Bus
from common.codec import DecodeError, decode_frame, decode_header
from common.mcap_io import (
    ZSTD_LEVEL,
    RecordedMessage,
    RecordingError,
    RecordingWriter,
    iter_file_order,
    read_messages,
)
from common.ordering import END_OF_TIME
from common.resume import Supervision
from common.worker import Sink, SinkStats

__all__ = ["Recorder", "RecorderStats"]

log = logging.getLogger(__name__)


@dataclass
class RecorderStats(SinkStats):
    recorded: dict[str, int] = field(default_factory=dict)
    invalid: dict[str, int] = field(default_factory=dict)
    ended: list[str] = field(default_factory=list)
    path: str = ""
    resumed_messages: int = 0

    def as_dict(self) -> dict[str, Any]:
        return {"service": "recorder", "path": self.path, "recorded": self.recorded, "invalid": self.invalid,
                "ended": sorted(self.ended), "aborted": self.aborted, "duplicates": self.duplicates,
                "missing": self.missing, "lost": self.lost,
                "checkpoints": self.checkpoints, "checkpoint_ms": round(self.checkpoint_ms, 3),
                "resumed_messages": self.resumed_messages}


class Recorder(Sink):
    """Record every key of the bus's namespace into ``out`` (see the module notes)."""

    stats: RecorderStats
    stop_at_once = False  # stopped: write what has already arrived, then close the file

    def __init__(self, bus: Bus, out: str | Path, expect: Iterable[str] | None = None,
                 metadata: dict[str, Any] | None = None, compression: str = "zstd", chunk_size: int = 1 << 20,
                 flush_interval_s: float = 0.5, name: str = "recorder", supervision: Supervision | None = None,
                 copy_from: str | Path | None = None, copy_keys: Iterable[str] = (), zstd_level: int = ZSTD_LEVEL,
                 input_digest: Callable[[], str] | None = None):
        self.out = Path(out)
        self.input_digest = input_digest
        self.copy_from = Path(copy_from) if copy_from is not None else None
        self.copy_keys = sorted(copy_keys) if copy_from is not None else []
        if self.copy_from is not None and self.copy_from.resolve() == self.out.resolve():
            raise ValueError(f"recorder: copy_from {self.copy_from} is the output recording itself")
        self._copy: Iterator[RecordedMessage] | None = None
        self._copy_next: RecordedMessage | None = None
        self.expect = set(expect) if expect is not None else None
        self.metadata = metadata or {}
        self._seen = -1
        self._compression, self._chunk_size, self._zstd_level = compression, chunk_size, zstd_level
        self._resume = supervision is not None and supervision.resume
        # a restarted recorder continues its file (run() rewrites it); never truncate it here
        self._writer = None if self._resume else RecordingWriter(self.out, compression=compression,
                                                                  chunk_size=chunk_size, zstd_level=zstd_level)
        self.flush_interval_s = flush_interval_s
        # fsync (the periodic flush, a checkpoint) on a thread of its own: 10-60 ms of waiting
        # for the disk each, every 0.2-0.5 s of a fast replay, that the receiving need not wait
        self._syncer = ThreadPoolExecutor(1, thread_name_prefix="poseidon-recorder-sync")
        self._syncing: Future[None] | None = None
        self._last_flush = 0.0
        self._ended: set[str] = set()  # = set(stats.ended)
        super().__init__(name, bus, RecorderStats(path=str(self.out)), supervision)
        self.subscribe(["**"])

    @property
    def writer(self) -> RecordingWriter:
        """The open recording (after :meth:`run` started it)."""
        assert self._writer is not None
        return self._writer

    def finished(self) -> bool:
        return self.expect is not None and self.expect <= self._ended

    # ---- supervision ------------------------------------------------------------------
    def checkpoint(self) -> None:
        """End the chunk, then on the sync thread: the file to disk, and only then the state
        saved and the positions reported (see the module notes)."""
        t0 = time.perf_counter()
        self._await_sync()  # the previous checkpoint's report first: positions only go forward
        self.writer.sync(to_disk=False)
        positions = dict(self.gate.expected)
        state = {"service": self.name, "counts": dict(self.writer.counts), "positions": positions, "seen": self._seen}
        stamp = self._ckpt_stamp = self._seen  # the next one is due from here on
        self._sync_in_background(lambda: self.save_state(state, positions, stamp, t0))

    def _sync_in_background(self, then: Callable[[], object] | None = None) -> None:
        """The recording to disk on the sync thread, then ``then()``; after the sync in flight."""
        self._await_sync()
        writer = self.writer

        def work() -> None:
            writer.fsync()
            if then is not None:
                then()
        self._syncing = self._syncer.submit(work)

    def _await_sync(self) -> None:
        """Wait for the sync in flight; its error is raised here."""
        if self._syncing is not None:
            syncing, self._syncing = self._syncing, None
            syncing.result()

    def _new_file(self, path: Path) -> RecordingWriter:
        """A recording at ``path`` holding the run's metadata record."""
        writer = RecordingWriter(path, compression=self._compression, chunk_size=self._chunk_size,
                                 zstd_level=self._zstd_level)
        writer.add_metadata("poseidon", self.metadata)
        return writer

    def _resume_file(self) -> None:
        """Restarted: keep per key the messages the checkpoint counted, continue the file."""
        state = self.load_state()
        expect = sorted(self.expect or [])
        if state is None:
            log.warning("recorder: restarted without a checkpoint: recording again from the start")
            self._writer = self._new_file(self.out)
            self.resume_gate({}, expect)
            return
        counts: dict[str, int] = state["counts"]
        # copied message by message: a recording of hours is never held in memory
        tmp = self.out.with_name(self.out.name + ".resume")
        writer = self._new_file(tmp)
        n: dict[str, int] = {}
        intact = kept = 0
        for m in iter_file_order(self.out) if self.out.exists() else ():
            intact += 1
            if n.get(m.key, 0) < counts.get(m.key, 0):
                writer.write_encoded(m.key, m.type_name, m.payload, m.stamp, m.seq)
                n[m.key] = n.get(m.key, 0) + 1
                kept += 1
        short = {k: (n.get(k, 0), c) for k, c in counts.items() if n.get(k, 0) < c}
        if short:
            writer.close()
            tmp.unlink()
            raise RecordingError(f"{self.out}: the recorder checkpoint counts messages the file does not hold "
                                 f"(key: (in file, checkpointed)) {short}")
        writer.sync()
        os.replace(tmp, self.out)  # the open file is now the recording
        writer.path = self.out
        self._writer = writer
        for k, c in counts.items():
            self.stats.recorded[k] = c
        self.stats.resumed_messages = kept
        self._seen = self._ckpt_stamp = int(state["seen"])
        self.resume_gate(state["positions"], sorted(set(expect) | set(state["positions"])))
        log.warning("recorder: resumed %s with %d messages (of %d intact in the file), positions %s", self.out,
                    kept, intact, state["positions"])

    # ---- run ----------------------------------------------------------------------------
    def run(self) -> RecorderStats:
        """Record until end-of-stream on every expected key, a stop or an abort; the file
        is closed with its summary in every case."""
        if self.input_digest is not None:
            self.metadata = {**self.metadata, "input_sha256": ""}  # until the digest is there
        try:
            if self._resume:
                self._resume_file()
            else:
                self.writer.add_metadata("poseidon", self.metadata)
            self._start_copy()
            self.writer.flush()
            self.bus.declare_alive(self.name)
            self._last_flush = time.monotonic()
            if self.receive() and not self.stats.aborted:
                self._copy_until(END_OF_TIME)
                self._write_digest()
        finally:
            try:
                self._await_sync()
            finally:
                self._syncer.shutdown()
                if self._writer is not None:
                    self.writer.close()
        if self.finished():
            self.progress.report(END_OF_TIME, force=True)  # finished normally (see common.bus)
        return self.stats

    def _write_digest(self) -> None:
        """The metadata record again, with the input's SHA-256 (waits for the hashing)."""
        if self.input_digest is None:
            return
        t0 = time.perf_counter()
        self.metadata = {**self.metadata, "input_sha256": self.input_digest()}
        self.writer.add_metadata("poseidon", self.metadata)
        log.debug("recorder: input digest written (waited %.2f s for it)", time.perf_counter() - t0)

    def _start_copy(self) -> None:
        """Open the copied keys of the input after what the file already holds (a resumed file:
        every copied message up to the checkpoint's event time)."""
        if self.copy_from is None or not self.copy_keys:
            return
        start = self._seen + 1 if self._seen >= 0 else None
        self._copy = read_messages(self.copy_from, keys=self.copy_keys, strict=True, start_ns=start)
        self._copy_next = next(self._copy, None)

    def _copy_until(self, stamp: int) -> None:
        """Write the copied keys' messages stamped at or before ``stamp``."""
        m = self._copy_next
        if m is None or m.stamp > stamp:
            return
        it, recorded, write = self._copy, self.stats.recorded, self.writer.write_encoded
        assert it is not None
        while m is not None and m.stamp <= stamp:
            write(m.key, m.type_name, m.payload, m.stamp, m.seq)
            recorded[m.key] = recorded.get(m.key, 0) + 1
            m = next(it, None)
        self._copy_next = m

    def on_frame(self, key: str, data: bytes) -> None:
        self._handle(key, data)
        if self._copy_next is not None:
            self._copy_until(self._seen)
        if self._seen >= 0:
            self.progress.report(self._seen, force=self.queue.empty())
        if time.monotonic() - self._last_flush > self.flush_interval_s:
            self.writer.flush(sync=False)
            if self._syncing is None or self._syncing.done():  # else the sync in flight will do
                self._sync_in_background()
            self._last_flush = time.monotonic()
        sup = self.supervision
        if sup is not None and self.checkpoint_due(self._seen, sup.recorder_checkpoint_interval_ns):
            self.checkpoint()

    def _handle(self, key: str, data: bytes) -> None:
        try:
            frame = decode_frame(data)
        except DecodeError as exc:
            self.stats.invalid[key] = self.stats.invalid.get(key, 0) + 1
            log.error("recorder: bad frame on %s skipped: %s", key, exc)
            return
        kind = frame.kind
        if kind == "watermark":  # the most frequent frame
            if self.gate.control(key) and frame.stamp > self._seen:
                self._seen = frame.stamp
            return
        if kind == "replay":
            self.gate.replay(key, frame.index, frame.type_name)
            return
        if kind == "eos":
            if self.gate.control(key) and key not in self._ended:
                self._ended.add(key)
                self.stats.ended.append(key)
            return
        if not self.gate.data(key, frame.index):
            self.stats.duplicates += 1
            self.progress.repeat()  # a restarted player learns how far the recorder is
            return
        try:
            header = decode_header(frame.payload)  # the body is the readers' to check
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
