"""Numbers written as text, by people (options, gates) and by files (pose and stamp files).

Only ASCII decimal notation is a number here. Python's ``float()`` and ``int()`` also take ``1_0``
(10) and the digits of other scripts (``٥`` is 5), so a typo or a pasted value would become another
number in silence: ``report --radius-m 0_5`` scored revisits within 5 m.
"""

from __future__ import annotations

import re

DECIMAL = re.compile(
    r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?|[+-]?(?:nan|inf|infinity)", re.ASCII | re.IGNORECASE
)
"""A decimal number: digits, an optional point and exponent; ``nan`` and ``inf`` spelled out."""

WHOLE = re.compile(r"[+-]?\d+", re.ASCII)
"""A whole number in decimal digits."""


def is_decimal(text: str) -> bool:
    return DECIMAL.fullmatch(text.strip()) is not None


def parse_decimal(text: str) -> float:
    """``text`` as a float; ValueError unless it is :data:`DECIMAL` (spaces around allowed)."""
    if not is_decimal(text):
        raise ValueError(f"{text!r} is not a decimal number")
    return float(text)


def parse_whole(text: str) -> int:
    """``text`` as an int; ValueError unless it is :data:`WHOLE` (spaces around allowed)."""
    if WHOLE.fullmatch(text.strip()) is None:
        raise ValueError(f"{text!r} is not a whole number")
    return int(text)
