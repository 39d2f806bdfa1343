"""The sweep file: which recordings, times which estimator parameters, scored how, collecting what.

A TOML file (``docs/sweep.md``, example in ``sweep_example.toml`` beside this module: package data,
so that ``aslam sweep --example`` has it in a wheel) read into frozen
dataclasses. Every problem in it (unknown keys, wrong types, globs that match nothing, parameter
values the estimator refuses, unknown summary keys) is found in one pass and reported at once,
as one :class:`ConfigError` line naming the file. Paths in the file are relative to its folder.
"""

from __future__ import annotations

import glob
import itertools
import math
import os
import re
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, NamedTuple

from aslam.app.config_file import type_problem
from aslam.core.config import REPORT_RANGES, REVISIT_HEADING_DEG, REVISIT_RADIUS_M, EstimatorConfig
from aslam.core.errors import AslamError, ConfigError
from aslam.data_formats.files import file_name_from_utf8, full_path
from aslam.data_formats.sources import TopicChoice
from aslam.data_formats.toml_files import read_toml
from aslam.recorder.config import CameraSpec, RecordConfig, parse_size
from aslam.recorder.routes import default_laps

DEFAULT_FIGURES = (
    "keyframes",
    "loop_closure.precision",
    "loop_closure.recall",
    "relocalisation.mean_delay_keyframes",
    "error.best.x_m.mean",
    "error.best.y_m.mean",
    "error.best.heading_deg.mean",
    "timing.keyframes_per_second",
)

TOP_LEVEL_KEYS = ("figures", "recordings", "render", "grid", "score")
#: The most parameter sets one grid (or recordings one [[render]] table) may make: each is checked
#: by building it, and a 1,000 × 1,000 grid took minutes and gigabytes before saying anything.
MAX_COMBINATIONS = 10_000
#: ``[recordings]``'s topic keys (``aslam estimate``'s options, with underscores) → TopicChoice fields.
TOPIC_KEYS = {
    "image_topic": "image",
    "odometry_topic": "odometry",
    "ground_truth_topic": "ground_truth",
    "odom_frame": "odom_frame",
    "base_frame": "base_frame",
}
RECORDINGS_KEYS = ("paths", *TOPIC_KEYS)
SCORE_KEYS = {"radius_m": float, "heading_deg": float}
#: Keys of a ``[[render]]`` table and their types; each may also be a list of such values.
RENDER_KEYS: dict[str, type] = {
    "route": str,
    "seeds": int,
    "laps": int,
    "noise": float,
    "drift_deg_per_m": float,
    "jitter_m": float,
    "jitter_deg": float,
    "wander_m": float,
    "wander_deg": float,
    "wander_length_m": float,
    "noise_model": str,
    "aliasing": float,
    "lighting_change": float,
    "odometry_reset_at": int,
    "world": str,
    "size": str,
    "fov_deg": float,
    "camera_height_m": float,
    "fps": float,
    "jpeg_quality": int,
}
_RESOLVED_HERE = ("route", "seeds", "laps", "world", "size")
"""The render keys :func:`_record_config` turns into values itself; the rest are
:meth:`RecordConfig.from_options`'s options, by the same names."""


@dataclass(frozen=True)
class ScoreOptions:
    """How every estimate is scored (``aslam.app.score.score``'s options)."""

    radius_m: float = REVISIT_RADIUS_M
    heading_deg: float = REVISIT_HEADING_DEG


Grid = tuple[tuple[str, tuple[Any, ...]], ...]
"""Estimator parameters and their values, in file order; its parameter sets are their product."""


class ListedRecording(NamedTuple):
    """A recording or bag a ``[recordings]`` table lists, with that table's topic keys."""

    path: Path
    topics: TopicChoice


@dataclass(frozen=True)
class Sweep:
    """A checked sweep file: every recording and parameter set it names, in a stable order."""

    path: Path
    recordings: tuple[ListedRecording, ...]
    """Recording files (absolute) with their tables' topics, in the order given, each glob's
    matches sorted by name; one file under two sets of topics is listed twice (two recordings)."""
    renders: tuple[RecordConfig, ...]
    """Recordings to render first, in the order of the ``[[render]]`` tables and their value lists."""
    grids: tuple[Grid, ...]
    """The ``[grid]`` table, or the ``[[grid]]`` tables in file order (none: the defaults)."""
    figures: tuple[str, ...] = DEFAULT_FIGURES
    score: ScoreOptions = field(default_factory=ScoreOptions)

    def parameter_sets(self) -> Iterator[tuple[tuple[str, Any], ...]]:
        """Every grid's combinations in turn, the last key varying fastest (one empty set for no grid)."""
        for grid in self.grids or ((),):
            names = [name for name, _values in grid]
            for values in itertools.product(*(values for _name, values in grid)):
                yield tuple(zip(names, values, strict=True))

    def parameter_names(self) -> tuple[str, ...]:
        """Every parameter some grid names, in order of first appearance."""
        return tuple(dict.fromkeys(name for grid in self.grids for name, _values in grid))


def _as_list(value: Any) -> list[Any]:
    return list(value) if isinstance(value, list) else [value]


def example_sweep_file() -> str:
    """An example with every table, commented (``aslam sweep --example``)."""
    return Path(__file__).with_name("sweep_example.toml").read_text(encoding="utf-8")


def read_sweep_file(path: Path | str) -> Sweep:
    """Read and check ``path``; :class:`ConfigError` (exit 2) listing every problem at once."""
    path = Path(path)
    document = read_toml(path, what="a sweep file")
    problems: list[str] = []
    base = full_path(path).parent
    problems += [
        f"unknown key '{key}' (known: {', '.join(TOP_LEVEL_KEYS)})"
        for key in document
        if key not in TOP_LEVEL_KEYS
    ]
    recordings = _recordings(document.get("recordings", {}), base, problems)
    renders = _renders(document.get("render", []), base, problems)
    if not recordings and not renders and not any("recordings" in p or "render" in p for p in problems):
        problems.append("no recordings: give [recordings] paths and/or [[render]] tables")
    grids = _grids(document.get("grid", []), problems)
    figures = _figures(document.get("figures", list(DEFAULT_FIGURES)), problems)
    score = _score(document.get("score", {}), problems)
    if problems:
        raise ConfigError("; ".join(dict.fromkeys(problems)), path=path)
    return Sweep(full_path(path), recordings, renders, grids, figures, score)


def _table(value: Any, name: str, known: Any, problems: list[str]) -> dict[str, Any]:
    if not isinstance(value, dict):
        problems.append(f"'{name}' must be a table ([{name}])")
        return {}
    for key in value:
        if key not in known:
            problems.append(f"unknown key '{name}.{key}' (known: {', '.join(known)})")
    return {key: item for key, item in value.items() if key in known}


def _recordings(value: Any, base: Path, problems: list[str]) -> tuple[ListedRecording, ...]:
    """The ``[recordings]`` table, or each ``[[recordings]]`` table in turn (bags of two robots, each
    with its own topics); a file listed twice under the same topics once. A problem in one of
    several tables names it by number, as ``render #2`` does."""
    found: dict[ListedRecording, None] = {}
    several = isinstance(value, list)
    for number, raw in enumerate(value if several else [value], start=1):
        shape: list[str] = []  # the table's own problems (not a table, unknown keys), told as they are
        table = _table(raw, "recordings", RECORDINGS_KEYS, shape)
        told: list[str] = []  # its keys' problems, told as the key they are about
        topics = _topics(table, told)
        paths = _paths(table, base, told)
        if isinstance(raw, dict) and not table.get("paths") and (several or topics != TopicChoice()):
            # A table whose paths were forgot: its robot's bags would be left out in silence.
            told.append("paths: none (a table's topic keys apply to the files its paths name)")
        if several:
            problems += [f"recordings #{number}: {line}" for line in (*shape, *told)]
        else:
            problems += [*shape, *(f"recordings.{line}" for line in told)]
        found.update(dict.fromkeys(ListedRecording(path, topics) for path in paths))
    return tuple(found)


def _paths(table: dict[str, Any], base: Path, problems: list[str]) -> tuple[Path, ...]:
    """The files a ``[recordings]`` table's ``paths`` name, in the order given (each problem told
    as the key it is about: ``paths: …``)."""
    patterns = table.get("paths", [])
    if not isinstance(patterns, list) or not all(isinstance(p, str) for p in patterns):
        problems.append(f"paths must be a list of strings (paths or globs), got {patterns!r}")
        return ()
    found: dict[Path, None] = {}
    for pattern in patterns:
        given = file_name_from_utf8(pattern).expanduser()
        full = given if given.is_absolute() else base / given
        if full.exists():  # a file named as it is, even one whose name holds [brackets]
            found[full_path(full)] = None
        elif glob.has_magic(str(given)):  # the pattern's own wildcards; the sweep file's folder literal
            search = str(given) if given.is_absolute() else os.path.join(glob.escape(str(base)), str(given))
            # The folders a ``**`` glob passes through are no recordings; a rosbag2 folder is one.
            matches = sorted(
                Path(p)
                for p in glob.glob(search, recursive=True)
                if Path(p).is_file() or (Path(p) / "metadata.yaml").is_file()
            )
            if not matches:
                problems.append(f"paths: '{pattern}' matches nothing")
            found.update(dict.fromkeys(full_path(m) for m in matches))
        else:
            problems.append(f"paths: '{pattern}' does not exist (a recording or a bag)")
    return tuple(found)


def _topics(value: dict[str, Any], problems: list[str]) -> TopicChoice:
    """The topics and frames a ``[recordings]`` table names, as ``aslam estimate``'s options would:
    a bag's ground truth is read (and its rows scored) only from a named topic. ROS names hold no
    spaces: a padded name passed here and failed every row it ran."""
    chosen: dict[str, str] = {}
    for key, field_name in TOPIC_KEYS.items():
        if key not in value:
            continue
        name = value[key]
        if not isinstance(name, str) or not name or any(c.isspace() for c in name):
            problems.append(f"{key} must be a topic or frame name (a string without spaces), got {name!r}")
            continue
        chosen[field_name] = name
    return TopicChoice(**chosen)


def _renders(value: Any, base: Path, problems: list[str]) -> tuple[RecordConfig, ...]:
    if isinstance(value, dict):
        value = [value]
    if not isinstance(value, list) or not all(isinstance(t, dict) for t in value):
        problems.append("'render' must be tables ([[render]])")
        return ()
    configs: dict[RecordConfig, None] = {}
    for number, raw in enumerate(value, start=1):
        where = f"render #{number}"
        lists, bad = _typed_lists(_table(raw, "render", RENDER_KEYS, problems), RENDER_KEYS, where, problems)
        lists.setdefault("route", ["paper"])
        lists.setdefault("seeds", [0])
        if (count := math.prod(len(values) for values in lists.values())) > MAX_COMBINATIONS:
            problems.append(f"{where}: {count:,} recordings; at most {MAX_COMBINATIONS:,} (split the sweep)")
            continue
        names = list(lists)
        for combination in itertools.product(*(lists[name] for name in names)):
            config = _record_config(dict(zip(names, combination, strict=True)), base, where, problems)
            if config is not None and not bad:
                configs[config] = None
    return tuple(configs)


def _typed_lists(
    table: dict[str, Any], types: dict[str, Any], where: str, problems: list[str]
) -> tuple[dict[str, list[Any]], bool]:
    """Each key's value as a list (a scalar is a list of one) whose every item is of its key's type,
    and whether any key was left out (an empty list, a mistyped item: the problems noted). The keys
    kept are still checked, so one mistyped key does not hide another's values out of range."""
    lists: dict[str, list[Any]] = {}
    bad = False
    for key, item in table.items():
        items = _as_list(item)
        found = [] if items else [f"{where}: {key} is an empty list"]
        found += [p for one in items if (p := type_problem(f"{where}: {key}", one, types[key]))]
        problems += found
        bad = bad or bool(found)
        if not found:
            lists[key] = items
    return lists, bad


def _record_config(knobs: dict[str, Any], base: Path, where: str, problems: list[str]) -> RecordConfig | None:
    from aslam.recorder.routes import PRESETS

    route = knobs["route"]
    if route not in PRESETS:
        route_path = base / file_name_from_utf8(route)  # an absolute one stays as it is
        if not route_path.is_file():
            problems.append(f"{where}: route '{route}' is neither a preset ({', '.join(PRESETS)}) nor a file")
            return None
        route = str(route_path)
    world = knobs.get("world")
    if world is not None:
        world_path = base / file_name_from_utf8(world)
        if not world_path.is_file():
            problems.append(f"{where}: world '{world}' is not a file")
            return None
        world = world_path
    width, height = CameraSpec().width_px, CameraSpec().height_px
    size_problem = None
    if "size" in knobs:
        try:
            width, height = parse_size(knobs["size"])
        except ConfigError as err:
            size_problem = f"{where}: {_option_to_key(err.problem)}"
    rest = {key: value for key, value in knobs.items() if key not in _RESOLVED_HERE}
    config = RecordConfig.from_options(
        route,
        # the default given is no other render (its label and its file were another's)
        laps=None if knobs.get("laps") == default_laps(route) else knobs.get("laps"),
        seed=knobs["seeds"],
        world=world,
        width_px=width,
        height_px=height,
        **rest,
    )
    found = [f"{where}: {_option_to_key(p)}" for p in config.problems()]
    if size_problem is not None:
        found.insert(0, size_problem)
    if not found:  # the route as driven: its file, laps of an open route, the action cap, the reset
        from aslam.recorder.record import driven_route

        try:
            driven_route(config)
        except AslamError as err:
            found.append(f"{where}: {_option_to_key(str(err))}")
    problems += found
    return None if found else config


def _option_to_key(message: str) -> str:
    """``--fov-deg must …`` (the recorder speaks in options) → ``fov_deg must …`` (sweep-file keys)."""
    return re.sub(r"--([a-z][a-z-]*)", lambda m: m.group(1).replace("-", "_"), message)


def _grids(value: Any, problems: list[str]) -> tuple[Grid, ...]:
    """``[grid]`` (one table) or ``[[grid]]`` (several, each a product; their sets run in turn)."""
    if isinstance(value, dict):
        return (_grid(value, "grid", problems),)
    if not isinstance(value, list) or not all(isinstance(t, dict) for t in value):
        problems.append("'grid' must be a table ([grid]) or tables ([[grid]])")
        return ()
    return tuple(
        _grid(table, f"grid #{n}" if len(value) > 1 else "grid", problems) for n, table in enumerate(value, 1)
    )


def estimator_config(parameters: Iterable[tuple[str, Any]]) -> EstimatorConfig:
    """A parameter set's configuration: ``paper_faithful = true`` starts from the paper's estimator
    (as ``aslam estimate --paper-faithful``), the other keys change it; else from the defaults."""
    values = dict(parameters)
    base = EstimatorConfig.paper_faithful() if values.pop("paper_faithful", False) else EstimatorConfig()
    return replace(base, **values)


def _as_kind(kind: type, value: Any) -> Any:
    """``value`` as ``kind``, -0.0 as 0.0: the same value, but JSON writes the sign, so the same
    configuration would be another task (its key a digest of the configuration's JSON)."""
    value = kind(value)
    return value + 0.0 if kind is float else value


def _grid(value: dict[str, Any], where: str, problems: list[str]) -> Grid:
    types = {name: kind for name, kind, _default, _help in EstimatorConfig.parameters()}
    types["paper_faithful"] = bool
    lists, bad = _typed_lists(_table(value, "grid", types, problems), types, where, problems)
    # A value listed twice (``[1, 1.0]``) is one value: every combination runs once.
    grid = [
        (key, tuple(dict.fromkeys(_as_kind(types[key], v) for v in values))) for key, values in lists.items()
    ]
    if (count := math.prod(len(values) for _name, values in grid)) > MAX_COMBINATIONS:
        problems.append(f"{where}: {count:,} parameter sets; at most {MAX_COMBINATIONS:,} (split the sweep)")
        return ()
    names = [name for name, _values in grid]
    for combination in itertools.product(*(values for _name, values in grid)):
        try:
            estimator_config(zip(names, combination, strict=True))
        except ConfigError as err:
            problems += [f"{where}: {one}" for one in err.problem.split("; ")]
    return () if bad else tuple(grid)  # a bad grid's problems are raised before any grid is used


def _figures(value: Any, problems: list[str]) -> tuple[str, ...]:
    from aslam.app.score import summary_keys

    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        problems.append(f"figures must be a list of summary keys, got {value!r}")
        return DEFAULT_FIGURES
    known = summary_keys()
    for key in value:
        if key not in known:
            problems.append(f"figures: unknown summary key '{key}' (known: {', '.join(sorted(known))})")
    return tuple(dict.fromkeys(value))


def _score(value: Any, problems: list[str]) -> ScoreOptions:
    table = _table(value, "score", SCORE_KEYS, problems)
    values = {}
    for key, item in table.items():
        problem = type_problem(f"score.{key}", item, float)
        if problem:
            problems.append(problem)
        else:
            values[key] = float(item)
    options = ScoreOptions(**values)
    # the ranges report takes (core.config.REPORT_RANGES), so no task can fail on them
    for key, bounds in REPORT_RANGES.items():
        if not bounds.holds(getattr(options, key)):
            problems.append(f"score.{key} must be {bounds.describe()}, got {getattr(options, key)!r}")
    return options
