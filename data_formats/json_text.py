"""JSON documents as aslam writes them (``report``'s graph and summary JSON, ``info --json``,
``sweep --dry-run --json``, a sweep's task results and hashes).

No negative zero: ``-0.0`` (a heading of −0.0, a KITTI ``y_m = −t_x`` of 0) is a sign no measured
value has, and it makes two runs that agree differ in their bytes and in a diff. File names as
their bytes read as UTF-8 under a UTF-8 or C locale (:func:`_utf8_name`); under a Latin-1 locale
Python has read them as Latin-1 text, which no string here can be told from, and they stay so.
"""

from __future__ import annotations

import json
from typing import Any

from aslam.data_formats.files import utf8_text


def json_text(document: Any, *, indent: int | None = None, sort_keys: bool = False) -> str:
    """``document`` as JSON text (``json.dumps`` with ``indent`` and ``sort_keys``) ending in a newline."""
    return json.dumps(_normalised(document), indent=indent, sort_keys=sort_keys) + "\n"


def _normalised(value: Any) -> Any:
    """``value`` with every float ``-0.0`` in it (in dicts, lists and tuples) made ``0.0`` and every
    string :func:`_utf8_name`."""
    if isinstance(value, float):
        return value + 0.0  # x + 0.0 is x, and 0.0 for -0.0 (IEEE 754, round to nearest)
    if isinstance(value, str):
        return _utf8_name(value)
    if isinstance(value, dict):
        return {_normalised(key): _normalised(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [_normalised(item) for item in value]
    return value


def _utf8_name(text: str) -> str:
    """``text`` with the bytes of a file name Python could not decode read as UTF-8
    (:func:`~aslam.data_formats.files.utf8_text`), a byte that is not UTF-8 kept as ``\\udcff``:
    under a C locale without UTF-8 mode the document said ``"caf\\udcc3\\udca9"`` where a UTF-8
    locale's says ``"caf\\u00e9"``; now both say the latter."""
    if text.isascii():
        return text
    try:
        return utf8_text(text, undecodable="surrogateescape")
    except UnicodeEncodeError:  # a surrogate no file name has: the text as it is
        return text
