"""rostopic-echo CSV logs (``rostopic echo -p``) -> PoseidonSLAM messages.

A log has a header line ``%time,field.header.seq,field.header.stamp,field.<name>...``
(as ``../shared/data/girona_caves/dvl_linkquest.csv`` and ``depth_sensor.csv``).  Column
names are matched to the message fields case-insensitively (``field.velocityInst0`` ->
``velocityinst[0]``, ``field.dataGood3`` -> ``datagood[3]``, ``field.soundSpeed`` ->
``soundspeed``).  ``field.header.stamp`` becomes the stamp (integer nanoseconds; a value
with a decimal point is read as seconds), ``field.header.seq`` the seq,
``field.header.frame_id`` (optional) the frame id.  String fields (``errcode``,
``rawdata``) are optional columns; every numeric field is required.

Also :func:`read_frame_timestamps`, the ``<frame name> <stamp s>`` list of an image-frame
folder (``camera_frame_timestamps.txt``).
"""
from __future__ import annotations

import csv
import typing
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from common.messages import Depth, Header, Imu, LinkquestDvl, Message
from common.stamps import parse_stamp_ns
from missions.importers.errors import InputFormatError

__all__ = ["KIND_TYPES", "read_rostopic_csv", "detect_kind", "read_frame_timestamps"]

#: kind (= recording key) -> message type of the flat messages a CSV log can hold
KIND_TYPES: dict[str, type[Message]] = {
    "dvl_linkquest": LinkquestDvl,
    "depth_sensor": Depth,
    "imu_adis": Imu,
}

# a column that identifies each kind (lower-case, without the ``field.`` prefix)
_SIGNATURE = {
    "dvl_linkquest": {"velocityinst0", "datagood0"},
    "imu_adis": {"qw", "roll", "gx"},
    "depth_sensor": {"depth"},
}


def _field_spec(model: type[Message]) -> list[tuple[str, type, int]]:
    """(field name, scalar type, length or 0 for a scalar) of every non-header field."""
    spec = []
    for name, info in model.model_fields.items():
        if name == "header":
            continue
        ann = info.annotation
        if typing.get_origin(ann) is list:
            (inner,) = typing.get_args(ann)
            length = next(m.max_length for m in info.metadata if getattr(m, "max_length", None) is not None)
            spec.append((name, inner, length))
        else:
            spec.append((name, ann, 0))
    return spec


def _columns(header: list[str]) -> dict[str, int]:
    cols = {}
    for i, name in enumerate(header):
        n = name.strip().lower()
        if n.startswith("field."):
            n = n[len("field."):]
        cols[n] = i
    return cols


def detect_kind(columns: list[str] | set[str]) -> str | None:
    """The kind of a CSV log from its column names, or None."""
    cols = set(_columns(list(columns)))
    for kind, sig in _SIGNATURE.items():
        if sig <= cols:
            return kind
    return None


#: largest magnitude accepted for a float field of a sensor log (nan, inf and 1e308 are errors)
MAX_ABS_VALUE = 1e9


def _number(text: str, typ: type, path: Path, line: int, column: str) -> Any:
    try:
        if typ is int:
            try:
                return int(text)
            except ValueError:
                v = float(text)
                if not v.is_integer():
                    raise
                return int(v)
        v = float(text)
    except ValueError:
        raise InputFormatError(f"{path}: line {line}, column {column!r}: "
                               f"malformed number {text!r} (expected {typ.__name__})") from None
    if not abs(v) <= MAX_ABS_VALUE:  # nan, inf, 1e308: no sensor reports these
        raise InputFormatError(f"{path}: line {line}, column {column!r}: value {text!r} is not a finite "
                               f"number of magnitude <= {MAX_ABS_VALUE:g}")
    return v


#: (field, value type, (column index, column name) of each element -- one for a scalar, length 0)
_Column = tuple[str, type, list[tuple[int, str]], int]


def _column_plan(p: Path, model: type[Message], cols: dict[str, int], header: list[str]) -> list[_Column]:
    """Where each field of ``model`` is read from; raises :class:`InputFormatError` naming a
    missing required column."""
    plan: list[_Column] = []
    for name, typ, length in _field_spec(model):
        if length:
            idx = []
            for k in range(length):
                col = f"{name}{k}"
                if col not in cols:
                    raise InputFormatError(f"{p}: missing column 'field.{col}' (case-insensitive) "
                                           f"for {model.__name__}.{name}[{k}]")
                idx.append((cols[col], header[cols[col]]))
            plan.append((name, typ, idx, length))
        elif name in cols:
            plan.append((name, typ, [(cols[name], header[cols[name]])], 0))
        elif typ is str or not model.model_fields[name].is_required():
            continue  # optional column (errcode, rawdata, defaulted IMU fields)
        else:
            raise InputFormatError(f"{p}: missing column 'field.{name}' (case-insensitive) "
                                   f"for {model.__name__}.{name}")
    return plan


def read_rostopic_csv(path: str | Path, kind: str | None = None) -> list[tuple[str, Message]]:
    """Every record of a rostopic-echo CSV log as ``(key, message)``; ``key`` = ``kind``.

    ``kind`` is one of :data:`KIND_TYPES` (``dvl_linkquest``, ``depth_sensor``,
    ``imu_adis``); None detects it from the columns.  Raises :class:`InputFormatError`
    naming the file and the missing column, or the line and column of a malformed value.
    """
    p = Path(path)
    try:
        f = open(p, newline="")
    except FileNotFoundError:
        raise InputFormatError(f"{p}: no such file") from None
    except IsADirectoryError:
        raise InputFormatError(f"{p}: is a directory, not a CSV log") from None
    with f:
        reader = csv.reader(f)
        try:
            header = next(reader)
        except StopIteration:
            raise InputFormatError(f"{p}: empty file (expected a rostopic-echo CSV header line)") from None
        cols = _columns(header)
        if kind is None:
            kind = detect_kind(header)
            if kind is None:
                raise InputFormatError(f"{p}: cannot tell the message kind from the columns {header[:6]}...; "
                                       f"pass kind= one of {sorted(KIND_TYPES)}")
        if kind not in KIND_TYPES:
            raise InputFormatError(f"{p}: unknown kind {kind!r}; known: {sorted(KIND_TYPES)}")
        model = KIND_TYPES[kind]
        for need in ("header.seq", "header.stamp"):
            if need not in cols:
                raise InputFormatError(f"{p}: missing column 'field.{need}' (needed for {kind})")
        plan = _column_plan(p, model, cols, header)
        i_seq, i_stamp = cols["header.seq"], cols["header.stamp"]
        i_frame = cols.get("header.frame_id")
        out: list[tuple[str, Message]] = []
        ncols = len(header)
        for row in reader:
            line = reader.line_num
            if not row:
                continue
            if len(row) != ncols:
                raise InputFormatError(f"{p}: line {line}: {len(row)} values for {ncols} columns")
            try:
                stamp = parse_stamp_ns(row[i_stamp])
            except ValueError:
                raise InputFormatError(f"{p}: line {line}, column {header[i_stamp]!r}: "
                                       f"malformed stamp {row[i_stamp]!r}") from None
            seq = _number(row[i_seq], int, p, line, header[i_seq])
            values: dict[str, Any] = {}
            for name, typ, where, length in plan:
                if length:
                    values[name] = [_number(row[i], typ, p, line, col) if typ is not str else row[i]
                                    for i, col in where]
                else:
                    i, col = where[0]
                    values[name] = row[i] if typ is str else _number(row[i], typ, p, line, col)
            try:
                msg = model(header=Header(seq=seq, stamp=stamp, frame_id=row[i_frame] if i_frame is not None else ""),
                            **values)
            except ValidationError as exc:
                raise InputFormatError(f"{p}: line {line}: invalid {model.__name__}: {exc}") from None
            out.append((kind, msg))
    return out


def read_frame_timestamps(path: str | Path) -> list[tuple[str, int]]:
    """``(frame file name, stamp ns)`` of every line of a frame timestamps file.

    Each line is ``<name><tab, space or comma><stamp>`` where the stamp is seconds with a
    decimal fraction (``frame_000000.png 1372687208.617629``) or integer nanoseconds.
    Blank lines and lines starting with ``#`` are skipped.
    """
    p = Path(path)
    try:
        text = p.read_text()
    except FileNotFoundError:
        raise InputFormatError(f"{p}: no such timestamps file") from None
    out = []
    for line_no, line in enumerate(text.splitlines(), start=1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        parts = s.replace(",", " ").split()
        if len(parts) != 2:
            raise InputFormatError(f"{p}: line {line_no}: expected '<frame name> <stamp>', got {line!r}")
        try:
            out.append((parts[0], parse_stamp_ns(parts[1])))
        except ValueError:
            raise InputFormatError(f"{p}: line {line_no}: malformed stamp {parts[1]!r}") from None
    if not out:
        raise InputFormatError(f"{p}: no frame timestamps in the file")
    return out
