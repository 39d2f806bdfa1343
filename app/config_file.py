"""Estimator configuration from its three sources, in one order of precedence.

option > ``--config`` file (TOML, an ``[estimator]`` table) > ``--paper-faithful`` base > default.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

from aslam.core.config import EstimatorConfig
from aslam.core.errors import ConfigError
from aslam.data_formats.toml_files import read_toml

CONFIG_TABLE = "estimator"


def option_name(field: str) -> str:
    """The command-line option of an ``EstimatorConfig`` field."""
    return "--" + field.replace("_", "-")


def estimator_options_markdown() -> str:
    """The estimator-parameter table of docs/usage.md (a test keeps the doc equal to this)."""
    rows = ["| option | config key | type | default | meaning |", "|---|---|---|---|---|"]
    for name, kind, default, help_text in EstimatorConfig.parameters():
        meaning = help_text.replace("|", "/")
        rows.append(f"| `{option_name(name)}` | `{name}` | {kind.__name__} | {default} | {meaning} |")
    return "\n".join(rows) + "\n"


_LARGEST_FLOAT = int(sys.float_info.max)


def type_problem(where: str, value: Any, kind: type) -> str | None:
    """Why a TOML ``value`` is not a ``kind`` (ints are accepted for floats, booleans for nothing),
    or None: the one type check of configuration files and sweep files."""
    if kind is float:
        ok = isinstance(value, int | float) and not isinstance(value, bool)
        want = "a number"
        if ok and isinstance(value, int) and abs(value) > _LARGEST_FLOAT:  # float() would overflow
            return f"{where} must be a number a float can hold (within ±1.8e308), got a larger integer"
    elif kind is int:
        ok = isinstance(value, int) and not isinstance(value, bool)
        want = "a whole number"
    else:
        ok = isinstance(value, kind)
        want = "true or false" if kind is bool else "a string"
    return None if ok else f"{where} must be {want}, got {toml_text(value)}"


def toml_text(value: Any) -> str:
    """A TOML value as the file spells it (an error's value, a sweep task's parameters): ``true``,
    ``"8"``, ``1979-05-27T07:32:00+00:00`` (a date, not Python's ``datetime.datetime(1979, …)``),
    an array, a table."""
    import datetime
    import json

    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, datetime.date | datetime.time):
        return f"{value.isoformat()} (a date or time)"
    if isinstance(value, list):
        return "an array"
    if isinstance(value, dict):
        return "a table"
    if isinstance(value, str):
        return json.dumps(value, ensure_ascii=False)
    return repr(value)


def read_config_file(path: Path | str) -> tuple[dict[str, Any], list[str]]:
    """The well-typed values of a TOML file's ``[estimator]`` table, and every unknown key and wrong
    type in it; the values' ranges are checked with the rest of the configuration (:func:`build_config`)."""
    path = Path(path)
    document = read_toml(path, what="a TOML file")
    unknown = [key for key in document if key != CONFIG_TABLE]
    table = document.get(CONFIG_TABLE, {})
    if not isinstance(table, dict):
        raise ConfigError(f"'{CONFIG_TABLE}' must be a table ([{CONFIG_TABLE}])", path=path)
    types = {name: kind for name, kind, _default, _help in EstimatorConfig.parameters()}
    unknown += [f"{CONFIG_TABLE}.{key}" for key in table if key not in types]
    problems = []
    if unknown:
        problems.append(
            f"unknown key{'s' if len(unknown) > 1 else ''} {', '.join(unknown)} "
            f"(keys go in an [{CONFIG_TABLE}] table; known: {', '.join(types)})"
        )
    values: dict[str, Any] = {}
    for key, value in table.items():
        if key not in types:
            continue
        problem = type_problem(key, value, types[key])
        if problem is None:
            values[key] = types[key](value)
        else:
            problems.append(problem)
    return values, problems


def build_config(
    *, paper_faithful: bool, config_file: Path | None, options: dict[str, Any]
) -> EstimatorConfig:
    """Defaults, then ``--paper-faithful``, then the file, then the options that were given.

    The file is checked on its own first, every problem at once (unknown keys and wrong types beside
    values out of range), and named: a value out of range in it was hidden by an option setting the
    same key, and an option's bad value was blamed on the file. The options' problems then name no file.
    """
    values: dict[str, Any] = {}
    if paper_faithful:
        base = EstimatorConfig.paper_faithful()
        values.update({name: getattr(base, name) for name, *_ in EstimatorConfig.parameters()})
    from_file, problems = read_config_file(config_file) if config_file is not None else ({}, [])
    values.update(from_file)
    if from_file:
        try:
            EstimatorConfig(**values)
        except ConfigError as err:
            problems.append(err.problem)
    if problems:
        raise ConfigError(f"bad estimator configuration: {'; '.join(problems)}", path=config_file)
    known = {name for name, *_ in EstimatorConfig.parameters()}
    if unknown := sorted(set(options) - known):  # a library caller's typo: not a TypeError
        raise ConfigError(
            f"unknown estimator parameter(s) {', '.join(unknown)} (known: {', '.join(sorted(known))})"
        )
    values.update({k: v for k, v in options.items() if v is not None})
    try:
        return EstimatorConfig(**values)
    except ConfigError as err:
        raise ConfigError(f"bad estimator configuration: {err.problem}") from None
