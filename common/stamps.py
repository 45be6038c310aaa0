"""Exact conversions between decimal seconds text and integer nanosecond stamps.

Logs such as CARMEN's give times as decimal seconds (``1071078718.462369``); a float
holds such a value only to ~0.1 us, so stamps are computed from the text itself.
"""
from __future__ import annotations

from decimal import Decimal, InvalidOperation

__all__ = ["seconds_to_ns", "ns_to_text", "parse_stamp_ns"]

NS = 1_000_000_000


def seconds_to_ns(text: str) -> int:
    """Decimal seconds text -> integer nanoseconds, rounded half to even (exact: no float).

    :raises ValueError: not a finite decimal number.
    """
    try:
        d = Decimal(text)
    except InvalidOperation:
        raise ValueError(f"{text!r} is not a number") from None
    if not d.is_finite():
        raise ValueError(f"{text!r} is not finite")
    return int((d * NS).to_integral_value())


def ns_to_text(ns: int) -> str:
    """Integer nanoseconds -> seconds with exactly 9 decimals (``stamp / 1e9`` without rounding)."""
    q, r = divmod(abs(int(ns)), NS)
    return f"{'-' if ns < 0 else ''}{q}.{r:09d}"


def parse_stamp_ns(text: str) -> int:
    """A stamp as integer nanoseconds: ``1372687208633787539`` (ns) or
    ``1372687208.617629`` (seconds, decimal; converted exactly without float rounding)."""
    t = text.strip()
    if "." in t:
        sec, frac = t.split(".", 1)
        if not (sec.isdigit() and (frac.isdigit() or frac == "")):
            raise ValueError(f"not a stamp: {text!r}")
        frac = (frac + "0" * 9)[:9]
        return int(sec) * 1_000_000_000 + int(frac)
    if not t.isdigit():
        raise ValueError(f"not a stamp: {text!r}")
    return int(t)
