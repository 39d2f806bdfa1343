"""Metrics against ground truth: revisits, claims, precision/recall, delays, errors."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from aslam.core.metrics import evaluate, ground_truth_revisits
from aslam.core.tree import Hypothesis


def new(t: int) -> Hypothesis:
    return Hypothesis(t, None, t, 1.0, True)


def claim(state: int, belief: float = 1.0) -> Hypothesis:
    return Hypothesis(0, None, state, belief, False)


# A square walked twice: 4 places, keyframes 4..7 revisit 0..3.
SQUARE = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]] * 2, dtype=float)


def test_ground_truth_revisits_need_position_and_heading():
    poses = np.array([[0, 0, 0], [0.3, 0, 0], [0.3, 0, math.pi], [5, 5, 0]], dtype=float)
    assert ground_truth_revisits(poses, 0.5, 45).tolist() == [False, True, False, False]


@given(st.lists(st.tuples(st.floats(-5, 5), st.floats(-5, 5), st.floats(-3, 3)), min_size=1, max_size=40))
def test_spatial_hash_agrees_with_brute_force(points):
    poses = np.array(points, dtype=float)
    fast = ground_truth_revisits(poses, 0.5, 45)
    for t in range(len(poses)):
        d = np.hypot(*(poses[:t, :2] - poses[t, :2]).T)
        h = np.abs((poses[:t, 2] - poses[t, 2] + np.pi) % (2 * np.pi) - np.pi)
        assert fast[t] == bool(np.any((d <= 0.5) & (h <= math.radians(45))))


def test_perfect_run():
    steps = [(t, [new(t)]) for t in range(4)] + [(t, [claim(t - 4)]) for t in range(4, 8)]
    result = evaluate(steps, SQUARE)
    assert result.precision == 1.0 and result.recall == 1.0
    assert result.first_delay == 0 and len(result.episodes) == 1
    assert result.error_stats(weighted=False)["x_m"].max == 0.0


def test_a_late_and_a_wrong_claim():
    steps = [(t, [new(t)]) for t in range(4)]
    steps += [(4, [new(4)]), (5, [claim(3)]), (6, [claim(2)]), (7, [claim(3)])]
    result = evaluate(steps, SQUARE)
    assert result.claims.sum() == 3 and result.correct.sum() == 2
    assert math.isclose(result.precision, 2 / 3) and math.isclose(result.recall, 2 / 4)
    assert result.first_delay == 2  # keyframe 4 starts the episode, 6 is the first correct claim
    errors = result.error_stats(weighted=False)
    assert errors["x_m"].max == 1.0 and errors["y_m"].max == 1.0  # keyframe 5 at (1, 0) claimed (0, 1)


def test_weighted_error_uses_beliefs_and_excludes_new_state_hypotheses():
    steps = [(t, [new(t)]) for t in range(4)]
    steps += [(4, [claim(0, 0.6), claim(1, 0.3), Hypothesis(9, None, 4, 0.1, True)])]
    poses = SQUARE[:5]
    result = evaluate(steps, poses)
    # |x error| is 0 for state 0 and 1 for state 1: (0.6*0 + 0.3*1) / 0.9
    assert math.isclose(result.weighted_error[4, 0], 1 / 3)


def test_without_ground_truth_only_counts():
    steps = [(0, [new(0)]), (1, [claim(0), new(1)])]
    result = evaluate(steps, None)
    assert result.precision is None and result.recall is None and result.first_delay is None
    assert result.claims.tolist() == [False, True]
    assert result.hypothesis_counts.tolist() == [1, 2]


@given(st.lists(st.booleans(), max_size=30))
def test_true_runs_are_the_maximal_runs(flags):
    from aslam.core.metrics import true_runs

    mask = np.array(flags, dtype=bool)
    rebuilt = np.zeros(len(mask), dtype=bool)
    for start, stop in true_runs(mask):
        assert start < stop and mask[start:stop].all()
        assert (start == 0 or not mask[start - 1]) and (stop == len(mask) or not mask[stop])
        rebuilt[start:stop] = True
    assert (rebuilt == mask).all()
