"""Bounds on route files, checked on the text before the route is built (docs/formats.md, "Route files").

A route file is untrusted input: 1e308 coordinates overflow the pose arithmetic, 100,000 nested
brackets overflow the JSON parser's recursion, and millions of actions or kilometres of travel make
a world and a plan no machine renders. These bounds are far beyond any indoor walkthrough and
make every such file one ``RouteError`` line instead.
"""

from __future__ import annotations

import json
import math
import re
import sys
from pathlib import Path
from typing import Any

from aslam.data_formats.files import check_input_file
from aslam.recorder.errors import RouteError

MAX_FILE_BYTES = 10_000_000
MAX_DEPTH = 32
"""JSON nesting; a route needs 3 (object → actions list → action object)."""
MAX_ACTIONS = 100_000
MAX_COORDINATE_M = 1_000.0
"""|start.x_m|, |start.y_m| and every commanded position stay within 1 km of the origin."""
MAX_TURN_DEG = 3600.0
MAX_ROUTE_LENGTH_M = 2_000.0
"""Total distance driven in one lap (a generated world costs about 13 ms and 0.1 MB per metre)."""

_STRING = re.compile(r'"(?:[^"\\]|\\.)*"', re.DOTALL)
_BRACKET = re.compile(r"[\[\]{}]")


class _DuplicateKey(Exception):
    pass


def _no_duplicates(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    """A JSON object, refused when a key repeats: ``json`` would keep the last in silence (a route
    whose second ``"actions"`` list replaced the first)."""
    doc: dict[str, Any] = {}
    for key, value in pairs:
        if key in doc:
            raise _DuplicateKey(key)
        doc[key] = value
    return doc


def read_route_document(path: Path | str) -> Any:
    """The JSON document of a route file, refused (RouteError naming the file and the bound) beyond
    the bounds above or when it is not JSON.

    The file must be a regular file (a FIFO is refused, not waited on) of UTF-8 text, a byte-order
    mark before it skipped (it was refused: "Unexpected UTF-8 BOM"). Values the
    route parser itself checks (types, a forward leg's sign and length) are left to it.
    """
    size = check_input_file(Path(path), error=RouteError, what="a route file")
    if size > MAX_FILE_BYTES:
        raise RouteError(f"route file is larger than {MAX_FILE_BYTES:,} bytes", path=path)
    try:
        text = Path(path).read_text(encoding="utf-8-sig")  # a byte-order mark (Windows editors) is no text
    except OSError as err:
        raise RouteError(f"cannot read route file: {err.strerror or err}", path=path) from err
    except UnicodeDecodeError as err:
        raise RouteError("route file is not UTF-8 text", path=path) from err
    depth = deepest = 0
    for match in _BRACKET.finditer(_STRING.sub('""', text)):
        depth += 1 if match.group() in "[{" else -1
        deepest = max(deepest, depth)
        if deepest > MAX_DEPTH:
            raise RouteError(f"JSON nested deeper than {MAX_DEPTH} levels", path=path)
    try:
        doc = json.loads(text, object_pairs_hook=_no_duplicates)  # nesting bounded above: no RecursionError
    except json.JSONDecodeError as err:
        raise RouteError(
            f"invalid JSON at line {err.lineno} column {err.colno}: {err.msg}", path=path
        ) from err
    except _DuplicateKey as err:
        raise RouteError(
            f"key {err.args[0]!r} given twice in one object (JSON keeps the last)", path=path
        ) from err
    except ValueError as err:  # Python refuses to read an integer of thousands of digits
        raise RouteError(f"a number of more than {sys.get_int_max_str_digits():,} digits", path=path) from err
    if isinstance(doc, dict):
        _check_values(doc, path)
    return doc


def _finite(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    try:
        value = float(value)
    except OverflowError:  # an integer literal beyond any float
        return math.inf
    return value


def _check_yaw(yaw: float | None, where: str, path: Path | str) -> None:
    """A heading in degrees (None: not a number, the parser's to name) within ±MAX_TURN_DEG; NaN
    was read on into positions, then named as a route beyond ±1 km."""
    if yaw is not None and not abs(yaw) <= MAX_TURN_DEG:
        raise RouteError(f"{where} must be a finite number within ±{MAX_TURN_DEG:g}°, got {yaw!r}", path=path)


def _check_values(doc: dict[str, Any], path: Path | str) -> None:
    start = doc.get("start")
    x_m = y_m = heading_rad = 0.0
    if isinstance(start, dict):
        for key in ("x_m", "y_m"):
            value = _finite(start.get(key))
            if value is not None and not abs(value) <= MAX_COORDINATE_M:
                raise RouteError(
                    f"start.{key} = {start.get(key)!r} is beyond ±{MAX_COORDINATE_M:g} m", path=path
                )
        x_m = _finite(start.get("x_m")) or 0.0
        y_m = _finite(start.get("y_m")) or 0.0
        yaw = _finite(start.get("yaw_deg"))
        _check_yaw(yaw, "start.yaw_deg", path)
        heading_rad = math.radians(yaw or 0.0)
    actions = doc.get("actions")
    if not isinstance(actions, list):
        return
    if len(actions) > MAX_ACTIONS:
        raise RouteError(
            f"{len(actions):,} actions; a route file may have at most {MAX_ACTIONS:,}", path=path
        )
    driven_m = 0.0
    for i, entry in enumerate(actions):
        if not isinstance(entry, dict) or len(entry) != 1:
            continue
        (key, raw), value = next(iter(entry.items())), _finite(next(iter(entry.values())))
        if key == "kidnap" and isinstance(raw, dict):  # carried to an absolute pose: it must be mapped ground
            to_x, to_y = _finite(raw.get("x_m", 0.0)), _finite(raw.get("y_m", 0.0))
            if to_x is not None and to_y is not None:
                if not (abs(to_x) <= MAX_COORDINATE_M and abs(to_y) <= MAX_COORDINATE_M):
                    raise RouteError(
                        f"actions[{i}]: kidnap to x={to_x:g} m, y={to_y:g} m is beyond "
                        f"±{MAX_COORDINATE_M:g} m of the origin",
                        path=path,
                    )
                x_m, y_m = to_x, to_y
                yaw = _finite(raw.get("yaw_deg", 0.0))
                _check_yaw(yaw, f"actions[{i}]: kidnap yaw_deg", path)
                heading_rad = math.radians(yaw) if yaw is not None else heading_rad
            continue
        if value is None:
            continue
        if key == "turn_deg":
            if not abs(value) <= MAX_TURN_DEG:
                raise RouteError(f"actions[{i}]: turn_deg = {raw!r} is beyond ±{MAX_TURN_DEG:g}°", path=path)
            heading_rad += math.radians(value)
        elif key == "forward_m" and 0.0 < value <= MAX_ROUTE_LENGTH_M:
            driven_m += value
            if driven_m > MAX_ROUTE_LENGTH_M:
                raise RouteError(
                    f"the route drives more than {MAX_ROUTE_LENGTH_M:g} m (at actions[{i}])", path=path
                )
            x_m += value * math.cos(heading_rad)
            y_m += value * math.sin(heading_rad)
            if not (abs(x_m) <= MAX_COORDINATE_M and abs(y_m) <= MAX_COORDINATE_M):
                raise RouteError(
                    f"actions[{i}] takes the route beyond ±{MAX_COORDINATE_M:g} m of the origin", path=path
                )
