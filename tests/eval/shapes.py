"""A result dict against its TypedDict (:mod:`eval.results`): the keys it must and may have, and
the same check down every nested TypedDict (also inside lists, dict values and optionals)."""
from __future__ import annotations

import types
import typing
from typing import Any, get_args, get_origin, get_type_hints, is_typeddict


def _typeddicts_in(hint: Any) -> list[tuple[str, type]]:
    """(container, TypedDict) pairs a hint holds: ``""`` for the TypedDict itself (or optional),
    ``"list"`` for its items, ``"dict"`` for its values."""
    if is_typeddict(hint):
        return [("", hint)]
    origin, args = get_origin(hint), get_args(hint)
    if origin in (typing.Union, types.UnionType):
        return [pair for a in args for pair in _typeddicts_in(a)]
    if origin is list and args and is_typeddict(args[0]):
        return [("list", args[0])]
    if origin is dict and len(args) == 2 and is_typeddict(args[1]):
        return [("dict", args[1])]
    return []


def assert_shape(value: Any, td: type, where: str = "result") -> None:
    """``value`` has every required key of ``td``, no key ``td`` does not name, and so on down."""
    assert isinstance(value, dict), f"{where}: {type(value).__name__}, not a dict"
    required: frozenset[str] = td.__required_keys__
    optional: frozenset[str] = td.__optional_keys__
    missing, extra = required - set(value), set(value) - required - optional
    assert not missing and not extra, f"{where} ({td.__name__}): missing {sorted(missing)}, unknown {sorted(extra)}"
    hints = get_type_hints(td)
    for key, v in value.items():
        if v is None:
            continue
        for container, inner in _typeddicts_in(hints[key]):
            if container == "" and isinstance(v, dict):
                assert_shape(v, inner, f"{where}.{key}")
            elif container == "list":
                for i, item in enumerate(v):
                    assert_shape(item, inner, f"{where}.{key}[{i}]")
            elif container == "dict":
                for k, item in v.items():
                    assert_shape(item, inner, f"{where}.{key}.{k}")
