"""Errors of the importers."""
from __future__ import annotations

__all__ = ["InputFormatError"]


class InputFormatError(ValueError):
    """An input that cannot be imported; the message names the file and what is wrong
    (column, line, topic or type)."""
