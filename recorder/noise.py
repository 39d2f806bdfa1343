"""The noise model: where the robot really is (ground truth) and where it thinks it is (odometry).

Why not simply let the true pose accumulate the paper's 3 % action error?  We measured it: on the
paper route the true path then drifts about 1 m per 30 m lap, the camera leaves a 2 m corridor and
only ~55 % of the lap-2 keyframes are real revisits of lap-1 places — the revisits that the
estimator is supposed to recognise stop being revisits.  So the two roles are split:

* **Ground truth** follows the commanded route with a small, *non-accumulating* jitter: each
  keyframe pose is the commanded pose plus independent Gaussian noise (σ = ``jitter_m`` in x and y,
  ``jitter_deg`` in yaw).  The camera stays in free space, revisits are real, and two visits of one
  place are never at exactly the same pose (as with a real robot).
* **Odometry** (``/odom``, what the robot believes) integrates each *true* action — the SE(2)
  motion between consecutive true poses — perturbed like real wheel odometry: the travelled
  distance and the turned angle are each scaled by ``1 + σ·n`` (σ = ``noise``, the paper's 3 %),
  plus a heading drift while moving of σ = ``drift_deg_per_m`` × distance.  It starts at the true
  start pose and accumulates error like real odometry: after a lap it is off by about the noise
  level times the distance travelled, while each single action is off by about σ.

Everything is drawn from one ``numpy.random.default_rng(seed)`` stream in a fixed order, so a seed
gives the same poses on every machine.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict

import numpy as np

from aslam.core import se2
from aslam.recorder.config import NoiseParams


def noise_json(model: NoiseParams) -> str:
    """The parameters and the model's name, as stored in the recording's metadata."""
    doc = {"model": "truth=route+jitter; odom=integrated noisy true actions", **asdict(model)}
    return json.dumps(doc, separators=(",", ":"))


def true_poses(commanded: np.ndarray, model: NoiseParams, rng: np.random.Generator) -> np.ndarray:
    """Ground-truth keyframe poses: the commanded poses plus independent, non-accumulating jitter."""
    commanded = np.asarray(commanded, dtype=float)
    jitter = rng.normal(size=commanded.shape) * np.array(
        [model.jitter_m, model.jitter_m, math.radians(model.jitter_deg)]
    )
    out = commanded + jitter
    out[:, 2] = se2.wrap_angle(out[:, 2])
    return out


def noisy_action(true_action: np.ndarray, model: NoiseParams, rng: np.random.Generator) -> np.ndarray:
    """One odometry reading of a true SE(2) action ``(dx, dy, dyaw)``.

    Distance and angle are scaled by ``1 + σ·n`` (independent n ~ N(0, 1)); moving adds a heading
    drift of σ = ``drift_deg_per_m`` × distance.  The direction of travel is kept.
    """
    dx, dy, dyaw = (float(v) for v in true_action)
    n_dist, n_turn, n_drift = rng.normal(size=3)
    distance = math.hypot(dx, dy)
    scale = 1.0 + model.noise * n_dist
    yaw = dyaw * (1.0 + model.noise * n_turn) + math.radians(model.drift_deg_per_m) * distance * n_drift
    return np.array([dx * scale, dy * scale, float(se2.wrap_angle(yaw))])


def odometry_poses(truth: np.ndarray, model: NoiseParams, rng: np.random.Generator) -> np.ndarray:
    """Odometry keyframe poses: the true start, then each noisy true action integrated."""
    truth = np.asarray(truth, dtype=float)
    out = np.empty_like(truth)
    out[0] = truth[0]
    for i in range(1, len(truth)):
        action = se2.between(truth[i - 1], truth[i])
        out[i] = se2.compose(out[i - 1], noisy_action(action, model, rng))
    return out


def simulate(commanded: np.ndarray, model: NoiseParams, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """``(truth, odometry)`` keyframe poses for commanded poses, deterministic for a seed.

    The noise stream is its own ``default_rng((seed, 1))`` so that the world generator (which
    uses ``(seed, 0)``) and the noise model do not shift each other when either changes.
    """
    rng = np.random.default_rng([seed, 1])
    truth = true_poses(commanded, model, rng)
    return truth, odometry_poses(truth, model, rng)
