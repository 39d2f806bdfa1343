"""``--fail-on`` quality gates: conditions on the summary's leaves that fail a CI run when they hold."""

from __future__ import annotations

import json
import math
import operator
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from aslam.app.score import leaves, summary_key, summary_keys
from aslam.core.decimal_text import parse_decimal
from aslam.core.errors import ConfigError

_OPERATORS: dict[str, Callable[[Any, Any], bool]] = {
    "<=": operator.le,
    ">=": operator.ge,
    "==": operator.eq,
    "!=": operator.ne,
    "<": operator.lt,
    ">": operator.gt,
}
_CONDITION = re.compile(r"^\s*([A-Za-z_][\w.]*)\s*(<=|>=|==|!=|<|>)\s*([^\s<>=!]+)\s*$")


@dataclass(frozen=True)
class Condition:
    """``KEY OP VALUE``: the gate fails when it holds."""

    text: str
    key: str
    op: str
    value: float | None
    """None stands for ``null`` (only with == and !=)."""

    def holds(self, summary: dict[str, Any]) -> tuple[bool, Any]:
        """Whether the condition holds, and the value it was tested on.

        A null value (not measurable, e.g. precision without any claim) holds for every test
        against a number, ``==`` and ``!=`` too: a gate never passes on a measurement that was not
        made. ``== null`` / ``!= null`` test for it explicitly.
        """
        actual = leaves(summary)[self.key]
        if self.value is None:
            return (actual is None) == (self.op == "=="), actual
        if actual is None:
            return True, None
        if isinstance(actual, float) and math.isnan(actual):
            return True, actual
        return bool(_OPERATORS[self.op](float(actual), self.value)), actual


def parse_condition(text: str, keys: set[str] | None = None) -> Condition:
    """``'loop_closure.precision<0.99'`` → Condition; ConfigError naming the problem otherwise. The
    key may be short as in ``sweep --pareto`` (``'precision<0.99'``: :func:`aslam.app.score.summary_key`)."""
    match = _CONDITION.match(text)
    if match is None:
        raise ConfigError(
            f"malformed --fail-on condition {text!r} (expected KEY OP NUMBER, e.g. "
            f"'loop_closure.precision<0.99'; OP is one of < <= > >= == !=)"
        )
    name, op, raw = match.groups()
    keys = summary_keys() if keys is None else keys
    try:
        key = summary_key(name, keys)
    except ValueError as err:
        raise ConfigError(f"--fail-on {text!r}: '{name}' {err}") from None
    text = f"{key}{op}{raw}"  # as the failure names it: the key in full
    if raw == "null":
        if op not in ("==", "!="):
            raise ConfigError(f"--fail-on {text!r}: null can only be compared with == or !=")
        return Condition(text, key, op, None)
    try:
        value = parse_decimal(raw)  # float() took 1_0 as 10 and digits of other scripts
    except ValueError as err:
        raise ConfigError(f"--fail-on {text!r}: {raw!r} is not a number (or null)") from err
    if not math.isfinite(value):
        raise ConfigError(f"--fail-on {text!r}: {raw!r} is not a finite number")
    return Condition(text, key, op, value)


def failed_conditions(conditions: Sequence[Condition], summary: dict[str, Any]) -> list[str]:
    """One description per condition that holds, e.g. ``loop_closure.precision<0.99 (is 0.95)``."""
    failed = []
    for condition in conditions:
        holds, actual = condition.holds(summary)
        if holds:
            failed.append(f"{condition.text.strip()} (is {_shown(actual)})")
    return failed


def _shown(value: Any) -> str:
    """A summary value as the summary JSON writes it (null, true, every digit of a float): rounded
    to 6 digits, ``recall<0.9714286`` failed on a recall shown as 0.971429."""
    if isinstance(value, float) and not math.isfinite(value):
        return "null"
    return json.dumps(value)
