"""Baselines for ``make bench``, scored by the same :func:`aslam.core.metrics.evaluate` as the estimator.

* **odometry only**: never claims a revisit (every keyframe is a new place), so recall is 0; what it
  does report is how far dead-reckoned odometry drifts from the ground truth when nothing closes
  the loop (:func:`odometry_drift`).
* **nearest neighbour**: the same orientation histograms as the estimator
  (:func:`aslam.core.features.orientation_histogram` with ``EstimatorConfig().histogram``). At each
  keyframe it claims the earlier keyframe with the smallest χ² if that χ² is below a threshold,
  else "new place". One hypothesis, no tree, no motion model. The threshold is tuned for F1 on
  one recording (:func:`tune_threshold`) and then used unchanged everywhere.

The keyframes are those of the estimator's own keyframe test (same ``Keyframer``), read with the
same pipeline as ``aslam estimate`` (:func:`aslam.app.pipeline.keyframe_views`), and the
ground truth is matched to keyframe stamps as ``aslam report`` does (``truth_at_stamps``).
"""

from __future__ import annotations

import itertools
import math
from contextlib import closing
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from aslam.app.pipeline import keyframe_views
from aslam.app.score import truth_at_stamps
from aslam.core import se2
from aslam.core.config import EstimatorConfig
from aslam.core.estimator import keyframer as make_keyframer
from aslam.core.features import chi2_distances
from aslam.core.metrics import Evaluation, evaluate
from aslam.core.observation import HistogramModel, ObservationModel
from aslam.core.se2 import dead_reckoning
from aslam.core.tree import Hypothesis
from aslam.data_formats.recording import Recording


@dataclass(frozen=True)
class Keyframes:
    """A recording's keyframes as the estimator sees them: odometry actions, histograms, truth."""

    stamps_ns: list[int]
    actions: np.ndarray
    """(n, 3) odometry action since the previous keyframe (the first is zero)."""
    histograms: np.ndarray
    """(n, length) float32 orientation histograms."""
    true_poses: np.ndarray
    """(n, 3) ground truth at the keyframe stamps (NaN where unknown)."""


def read_keyframes(
    recording: Path, config: EstimatorConfig | None = None, *, model: ObservationModel | None = None
) -> Keyframes:
    """The keyframes of ``recording`` under ``config``'s keyframe test, described by ``model``
    (default: the gradient-orientation histogram of ``config``'s settings, the baselines' own)."""
    config = config or EstimatorConfig()
    model = model if model is not None else HistogramModel(config.histogram)
    keyframer = make_keyframer(config)
    stamps, actions, histograms = [], [], []
    with closing(keyframe_views(Recording(recording).samples(), keyframer, model)) as keyframes:
        for keyframe in keyframes:
            stamps.append(keyframe.stamp_ns)
            actions.append(np.asarray(keyframe.action, float))
            histograms.append(keyframe.view)
    with closing(Recording(recording).ground_truth()) as truth:
        true_poses = truth_at_stamps(stamps, truth)
    return Keyframes(stamps, np.array(actions).reshape(-1, 3), np.array(histograms), true_poses)


# --- odometry only ---------------------------------------------------------------------------------


def odometry_only(keyframes: Keyframes) -> Evaluation:
    """Every keyframe a new place: the scores of never closing a loop."""
    steps = [
        (t, (Hypothesis(id=t, parent_id=None, state=t, belief=1.0, is_new_state=True),))
        for t in range(len(keyframes.stamps_ns))
    ]
    return evaluate(steps, keyframes.true_poses)


@dataclass(frozen=True)
class Drift:
    """Dead-reckoned odometry (keyframe actions composed from the first true pose) against truth."""

    position_m: np.ndarray
    """(n,) distance between the odometry position and the true position."""
    x_m: np.ndarray
    y_m: np.ndarray
    heading_deg: np.ndarray
    """(n,) absolute errors per axis."""

    @property
    def final_m(self) -> float:
        return float(self.position_m[-1])

    @property
    def max_m(self) -> float:
        return float(self.position_m.max())

    @property
    def max_heading_deg(self) -> float:
        return float(self.heading_deg.max())

    def axis_stats(self) -> dict[str, dict[str, float]]:
        """Mean and max of |x|, |y|, |heading| error, shaped like the summary JSON's error stats."""
        return {
            name: {"mean": float(values.mean()), "max": float(values.max())}
            for name, values in (("x_m", self.x_m), ("y_m", self.y_m), ("heading_deg", self.heading_deg))
        }


def odometry_drift(keyframes: Keyframes) -> Drift:
    truth = keyframes.true_poses
    odometry = dead_reckoning(keyframes.actions, truth[0])
    delta = odometry - truth
    heading = np.abs(np.degrees(se2.wrap_angle(delta[:, 2])))
    return Drift(np.hypot(delta[:, 0], delta[:, 1]), np.abs(delta[:, 0]), np.abs(delta[:, 1]), heading)


# --- nearest neighbour -----------------------------------------------------------------------------


def nearest_neighbours(histograms: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each keyframe t ≥ 1: the earlier keyframe with the smallest χ², and that χ² (inf at t = 0)."""
    n = len(histograms)
    best = np.full(n, -1, dtype=np.int64)
    chi2 = np.full(n, np.inf)
    for t in range(1, n):
        distances = chi2_distances(histograms[t], histograms[:t])
        j = int(np.argmin(distances))
        best[t], chi2[t] = j, float(distances[j])
    return best, chi2


def nearest_neighbour(keyframes: Keyframes, threshold: float, matches=None) -> Evaluation:
    """Claim the nearest earlier keyframe when its χ² is below ``threshold``, else a new place.

    A claim names the matched keyframe itself (its first-visit ground truth is that keyframe's).
    """
    best, chi2 = matches if matches is not None else nearest_neighbours(keyframes.histograms)
    steps = []
    for t in range(len(best)):
        if chi2[t] < threshold:
            hypothesis = Hypothesis(id=t, parent_id=None, state=int(best[t]), belief=1.0, is_new_state=False)
        else:
            hypothesis = Hypothesis(id=t, parent_id=None, state=t, belief=1.0, is_new_state=True)
        steps.append((t, (hypothesis,)))
    return evaluate(steps, keyframes.true_poses)


def f1(evaluation: Evaluation) -> float:
    p, r = evaluation.precision or 0.0, evaluation.recall or 0.0
    return 0.0 if p + r == 0 else 2 * p * r / (p + r)


def tune_threshold(keyframes: Keyframes) -> tuple[float, Evaluation]:
    """The χ² threshold with the best F1 on ``keyframes`` (ties: the smaller threshold).

    Candidates are midpoints between consecutive nearest-neighbour χ² values, so each candidate
    admits one more claim than the last.
    """
    matches = nearest_neighbours(keyframes.histograms)
    values = np.unique(matches[1][np.isfinite(matches[1])])
    candidates = [float(values[0]) / 2] + [float(a + b) / 2 for a, b in itertools.pairwise(values)]
    candidates.append(float(values[-1]) * 1.01 + 1e-9)
    best_threshold, best_eval, best_f1 = math.nan, None, -1.0
    for threshold in candidates:
        evaluation = nearest_neighbour(keyframes, threshold, matches)
        score = f1(evaluation)
        if score > best_f1:
            best_threshold, best_eval, best_f1 = threshold, evaluation, score
    assert best_eval is not None
    return best_threshold, best_eval
