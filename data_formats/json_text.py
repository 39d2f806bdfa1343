"""JSON documents as the commands write them (``report``'s graph and summary JSON, ``info --json``,
``sweep --dry-run --json``).

No negative zero: ``-0.0`` (a heading of −0.0, a KITTI ``y_m = −t_x`` of 0) is a sign no measured
value has, and it makes two runs that agree differ in their bytes and in a diff.
"""

from __future__ import annotations

import json
from typing import Any


def json_text(document: Any, *, indent: int | None = None) -> str:
    """``document`` as JSON text (``json.dumps`` with ``indent``) ending in a newline."""
    return json.dumps(without_negative_zero(document), indent=indent) + "\n"


def without_negative_zero(value: Any) -> Any:
    """``value`` with every float ``-0.0`` in it (in dicts, lists and tuples) made ``0.0``."""
    if isinstance(value, float):
        return value + 0.0  # x + 0.0 is x, and 0.0 for -0.0 (IEEE 754, round to nearest)
    if isinstance(value, dict):
        return {key: without_negative_zero(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [without_negative_zero(item) for item in value]
    return value
