"""Graph JSON (``docs/graph-json.md``): the estimate's map joined with keyframe stamps and truth."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from aslam.data_formats.estimate import EstimateGraph, action_json, hypothesis_json

GRAPH_JSON_VERSION = 1


def _pose_json(pose: np.ndarray) -> dict[str, float] | None:
    if not np.isfinite(pose).all():
        return None
    return {"x_m": float(pose[0]), "y_m": float(pose[1]), "yaw_rad": float(pose[2])}


def is_loop_closure_link(a: int, b: int) -> bool:
    """A link that involves a revisit: anything but first-visit state k followed by new state k + 1.

    State ids are first-visit keyframes, so the exploration link from a new place to the next new
    place always joins k and k + 1; every other link was made by a keyframe that revisited a state.
    """
    return abs(a - b) != 1


def build_graph_json(
    graph: EstimateGraph,
    stamps_ns: Sequence[int],
    true_poses: np.ndarray | None,
    *,
    estimate_path: str,
    recording_path: str | None,
) -> dict[str, Any]:
    """The map as JSON (``docs/graph-json.md``). ``stamps_ns`` are this run's keyframes' (from
    ``graph.first_keyframe`` on); ``true_poses`` covers every keyframe of the map."""
    n = len(stamps_ns)
    first = graph.first_keyframe

    def truth(keyframe: int) -> dict[str, float] | None:
        if true_poses is None or not 0 <= keyframe < len(true_poses):
            return None
        return _pose_json(true_poses[keyframe])

    states = [
        {
            "id": state.id,
            "keyframes": list(state.keyframes),
            "stamps_ns": [int(stamps_ns[k - first]) for k in state.keyframes if first <= k < first + n],
            "first_visit_truth": truth(state.id),
        }
        for state in graph.states
    ]
    links = [
        {
            "from": link.from_state,
            "to": link.to_state,
            "action": action_json(link.action),
            "covariance": [list(row) for row in link.covariance],
            "count": link.count,
            "loop_closure": is_loop_closure_link(link.from_state, link.to_state),
        }
        for link in graph.links
    ]
    return {
        "version": GRAPH_JSON_VERSION,
        "estimate": estimate_path,
        "recording": recording_path,
        "keyframes": n,
        "first_keyframe": first,
        # known for some place: a map whose sessions' recordings are gone has none, with truth elsewhere
        "ground_truth": any(state["first_visit_truth"] is not None for state in states),
        "states": states,
        "links": links,
        "hypotheses": [hypothesis_json(h) for h in graph.hypotheses],
    }
