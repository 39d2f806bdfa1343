"""What ``aslam report`` computes and writes: ground truth at keyframes, the summary, graph JSON.

* ``truth_at_stamps`` matches a ground-truth stream to keyframe stamps (streaming, interpolating);
* ``build_summary`` turns an :class:`~aslam.core.metrics.Evaluation` into the summary JSON
  (``docs/usage.md``), whose leaves ``--fail-on`` conditions test (``parse_condition``);
* ``build_graph_json`` is the map as documented in ``docs/graph-json.md``;
"""

from __future__ import annotations

import math
import operator
import re
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from aslam.core import se2
from aslam.core.errors import ConfigError
from aslam.core.metrics import Evaluation

GRAPH_JSON_VERSION = 1

# --- ground truth ----------------------------------------------------------------------------------


def truth_at_stamps(
    stamps_ns: Sequence[int], truth: Iterable[tuple[int, np.ndarray]], *, max_gap_ns: int = 1_000_000_000
) -> np.ndarray:
    """(n, 3) true poses at ``stamps_ns`` (ascending), NaN where unknown.

    ``truth`` is a time-ordered stream of ``(stamp_ns, (x_m, y_m, yaw_rad))``, read once. A stamp
    matching a message exactly takes its pose; between two messages at most ``max_gap_ns`` apart
    the pose is interpolated (heading along the shorter arc); outside the messages it is unknown.
    """
    n = len(stamps_ns)
    poses = np.full((n, 3), np.nan)
    i = 0
    previous: tuple[int, np.ndarray] | None = None
    for stamp, pose in truth:
        pose = np.asarray(pose, dtype=float)
        while i < n and stamps_ns[i] <= stamp:
            target = stamps_ns[i]
            if target == stamp:
                poses[i] = pose
            elif previous is not None and stamp - previous[0] <= max_gap_ns:
                t0, p0 = previous
                f = (target - t0) / (stamp - t0)
                poses[i, :2] = p0[:2] + f * (pose[:2] - p0[:2])
                poses[i, 2] = se2.wrap_angle(p0[2] + f * se2.wrap_angle(pose[2] - p0[2]))
            i += 1
        previous = (stamp, pose)
        if i >= n:
            break
    return poses


def dead_reckoning(actions: np.ndarray, start: np.ndarray | None = None) -> np.ndarray:
    """(n, 3) poses from composing the keyframe actions (the first action is the start's)."""
    poses = np.zeros((len(actions), 3))
    pose = np.zeros(3) if start is None else np.asarray(start, dtype=float)
    for i, action in enumerate(actions):
        pose = pose if i == 0 else se2.compose(pose, action)
        poses[i] = pose
    return poses


# --- the summary -----------------------------------------------------------------------------------


def _stats(values: dict[str, Any]) -> dict[str, dict[str, float | None]]:
    return {axis: {"mean": s.mean, "median": s.median, "max": s.max} for axis, s in values.items()}


def build_summary(
    evaluation: Evaluation,
    *,
    states: int,
    links: int,
    keyframes_per_second: float | None,
) -> dict[str, Any]:
    """The summary JSON (every key always present; null where not measurable)."""
    counts = evaluation.hypothesis_counts
    has_truth = evaluation.has_ground_truth
    return {
        "keyframes": int(evaluation.keyframes),
        "states": int(states),
        "links": int(links),
        "ground_truth": bool(has_truth),
        "hypotheses": {
            "max": int(counts.max()) if counts.size else 0,
            "mean": float(counts.mean()) if counts.size else 0.0,
            "final": int(counts[-1]) if counts.size else 0,
        },
        "relocalisation": {
            "episodes": len(evaluation.episodes),
            "first_delay_keyframes": evaluation.first_delay,
            "mean_delay_keyframes": evaluation.mean_delay,
        },
        "loop_closure": {
            "claims": int(evaluation.claims.sum()),
            "correct": int(evaluation.correct.sum()) if has_truth else None,
            "ground_truth_revisits": int(evaluation.true_revisit.sum()) if has_truth else None,
            "precision": evaluation.precision,
            "recall": evaluation.recall,
        },
        "error": {
            "best": _stats(evaluation.error_stats(weighted=False)),
            "weighted": _stats(evaluation.error_stats(weighted=True)),
        },
        "timing": {"keyframes_per_second": keyframes_per_second},
    }


def summary_keys() -> set[str]:
    """Every dotted leaf key of the summary (what ``--fail-on`` may test)."""
    empty = Evaluation(
        0,
        np.zeros(0, np.int64),
        np.zeros(0, bool),
        False,
        np.zeros(0, bool),
        np.zeros(0, bool),
        np.zeros((0, 3)),
        np.zeros((0, 3)),
        (),
    )
    return set(_leaves(build_summary(empty, states=0, links=0, keyframes_per_second=None)))


def _leaves(tree: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in tree.items():
        if isinstance(value, dict):
            out.update(_leaves(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = value
    return out


# --- quality gates ---------------------------------------------------------------------------------

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

        A null value (not measurable, e.g. precision without any claim) holds for every ordering
        test: a gate never passes on a measurement that was not made. ``== null`` / ``!= null``
        test for it explicitly.
        """
        actual = _leaves(summary)[self.key]
        if self.value is None:
            return (actual is None) == (self.op == "=="), actual
        if actual is None:
            return True, None
        if isinstance(actual, float) and math.isnan(actual):
            return True, actual
        return bool(_OPERATORS[self.op](float(actual), self.value)), actual


def parse_condition(text: str, keys: set[str] | None = None) -> Condition:
    """``'loop_closure.precision<0.99'`` → Condition; ConfigError naming the problem otherwise."""
    match = _CONDITION.match(text)
    if match is None:
        raise ConfigError(
            f"malformed --fail-on condition {text!r} (expected KEY OP NUMBER, e.g. "
            f"'loop_closure.precision<0.99'; OP is one of < <= > >= == !=)"
        )
    key, op, raw = match.groups()
    keys = summary_keys() if keys is None else keys
    if key not in keys:
        raise ConfigError(
            f"--fail-on {text!r}: unknown summary key '{key}' (known: {', '.join(sorted(keys))})"
        )
    if raw == "null":
        if op not in ("==", "!="):
            raise ConfigError(f"--fail-on {text!r}: null can only be compared with == or !=")
        return Condition(text, key, op, None)
    try:
        value = float(raw)
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
            shown = "null" if actual is None else f"{actual:.6g}" if isinstance(actual, float) else actual
            failed.append(f"{condition.text.strip()} (is {shown})")
    return failed


# --- graph JSON ------------------------------------------------------------------------------------


def _pose_json(pose: np.ndarray) -> dict[str, float] | None:
    if not np.isfinite(pose).all():
        return None
    return {"x_m": float(pose[0]), "y_m": float(pose[1]), "yaw_rad": float(pose[2])}


def build_graph_json(
    graph: dict[str, Any],
    stamps_ns: Sequence[int],
    true_poses: np.ndarray | None,
    *,
    estimate_path: str,
    recording_path: str | None,
) -> dict[str, Any]:
    """The map as JSON (``docs/graph-json.md``): the estimate's graph joined with stamps and truth."""
    n = len(stamps_ns)

    def truth(keyframe: int) -> dict[str, float] | None:
        if true_poses is None or not 0 <= keyframe < len(true_poses):
            return None
        return _pose_json(true_poses[keyframe])

    states = []
    for state in graph["states"]:
        keyframes = [int(k) for k in state["keyframes"]]
        first = int(state["id"])
        states.append(
            {
                "id": first,
                "keyframes": keyframes,
                "stamps_ns": [int(stamps_ns[k]) for k in keyframes if 0 <= k < n],
                "first_visit_truth": truth(first),
            }
        )
    links = [
        {
            "from": int(link["from"]),
            "to": int(link["to"]),
            "action": link["action"],
            "covariance": link["covariance"],
            "count": int(link["count"]),
            "loop_closure": is_loop_closure_link(int(link["from"]), int(link["to"])),
        }
        for link in graph["links"]
    ]
    return {
        "version": GRAPH_JSON_VERSION,
        "estimate": estimate_path,
        "recording": recording_path,
        "keyframes": n,
        "ground_truth": true_poses is not None,
        "states": states,
        "links": links,
        "hypotheses": [
            {
                "id": h["id"],
                "parent": h["parent"],
                "state": h["state"],
                "belief": h["belief"],
                "new_state": h["new_state"],
            }
            for h in graph["hypotheses"]
        ],
    }


def is_loop_closure_link(a: int, b: int) -> bool:
    """A link that involves a revisit: anything but first-visit state k followed by new state k + 1.

    State ids are first-visit keyframes, so the exploration link from a new place to the next new
    place always joins k and k + 1; every other link was made by a keyframe that revisited a state.
    """
    return abs(a - b) != 1


# --- files -----------------------------------------------------------------------------------------
