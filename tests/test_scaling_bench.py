"""bench/slam_scaling_bench.py: the replayed first window is the same run as the long one's start."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "bench"))

import slam_scaling_bench


def test_two_runs_with_the_same_arguments_are_the_same_run():
    """The side-by-side ratio replays the start of the long run: that replay must be identical."""
    first, second = (slam_scaling_bench.Run(400, "blocks", 20, seed=3) for _ in range(2))
    for _ in range(150):
        first.step()
        second.step()
    a, b = first.estimator.result(), second.estimator.result()
    assert [s.id for s in a.states] == [s.id for s in b.states]
    assert [(h.state, h.belief) for h in a.hypotheses] == [(h.state, h.belief) for h in b.hypotheses]
    np.testing.assert_array_equal(
        first.estimator.place_views(a.states), second.estimator.place_views(b.states)
    )


def test_the_ratio_is_judged_on_the_replayed_window_and_the_start_is_kept():
    result = slam_scaling_bench.run(400, "random", 8, seed=1, trace_memory=False)
    assert result["keyframes"] == 400 and result["states"] > 0
    for key in ("first_ms", "first_ms_at_start", "last_ms"):
        assert math.isfinite(result[key]) and result[key] > 0
    assert result["ratio_last_over_first"] == pytest.approx(result["last_ms"] / result["first_ms"])
    assert result["ratio_at_start"] == pytest.approx(result["last_ms"] / result["first_ms_at_start"])
    assert result["second_ms"] is None  # too short a run for a second window apart from the last


def test_a_long_enough_run_also_measures_its_second_window_alongside_the_last(monkeypatch):
    monkeypatch.setattr(slam_scaling_bench, "WINDOW", 100)
    monkeypatch.setattr(slam_scaling_bench, "BLOCK", 50)
    result = slam_scaling_bench.run(500, "blocks", 20, seed=2, trace_memory=False)
    assert math.isfinite(result["second_ms"]) and result["second_ms"] > 0
    assert result["ratio_last_over_second"] == pytest.approx(result["last_ms"] / result["second_ms"])
