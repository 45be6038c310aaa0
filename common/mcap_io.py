"""MCAP recordings of PoseidonSLAM messages.

(Over 500 lines because the writer, the fast reader and the recovery of a damaged file share
one record layout, which is clearer in one place.)

Layout of a recording (what :class:`RecordingWriter` writes and the recorder produces):

- one channel per key; the topic is the namespace-relative key (``camera/image_raw``);
- one schema per message type, named by its type name (``poseidon_msgs/Image``), encoding
  ``jsonschema`` with the pydantic JSON schema; message encoding ``msgpack``;
- log time = publish time = the header stamp (event time, ns); sequence = header seq;
- metadata records: ``poseidon`` (code revision, configuration snapshot, input hash, tool)
  and, for simulated missions, whatever the generator adds (e.g. ``ground_truth``).

Reading (:func:`read_messages`) yields messages in event-time order.  A file without a
summary (a recorder killed with SIGKILL) is read sequentially up to its last complete
chunk and sorted, and :class:`RecordingError` names the file and the byte offset where a
corrupt or truncated file stops being readable.  A file with no readable MCAP record at all
(empty, random bytes, another format) is always a :class:`RecordingError`.

:func:`recording_status` tells a complete file from a damaged one, and
:func:`recover_recording` rewrites every intact message and metadata record of a damaged
file (e.g. a recorder killed with SIGKILL) into a complete MCAP that any standard reader
opens (``poseidon info FILE --recover FIXED.mcap``).
"""
from __future__ import annotations

import bisect
import functools
import hashlib
import io
import json
import logging
import mmap
import os
import stat
import struct
import subprocess
import threading
import time
from collections.abc import Iterator
from concurrent.futures import CancelledError, Future
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

import zstandard
from isal.isal_zlib import crc32  # zlib's CRC-32, by ISA-L: 5x faster than Python's zlib here
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.reader import _chunks_matching_topics, make_reader
from mcap.records import Channel, Chunk, ChunkIndex, MessageIndex, Metadata, Schema
from mcap.records import Message as McapMessage
from mcap.stream_reader import CRCValidationError, StreamReader
from mcap.summary import Summary
from mcap.writer import CompressionType, IndexType, Writer
from zstandard import ZstdError

from common.codec import decode, encode
from common.messages import Message, message_type

__all__ = [
    "RecordingWriter", "RecordedMessage", "RecordingError", "read_messages", "read_metadata",
    "recording_summary", "recording_keys", "recording_message_count", "file_sha256", "FileDigest", "DigestCache", "digest_from_file", "code_revision",
    "recording_status", "recover_recording", "read_file_order", "iter_file_order", "key_digests",
]

log = logging.getLogger(__name__)

_COMPRESSION = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}
#: zstd level of the chunks :class:`RecordingWriter` writes (docs/DECISIONS.md, "Player replay,
#: recorder compression, flow window").  mcap's writer uses zstd's default (3).  On 300 chunks (352 MB) of a simulated
#: mission, Intel Xeon: level -1 compresses in 0.89 ns per byte and decompresses in 0.64, ratio
#: 1.136; level 1 in 1.71 and 1.42, ratio 1.349: the camera frames hardly compress, so the
#: faster level costs 19 % more disk and saves the recorder and the player ~1.6 ns per byte
ZSTD_LEVEL = -1


class RecordingError(RuntimeError):
    """A recording that cannot be read; the message names the file and the byte offset."""


def code_revision() -> str:
    """The git revision of this checkout (with ``-dirty``), or ``unknown`` outside git."""
    root = Path(__file__).resolve().parent.parent
    try:
        rev = subprocess.run(["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True, text=True,
                             timeout=5, check=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, timeout=5, check=True).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return rev + ("-dirty" if dirty else "")


def file_sha256(path: str | Path, chunk: int = 1 << 20) -> str:
    digest: str = _sha256(path, chunk).hexdigest()
    return digest


def _sha256(path: str | Path, chunk: int, stop: threading.Event | None = None) -> Any:
    """hashlib's SHA-256 of the file read ``chunk`` bytes at a time (up to where ``stop`` was set)."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while not (stop is not None and stop.is_set()) and (block := f.read(chunk)):
            h.update(block)
    return h


#: environment variable: where :class:`DigestCache` keeps its entries, or ``off``
DIGEST_CACHE_ENV = "POSEIDON_DIGEST_CACHE"
#: files smaller than this are always hashed (a few ms): the cache holds the large recordings only
DIGEST_CACHE_MIN_BYTES = 64 << 20
#: entries kept at most; the least recently used go first
DIGEST_CACHE_ENTRIES = 256


class DigestCache:
    """SHA-256 digests of large files, kept between runs so that a recording replayed again is
    not hashed again (~0.9 CPU s per GB on a core the services need: ~6 s for a 60-minute
    mission's 6 GB).

    One JSON entry per file (named by the SHA-1 of its resolved path) holds the digest beside the
    file's size, inode, device, and modification and status-change times in ns, as ``os.stat``
    gave them just before and just after it was hashed.  An entry is used only while all of them
    still match: any write changes the status-change time, which no tool can set back, so a
    changed file is hashed again.  A file that changed while it was hashed is not cached.
    Directory: ``$POSEIDON_DIGEST_CACHE`` (``off``: no cache), else
    ``$XDG_CACHE_HOME/poseidonslam/digests``, else ``~/.cache/poseidonslam/digests``."""

    def __init__(self, directory: str | Path, min_bytes: int = DIGEST_CACHE_MIN_BYTES,
                 max_entries: int = DIGEST_CACHE_ENTRIES):
        self.directory = Path(directory)
        self.min_bytes = int(min_bytes)
        self.max_entries = int(max_entries)

    @classmethod
    def default(cls) -> DigestCache | None:
        """The cache the environment names (module doc), or None when it says ``off``."""
        env = os.environ.get(DIGEST_CACHE_ENV, "")
        if env.strip().lower() == "off":
            return None
        if env:
            return cls(env)
        home = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
        return cls(Path(home) / "poseidonslam" / "digests")

    @staticmethod
    def _identity(st: os.stat_result) -> list[int]:
        return [st.st_size, st.st_ino, st.st_dev, st.st_mtime_ns, st.st_ctime_ns]

    def _entry(self, path: Path) -> Path:
        return self.directory / (hashlib.sha1(str(path.resolve()).encode()).hexdigest() + ".json")

    def lookup(self, path: str | Path) -> str | None:
        """The cached digest of ``path`` when the file is unchanged since it was hashed, else None
        (an unreadable or malformed entry is logged and ignored: the file is hashed again)."""
        p = Path(path)
        st = os.stat(p)
        if not _cacheable(st, self.min_bytes):
            return None
        entry = self._entry(p)
        try:
            data = json.loads(entry.read_text())
        except FileNotFoundError:
            return None
        except (OSError, ValueError) as exc:
            log.warning("digest cache: entry %s for %s unreadable (%s); hashing the file again", entry, p, exc)
            return None
        digest = data.get("sha256") if isinstance(data, dict) else None
        if (not isinstance(digest, str) or len(digest) != 64 or data.get("path") != str(p.resolve())
                or data.get("stat") != self._identity(st)):
            return None
        try:
            os.utime(entry)  # most recently used
        except OSError as exc:
            log.debug("digest cache: cannot touch %s: %s", entry, exc)
        return digest

    def store(self, path: str | Path, before: os.stat_result, digest: str) -> bool:
        """Keep ``digest`` of ``path`` if the file still is what ``before`` described (True when
        kept).  A cache that cannot be written (read-only home) is logged, and the run goes on."""
        p = Path(path)
        if not _cacheable(before, self.min_bytes):
            return False
        try:
            if self._identity(os.stat(p)) != self._identity(before):  # written to while it was hashed
                return False
            entry = self._entry(p)
            text = json.dumps({"path": str(p.resolve()), "stat": self._identity(before), "sha256": digest})
            self.directory.mkdir(parents=True, exist_ok=True)
            tmp = entry.with_name(f"{entry.name}.{os.getpid()}.{threading.get_ident()}.tmp")
            tmp.write_text(text + "\n")
            os.replace(tmp, entry)
            self._prune()
        except OSError as exc:
            log.warning("digest cache: cannot keep the digest of %s in %s: %s", p, self.directory, exc)
            return False
        return True

    def _prune(self) -> None:
        """Remove the least recently used entries beyond ``max_entries`` (another process may
        remove one meanwhile)."""
        entries = []
        for e in self.directory.glob("*.json"):
            try:
                entries.append((e.stat().st_mtime_ns, e))
            except FileNotFoundError:
                continue
        for _, old in sorted(entries, reverse=True)[self.max_entries:]:
            old.unlink(missing_ok=True)


def _cacheable(st: os.stat_result, min_bytes: int) -> bool:
    return stat.S_ISREG(st.st_mode) and st.st_size >= min_bytes


class FileDigest:
    """The SHA-256 of a file, computed on a thread of its own from construction on: hashlib
    releases the GIL while it hashes, so the caller goes on meanwhile (a launcher plans its run
    and starts its services; ~0.9 CPU s per GB from the page cache, the disk's speed otherwise).
    With a ``cache`` (:class:`DigestCache`) an unchanged file hashed before is not read again
    (:attr:`cached` True) and a file hashed in full is remembered."""

    def __init__(self, path: str | Path, chunk: int = 1 << 20, cache: DigestCache | None = None):
        self.path = Path(path)
        self._chunk = chunk
        self._cache = cache
        self._stop = threading.Event()
        self._future: Future[str] = Future()
        self.cached = False
        known = self._lookup()
        if known is not None:
            self.cached = True
            self._future.set_running_or_notify_cancel()
            self._future.set_result(known)
            self._thread = threading.Thread(target=lambda: None, name="poseidon-sha256", daemon=True)
        else:
            self._thread = threading.Thread(target=self._work, name="poseidon-sha256", daemon=True)
        self._thread.start()

    def _lookup(self) -> str | None:
        if self._cache is None:
            return None
        try:
            return self._cache.lookup(self.path)
        except OSError:  # no such file, or not readable: the thread raises it to result()'s caller
            return None

    def _work(self) -> None:
        self._future.set_running_or_notify_cancel()
        try:
            before = os.stat(self.path) if self._cache is not None else None
            h = _sha256(self.path, self._chunk, self._stop)
            if self._cache is not None and before is not None and not self._stop.is_set():
                self._cache.store(self.path, before, h.hexdigest())
        except BaseException as exc:  # handed to whoever calls result()
            self._future.set_exception(exc)
            return
        if self._stop.is_set():
            self._future.set_exception(CancelledError(f"hashing {self.path} was cancelled"))
        else:
            self._future.set_result(h.hexdigest())

    def result(self, timeout: float | None = None) -> str:
        """The hex digest (waits for it); raises what reading the file raised."""
        return self._future.result(timeout)

    def publish_to(self, path: str | Path) -> None:
        """Once it is there, write the digest (or ``error: ...``) to ``path`` atomically, for
        another process (:func:`digest_from_file`: a distributed run's recorder)."""
        target = Path(path)

        def write(future: Future[str]) -> None:
            exc = future.exception()
            text = f"error: {type(exc).__name__}: {exc}" if exc is not None else future.result()
            tmp = target.with_name(target.name + ".tmp")
            tmp.write_text(text + "\n")
            os.replace(tmp, target)
        self._future.add_done_callback(write)

    def cancel(self) -> None:
        """Stop hashing and wait for the thread to end (a caller that no longer needs the digest)."""
        self._stop.set()
        self._thread.join()


def digest_from_file(path: str | Path, timeout_s: float = 600.0, poll_s: float = 0.05) -> str:
    """The digest :meth:`FileDigest.publish_to` wrote to ``path``, waiting for the file up to
    ``timeout_s``; RecordingError naming the file when it holds the hashing's error or never came."""
    p = Path(path)
    deadline = time.monotonic() + timeout_s
    while not p.exists():
        if time.monotonic() > deadline:
            raise RecordingError(f"{p}: the input's digest did not arrive within {timeout_s:.0f} s")
        time.sleep(poll_s)
    text = p.read_text().strip()
    if text.startswith("error:") or len(text) != 64:
        raise RecordingError(f"{p}: no digest of the input: {text}")
    return text


_MESSAGE_OPCODE = int(Opcode.MESSAGE)
_MESSAGE_RECORD = struct.Struct("<BQHIQQ")  # opcode, length, channel id, sequence, log time, publish time


_CHUNK_HEAD = struct.Struct("<BQQQQII")  # opcode, length, start, end, uncompressed size, crc, compression name length
#: the mcap writer's private state :meth:`RecordingWriter._end_chunk` uses
_CHUNK_STATE = ("enable_crcs", "enable_data_crcs", "flush", "stream", "record_builder", "index_types",
                "chunk_indices")


class _MessageIndex(MessageIndex):
    """mcap's MessageIndex record, written with one ``struct.pack`` (same bytes)."""

    def write(self, stream: Any) -> None:
        n = len(self.records)
        flat = [v for pair in self.records for v in pair]
        stream.write(struct.pack(f"<BQHI{2 * n}Q", Opcode.MESSAGE_INDEX, 6 + 16 * n, self.channel_id, 16 * n, *flat))


class RecordingWriter:
    """Write PoseidonSLAM messages into one MCAP file.

    ``flush_every`` flushes the OS file after that many messages so that a process killed
    without warning leaves every complete chunk readable.
    """

    def __init__(self, path: str | Path, compression: str = "zstd", chunk_size: int = 1 << 20,
                 profile: str = "poseidon", flush_every: int = 0, zstd_level: int = ZSTD_LEVEL):
        self.path = Path(path)
        if compression not in _COMPRESSION:
            raise ValueError(f"compression must be one of {sorted(_COMPRESSION)}, got {compression!r}")
        if not -7 <= zstd_level <= 22:
            raise ValueError(f"zstd level must be in [-7, 22], got {zstd_level}")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file: IO[bytes] = open(self.path, "wb")
        self._writer = Writer(self._file, chunk_size=chunk_size, compression=_COMPRESSION[compression])
        self._writer.start(profile=profile, library="poseidonslam")
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._channel_type: dict[str, str] = {}
        self.counts: dict[str, int] = {}
        self._flush_every = flush_every
        self._since_flush = 0
        self._closed = False
        self._chunk_size = chunk_size
        # the mcap writer's own state, which write_encoded updates directly (see _add_message)
        # (mcap's private, name-mangled attributes: untyped, hence Any)
        self._stats: Any = getattr(self._writer, "_Writer__statistics", None)
        self._chunk_builder: Any = getattr(self._writer, "_Writer__chunk_builder", None)
        self._finalize_chunk: Any = getattr(self._writer, "_Writer__finalize_chunk", None)
        self._fast = (self._stats is not None and hasattr(self._writer, "_Writer__chunk_builder")
                      and hasattr(self._writer, "_Writer__finalize_chunk"))
        self._compression = compression
        self._zstd = zstandard.ZstdCompressor(level=zstd_level)
        mcap: Any = self._writer
        if (self._fast and all(hasattr(mcap, f"_Writer__{a}") for a in _CHUNK_STATE)
                and not mcap._Writer__enable_data_crcs):
            # mcap's own chunk ends (its flush, finish and size check) run this one instead
            mcap._Writer__finalize_chunk = self._end_chunk
            self._finalize_chunk = self._end_chunk

    def _channel(self, key: str, type_name: str) -> int:
        cid = self._channels.get(key)
        if cid is not None:
            if self._channel_type[key] != type_name:
                raise ValueError(f"key {key!r} carries {self._channel_type[key]}, cannot also carry {type_name}")
            return cid
        sid = self._schemas.get(type_name)
        if sid is None:
            schema = message_type(type_name).model_json_schema()
            sid = self._writer.register_schema(type_name, "jsonschema", json.dumps(schema).encode())
            self._schemas[type_name] = sid
        cid = self._writer.register_channel(key, "msgpack", sid)
        self._channels[key] = cid
        self._channel_type[key] = type_name
        return cid

    def write(self, key: str, msg: Message) -> None:
        """Encode and record ``msg`` on ``key``."""
        self.write_encoded(key, msg.type_name, encode(msg), msg.header.stamp, msg.header.seq)

    def write_encoded(self, key: str, type_name: str, payload: bytes | memoryview, stamp: int, seq: int) -> None:
        """Record an already encoded payload (the recorder stores what it received, byte for byte)."""
        cid = self._channel(key, type_name)
        if self._fast:   # the payload is copied into the chunk once, never to a bytes object first
            self._add_message(cid, stamp, payload, seq & 0xFFFFFFFF)
        else:
            self._writer.add_message(cid, log_time=stamp, data=bytes(payload), publish_time=stamp,
                                     sequence=seq & 0xFFFFFFFF)
        self.counts[key] = self.counts.get(key, 0) + 1
        if self._flush_every:
            self._since_flush += 1
            if self._since_flush >= self._flush_every:
                self.flush()

    def _add_message(self, cid: int, stamp: int, data: bytes | memoryview, seq: int) -> None:
        """What ``mcap.writer.Writer.add_message(cid, stamp, data, stamp, seq)`` does -- the same
        statistics, chunk bounds, message index entry and Message record, byte for byte
        (``tests/common/test_mcap_fast.py`` compares the files) -- with one ``struct.pack``
        instead of a record object and a write call per field."""
        size = data.nbytes if isinstance(data, memoryview) else len(data)
        head = _MESSAGE_RECORD.pack(_MESSAGE_OPCODE, 22 + size, cid, seq, stamp, stamp)
        st = self._stats
        if st.message_count == 0 or stamp < st.message_start_time:
            st.message_start_time = stamp
        if stamp > st.message_end_time:
            st.message_end_time = stamp
        st.channel_message_counts[cid] += 1
        st.message_count += 1
        cb = self._chunk_builder
        if cb.num_messages == 0 or stamp < cb.message_start_time:
            cb.message_start_time = stamp
        if stamp > cb.message_end_time:
            cb.message_end_time = stamp
        index = cb.message_indices.get(cid)
        if index is None:
            index = cb.message_indices[cid] = _MessageIndex(channel_id=cid, records=[])
        buf = cb.record_writer._buffer
        index.records.append((stamp, buf.tell()))
        cb.num_messages += 1
        buf.write(head)
        buf.write(data)
        if buf.tell() > self._chunk_size:
            self._finalize_chunk()

    def _end_chunk(self) -> None:
        """What mcap's ``Writer.__finalize_chunk`` does -- the same Chunk record, chunk index and
        message indexes -- with zstd at the writer's level through one reused context, the records
        compressed from the chunk builder's buffer in place, and that buffer rewound for the next
        chunk instead of copied out and allocated anew (its pages stay mapped: docs/DECISIONS.md,
        CPU per mission hour)."""
        w: Any = self._writer
        cb = self._chunk_builder
        if cb.num_messages == 0:
            return
        self._stats.chunk_count += 1
        buf = cb.record_writer._buffer
        size = buf.tell()  # the records end here; a rewound buffer may hold an older chunk's bytes after it
        enable_crcs = w._Writer__enable_crcs
        with buf.getbuffer() as whole, whole[:size] as data:
            if self._compression == "zstd":
                packed: bytes = self._zstd.compress(data)
            elif self._compression == "lz4":
                import lz4.frame
                packed = lz4.frame.compress(data)
            else:
                packed = bytes(data)
            crc = crc32(data) if enable_crcs else 0
        name = {"zstd": b"zstd", "lz4": b"lz4", "none": b""}[self._compression]
        flush = w._Writer__flush
        flush()
        stream = w._Writer__stream
        start = stream.tell()
        length = 8 + 8 + 8 + 4 + 4 + len(name) + 8 + len(packed)
        stream.write(_CHUNK_HEAD.pack(Opcode.CHUNK, length, cb.message_start_time, cb.message_end_time, size,
                                      crc, len(name)) + name + struct.pack("<Q", len(packed)))
        stream.write(packed)
        index = ChunkIndex(message_start_time=cb.message_start_time, message_end_time=cb.message_end_time,
                           chunk_start_offset=start, chunk_length=9 + length, message_index_offsets={},
                           message_index_length=0, compression=name.decode(), compressed_size=len(packed),
                           uncompressed_size=size)
        records = w._Writer__record_builder
        index_start = stream.tell()
        if w._Writer__index_types & IndexType.MESSAGE:
            for cid, mi in cb.message_indices.items():
                index.message_index_offsets[cid] = index_start + records.count
                mi.write(records)
        index.message_index_length = records.count
        flush()
        w._Writer__chunk_indices.append(index)
        # ChunkBuilder.reset() without its record_writer.end(), which copies the buffer out and
        # allocates a new one; a buffer grown past 4 chunks by one large message is let go
        cb.message_end_time = cb.message_start_time = cb.num_messages = 0
        cb.message_indices.clear()
        if buf.getbuffer().nbytes > 4 * self._chunk_size:
            cb.record_writer._buffer = io.BytesIO()
        else:
            buf.seek(0)

    def add_metadata(self, name: str, data: dict[str, Any]) -> None:
        """Add a metadata record; values that are not strings are stored as JSON."""
        self._writer.add_metadata(name, {k: v if isinstance(v, str) else json.dumps(v) for k, v in data.items()})

    def flush(self, sync: bool = True) -> None:
        """The complete chunks to the operating system (a killed process loses none of them);
        ``sync``: and to disk (a crashed machine neither), or leave that to :meth:`fsync`."""
        self._file.flush()
        if sync:
            os.fsync(self._file.fileno())
        self._since_flush = 0

    def fsync(self) -> None:
        """What was flushed to the operating system so far, to disk (callable from another
        thread while this one goes on writing: the recorder's sync thread)."""
        os.fsync(self._file.fileno())

    def sync(self, to_disk: bool = True) -> None:
        """End the chunk in progress and flush: every message written so far is then readable
        from the file even if the process dies the next instant (a recorder checkpoint);
        ``to_disk`` False leaves the disk to :meth:`fsync`."""
        self._writer.flush()  # type: ignore[no-untyped-call]  # mcap leaves Writer.flush() unannotated
        self.flush(sync=to_disk)

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        self._writer.finish()  # type: ignore[no-untyped-call]  # mcap leaves Writer.finish() unannotated
        self._file.close()

    def __enter__(self) -> RecordingWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


@dataclass(frozen=True)
class RecordedMessage:
    """One message of a recording, not yet decoded."""

    key: str
    type_name: str
    stamp: int
    seq: int
    payload: bytes

    def message(self) -> Message:
        """Decode and validate (raises :class:`common.codec.DecodeError` naming the field)."""
        return decode(self.payload, message_type(self.type_name))


def _open(path: Path) -> IO[bytes]:
    try:
        return open(path, "rb")
    except FileNotFoundError:
        raise RecordingError(f"{path}: no such recording") from None
    except IsADirectoryError:
        raise RecordingError(f"{path}: is a directory, not an MCAP recording") from None


_UNREADABLE = (McapError, ValueError, EOFError, KeyError, AssertionError, OSError, struct.error)


def _summary_of(path: Path) -> Summary | None:
    """The summary section of a complete recording, None for a file without a readable one.
    Parsed once per file version (device, inode, size, modification time): the summary of a
    mission hour holds ~6000 chunk indexes, ~0.4 s to parse, and a run's launcher, player and
    recorder each ask several times."""
    try:
        st = path.stat()
    except FileNotFoundError:
        raise RecordingError(f"{path}: no such recording") from None
    return _summary_cached(str(path.resolve()), st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns)


@functools.lru_cache(maxsize=8)
def _summary_cached(path: str, _dev: int, _ino: int, _size: int, _mtime_ns: int) -> Summary | None:
    with _open(Path(path)) as f:
        try:
            return make_reader(f).get_summary()
        except _UNREADABLE:
            return None


def _reader_with(f: IO[bytes], summary: Summary, validate_crcs: bool = False) -> Any:
    """mcap's reader on ``f`` with its summary already parsed (:func:`_summary_of`)."""
    reader: Any = make_reader(f, validate_crcs=validate_crcs)
    reader._summary = summary  # the attribute mcap's SeekingReader.get_summary() caches it in
    return reader


def _has_summary(path: Path) -> bool:
    return _summary_of(path) is not None


def _sequential(path: Path, keys: set[str] | None, strict: bool) -> tuple[list[RecordedMessage], list[Metadata]]:
    """Read every complete record; stop at the first unreadable one."""
    metadata: list[Metadata] = []
    return list(_iter_sequential(path, keys, strict, metadata)), metadata


def _iter_sequential(path: Path, keys: set[str] | None, strict: bool,
                     metadata: list[Metadata]) -> Iterator[RecordedMessage]:
    """The messages of every complete record in file order, one at a time (the metadata
    records are appended to ``metadata``); stop at the first unreadable one."""
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    n = 0
    with _open(path) as raw:
        reader = StreamReader(raw, validate_crcs=True)
        good_offset = 0
        any_record = False
        try:
            for record in reader.records:
                if isinstance(record, Schema):
                    schemas[record.id] = record
                elif isinstance(record, Channel):
                    channels[record.id] = record
                elif isinstance(record, McapMessage):
                    ch = channels[record.channel_id]
                    if keys is None or ch.topic in keys:
                        n += 1
                        yield RecordedMessage(ch.topic, schemas[ch.schema_id].name, record.log_time, record.sequence,
                                              bytes(record.data))
                elif isinstance(record, Metadata):
                    metadata.append(record)
                # bytes consumed by the reader: the end of the last complete top-level record
                good_offset = reader._stream.count
                any_record = True
        except (McapError, ValueError, EOFError, KeyError, AssertionError, OSError, struct.error) as exc:
            if not any_record:
                reason = type(exc).__name__ + (f": {exc}" if str(exc) else "")
                raise RecordingError(f"{path}: not an MCAP recording ({path.stat().st_size} bytes, unreadable from "
                                     f"byte 0: {reason})") from None
            msg = (f"{path}: unreadable from about byte {good_offset} of {path.stat().st_size} "
                   f"({type(exc).__name__}: {exc}); {n} messages before that point are intact")
            if strict:
                raise RecordingError(msg) from None
            log.warning("%s", msg)


_MESSAGE_HEAD = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time
_RECORD_HEAD = struct.Struct("<BQ")  # opcode, record length


def _chunk_records(chunk: Chunk, validate_crc: bool) -> bytes:
    """The decompressed records of ``chunk`` (CRC-checked as mcap's own reader does)."""
    return _records(chunk, chunk.data, validate_crc)


def _records(chunk: Chunk, packed: bytes | memoryview, validate_crc: bool) -> bytes:
    """The records ``packed`` of ``chunk`` (its fields; ``packed`` may be a view of them instead
    of ``chunk.data``) decompressed and CRC-checked as mcap's own reader does; one stored as is
    comes back as bytes of its own."""
    if chunk.compression == "zstd":
        data = zstandard.decompress(packed, chunk.uncompressed_size)
    elif chunk.compression == "lz4":
        import lz4.frame
        data = lz4.frame.decompress(packed)
    else:  # "" (and, as mcap's reader does, anything else) is stored as is
        data = packed if isinstance(packed, bytes) else bytes(packed)
    if validate_crc and chunk.uncompressed_crc != 0:
        crc = crc32(data)
        if crc != chunk.uncompressed_crc:
            raise CRCValidationError(expected=chunk.uncompressed_crc, actual=crc, record=chunk)
    return data


_U64 = struct.Struct("<Q")


#: unmaps pages of a file mapping from the process (Linux; None elsewhere: the pages stay mapped)
_MADV_DONTNEED: int | None = getattr(mmap, "MADV_DONTNEED", None)
#: a page fault on a file mapping maps the page cache around it: 64 KiB (Linux
#: ``fault_around_bytes``), or a whole large folio, at most a 2 MiB huge page
_MAP_MARGIN = 2 << 20


class _ChunkReader:
    """The decompressed records of a summary's chunks, read through a read-only memory map of the
    file: zstd decompresses straight from the page cache, where mcap's ``Chunk.read`` copies each
    chunk into a new bytes object first (1 GB of chunks: ~0.7-1.8 against ~1.8-2.8 CPU s, decompression
    and CRC included; docs/DECISIONS.md, CPU per mission hour).  The records are decompressed and
    CRC-checked by :func:`_records`, as :func:`_chunk_records` does for ``Chunk.read`` of the record.
    Each chunk read is unmapped from the process again (``MADV_DONTNEED``): its pages stay in the
    page cache, but a reader of a 6 GB mission does not show 6 GB more resident memory.
    The file must not shrink while it is read (a mapped page past its end is SIGBUS, not an error)."""

    def __init__(self, f: IO[bytes]):
        self._map = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)
        self._view = memoryview(self._map)

    def close(self) -> None:
        self._view.release()
        self._map.close()

    def __call__(self, ci: ChunkIndex, validate_crc: bool) -> bytes:
        n, at = ci.chunk_length, ci.chunk_start_offset
        with self._view[at:at + n] as mv:  # views released on the way out, an error's included
            if len(mv) != n:
                raise EOFError(f"chunk at byte {at}: {len(mv)} of its {n} bytes in the file")
            opcode, length, start, end, size, crc, name_len = _CHUNK_HEAD.unpack_from(mv, 0)
            if opcode != Opcode.CHUNK or 9 + length != n:
                raise McapError(f"chunk index at byte {at} points at a record of opcode {opcode} and {length} "
                                f"bytes, not a chunk of {n - 9}")
            pos = _CHUNK_HEAD.size + name_len
            compression = str(mv[_CHUNK_HEAD.size:pos], "utf-8")
            (data_len,) = _U64.unpack_from(mv, pos)
            pos += 8
            if pos + data_len > n:
                raise McapError(f"chunk at byte {at}: {data_len} bytes of records overrun the record")
            chunk = Chunk(compression=compression, data=b"", message_start_time=start, message_end_time=end,
                          uncompressed_crc=crc, uncompressed_size=size)   # its fields; the records stay mapped
            with mv[pos:pos + data_len] as packed:
                data = _records(chunk, packed, validate_crc)
        if _MADV_DONTNEED is not None:
            # the chunk's pages leave this process (they stay in the page cache), with what the
            # kernel mapped before them: a fault maps a whole folio of the page cache, up to a huge
            # page, and the message indexes between chunks are never read through the map (what it
            # mapped past the chunk's end goes with the next chunk; a chunk read ahead is not undone)
            lo = max(0, at - _MAP_MARGIN)
            lo -= lo % mmap.PAGESIZE
            self._map.madvise(_MADV_DONTNEED, lo, at + n - lo)
        return data


def _chunk_messages(data: bytes, offset: int, channels: dict[int, tuple[str, str] | None],
                    start_ns: int | None) -> list[tuple[int, int, int, str, str, int, bytes]]:
    """``(log time, chunk offset, record index, key, type, seq, payload)`` of every wanted
    message in the records ``data`` of the chunk at file offset ``offset``; ``channels``:
    channel id -> (key, type) or None for a channel not wanted (KeyError for an unknown one)."""
    out = []
    pos, end, index = 0, len(data), 0
    unpack_record, unpack_message = _RECORD_HEAD.unpack_from, _MESSAGE_HEAD.unpack_from
    while pos < end:
        opcode, length = unpack_record(data, pos)
        body = pos + 9
        pos = body + length
        if pos > end:
            raise McapError(f"chunk record of {length} bytes overruns its chunk ({end - body} bytes left)")
        if opcode == _MESSAGE_OPCODE:
            if length < 22:
                raise McapError(f"message record of {length} bytes (at least 22)")
            cid, seq, log_time, _publish = unpack_message(data, body)
            named = channels[cid]
            if named is not None and (start_ns is None or log_time >= start_ns):
                out.append((log_time, offset, index, named[0], named[1], seq, data[body + 22:pos]))
        index += 1
    return out


def _merge_chunks(f: IO[bytes], summary: Any, keys: list[str] | None, start_ns: int | None,
                  validate_crc: bool, end_ns: int | None = None) -> Iterator[RecordedMessage]:
    """The messages of the summary's chunks in mcap's log-time order -- (log time, chunk
    start offset, record index inside the chunk), what ``iter_messages(log_time_order=True)``
    yields -- reading each chunk once.  A chunk is opened in (message start time, offset)
    order; every buffered message that sorts before the next chunk's first possible
    message is emitted (one sort per chunk instead of a heap operation per message)."""
    wanted = None if keys is None else set(keys)
    channels: dict[int, tuple[str, str] | None] = {}
    for cid, ch in summary.channels.items():
        if wanted is not None and ch.topic not in wanted:
            channels[cid] = None
        elif ch.schema_id == 0:
            channels[cid] = (ch.topic, "")
        elif ch.schema_id in summary.schemas:  # else a message on it is a KeyError, as with mcap's reader
            channels[cid] = (ch.topic, summary.schemas[ch.schema_id].name)
    chunks = sorted(_chunks_matching_topics(summary, keys, start_ns, end_ns),
                    key=lambda c: (c.message_start_time, c.chunk_start_offset))
    pending: list[tuple[int, int, int, str, str, int, bytes]] = []
    read_chunk = _ChunkReader(f)
    try:
        for i, ci in enumerate(chunks):
            pending.extend(_chunk_messages(read_chunk(ci, validate_crc), ci.chunk_start_offset, channels, start_ns))
            pending.sort()  # keys are unique (offset, index): the payloads are never compared
            if i + 1 < len(chunks):
                nxt = chunks[i + 1]
                cut = bisect.bisect_left(pending, (nxt.message_start_time, nxt.chunk_start_offset))
            else:
                cut = len(pending)
            for stamp, _off, _idx, key, type_name, seq, payload in pending[:cut]:
                if end_ns is not None and stamp >= end_ns:
                    return
                yield RecordedMessage(key, type_name, stamp, seq, payload)
            del pending[:cut]
    finally:
        read_chunk.close()


def read_messages(path: str | Path, keys: list[str] | None = None, strict: bool = False,
                  start_ns: int | None = None, end_ns: int | None = None) -> Iterator[RecordedMessage]:
    """Yield the messages of a recording in event-time order (stamp, then file order);
    ``start_ns``: only those stamped at or after it; ``end_ns``: only those stamped before it
    (an indexed file then reads only the chunks that can hold such messages).

    A complete file is streamed chunk by chunk, in exactly the order of mcap's
    ``iter_messages(log_time_order=True)``.  A file without a summary (killed writer)
    or with a damaged index is read sequentially: every message up to the first unreadable
    record is returned (``strict=True`` raises :class:`RecordingError` instead).
    """
    p = Path(path)
    wanted = set(keys) if keys is not None else None
    summary = _summary_of(p)
    with _open(p) as f:
        if summary is not None:
            reader = _reader_with(f, summary, validate_crcs=True)
            try:
                if summary.chunk_indexes:
                    yield from _merge_chunks(f, summary, keys, start_ns, validate_crc=True, end_ns=end_ns)
                    return
                for schema, channel, m in reader.iter_messages(topics=keys, log_time_order=True, start_time=start_ns,
                                                               ending_before=end_ns):
                    yield RecordedMessage(channel.topic, schema.name if schema else "", m.log_time, m.sequence,
                                          bytes(m.data))
                return
            except (McapError, ValueError, EOFError, KeyError, AssertionError, struct.error, ZstdError) as exc:
                raise RecordingError(f"{p}: corrupt chunk at or after byte {f.tell()}: {type(exc).__name__}: {exc}") from None
    messages, _ = _sequential(p, wanted, strict)
    messages.sort(key=lambda r: r.stamp)
    yield from (m for m in messages if (start_ns is None or m.stamp >= start_ns)
                and (end_ns is None or m.stamp < end_ns))


def key_digests(path: str | Path) -> dict[str, dict[str, Any]]:
    """Per key of a recording: ``{"messages": n, "sha256": hex}``, the digest of every message's
    stamp (ns), sequence number and payload bytes in event-time order.

    Two recordings with equal digests on a key carry the same stream on it, byte for byte,
    whatever their chunking, compression or metadata (the run's configuration and code revision
    are metadata, not messages).
    """
    hashes: dict[str, Any] = {}
    counts: dict[str, int] = {}
    for m in read_messages(path, strict=True):
        h = hashes.get(m.key)
        if h is None:
            h = hashes[m.key] = hashlib.sha256()
            counts[m.key] = 0
        h.update(struct.pack("<qQI", m.stamp, m.seq, len(m.payload)))
        h.update(m.payload)
        counts[m.key] += 1
    return {k: {"messages": counts[k], "sha256": hashes[k].hexdigest()} for k in sorted(hashes)}


def recording_keys(path: str | Path) -> dict[str, str]:
    """Key -> message type name of every channel of a recording."""
    p = Path(path)
    summary = _summary_of(p)
    if summary is not None:
        schemas = summary.schemas
        return {ch.topic: schemas[ch.schema_id].name for ch in summary.channels.values()}
    messages, _ = _sequential(p, None, strict=False)
    return {r.key: r.type_name for r in messages}


def recording_message_count(path: str | Path, keys: list[str] | None = None) -> int | None:
    """Number of messages (of ``keys``) from the summary statistics, or None without a summary."""
    p = Path(path)
    summary = _summary_of(p)
    if summary is None or summary.statistics is None:
        return None
    wanted = None if keys is None else set(keys)
    return sum(n for cid, n in summary.statistics.channel_message_counts.items()
               if wanted is None or summary.channels[cid].topic in wanted)


def read_metadata(path: str | Path) -> dict[str, dict[str, str]]:
    """Every metadata record of a recording, by name: a name written more than once gives its
    last record (the recorder's ``poseidon`` record is written again at the end with the input's
    digest)."""
    p = Path(path)
    summary = _summary_of(p)
    if summary is not None:
        with _open(p) as f:
            return {m.name: dict(m.metadata) for m in _reader_with(f, summary).iter_metadata()}
    _, metadata = _sequential(p, set(), strict=False)
    return {m.name: dict(m.metadata) for m in metadata}


def recording_status(path: str | Path) -> dict[str, Any]:
    """``{"complete", "size", "error"}``: complete means a readable summary (every standard
    reader opens it); otherwise ``error`` says where the file stops being readable.
    RecordingError if the file is not an MCAP recording at all."""
    p = Path(path)
    size = p.stat().st_size if p.exists() else 0
    if _has_summary(p):
        return {"complete": True, "size": size, "error": ""}
    try:
        _sequential(p, set(), strict=True)
    except RecordingError as exc:
        if "not an MCAP recording" in str(exc) or "no such recording" in str(exc):
            raise
        return {"complete": False, "size": size, "error": str(exc)}
    return {"complete": False, "size": size, "error": f"{p}: no summary section"}


def read_file_order(path: str | Path) -> tuple[list[RecordedMessage], dict[str, dict[str, str]]]:
    """Every intact message of a recording in file order (as written), and its metadata
    records; a damaged end is skipped (logged)."""
    messages, metadata = _sequential(Path(path), None, strict=False)
    return messages, {m.name: dict(m.metadata) for m in metadata}


def iter_file_order(path: str | Path) -> Iterator[RecordedMessage]:
    """The intact messages of a recording in file order, one at a time (a restarted recorder
    copies a recording of hours without holding it in memory); a damaged end is skipped (logged)."""
    return _iter_sequential(Path(path), None, False, [])


def recover_recording(src: str | Path, dst: str | Path, compression: str = "zstd") -> int:
    """Write every intact message and metadata record of ``src`` into a complete MCAP ``dst``.

    Returns the number of messages recovered.  ``dst`` must differ from ``src``.
    """
    src, dst = Path(src), Path(dst)
    if dst.resolve() == src.resolve():
        raise RecordingError(f"{dst}: recover into another file than the damaged one")
    messages, metadata = _sequential(src, None, strict=False)
    messages.sort(key=lambda r: r.stamp)
    with RecordingWriter(dst, compression=compression) as w:
        for m in metadata:
            w.add_metadata(m.name, dict(m.metadata))
        for r in messages:
            w.write_encoded(r.key, r.type_name, r.payload, r.stamp, r.seq)
    return len(messages)


def _summary_statistics(path: Path) -> Any:
    """The summary of a complete recording that has a statistics record, else None."""
    summary = _summary_of(path)
    return summary if summary is not None and summary.statistics is not None else None


def recording_summary(path: str | Path) -> dict[str, Any]:
    """Per-key message counts, types and time span of a recording.

    A complete recording answers from its summary section (statistics: messages per
    channel, first and last log time; channels and schemas: the types) without reading a
    message; a file without one (killed writer) is read through."""
    p = Path(path)
    summary = _summary_statistics(p)
    counts: dict[str, int] = {}
    types: dict[str, str] = {}
    first = last = None
    if summary is not None:
        stats = summary.statistics
        for cid, n in sorted(stats.channel_message_counts.items()):
            if n <= 0:
                continue
            ch = summary.channels[cid]
            counts[ch.topic] = counts.get(ch.topic, 0) + n
            types[ch.topic] = summary.schemas[ch.schema_id].name if ch.schema_id != 0 else ""
        if stats.message_count > 0:
            first, last = stats.message_start_time, stats.message_end_time
    else:
        for r in read_messages(p):
            counts[r.key] = counts.get(r.key, 0) + 1
            types[r.key] = r.type_name
            first = r.stamp if first is None else min(first, r.stamp)
            last = r.stamp if last is None else max(last, r.stamp)
    counts = {k: counts[k] for k in sorted(counts)}  # keys sorted: the same dict, in the same order, both ways
    types = {k: types[k] for k in sorted(types)}
    return {"counts": counts, "types": types, "start_ns": first, "end_ns": last,
            "duration_s": (last - first) / 1e9 if first is not None else 0.0}
