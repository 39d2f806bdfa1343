"""Routes: a start pose and actions (``forward_m``, ``turn_deg``, ``kidnap``), from presets or JSON.

A route is what the robot is *commanded* to do.  The ground truth follows the commanded poses
(plus a small non-accumulating jitter, see :mod:`aslam.recorder.noise`), so a closed route really
comes back to the places it has seen.

A ``kidnap`` action carries the robot to an absolute pose: the ground truth jumps there, the
odometry sees no motion (the "kidnapped robot" test of relocalisation).

JSON form (angles in degrees, CCW positive; distances in metres)::

    {"start": {"x_m": 0, "y_m": 0, "yaw_deg": 0},
     "actions": [{"forward_m": 1.0}, {"turn_deg": 90},
                 {"kidnap": {"x_m": 4, "y_m": 5, "yaw_deg": 180}}]}
"""

from __future__ import annotations

import itertools
import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from aslam.core import se2
from aslam.recorder.errors import RouteError
from aslam.recorder.route_limits import MAX_ACTIONS, read_route_document

#: A route is closed when its last commanded pose is its start pose within these tolerances.
CLOSE_TOL_M = 1e-6
CLOSE_TOL_RAD = 1e-6
#: Largest single action accepted from a file (a sanity bound, not a physical one).
MAX_FORWARD_M = 1000.0


class Action(NamedTuple):
    """One commanded action: drive ``forward_m`` metres, turn ``turn_rad`` in place (CCW +), or be
    carried to the absolute pose ``kidnap_to`` ``(x_m, y_m, yaw_rad)`` (odometry sees nothing)."""

    forward_m: float = 0.0
    turn_rad: float = 0.0
    kidnap_to: tuple[float, float, float] | None = None

    @property
    def is_kidnap(self) -> bool:
        return self.kidnap_to is not None

    @property
    def motion(self) -> np.ndarray:
        """The action as an SE(2) motion in the robot's frame (a kidnap has none: see ``apply``)."""
        return np.array([self.forward_m, 0.0, self.turn_rad])

    def apply(self, pose: np.ndarray) -> np.ndarray:
        """The commanded pose after this action, from ``pose``."""
        if self.kidnap_to is not None:
            return np.array(self.kidnap_to, dtype=float)
        return se2.compose(pose, self.motion)

    def to_json(self) -> dict[str, Any]:
        if self.kidnap_to is not None:
            x, y, yaw = self.kidnap_to
            return {"kidnap": {"x_m": x, "y_m": y, "yaw_deg": round(math.degrees(yaw), 9)}}
        if self.turn_rad != 0.0 or self.forward_m == 0.0:
            return {"turn_deg": round(math.degrees(self.turn_rad), 9)}
        return {"forward_m": self.forward_m}


@dataclass(frozen=True)
class Route:
    """A named start pose and a tuple of actions; ``poses()`` gives the commanded keyframe poses."""

    name: str
    start_pose: tuple[float, float, float]  # x_m, y_m, yaw_rad
    actions: tuple[Action, ...]

    def poses(self) -> np.ndarray:
        """Commanded poses, shape ``(len(actions) + 1, 3)``: the start, then one after each action."""
        out = np.empty((len(self.actions) + 1, 3))
        out[0] = self.start_pose
        for i, action in enumerate(self.actions):
            out[i + 1] = action.apply(out[i])
        return out

    @property
    def connected(self) -> np.ndarray:
        """Per action, whether the robot drives from its pose to the next (False for a kidnap)."""
        return np.array([not a.is_kidnap for a in self.actions], dtype=bool)

    @property
    def is_closed(self) -> bool:
        """True when the last commanded pose is the start pose (position and heading)."""
        end = self.poses()[-1]
        start = np.asarray(self.start_pose)
        return bool(
            np.hypot(*(end[:2] - start[:2])) < CLOSE_TOL_M
            and abs(float(se2.wrap_angle(end[2] - start[2]))) < CLOSE_TOL_RAD
        )

    @property
    def length_m(self) -> float:
        return float(sum(a.forward_m for a in self.actions))

    def repeated(self, laps: int) -> Route:
        """The route driven ``laps`` times; refused for an open route when ``laps > 1``."""
        if laps < 1:
            raise RouteError(f"--laps must be at least 1, got {laps}")
        if laps * len(self.actions) > MAX_ACTIONS:  # a recording that would never end
            raise RouteError(
                f"--laps {laps} drives route '{self.name}' ({len(self.actions)} actions a lap) for "
                f"{laps * len(self.actions):,} actions; at most {MAX_ACTIONS:,}"
            )
        if laps > 1 and not self.is_closed:
            end = self.poses()[-1]
            raise RouteError(
                f"route '{self.name}' is open (it ends at x={end[0]:.2f} m, y={end[1]:.2f} m, "
                f"yaw={math.degrees(end[2]):.1f} deg, not at its start), so --laps {laps} cannot repeat it; "
                "use --laps 1 or close the route"
            )
        return Route(self.name, self.start_pose, self.actions * laps)

    def to_json(self) -> str:
        """Canonical JSON (stored in the recording's metadata; parses back with :func:`parse_route`)."""
        x, y, yaw = self.start_pose
        doc = {
            "name": self.name,
            "start": {"x_m": x, "y_m": y, "yaw_deg": round(math.degrees(yaw), 9)},
            "actions": [a.to_json() for a in self.actions],
        }
        return json.dumps(doc, separators=(",", ":"))


def kidnapped(route: Route, at_keyframe: int, to_keyframe: int) -> Route:
    """``route`` driven up to keyframe ``at_keyframe``, then carried to the commanded pose of keyframe
    ``to_keyframe`` and driven on from there to the end (for relocalisation tests and benchmarks).

    E.g. ``kidnapped(preset("paper").repeated(2), 44, 20)``: lap 1, ten metres of lap 2, then carried
    back to keyframe 20's corridor and driven on to the end of the route.
    """
    n = len(route.actions)
    if not (0 <= at_keyframe <= n and 0 <= to_keyframe <= n):
        raise RouteError(f"kidnap keyframes must be within 0..{n}, got {at_keyframe} and {to_keyframe}")
    x, y, yaw = (float(v) for v in route.poses()[to_keyframe])
    kidnap = Action(kidnap_to=(x, y, yaw))
    actions = (*route.actions[:at_keyframe], kidnap, *route.actions[to_keyframe:])
    return Route(f"{route.name}-kidnap-{at_keyframe}-to-{to_keyframe}", route.start_pose, actions)


# --------------------------------------------------------------------------------------- presets


def _from_waypoints(name: str, points: Sequence[tuple[float, float]], step_m: float = 1.0) -> Route:
    """A closed route through ``points`` in ``step_m`` forward steps, turning in place at corners.

    The route starts at ``points[0]`` facing ``points[1]`` and ends there facing the same way.
    """
    pts = [np.asarray(p, dtype=float) for p in points]
    if np.hypot(*(pts[-1] - pts[0])) > 1e-9:
        pts.append(pts[0])
    headings = [math.atan2(*(b - a)[::-1]) for a, b in itertools.pairwise(pts)]
    actions: list[Action] = []
    for i, (a, b) in enumerate(itertools.pairwise(pts)):
        if i > 0:
            actions.append(Action(turn_rad=float(se2.wrap_angle(headings[i] - headings[i - 1]))))
        length = float(np.hypot(*(b - a)))
        n = round(length / step_m)
        if n < 1 or abs(n * step_m - length) > 1e-9:
            raise ValueError(f"preset {name}: leg {i} is not a whole number of steps")
        actions.extend(Action(forward_m=step_m) for _ in range(n))
    closing = float(se2.wrap_angle(headings[0] - headings[-1]))
    if abs(closing) > 1e-12:
        actions.append(Action(turn_rad=closing))
    return Route(name, (float(pts[0][0]), float(pts[0][1]), headings[0]), tuple(actions))


def _paper() -> Route:
    # The paper's cyclic path: a 10 m × 5 m rectangle from a corner, 1 m steps, 90° turns.
    return _from_waypoints("paper", [(0, 0), (10, 0), (10, 5), (0, 5)])


def _figure8() -> Route:
    # Two 6 m squares touching at the origin, one driven CCW and one CW: a + junction at the origin.
    return _from_waypoints("figure8", [(0, 0), (6, 0), (6, 6), (0, 6), (0, -6), (-6, -6), (-6, 0)])


def _grid() -> Route:
    # A 10 m × 10 m block cut by a middle street each way: four loops sharing corridors, several
    # corridors driven in both directions.
    return _from_waypoints(
        "grid",
        [(0, 0), (10, 0), (10, 10), (0, 10), (0, 5), (10, 5), (10, 0), (5, 0), (5, 10), (0, 10)],
    )


PRESETS = {"paper": _paper, "figure8": _figure8, "grid": _grid}
#: Laps when ``--laps`` is not given: every preset is driven twice (a first visit, then revisits).
DEFAULT_PRESET_LAPS = 2


def default_laps(route: str) -> int:
    """Laps driven when none are given: two of a preset, one of a route file."""
    return DEFAULT_PRESET_LAPS if route in PRESETS else 1


def preset(name: str) -> Route:
    try:
        return PRESETS[name]()
    except KeyError:
        raise RouteError(
            f"unknown route preset '{name}' (presets: {', '.join(PRESETS)}; or give a .json file)"
        ) from None


# ------------------------------------------------------------------------------------- JSON files


def _number(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    try:
        value = float(value)
    except OverflowError:  # an integer literal beyond any float
        return None
    return value if math.isfinite(value) else None


def _pose(doc: Any, where: str, problems: list[str]) -> tuple[float, float, float] | None:
    """``{x_m, y_m, yaw_deg}`` (each defaulting to 0) → ``(x_m, y_m, yaw_rad)``; problems appended."""
    if not isinstance(doc, dict):
        problems.append(f"'{where}' must be an object {{x_m, y_m, yaw_deg}}, got {json.dumps(doc)}")
        return None
    values = []
    ok = True
    for key in ("x_m", "y_m", "yaw_deg"):
        value = _number(doc.get(key, 0.0))
        if value is None:
            problems.append(f"{where}.{key} must be a finite number, got {doc.get(key)!r}")
            ok = False
            value = 0.0
        values.append(value)
    extra = sorted(set(doc) - {"x_m", "y_m", "yaw_deg"})
    if extra:
        problems.append(f"{where} has unknown key(s) {', '.join(map(repr, extra))}")
        ok = False
    return (values[0], values[1], float(se2.wrap_angle(math.radians(values[2])))) if ok else None


def parse_route(doc: Any, *, name: str = "route", path: Path | str | None = None) -> Route:
    """Validate a decoded route document; raise :class:`RouteError` naming the first bad entry.

    The message also says how many further problems were found, so one run shows the extent.
    """
    problems: list[str] = []
    if not isinstance(doc, dict):
        raise RouteError("a route must be a JSON object with 'start' and 'actions'", path=path)
    unknown = sorted(set(doc) - {"start", "actions", "name"})
    if unknown:
        problems.append(
            f"unknown key(s) {', '.join(map(repr, unknown))} (expected 'start', 'actions', 'name')"
        )
    if "name" in doc and not isinstance(doc["name"], str):
        problems.append(f"'name' must be a string, got {doc['name']!r}")
    start_pose = _pose(doc.get("start", {"x_m": 0, "y_m": 0, "yaw_deg": 0}), "start", problems)
    start_pose = start_pose or (0.0, 0.0, 0.0)
    actions_doc = doc.get("actions")
    actions: list[Action] = []
    if not isinstance(actions_doc, list) or not actions_doc:
        problems.append(
            "'actions' must be a non-empty list of {forward_m: d}, {turn_deg: a} or {kidnap: pose}"
        )
        actions_doc = []
    for i, entry in enumerate(actions_doc):
        where = f"actions[{i}]"
        if not isinstance(entry, dict) or len(entry) != 1:
            problems.append(
                f"{where} = {json.dumps(entry)}: expected exactly one of forward_m, turn_deg or kidnap"
            )
            continue
        (key, raw), value = next(iter(entry.items())), _number(next(iter(entry.values())))
        if key == "forward_m":
            if value is None or not 0.0 < value <= MAX_FORWARD_M:
                problems.append(f"{where}: forward_m must be a number in (0, {MAX_FORWARD_M:g}], got {raw!r}")
                continue
            actions.append(Action(forward_m=value))
        elif key == "turn_deg":
            if value is None:
                problems.append(f"{where}: turn_deg must be a finite number, got {raw!r}")
                continue
            actions.append(Action(turn_rad=math.radians(value)))
        elif key == "kidnap":
            pose = _pose(raw, f"{where}: kidnap", problems)
            if pose is not None:
                actions.append(Action(kidnap_to=pose))
        else:
            problems.append(f"{where}: unknown action {key!r} (expected forward_m, turn_deg or kidnap)")
    if problems:
        more = f" (and {len(problems) - 1} more problem(s))" if len(problems) > 1 else ""
        raise RouteError(problems[0] + more, path=path)
    route_name = doc.get("name")
    return Route(route_name if isinstance(route_name, str) else name, start_pose, tuple(actions))


def load_route_file(path: Path) -> Route:
    doc = read_route_document(path)  # read errors, JSON syntax and bounds: recorder/route_limits.py
    return parse_route(doc, name=Path(path).stem, path=path)


def resolve_route(spec: str) -> Route:
    """A preset name, or a path to a JSON route file (anything ending in .json or that exists)."""
    if spec in PRESETS:
        return preset(spec)
    candidate = Path(spec)  # (Path("") is the current folder: an empty --route names no file)
    if spec and (candidate.suffix.lower() == ".json" or candidate.exists()):
        return load_route_file(candidate)
    return preset(spec)  # raises with the list of presets
