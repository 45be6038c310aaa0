"""Restart and resume of a supervised run: checkpoints, replay and de-duplication.

The launcher (:mod:`launcher.run`) restarts a service that dies; this module makes the
restarted service continue so that every stream equals an uninterrupted run's:

- **Checkpoints.**  Every ``supervise.checkpoint_interval_s`` of *event* time a service
  (the recorder: every ``supervise.recorder_checkpoint_interval_s``, shorter because
  every publisher holds its frames until the recorder has them on disk) writes ``<state_dir>/<service>.ckpt`` atomically (temporary file, fsync, rename): the
  node's state (:meth:`common.node.ServiceNode.checkpoint_state`: the algorithm core's
  objects), per input key the transport index of the next frame it has not processed,
  the event time of the last processed input, and per output key the next transport index
  with the frames its consumers may still need.  Pickle is the format: a private file of
  one run, written and read by the same code (never load one from elsewhere).  Checkpoints
  are incremental: numpy arrays of 256 KiB or more are kept as content-addressed 1 MiB blocks in
  ``<service>.ckpt.blocks/``, written only when new, so a state that grows by appending
  writes its new tail, not its whole self, every interval (:func:`save_checkpoint`).
- **Replay.**  Publishers number their data frames per key (transport index,
  :mod:`common.codec`) and keep what they sent (:class:`common.bus.BusPublisher` with
  ``retain``) until every consumer of the key has checkpointed past it: consumers report
  their checkpointed positions on ``@ckpt/<service>`` (JSON ``{key: next index}``), so the
  retained frames are about one checkpoint interval, whatever the mission length.  A
  restarted consumer puts ``{"from": n, "by": service}`` on ``@replay/<key>``; the publisher
  sends an ``R n`` frame, the frames from ``n``, its last watermark and, if the stream ended,
  end-of-stream, on the key itself, so they arrive in order with the live frames.  The
  player answers from its recording.
- **De-duplication** (:class:`SequenceGate`).  Every consumer (the recorder included) keeps
  per key the next index it expects and drops frames below it: a replay, or a restarted
  publisher producing again the outputs since its checkpoint, is harmless.  A restarted
  consumer ignores a key (data, watermarks, end-of-stream) until that key is *in step*:
  the frame it expects arrives, or a replay starting at or before it.
- **Finish.**  A finished publisher stays (answering replays) until every consumer of its
  keys reported progress ``END_OF_TIME``; a finished service checkpoints once more, so a
  restart after its end only re-announces its end.

Limits: the player is not checkpointed (a restarted player sends its recording again from
the start; consumers drop the duplicates); an un-numbered ``D`` frame (a foreign publisher)
is never de-duplicated; if every copy of a frame is gone (a consumer asking for frames
every other consumer checkpointed past, after its publisher restarted too) the consumer
fails naming the key (:class:`LostFrames`) instead of resuming wrongly.
"""
from __future__ import annotations

import json
import logging
import os
import pickle
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import xxhash

__all__ = ["Supervision", "SequenceGate", "LostFrames", "Retention", "save_checkpoint", "load_checkpoint", "CheckpointSize", "ReplayServer",
           "REPLAY", "CKPT", "checkpoint_path"]

log = logging.getLogger(__name__)

REPLAY = "@replay"
CKPT = "@ckpt"
_CKPT_VERSION = 2
_CKPT_READABLE = (1, 2)   # version 1: the same, every array inside the file


class LostFrames(RuntimeError):
    """A restarted consumer cannot get the frames it needs (trimmed everywhere)."""


@dataclass
class Supervision:
    """What a supervised service needs to know (written by the launcher as JSON)."""

    state_dir: Path
    consumers: dict[str, list[str]] = field(default_factory=dict)  # key -> services that consume it
    checkpoint_interval_ns: int = 30_000_000_000
    replay_retry_s: float = 3.0
    rejoin_timeout_s: float = 60.0
    resume: bool = False  # this process is a restart: load the checkpoint, ask for replays
    recorder_checkpoint_interval_ns: int = 5_000_000_000
    #: a live run: frames a live source no longer keeps are counted lost instead of failing the
    #: consumer (:class:`SequenceGate` ``lossy``), and a gap in a stream is asked for again
    live: bool = False
    #: live runs: what a publisher keeps for replays at most, per key (``live.retain_s`` of event
    #: time, ``live.retain_mb``; 0: no bound but the consumers' checkpoints)
    retain_ns: int = 0
    retain_bytes: int = 0

    def to_json(self) -> str:
        return json.dumps({"state_dir": str(self.state_dir), "consumers": self.consumers,
                           "checkpoint_interval_ns": self.checkpoint_interval_ns,
                           "replay_retry_s": self.replay_retry_s, "rejoin_timeout_s": self.rejoin_timeout_s,
                           "recorder_checkpoint_interval_ns": self.recorder_checkpoint_interval_ns,
                           "live": self.live, "retain_ns": self.retain_ns, "retain_bytes": self.retain_bytes})

    @classmethod
    def from_file(cls, path: str | Path, resume: bool = False) -> Supervision:
        try:
            d = json.loads(Path(path).read_text())
            return cls(Path(d["state_dir"]), {k: list(v) for k, v in d["consumers"].items()},
                       int(d["checkpoint_interval_ns"]), float(d["replay_retry_s"]), float(d["rejoin_timeout_s"]),
                       resume, int(d["recorder_checkpoint_interval_ns"]), bool(d.get("live", False)),
                       int(d.get("retain_ns", 0)), int(d.get("retain_bytes", 0)))
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise ValueError(f"{path}: not a supervision file: {type(exc).__name__}: {exc}") from None

    def consumers_of(self, keys: Iterable[str]) -> set[str]:
        return {c for k in keys for c in self.consumers.get(k, [])}


def checkpoint_path(state_dir: str | Path, service: str) -> Path:
    return Path(state_dir) / f"{service}.ckpt"


class CheckpointSize(NamedTuple):
    """What a checkpoint takes: ``total`` bytes (its file and every array block it names) and
    the bytes ``written`` to make it (the file and the blocks that were not on disk yet)."""

    total: int
    written: int


#: arrays of at least this many bytes are kept as content-addressed blocks beside the checkpoint
BLOCK_MIN_BYTES = 1 << 18
#: the size of one block (bytes of the array's C-order buffer)
BLOCK_BYTES = 1 << 20


def blocks_dir(path: Path) -> Path:
    """Where the array blocks of the checkpoint ``path`` live (``<service>.ckpt.blocks``)."""
    return path.with_name(path.name + ".blocks")


class _BlockPickler(pickle.Pickler):
    """Pickles a checkpoint, keeping every large numpy array out of the file: its buffer is cut
    into ``BLOCK_BYTES`` blocks named by their XXH3-128 digest, and a block already on disk is not
    written again.  A state that grows by appending (the sequence memory's frames, the map's
    nodes, the LVC templates) therefore writes only its new tail at each checkpoint."""

    def __init__(self, file: Any, blocks: Path):
        super().__init__(file, protocol=pickle.HIGHEST_PROTOCOL)
        self.blocks = blocks
        self.names: set[str] = set()
        self.total = 0
        self.written = 0

    def persistent_id(self, obj: Any) -> Any:
        if type(obj) is not np.ndarray or obj.nbytes < BLOCK_MIN_BYTES or obj.dtype.hasobject:
            return None
        buf = np.ascontiguousarray(obj).reshape(-1).view(np.uint8).data
        names = []
        for start in range(0, len(buf), BLOCK_BYTES):
            piece = buf[start:start + BLOCK_BYTES]
            name = xxhash.xxh3_128_hexdigest(piece)
            names.append(name)
            self.total += len(piece)
            if name in self.names:
                continue
            self.names.add(name)
            block = self.blocks / name
            if not block.exists():
                tmp = block.with_name(name + ".tmp")
                with open(tmp, "wb") as f:
                    f.write(piece)
                    f.flush()
                    os.fsync(f.fileno())
                os.replace(tmp, block)
                self.written += len(piece)
        return ("ndarray", obj.dtype.str, obj.shape, names)


class _BlockUnpickler(pickle.Unpickler):
    def __init__(self, file: Any, path: Path):
        super().__init__(file)
        self.path = path

    def persistent_load(self, pid: Any) -> Any:
        kind, dtype, shape, names = pid
        if kind != "ndarray":
            raise pickle.UnpicklingError(f"unknown persistent id {kind!r}")
        parts = []
        for name in names:
            block = blocks_dir(self.path) / name
            if not block.is_file():
                raise _MissingBlock(f"{self.path}: array block {block.name} is missing from {block.parent}")
            parts.append(block.read_bytes())
        buf = bytearray(b"".join(parts))   # writable: the restored state is mutated in place
        return np.frombuffer(buf, dtype=np.dtype(dtype)).reshape(shape)


def save_checkpoint(path: Path, state: dict[str, Any]) -> CheckpointSize:
    """Write ``state`` to ``path`` atomically (temporary file, fsync, rename); returns its size.

    Pickled straight into the file (no in-memory copy of the whole checkpoint: a service's
    peak memory does not grow with its state at every checkpoint).  Incremental: large numpy
    arrays go to content-addressed blocks in :func:`blocks_dir` (:class:`_BlockPickler`), so
    what a checkpoint writes is what changed since the last one.  The blocks a new checkpoint
    needs are on disk (fsync) before its file replaces the old one; blocks no checkpoint names
    any more are deleted after.  A crash in between leaves extra blocks, never missing ones."""
    path.parent.mkdir(parents=True, exist_ok=True)
    blocks = blocks_dir(path)
    blocks.mkdir(exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as f:
        pickler = _BlockPickler(f, blocks)
        pickler.dump({"version": _CKPT_VERSION, **state})
        f.flush()
        os.fsync(f.fileno())
        size = f.tell()
    os.replace(tmp, path)
    for old in blocks.iterdir():
        if old.name not in pickler.names:
            old.unlink()
    return CheckpointSize(total=size + pickler.total, written=size + pickler.written)


def load_checkpoint(path: Path, attempts: int = 5) -> dict[str, Any] | None:
    """The checkpoint at ``path``, or None when there is none yet; ValueError naming the file if unreadable.

    A reader may race a writer (a monitor, a test, a tool reading a live service's checkpoint):
    the writer replaces the file and then deletes the blocks only the old one named, so a reader
    still on the old file can find one of its blocks gone.  When a block is missing and the file
    was replaced meanwhile (another inode or mtime), the load starts again on the new file, up to
    ``attempts`` times; a block missing from an unchanged file is damage and raises at once."""
    if not path.exists():
        return None
    for _ in range(max(1, attempts)):
        before = path.stat()
        try:
            state = _load_once(path)
        except _MissingBlock as exc:
            try:
                now = path.stat()
            except FileNotFoundError:
                raise ValueError(str(exc)) from None
            if (now.st_ino, now.st_mtime_ns) == (before.st_ino, before.st_mtime_ns):
                raise ValueError(str(exc)) from None
            log.debug("%s: replaced while being read; reading it again", path)
            continue
        if not isinstance(state, dict) or state.get("version") not in _CKPT_READABLE:
            raise ValueError(f"{path}: not a checkpoint of version {_CKPT_VERSION}")
        return state
    raise ValueError(f"{path}: replaced by its writer during each of {attempts} reads")


class _MissingBlock(Exception):
    """An array block named by the checkpoint file is not on disk (message names both)."""


def _load_once(path: Path) -> Any:
    try:
        with open(path, "rb") as f:
            return _BlockUnpickler(f, path).load()
    except (_MissingBlock, ValueError):
        raise
    except Exception as exc:  # noqa: BLE001 - any unpickling failure is a damaged checkpoint
        raise ValueError(f"{path}: unreadable checkpoint: {type(exc).__name__}: {exc}") from None


class SequenceGate:
    """Per-key de-duplication of numbered frames (see the module notes).

    ``positions``: next expected index per key; keys in ``catch_up`` are out of step (a
    restarted consumer) until the expected frame or a replay starting at or before it arrives.
    Live runs (``live``): a gap in a stream that the consumer's own bounded queue did not make
    (``queue_dropped(key, lo, hi)``: how many of indices ``lo..hi-1`` it dropped) is frames lost
    in transit -- a hub restarted, a link cut -- and puts the key back into catch-up, so the
    frames are asked for again; a replay that starts past the expected index (the publisher no
    longer keeps the frames: the retention bound, ``live.retain_s`` / ``live.retain_mb``) is
    counted per key in ``lost`` (and ``missing``) and the stream continues from it, where a
    replay fails the consumer (:class:`LostFrames`).
    """

    def __init__(self, positions: dict[str, int] | None = None, catch_up: Iterable[str] = (), owner: str = "",
                 missing: dict[str, int] | None = None, live: bool = False,
                 queue_dropped: Callable[[str, int, int], int] | None = None,
                 lost: dict[str, int] | None = None):
        self.expected: dict[str, int] = dict(positions or {})
        self.catch_up: set[str] = set(catch_up)
        self.owner = owner
        self.live = live
        self.queue_dropped = queue_dropped
        self.duplicates = 0
        self.skipped = 0  # frames of a key that is not in step yet
        self.gaps = 0
        self.refetched = 0  # gaps asked for again (live)
        #: per key, how many numbered frames never arrived (the index jumped over them)
        self.missing: dict[str, int] = missing if missing is not None else {}
        #: per key, frames that could not be caught up (live: no longer kept by the publisher)
        self.lost: dict[str, int] = lost if lost is not None else {}

    def in_step(self, key: str) -> bool:
        return key not in self.catch_up

    def data(self, key: str, index: int) -> bool:
        """Accept (True) or drop (False) a data frame with transport ``index`` (-1: unnumbered,
        accepted, and its key in step: an unnumbered stream is never replayed)."""
        if index < 0:
            self.catch_up.discard(key)
            return True
        exp = self.expected.get(key)
        if key in self.catch_up:
            if index != (exp or 0):
                self.skipped += 1
                return False
            self.catch_up.discard(key)
            log.info("%s: %s in step again at index %d", self.owner, key, index)
        elif exp is not None and index < exp:
            self.duplicates += 1
            return False
        elif exp is not None and index > exp:
            dropped = self.queue_dropped(key, exp, index) if self.queue_dropped is not None else 0
            if self.live and dropped < index - exp:
                self.catch_up.add(key)
                self.refetched += 1
                self.skipped += 1
                log.warning("%s: frames %d..%d of %s lost in transit; asking for them again", self.owner, exp,
                            index - 1, key)
                return False
            self.gaps += 1
            self.missing[key] = self.missing.get(key, 0) + index - exp
            log.warning("%s: frames %d..%d of %s never arrived", self.owner, exp, index - 1, key)
        self.expected[key] = index + 1
        return True

    def control(self, key: str) -> bool:
        """Watermarks and end-of-stream count only once the key is in step."""
        return key not in self.catch_up

    def replay(self, key: str, start: int, by: str = "") -> None:
        """An ``R start`` frame: the publisher now sends every frame from ``start`` (``by``: the
        consumer that asked for it; a replay another consumer asked for that starts after what
        this one expects is not its answer: it keeps waiting for its own)."""
        if key not in self.catch_up:
            return
        exp = self.expected.get(key, 0)
        if start > exp and by and by != self.owner:
            return
        if start > exp:
            if not self.live:
                raise LostFrames(f"{self.owner}: frames {exp}..{start - 1} of {key} are no longer kept by its publisher")
            n = start - exp
            self.lost[key] = self.lost.get(key, 0) + n
            self.missing[key] = self.missing.get(key, 0) + n
            self.expected[key] = start
            log.error("%s: frames %d..%d of %s are no longer kept by its publisher (retention bound): %d lost; "
                      "continuing from %d", self.owner, exp, start - 1, key, n, start)
        self.catch_up.discard(key)
        log.info("%s: %s in step again (replay from %d, expecting %d)", self.owner, key, start,
                 self.expected.get(key, 0))


class Retention:
    """The bound on what a publisher keeps for replays in a live run, per key: frames older than
    ``max_age_ns`` of event time behind the newest sent, and beyond ``max_bytes``, are forgotten
    even before every consumer checkpointed past them (a consumer that needs them later counts
    them lost, :class:`SequenceGate`).  0 leaves that limit out."""

    def __init__(self, max_age_ns: int = 0, max_bytes: int = 0):
        if max_age_ns < 0 or max_bytes < 0:
            raise ValueError(f"a retention bound is >= 0, got {max_age_ns} ns, {max_bytes} bytes")
        self.max_age_ns = max_age_ns
        self.max_bytes = max_bytes
        self._stamps: dict[str, deque[tuple[int, int]]] = {}  # key -> (index, stamp) of frames sent
        self._aged: dict[str, int] = {}  # key -> the index after the newest frame that aged out

    def sent(self, pub: Any, stamp_ns: int) -> list[int]:
        """``pub`` just numbered a frame stamped ``stamp_ns``: forget what falls outside the
        bound; returns the indices forgotten.  Only frames seen here age out (with everything
        numbered before them): frames a restarted publisher restored from its checkpoint stay
        until a newer frame ages out, or its consumers checkpoint past them."""
        if self.max_age_ns:
            kept = self._stamps.setdefault(pub.key, deque())
            kept.append((pub.index - 1, stamp_ns))
            while kept and kept[0][1] < stamp_ns - self.max_age_ns:
                self._aged[pub.key] = kept.popleft()[0] + 1
        gone: list[int] = pub.bound(1 << 62, self.max_bytes or 1 << 62, self._aged.get(pub.key, 0))
        return gone


class ReplayServer:
    """The publisher side: answers replay requests for ``publishers`` and trims their retained
    frames by the consumers' checkpoint reports.  Requests are queued by Zenoh callbacks and
    answered by the owner's thread (:meth:`serve`), so a replay never interleaves with a send."""

    def __init__(self, bus: Any, publishers: dict[str, Any], consumers: dict[str, list[str]],
                 wake: Callable[[], None] | None = None):
        self.bus = bus
        self.publishers = publishers
        self.consumers = consumers
        self._acks: dict[str, dict[str, int]] = {}
        self._requests: list[tuple[str, int, str]] = []
        self._lock = threading.Lock()
        self._wake = wake
        self.served = 0
        #: per key, frames asked for that the publisher no longer kept (the replay began after them)
        self.short: dict[str, int] = {}
        for key in publishers:
            bus.subscribe_callback(f"{REPLAY}/{key}", self._on_request)
        bus.subscribe_callback(f"{CKPT}/*", self._on_ack)

    def add(self, key: str, publisher: Any) -> None:
        """Answer replays of ``key`` too (a publisher declared after the server)."""
        if key in self.publishers:
            return
        self.publishers[key] = publisher
        self.bus.subscribe_callback(f"{REPLAY}/{key}", self._on_request)

    def _on_request(self, key: str, payload: bytes) -> None:
        key = key.removeprefix(REPLAY + "/")
        try:
            req = json.loads(payload)
            start, by = int(req["from"]), str(req.get("by", "?"))
        except (ValueError, KeyError, TypeError) as exc:
            log.error("replay request on %s ignored: %s", key, exc)
            return
        if key not in self.publishers or start < 0:
            return
        with self._lock:
            self._requests.append((key, start, by))
        if self._wake is not None:
            self._wake()

    def _on_ack(self, key: str, payload: bytes) -> None:
        service = key.removeprefix(CKPT + "/")
        try:
            positions = {str(k): int(v) for k, v in json.loads(payload).items()}
        except (ValueError, AttributeError, TypeError) as exc:
            log.error("checkpoint report of %s ignored: %s", service, exc)
            return
        with self._lock:
            self._acks[service] = positions
            acks = dict(self._acks)
        for k, pub in self.publishers.items():
            users = self.consumers.get(k, [])
            if pub.retain and users and all(u in acks for u in users):
                pub.trim(min(acks[u].get(k, 0) for u in users))

    def pending(self) -> bool:
        # asked once per frame by the owner thread: reading the list's length is atomic, and a
        # request appended during the read is seen at the next call (as it would be with the lock)
        return bool(self._requests)

    def serve(self, source: Callable[[str, int], tuple[int, Iterable[bytes]]] | None = None) -> int:
        """Answer the queued requests (owner thread).  ``source(key, start) -> (first, frames)``
        supplies frames kept elsewhere (the player's recording).  Returns how many were answered."""
        with self._lock:
            requests, self._requests = self._requests, []
        for key, start, by in requests:
            pub = self.publishers[key]
            if source is not None:
                first, frames = source(key, start)
                begin = pub.replay(start, frames, first, by=by)
            else:
                begin = pub.replay(start, by=by)
            if begin > start:
                self.short[key] = self.short.get(key, 0) + begin - start
                log.warning("replay of %s asked from %d by %s: frames up to %d are no longer kept", key, start, by,
                            begin - 1)
            log.info("replayed %s from %d (asked from %d by %s; next %d)", key, begin, start, by, pub.index)
            self.served += 1
        return len(requests)


def request_replays(bus: Any, gate: SequenceGate, by: str, last: dict[str, float], retry_s: float) -> None:
    """Ask (again, every ``retry_s`` wall seconds) for the keys ``gate`` still catches up on."""
    now = time.monotonic()
    for key in sorted(gate.catch_up):
        if now - last.get(key, -1e9) >= retry_s:
            start = gate.expected.get(key, 0)
            bus.session.put(bus.full_key(f"{REPLAY}/{key}"), json.dumps({"from": start, "by": by}).encode())
            last[key] = now
            log.info("%s: asked for a replay of %s from %d", by, key, start)


def report_checkpoint(bus: Any, service: str, positions: dict[str, int]) -> None:
    """Tell publishers what ``service`` has checkpointed (they may forget older frames)."""
    bus.session.put(bus.full_key(f"{CKPT}/{service}"), json.dumps(positions).encode())
