"""Metrics against ground truth: revisits, claims, precision/recall, delays, errors."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from aslam.core import se2
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


def test_claims_in_a_gap_of_the_truth_are_neither_right_nor_wrong():
    """Keyframe 6 has no true pose, keyframe 7 names a place whose first visit has none: neither
    can be scored, so precision and the curve leave them out (as recall's revisits already do)."""
    from aslam.core.metrics import score_assignment

    poses = SQUARE.copy()
    poses[6] = np.nan
    poses[3] = np.nan
    steps = [(t, [new(t)]) for t in range(4)] + [(t, [claim(t - 4)]) for t in range(4, 8)]
    result = evaluate(steps, poses)
    assert result.claims.sum() == 4 and result.judged_claims.tolist() == [False] * 4 + [
        True,
        True,
        False,
        False,
    ]
    assert result.precision == 1.0 and not result.wrong.any()
    curve = result.pr_curve()
    assert curve.precision.tolist() == [1.0] and curve.recall_at_full_precision == result.recall
    scored = score_assignment(np.array([0, 1, 2, 3, 0, 1, 2, 3]), poses)
    assert scored.precision == 1.0 and scored.claims.sum() == 4


def test_a_revisit_named_as_a_place_of_unknown_truth_is_no_miss():
    """A run in a map without truth: keyframe 3 truly revisits keyframe 1, and names the map's place
    0, as keyframe 1 did; neither claim can be judged, so recall has nothing to count (not 0)."""
    poses = np.array([[np.nan] * 3, [0, 0, 0], [1, 0, 0], [0, 0, 0]], dtype=float)
    steps = [(0, [new(0)]), (1, [claim(0)]), (2, [new(2)]), (3, [claim(0)])]
    result = evaluate(steps, poses)
    assert result.true_revisit.tolist() == [False, False, False, True]
    assert result.recall is None and result.precision is None and result.pr_curve().auc is None
    assert result.episodes == ()


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


def test_pr_curve_ranks_claims_by_belief():
    from aslam.core.metrics import precision_recall_curve

    confidence = np.array([np.nan, 0.9, 0.8, 0.8, 0.3, np.nan])
    correct = np.array([False, True, True, False, True, False])
    curve = precision_recall_curve(confidence, correct, revisits=4)
    assert curve.thresholds.tolist() == [0.9, 0.8, 0.3]  # the tie at 0.8 enters together
    assert curve.precision.tolist() == [1.0, 2 / 3, 3 / 4]
    assert curve.recall.tolist() == [0.25, 0.5, 0.75]
    assert curve.recall_at_full_precision == 0.25
    assert math.isclose(curve.auc, 0.25 * 1.0 + 0.25 * 2 / 3 + 0.25 * 3 / 4)


def test_pr_curve_of_a_wrong_first_claim_and_of_no_claims():
    from aslam.core.metrics import precision_recall_curve

    curve = precision_recall_curve(np.array([0.9, 0.5]), np.array([False, True]), revisits=2)
    assert curve.recall_at_full_precision == 0.0
    empty = precision_recall_curve(np.full(3, np.nan), np.zeros(3, bool), revisits=2)
    assert empty.thresholds.size == 0 and empty.recall_at_full_precision == 0.0 and empty.auc == 0.0
    assert precision_recall_curve(np.full(3, np.nan), np.zeros(3, bool), revisits=0).auc is None


@given(
    st.lists(st.tuples(st.one_of(st.none(), st.floats(0.01, 1.0)), st.booleans()), min_size=1, max_size=40)
)
def test_pr_curve_ends_at_the_best_hypothesis_precision_and_recall(rows):
    """The lowest threshold keeps every claim: its point is the plain precision and recall."""
    from aslam.core.metrics import precision_recall_curve

    confidence = np.array([np.nan if c is None else c for c, _ in rows])
    correct = np.array([c is not None and ok for c, ok in rows])
    revisits = max(1, int(correct.sum()))
    curve = precision_recall_curve(confidence, correct, revisits)
    claims = np.isfinite(confidence)
    if claims.any():
        assert math.isclose(curve.precision[-1], correct.sum() / claims.sum())
        assert math.isclose(curve.recall[-1], correct.sum() / revisits)
        assert np.all(np.diff(curve.recall) >= 0) and np.all(np.diff(curve.thresholds) < 0)
        assert 0.0 <= curve.auc <= 1.0 and curve.recall_at_full_precision <= curve.recall[-1]


def test_evaluation_keeps_the_belief_of_each_claim():
    steps = [(t, [new(t)]) for t in range(4)]
    steps += [(4, [claim(0, 0.9)]), (5, [claim(3, 0.4)]), (6, [claim(2, 0.7)]), (7, [new(7)])]
    result = evaluate(steps, SQUARE)
    assert np.isnan(result.confidence[:4]).all() and result.confidence[4] == 0.9
    curve = result.pr_curve()
    assert curve.recall_at_full_precision == 0.5  # 0.9 and 0.7 are right, 0.4 is wrong
    assert curve.precision[-1] == result.precision and curve.recall[-1] == result.recall


def test_a_map_assignment_is_scored_like_claims():
    from aslam.core.metrics import score_assignment

    assignment = np.array([0, 1, 2, 3, 0, 1, 3, 7])  # keyframe 6 names place 3 at (0, 1): wrong
    scored = score_assignment(assignment, SQUARE)
    assert scored.claims.tolist() == [False] * 4 + [True, True, True, False]
    assert scored.correct.tolist() == [False] * 4 + [True, True, False, False]
    assert scored.precision == 2 / 3 and scored.recall == 2 / 4


def test_summary_reports_the_curve_and_the_committed_map():
    from aslam.app.score import build_summary, summary_keys
    from aslam.core.metrics import score_assignment

    keys = summary_keys()
    for key in (
        "loop_closure.recall_at_full_precision",
        "loop_closure.auc",
        "committed.precision",
        "committed.recall",
        "timing.slam_ms_per_keyframe",
    ):
        assert key in keys
    steps = [(t, [new(t)]) for t in range(4)]
    steps += [(4, [claim(0, 0.9)]), (5, [claim(3, 0.4)]), (6, [claim(2, 0.7)]), (7, [new(7)])]
    evaluation = evaluate(steps, SQUARE)
    committed = score_assignment(np.array([0, 1, 2, 3, 0, 1, 2, 3]), SQUARE)
    summary = build_summary(evaluation, states=4, links=4, keyframes_per_second=None, committed=committed)
    assert summary["loop_closure"]["recall_at_full_precision"] == 0.5
    assert summary["loop_closure"]["precision"] == 2 / 3
    assert summary["committed"]["precision"] == 1.0 and summary["committed"]["recall"] == 1.0


@given(
    st.lists(
        st.lists(st.tuples(st.integers(0, 7), st.floats(0.01, 1.0), st.booleans()), max_size=4),
        min_size=8,
        max_size=8,
    )
)
def test_a_stream_of_steps_scores_as_the_list_does(raw):
    """``report`` streams the keyframes into ``evaluate`` (their hypotheses never all held): the
    same evaluation, array for array, as from a list."""
    steps = [
        (
            t,
            [
                Hypothesis(i, None, min(state, t), belief, is_new)
                for i, (state, belief, is_new) in enumerate(hs)
            ],
        )
        for t, hs in enumerate(raw)
    ]
    listed = evaluate(steps, SQUARE)
    streamed = evaluate((step for step in steps), SQUARE, count=len(steps))
    for name in ("hypothesis_counts", "claims", "true_revisit", "correct", "best_error", "weighted_error"):
        assert np.array_equal(getattr(listed, name), getattr(streamed, name), equal_nan=True), name
    assert np.array_equal(listed.confidence, streamed.confidence, equal_nan=True)
    assert listed.episodes == streamed.episodes


@pytest.mark.parametrize("count", [3, 5])
def test_a_stream_of_another_length_than_counted_is_refused(count):
    steps = [(t, [new(t)]) for t in range(4)]
    with pytest.raises(ValueError, match="counted"):
        evaluate(iter(steps), SQUARE[:count], count=count)


# Where the revisit test's boundaries are: 0.5 m away, or (0.3, 0.4) whose length rounds either way.
_BOUNDARY_PLACES = [(0.0, 0.0), (0.5, 0.0), (0.0, -0.5), (0.3, 0.4), (0.3, 0.4000000000000001), (0.6, 0.0)]


def _nudged(value: float, ulps: int) -> float:
    for _ in range(abs(ulps)):
        value = float(np.nextafter(value, math.copysign(math.inf, ulps)))
    return value


@settings(max_examples=150, deadline=None)
@given(
    anchor=st.floats(-math.pi, math.pi, exclude_max=True),
    heading_deg=st.one_of(st.just(45.0), st.floats(0.5, 180.0)),
)
def test_a_claim_is_judged_right_exactly_where_the_truth_has_a_revisit(anchor, heading_deg):
    """One test of "the same place" for the truth's revisits, the claims and the committed map. A
    keyframe whose one earlier keyframe it claims: the claim is right exactly when the keyframe is a
    ground-truth revisit, and the map's assignment is scored alike, however the pair sits on the
    radius and the heading (a few ulps either side; headings across ±π as often as not)."""
    from aslam.core.metrics import score_assignment

    heading = math.radians(heading_deg)
    steps = [(0, [new(0)]), (1, [claim(0)])]
    for (x, y), turn, ulps in itertools.product(_BOUNDARY_PLACES, (0.0, heading, -heading), range(-2, 3)):
        poses = np.array([[0.0, 0.0, anchor], [x, y, _nudged(float(se2.wrap_angle(anchor + turn)), ulps)]])
        result = evaluate(steps, poses, heading_deg=heading_deg)
        assignment = score_assignment(np.array([0, 0]), poses, heading_deg=heading_deg)
        assert result.correct[1] == result.true_revisit[1], poses
        assert (
            assignment.correct[1] == result.correct[1]
            and assignment.true_revisit[1] == result.true_revisit[1]
        )
        assert result.recall in (None, 1.0) and result.precision in (0.0, 1.0)


@settings(max_examples=100, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.sampled_from([0.0, 0.3, 0.5]), st.sampled_from([0.0, 0.4]), st.floats(-math.pi, math.pi)
        ),
        min_size=1,
        max_size=12,
    ),
    st.data(),
)
def test_precision_recall_and_the_curve_stay_within_zero_and_one(rows, data):
    """Any run: right claims are judged claims at true revisits, precision, recall, the curve's area
    and its recall at full precision lie in [0, 1], and the committed map agrees claim for claim."""
    from aslam.core.metrics import score_assignment

    true_poses = np.array(rows)
    named = [data.draw(st.integers(-1, t - 1)) for t in range(len(rows))]  # -1: a new place
    steps = [
        (t, [new(t) if k < 0 else claim(k, data.draw(st.floats(0.01, 1.0)))]) for t, k in enumerate(named)
    ]
    result = evaluate(steps, true_poses)
    assert not (result.correct & ~(result.judged_claims & result.true_revisit)).any()
    curve = result.pr_curve()
    for value in (result.precision, result.recall, curve.auc, curve.recall_at_full_precision):
        assert value is None or 0.0 <= value <= 1.0
    if curve.revisits:
        assert curve.recall_at_full_precision <= (result.recall or 0.0)
    assignment = score_assignment(np.array([t if k < 0 else k for t, k in enumerate(named)]), true_poses)
    assert np.array_equal(assignment.claims, result.claims)
    assert np.array_equal(assignment.correct, result.correct)
    assert np.array_equal(assignment.true_revisit, result.true_revisit)
