"""The noise model: where the robot really is (ground truth) and where it thinks it is (odometry).

Two models (``--noise-model``):

**default** — why not simply let the true pose accumulate the paper's 3 % action error?  We
measured it: on the paper route the true path then drifts about 1 m per 30 m lap, the camera leaves
a 2 m corridor and only ~55 % of the lap-2 keyframes are real revisits of lap-1 places — the
revisits that the estimator is supposed to recognise stop being revisits.  So the two roles are split:

* **Ground truth** follows the commanded route with two kinds of *non-accumulating* deviation:

  - *jitter*: each keyframe pose is the commanded pose plus independent Gaussian noise
    (σ = ``jitter_m`` in x and y, ``jitter_deg`` in yaw) — white, uncorrelated from one keyframe to
    the next;
  - *wander* (off by default): a smooth offset of x and y (σ = ``wander_m`` each, so across and
    along the corridor) and of the heading (σ = ``wander_deg``), each a Gaussian-smoothed random
    process of the distance driven with correlation ``exp(-½ (Δs / wander_length_m)²)``: the robot
    drifts slowly to one side and back as a real one does, and since the process runs on along the
    whole route, every lap wanders differently.  The position part is soft-limited to
    :data:`WANDER_LIMIT_M` (``r → R·tanh(r/R)``), so it stays smooth and inside a 2 m corridor.

  The total position offset is clamped to :data:`MAX_OFFSET_M` (this never binds for the default
  jitter), so the camera stays in free space; revisits are real, and two visits of one place are
  never at exactly the same pose (as with a real robot).
* **Odometry** (``/odom``, what the robot believes) integrates each *true* action — the SE(2)
  motion between consecutive true poses — perturbed like real wheel odometry: the travelled
  distance and the turned angle are each scaled by ``1 + σ·n`` (σ = ``noise``, the paper's 3 %),
  plus a heading drift while moving of σ = ``drift_deg_per_m`` × distance.  It starts at the true
  start pose and accumulates error like real odometry: after a lap it is off by about the noise
  level times the distance travelled, while each single action is off by about σ.

**paper** — the paper's experiment literally: each *executed* action is the commanded one read
through the same error (distance and angle scaled by ``1 + σ·n``, heading drift while moving), the
true path integrates the executed actions so the error accumulates in the truth, and the odometry
reports the *commanded* actions.  Jitter and wander, when given, are added to the executed path.
The generated world is then built around the true path (see :func:`aslam.recorder.record.plan`),
so the camera stays in free space however far the truth drifts.

In both models a **kidnap** action (see :mod:`aslam.recorder.routes`) moves the truth to its pose
while the odometry reports no motion, and :func:`reset_odometry` restarts the odometry from zero
at a keyframe.

Everything is drawn from ``numpy.random.default_rng((seed, k))`` streams in a fixed order (k = 1
for jitter and action noise, k = 4 for wander), so a seed gives the same poses on every machine and
turning the wander on does not change the jitter or the odometry noise drawn.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict

import numpy as np

from aslam.core import se2
from aslam.recorder.config import NoiseModel, NoiseParams

#: Soft limit of the wander's position offset: keeps a wandering camera ≥ 0.4 m off the walls of a
#: 2 m corridor.
WANDER_LIMIT_M = 0.6
#: Hard limit of the total true offset from the commanded path in the default model (jitter +
#: wander): the camera stays ≥ 0.1 m off the walls of a 2 m corridor (0.3 m when axis-aligned).
MAX_OFFSET_M = 0.7
#: Grid step of the wander process, as a fraction of its correlation length.
WANDER_STEP_FRACTION = 1.0 / 8.0

_SUMMARY = {
    NoiseModel.DEFAULT: "truth=route+jitter+wander; odom=integrated noisy true actions",
    NoiseModel.PAPER: "truth=integrated noisy executed actions (+jitter+wander); odom=commanded actions",
}


def noise_json(model: NoiseParams, *, odometry_reset_at: int | None = None) -> str:
    """The parameters and the model's name, as stored in the recording's metadata."""
    params = {k: v for k, v in asdict(model).items() if k != "model"}
    doc = {
        "model": model.model.value,
        "summary": _SUMMARY[model.model],
        **params,
        "odometry_reset_at": odometry_reset_at,
    }
    return json.dumps(doc, separators=(",", ":"))


def jitter(n: int, model: NoiseParams, rng: np.random.Generator) -> np.ndarray:
    """Independent per-keyframe ``(dx, dy, dyaw)`` deviations (white)."""
    return rng.normal(size=(n, 3)) * np.array(
        [model.jitter_m, model.jitter_m, math.radians(model.jitter_deg)]
    )


def arc_length(poses: np.ndarray, connected: np.ndarray | None = None) -> np.ndarray:
    """Distance driven up to each pose (a kidnap adds none)."""
    poses = np.asarray(poses, dtype=float)
    steps = np.hypot(*np.diff(poses[:, :2], axis=0).T)
    if connected is not None:
        steps = np.where(connected, steps, 0.0)
    return np.concatenate([[0.0], np.cumsum(steps)])


def smooth_process(arc_m: np.ndarray, length_m: float, channels: int, rng: np.random.Generator) -> np.ndarray:
    """Unit-variance Gaussian processes of the distance ``arc_m``, shape ``(len(arc_m), channels)``.

    White noise on a grid of ``length_m / 8`` smoothed with a Gaussian kernel of σ = ``length_m / √2``
    (normalised to unit variance), so the correlation between two points ``Δs`` apart is
    ``exp(-½ (Δs / length_m)²)``; read at ``arc_m`` by linear interpolation.
    """
    arc_m = np.asarray(arc_m, dtype=float)
    step = length_m * WANDER_STEP_FRACTION
    kernel_sigma = length_m / math.sqrt(2.0)
    half = math.ceil(4.0 * kernel_sigma / step)
    t = np.arange(-half, half + 1) * step
    kernel = np.exp(-0.5 * (t / kernel_sigma) ** 2)
    kernel /= math.sqrt(float(np.sum(kernel**2)))
    n_grid = math.ceil(float(arc_m.max(initial=0.0)) / step) + 2
    white = rng.normal(size=(n_grid + 2 * half, channels))
    s_grid = np.arange(n_grid) * step
    out = np.empty((len(arc_m), channels))
    for c in range(channels):
        smooth = np.convolve(white[:, c], kernel, mode="valid")
        out[:, c] = np.interp(arc_m, s_grid, smooth)
    return out


def wander(arc_m: np.ndarray, model: NoiseParams, rng: np.random.Generator) -> np.ndarray:
    """Smooth ``(dx, dy, dyaw)`` deviations at the distances ``arc_m`` (see the module docstring)."""
    unit = smooth_process(arc_m, model.wander_length_m, 3, rng)
    xy = unit[:, :2] * model.wander_m
    r = np.hypot(xy[:, 0], xy[:, 1])
    with np.errstate(invalid="ignore", divide="ignore"):
        scale = np.where(r > 0, WANDER_LIMIT_M * np.tanh(r / WANDER_LIMIT_M) / r, 1.0)
    return np.column_stack([xy * scale[:, None], unit[:, 2] * math.radians(model.wander_deg)])


def clamp_offset(truth: np.ndarray, base: np.ndarray, limit_m: float = MAX_OFFSET_M) -> np.ndarray:
    """``truth`` with each position moved back to within ``limit_m`` of ``base`` (only where beyond)."""
    d = truth[:, :2] - base[:, :2]
    r = np.hypot(d[:, 0], d[:, 1])
    over = r > limit_m
    if not over.any():
        return truth
    out = truth.copy()
    out[over, :2] = base[over, :2] + d[over] * (limit_m / r[over])[:, None]
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


def _connected(n_poses: int, connected: np.ndarray | None) -> np.ndarray:
    if connected is None:
        return np.ones(max(0, n_poses - 1), dtype=bool)
    connected = np.asarray(connected, dtype=bool)
    if len(connected) != n_poses - 1:
        raise ValueError(f"connected has {len(connected)} entries for {n_poses} poses")
    return connected


def odometry_poses(
    truth: np.ndarray,
    model: NoiseParams,
    rng: np.random.Generator,
    connected: np.ndarray | None = None,
) -> np.ndarray:
    """Odometry keyframe poses: the true start, then each noisy true action integrated.

    Across a kidnap (``connected[i]`` False) the odometry reports no motion; its noise is drawn
    anyway so the actions after it get the same noise as without the kidnap.
    """
    truth = np.asarray(truth, dtype=float)
    connected = _connected(len(truth), connected)
    out = np.empty_like(truth)
    out[0] = truth[0]
    for i in range(1, len(truth)):
        reading = noisy_action(se2.between(truth[i - 1], truth[i]), model, rng)
        out[i] = se2.compose(out[i - 1], reading) if connected[i - 1] else out[i - 1]
    return out


def executed_poses(
    commanded: np.ndarray,
    model: NoiseParams,
    rng: np.random.Generator,
    connected: np.ndarray | None = None,
) -> np.ndarray:
    """The paper's model: each commanded action executed with error, accumulated from the start.

    A kidnap puts the robot exactly at its commanded pose.
    """
    commanded = np.asarray(commanded, dtype=float)
    connected = _connected(len(commanded), connected)
    out = np.empty_like(commanded)
    out[0] = commanded[0]
    for i in range(1, len(commanded)):
        executed = noisy_action(se2.between(commanded[i - 1], commanded[i]), model, rng)
        out[i] = se2.compose(out[i - 1], executed) if connected[i - 1] else commanded[i]
    return out


def commanded_odometry(
    start: np.ndarray, commanded: np.ndarray, connected: np.ndarray | None = None
) -> np.ndarray:
    """Odometry that reports the commanded actions exactly, from ``start`` (none across a kidnap)."""
    commanded = np.asarray(commanded, dtype=float)
    connected = _connected(len(commanded), connected)
    out = np.empty_like(commanded)
    out[0] = start
    for i in range(1, len(commanded)):
        action = se2.between(commanded[i - 1], commanded[i])
        out[i] = se2.compose(out[i - 1], action) if connected[i - 1] else out[i - 1]
    return out


def simulate(
    commanded: np.ndarray,
    model: NoiseParams,
    seed: int,
    *,
    connected: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """``(truth, odometry)`` keyframe poses for commanded poses, deterministic for a seed.

    ``connected[i]`` is False where action ``i`` is a kidnap.  The noise stream is its own
    ``default_rng((seed, 1))`` so that the world generator (which uses ``(seed, 0)``) and the noise
    model do not shift each other when either changes; the wander has ``(seed, 4)``.
    """
    commanded = np.asarray(commanded, dtype=float)
    connected = _connected(len(commanded), connected)
    rng = np.random.default_rng([seed, 1])
    wander_rng = np.random.default_rng([seed, 4])
    arc_m = arc_length(commanded, connected)
    if model.model is NoiseModel.PAPER:
        offsets = jitter(len(commanded), model, rng)
        executed = executed_poses(commanded, model, rng, connected)
        truth = executed + offsets
        if model.wander_m > 0 or model.wander_deg > 0:
            truth = truth + wander(arc_m, model, wander_rng)
        truth[:, 2] = se2.wrap_angle(truth[:, 2])
        return truth, commanded_odometry(truth[0], commanded, connected)
    truth = commanded + jitter(len(commanded), model, rng)
    if model.wander_m > 0 or model.wander_deg > 0:
        truth = truth + wander(arc_m, model, wander_rng)
    truth[:, 2] = se2.wrap_angle(truth[:, 2])
    truth = clamp_offset(truth, commanded)
    return truth, odometry_poses(truth, model, rng, connected)


def reset_odometry(odometry: np.ndarray, at: int) -> np.ndarray:
    """Odometry restarted from zero at keyframe ``at``: poses from ``at`` on are re-expressed in the
    frame of pose ``at`` (so it becomes ``(0, 0, 0)``); every relative motion after it is unchanged."""
    odometry = np.asarray(odometry, dtype=float)
    out = odometry.copy()
    out[at:] = se2.between(odometry[at], odometry[at:])
    out[at] = 0.0
    return out
