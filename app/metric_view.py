"""A metric view of the map: the best hypothesis's keyframes embedded in one frame, and scored.

The estimator keeps no global frame (the paper's design); this view is derived, never the state.
The best hypothesis says which keyframes revisit which place; with the odometry between keyframes
that is a pose graph, which GTSAM optimises (``Pose2`` per keyframe, ``BetweenFactorPose2`` per
odometry step with the motion model's covariance, and per revisit an identity ``BetweenFactorPose2``
from the place's first visit with the revisit tolerance). Closures go through a robust kernel, so
one wrong closure is outvoted instead of folding the map. Scores (APE, RPE) come from evo's library
with evo's alignment, so they are the numbers ``evo_ape``/``evo_rpe`` print for the exported files.

GTSAM and evo are imported inside the functions that need them: ``aslam --help`` stays instant.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from aslam.core import se2
from aslam.core.config import MotionNoise
from aslam.core.motion import action_covariance

if TYPE_CHECKING:
    from aslam.core.config import EstimatorConfig
    from aslam.core.estimator import MapLink, MapState
    from aslam.data_formats.foxglove import MetricScene

OUTVOTED_SIGMA = 5.0
"""A closure this many σ (Mahalanobis, of the revisit tolerance) from agreeing at the solution was
outvoted by the rest of the graph: reported as probably wrong, drawn red in Foxglove."""

PRIOR_SIGMA = 1e-6
"""σ (m and rad) pinning keyframe 0 at the origin: the view's frame is the odometry's start."""


JUMP_VARIANCE = 1e4
"""A map link with this position variance (m²) or more is no constraint (the estimator marks a
relocalisation jump with 1e6)."""
JUMP_SIGMA_M = 1e3


class Kernel(StrEnum):
    """How a loop closure's residual is weighed (the odometry is always Gaussian)."""

    CAUCHY = "cauchy"
    """Weight 1/(1+(r/k)²): a closure many σ away pulls with almost no force (default)."""
    HUBER = "huber"
    """Quadratic up to k σ, linear beyond: convex, but a wrong closure still pulls."""
    GAUSSIAN = "gaussian"
    """No kernel: every closure is believed; one wrong closure folds the map (for comparison)."""


@dataclass(frozen=True)
class RevisitTolerance:
    """σ of "two visits of one place are at the same pose": the closure factors' noise."""

    x_m: float = 0.2
    y_m: float = 0.2
    yaw_rad: float = math.radians(10.0)

    def __post_init__(self) -> None:
        for name in ("x_m", "y_m", "yaw_rad"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"RevisitTolerance.{name} must be positive, got {value!r}")

    @classmethod
    def from_config(cls, config: EstimatorConfig) -> RevisitTolerance:
        """The tolerance the estimator itself used to accept the revisits."""
        return cls(config.place_radius_m, config.place_radius_m, math.radians(config.place_heading_deg))


@dataclass(frozen=True)
class EmbedOptions:
    """How :func:`embed` builds and solves the pose graph."""

    noise: MotionNoise = field(default_factory=MotionNoise)
    """The estimator's motion model: covariance of each odometry factor."""
    revisit: RevisitTolerance = field(default_factory=RevisitTolerance)
    kernel: Kernel = Kernel.CAUCHY
    kernel_width: float = 1.0
    """The kernel's k, in σ of the closure's noise."""
    max_iterations: int = 100

    @classmethod
    def from_config(cls, config: EstimatorConfig, **overrides: Any) -> EmbedOptions:
        """Options matching an estimator configuration (its motion noise and place tolerance)."""
        return cls(
            **{"noise": config.motion_noise, "revisit": RevisitTolerance.from_config(config), **overrides}
        )


def _frozen(array: np.ndarray) -> np.ndarray:
    array = np.ascontiguousarray(array)
    array.setflags(write=False)
    return array


@dataclass(frozen=True, eq=False)
class Embedding:
    """One pose per keyframe in the frame of keyframe 0, optimised and from odometry alone."""

    poses: np.ndarray
    """(n, 3) optimised ``(x_m, y_m, yaw_rad)`` per keyframe."""
    odometry: np.ndarray
    """(n, 3) dead reckoning: the keyframe actions composed (the optimiser's starting point)."""
    assignment: np.ndarray
    """(n,) state (first-visit keyframe) of each keyframe, as given."""
    closures: np.ndarray
    """(m, 2) ``(first-visit keyframe, revisiting keyframe)`` of every closure factor."""
    closure_sigmas: np.ndarray
    """(m,) each closure's Mahalanobis distance at the solution (in σ of the revisit tolerance):
    a closure far beyond the kernel's width was outvoted, i.e. probably wrong."""
    iterations: int

    @property
    def keyframes(self) -> int:
        return len(self.poses)

    @property
    def outvoted(self) -> np.ndarray:
        """(n,) True for the keyframes whose closure the graph outvoted (see ``OUTVOTED_SIGMA``)."""
        mask = np.zeros(self.keyframes, bool)
        mask[self.closures[self.closure_sigmas > OUTVOTED_SIGMA, 1]] = True
        return mask


def check_assignment(assignment: np.ndarray) -> list[str]:
    """Every reason ``assignment`` is not a keyframe → first-visit-keyframe map (empty when it is)."""
    problems = []
    n = len(assignment)
    if n and assignment[0] != 0:
        problems.append(f"keyframe 0 must be state 0, got {assignment[0]}")
    bad_range = np.flatnonzero((assignment < 0) | (assignment > np.arange(n)))
    if len(bad_range):
        k = int(bad_range[0])
        problems.append(f"keyframe {k} is assigned state {assignment[k]}, not an earlier keyframe")
    else:
        not_first = np.flatnonzero(assignment[assignment] != assignment)
        if len(not_first):
            k = int(not_first[0])
            problems.append(
                f"keyframe {k} revisits state {assignment[k]}, whose own keyframe is assigned"
                f" state {assignment[assignment[k]]} (states are first-visit keyframes)"
            )
    return problems


def preload() -> None:
    """Import what the metric view needs, GTSAM and Foxglove's schemas (0.15 s), ahead of it:
    ``aslam estimate`` does it while its reader process starts."""
    import gtsam  # noqa: F401

    from aslam.data_formats.foxglove import preload_schemas

    preload_schemas()


def embed(
    actions: np.ndarray,
    assignment: np.ndarray,
    options: EmbedOptions | None = None,
    jumps: np.ndarray | None = None,
    *,
    on_iteration: Callable[[int], None] | None = None,
) -> Embedding:
    """Optimise the best hypothesis's keyframes as a pose graph (Levenberg–Marquardt, GTSAM).

    ``actions`` (n, 3) are the keyframe-to-keyframe odometry actions (the first is the start's and
    ignored); ``assignment`` (n,) the state of each keyframe, where a state is the keyframe of its
    first visit, so keyframe k with ``assignment[k] != k`` revisits the place of keyframe
    ``assignment[k]``. ``jumps`` (n,) marks the actions that are no constraint: the robot was
    carried, or odometry restarted, and the estimator relocalised (its link has a huge covariance);
    those factors get a σ of ``JUMP_SIGMA_M`` so the closures place what follows. The result is in
    the frame of keyframe 0. ValueError on inconsistent input. ``on_iteration(i)`` is called after
    each Levenberg–Marquardt iteration: GTSAM holds the interpreter while it optimises (seconds at
    10,000 keyframes), so this is where a progress display can move and Ctrl-C can land.
    """
    import gtsam

    options = options or EmbedOptions()
    actions = np.asarray(actions, dtype=float).reshape(-1, 3)
    assignment = np.asarray(assignment).astype(np.int64, copy=False)
    n = len(actions)
    if assignment.shape != (n,):
        raise ValueError(f"assignment has shape {assignment.shape}, expected ({n},) like the actions")
    if not np.isfinite(actions).all():
        raise ValueError("actions contain NaN or infinity")
    problems = check_assignment(assignment)
    if problems:
        raise ValueError("; ".join(problems))

    odometry = se2.dead_reckoning(actions)
    graph = gtsam.NonlinearFactorGraph()
    initial = gtsam.Values()
    if n:
        graph.add(
            gtsam.PriorFactorPose2(
                0, gtsam.Pose2(0.0, 0.0, 0.0), gtsam.noiseModel.Isotropic.Sigma(3, PRIOR_SIGMA)
            )
        )
    for k in range(n):
        initial.insert(k, gtsam.Pose2(*odometry[k]))
        if k:
            covariance = action_covariance(actions[k], options.noise)
            if jumps is not None and jumps[k]:
                covariance = np.diag([JUMP_SIGMA_M**2, JUMP_SIGMA_M**2, math.pi**2])
            graph.add(
                gtsam.BetweenFactorPose2(
                    k - 1, k, gtsam.Pose2(*actions[k]), gtsam.noiseModel.Gaussian.Covariance(covariance)
                )
            )
    revisit = options.revisit
    closure_noise: gtsam.noiseModel.Base = gtsam.noiseModel.Diagonal.Sigmas(
        np.array([revisit.x_m, revisit.y_m, revisit.yaw_rad])
    )
    if options.kernel is Kernel.CAUCHY:
        closure_noise = gtsam.noiseModel.Robust.Create(
            gtsam.noiseModel.mEstimator.Cauchy.Create(options.kernel_width), closure_noise
        )
    elif options.kernel is Kernel.HUBER:
        closure_noise = gtsam.noiseModel.Robust.Create(
            gtsam.noiseModel.mEstimator.Huber.Create(options.kernel_width), closure_noise
        )
    revisits = np.flatnonzero(assignment != np.arange(n))
    closures = (
        np.stack([assignment[revisits], revisits], axis=1) if len(revisits) else np.zeros((0, 2), np.int64)
    )
    for place, k in closures.tolist():
        graph.add(gtsam.BetweenFactorPose2(place, k, gtsam.Pose2(0.0, 0.0, 0.0), closure_noise))

    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(options.max_iterations)
    if on_iteration is not None:
        params.iterationHook = lambda iteration, _error_before, _error_after: on_iteration(int(iteration))
    optimizer = gtsam.LevenbergMarquardtOptimizer(graph, initial, params)
    result = optimizer.optimize() if n else initial
    poses = np.array([[p.x(), p.y(), p.theta()] for p in (result.atPose2(k) for k in range(n))]).reshape(
        -1, 3
    )

    sigmas = np.array([revisit.x_m, revisit.y_m, revisit.yaw_rad])
    if len(closures):
        residual = se2.between(poses[closures[:, 0]], poses[closures[:, 1]])
        closure_sigmas = np.sqrt(((residual / sigmas) ** 2).sum(axis=1))
    else:
        closure_sigmas = np.zeros(0)
    return Embedding(
        poses=_frozen(poses),
        odometry=_frozen(odometry),
        assignment=_frozen(assignment.copy()),
        closures=_frozen(closures.astype(np.int64)),
        closure_sigmas=_frozen(closure_sigmas),
        iterations=int(optimizer.iterations()) if n else 0,
    )


def assignment_from_states(states: Sequence[tuple[int, Sequence[int]]], keyframes: int) -> np.ndarray:
    """(n,) state per keyframe from the map's ``(state id, keyframes assigned to it)`` pairs.

    ValueError when a keyframe has no state or two.
    """
    assignment = np.full(keyframes, -1, np.int64)
    for state, members in states:
        for k in members:
            if not 0 <= k < keyframes:
                raise ValueError(f"state {state} lists keyframe {k}, outside 0..{keyframes - 1}")
            if assignment[k] >= 0:
                raise ValueError(f"keyframe {k} is in states {assignment[k]} and {state}")
            assignment[k] = state
    missing = np.flatnonzero(assignment < 0)
    if len(missing):
        raise ValueError(f"keyframe {int(missing[0])} has no state ({len(missing)} keyframes without one)")
    return assignment


# --- scores (evo) --------------------------------------------------------------------------------


@dataclass(frozen=True)
class ErrorStats:
    """Summary of one error series, as evo reports it."""

    rmse: float
    mean: float
    median: float
    max: float


@dataclass(frozen=True)
class TrajectoryScores:
    """evo's APE (translation, after SE(3) Umeyama alignment) and RPE (per keyframe step)."""

    ape_m: ErrorStats | None
    """None where no alignment exists (``unaligned`` says why): RPE needs none."""
    rpe_m: ErrorStats
    """Translation error of each keyframe-to-keyframe motion."""
    rpe_deg: ErrorStats
    """Rotation error of each keyframe-to-keyframe motion."""
    keyframes: int
    """Keyframes scored (those with ground truth)."""
    unaligned: str | None = None
    """Why the trajectory could not be aligned to the truth (every true position on one line: a
    train, a corridor, a turn in place), or None."""


@dataclass(frozen=True)
class MetricScores:
    optimised: TrajectoryScores
    odometry: TrajectoryScores


def _stats(metric: Any) -> ErrorStats:
    from evo.core.metrics import StatisticsType

    return ErrorStats(
        rmse=float(metric.get_statistic(StatisticsType.rmse)),
        mean=float(metric.get_statistic(StatisticsType.mean)),
        median=float(metric.get_statistic(StatisticsType.median)),
        max=float(metric.get_statistic(StatisticsType.max)),
    )


def score_trajectory(
    poses: np.ndarray, truth: np.ndarray, stamps_ns: Sequence[int] | np.ndarray
) -> TrajectoryScores:
    """Score ``poses`` (n, 3) against ``truth`` (n, 3; NaN rows = unknown) at the same stamps.

    Keyframes without truth are dropped. APE aligns the estimate to the truth with evo's Umeyama
    SE(3) alignment (no scale), as ``evo_ape -a``; RPE compares consecutive scored keyframes, which
    no rigid alignment changes: where none exists (every true position on one line leaves the
    rotation about it free) APE is None and RPE is still scored. ValueError when fewer than two
    keyframes have truth.
    """
    import copy

    from evo.core import metrics

    from aslam.data_formats.trajectory import evo_trajectory

    poses = np.asarray(poses, dtype=float).reshape(-1, 3)
    truth = np.asarray(truth, dtype=float).reshape(-1, 3)
    stamps = np.asarray(stamps_ns, dtype=np.int64)
    if not (len(poses) == len(truth) == len(stamps)):
        raise ValueError(f"{len(poses)} poses, {len(truth)} true poses and {len(stamps)} stamps")
    known = np.isfinite(truth).all(axis=1)
    if known.sum() < 2:
        raise ValueError(f"only {int(known.sum())} keyframes have ground truth; need 2 to score")
    reference = evo_trajectory(truth[known], stamps[known])
    estimate = copy.deepcopy(evo_trajectory(poses[known], stamps[known]))
    from evo.core.geometry import GeometryException

    ape_stats, unaligned = None, None
    try:
        estimate.align(reference, correct_scale=False)
    except GeometryException as err:  # e.g. every position on one line: no unique rotation
        unaligned = str(err)
    else:
        ape = metrics.APE(metrics.PoseRelation.translation_part)
        ape.process_data((reference, estimate))
        ape_stats = _stats(ape)
    rpe_m = metrics.RPE(metrics.PoseRelation.translation_part, delta=1, delta_unit=metrics.Unit.frames)
    rpe_m.process_data((reference, estimate))
    rpe_deg = metrics.RPE(metrics.PoseRelation.rotation_angle_deg, delta=1, delta_unit=metrics.Unit.frames)
    rpe_deg.process_data((reference, estimate))
    return TrajectoryScores(ape_stats, _stats(rpe_m), _stats(rpe_deg), int(known.sum()), unaligned)


def score(embedding: Embedding, truth: np.ndarray, stamps_ns: Sequence[int] | np.ndarray) -> MetricScores:
    """evo's scores of the optimised and of the odometry-only trajectory against the truth."""
    return MetricScores(
        optimised=score_trajectory(embedding.poses, truth, stamps_ns),
        odometry=score_trajectory(embedding.odometry, truth, stamps_ns),
    )


def metric_scene(embedding: Embedding, stamps_ns: Sequence[int] | np.ndarray) -> MetricScene:
    """What Foxglove draws of an embedding (see ``aslam.data_formats.foxglove.write_scene``)."""
    from aslam.data_formats.foxglove import MetricScene

    return MetricScene(
        stamps_ns=np.asarray(stamps_ns, dtype=np.int64),
        poses=embedding.poses,
        assignment=embedding.assignment,
        odometry=embedding.odometry,
        outvoted=embedding.outvoted,
    )


def export_trajectories(
    path: Path | str,
    embedding: Embedding,
    stamps_ns: Sequence[int] | np.ndarray,
    truth: np.ndarray | None = None,
    fmt: str | None = None,
    *,
    force: bool = False,
    on_warning: Callable[[str], None] | None = None,
) -> dict[str, Path]:
    """Write the optimised trajectory to ``path``, and beside it ``*.odometry.*`` and ``*.truth.*``.

    The format is ``fmt``, else the one the name says (``data_formats.trajectory.export_plan``).
    The truth is written where known: in TUM the keyframes without truth are left out (evo pairs
    poses by stamp); KITTI has no stamps, so its truth file is written only when every keyframe has
    truth (``on_warning`` hears why it is missing; with ``force`` an earlier run's truth file there
    is removed). Every path is checked before anything is written. Returns ``{"optimised": …, …}``.
    """
    from aslam.data_formats import files
    from aslam.data_formats.trajectory import TrajectoryError, TrajectoryFormat, export_plan, write_trajectory

    paths, fmt = export_plan(path, None if fmt is None else TrajectoryFormat(fmt))
    stamps = np.asarray(stamps_ns, dtype=np.int64)
    known = np.zeros(len(stamps), bool) if truth is None else np.isfinite(truth).all(axis=1)
    with_truth = known.all() if fmt is TrajectoryFormat.KITTI else known.any()
    targets = {"optimised": paths.optimised, "odometry": paths.odometry}
    if with_truth:
        targets["truth"] = paths.truth
    elif known.any() and on_warning is not None:
        on_warning(
            f"{paths.truth}: not written: {int((~known).sum())} of {len(known)} keyframes have no ground "
            "truth, and KITTI rows carry no stamps to pair them by (--trajectory-format tum leaves them out)"
        )
    for target in targets.values():
        files.check_output_path(target, force=force, error=TrajectoryError)
    write_trajectory(paths.optimised, embedding.poses, stamps, fmt)
    write_trajectory(paths.odometry, embedding.odometry, stamps, fmt)
    if with_truth and truth is not None:
        write_trajectory(paths.truth, truth[known], stamps[known], fmt)
    else:  # an earlier run's truth file beside this run's trajectory would pair with it in evo
        files.remove_superseded(paths.truth, force=force)
    return targets


# --- from a run ----------------------------------------------------------------------------------


def estimator_config(config: dict[str, Any]) -> EstimatorConfig:
    """The configuration an estimate file records, as the dataclass (unknown keys ignored).

    ValueError when the recorded values are not a valid configuration.
    """
    from dataclasses import fields

    from aslam.core.config import EstimatorConfig
    from aslam.core.errors import ConfigError

    known = {f.name for f in fields(EstimatorConfig)}
    try:
        return EstimatorConfig(**{k: v for k, v in config.items() if k in known})
    except (ConfigError, TypeError) as err:
        raise ValueError(f"unusable estimator configuration ({err})") from err


def embed_run(
    actions: np.ndarray,
    states: Sequence[MapState],
    links: Sequence[MapLink],
    config: EstimatorConfig,
    first_keyframe: int = 0,
    *,
    on_iteration: Callable[[int], None] | None = None,
) -> Embedding | None:
    """The metric view of a run's best map (``states`` and ``links`` as ``Estimator.result()`` or the
    estimate file give them), with the run's own motion noise and place tolerance; None without
    keyframes (one keyframe is one pose, at the origin: a trajectory still, which evo reads). With a
    prior map (``first_keyframe`` > 0) only this run's keyframes are embedded: a revisit of a prior
    place has no first visit in this run to close on. An action whose map link
    the estimator marked as no constraint (a relocalisation after a kidnap or an odometry reset:
    variance ≥ ``JUMP_VARIANCE``) is not trusted either. ``on_iteration`` as :func:`embed`'s.
    """
    actions = np.asarray(actions, dtype=float).reshape(-1, 3)
    if not len(actions):
        return None
    # This run's keyframes only, each place named by its first visit in this run (a prior map's
    # place first seen here is, for the pose graph, first seen here).
    label: dict[int, int] = {}
    session = []
    for state in states:
        visits = [k - first_keyframe for k in state.keyframes if k >= first_keyframe]
        if visits:
            label[state.id] = min(visits)
            session.append((label[state.id], visits))
    assignment = assignment_from_states(session, len(actions))
    loose = {
        frozenset((label[link.from_state], label[link.to_state]))
        for link in links
        if max(link.covariance[0][0], link.covariance[1][1]) >= JUMP_VARIANCE
        and link.from_state in label
        and link.to_state in label
    }
    pairs = [frozenset((int(a), int(b))) for a, b in itertools.pairwise(assignment)]
    jumps = np.array([False] + [pair in loose for pair in pairs])
    return embed(actions, assignment, EmbedOptions.from_config(config), jumps, on_iteration=on_iteration)
