"""Every parameter of the estimator, with the reason for its default."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from typing import Any, TypeVar

from aslam.core.errors import ConfigError


@dataclass(frozen=True)
class MotionNoise:
    """Odometry noise proportional to distance and angle (the paper injects 3 %); the motion model
    (:mod:`aslam.core.motion`) turns it into covariances."""

    fraction: float = 0.03
    """σ of a move's length per metre and of a turn's angle per radian."""
    drift_rad_per_m: float = math.radians(0.5)
    """σ of the heading drift while moving forward, per metre."""
    floor_m: float = 0.01
    """σ floor in position, so a zero-length action is not infinitely certain."""
    floor_rad: float = math.radians(0.5)
    """σ floor in heading."""


@dataclass(frozen=True)
class HistogramConfig:
    """How an image becomes an observation vector."""

    bins: int = 16
    """Orientation bins over [-π, π)."""
    cells_x: int = 1
    """Columns of spatial cells (1 = the paper's single global histogram)."""
    cells_y: int = 1
    """Rows of spatial cells."""

    @property
    def length(self) -> int:
        return self.bins * self.cells_x * self.cells_y


@dataclass(frozen=True)
class Bounds:
    """The accepted values of a parameter: a closed or half-open interval, finite, whole if ``integer``.

    Wide enough for every sensible setting; their job is to keep the arithmetic finite (no
    ``--beta 1e200`` overflow, no ``--cells-y 100000`` allocation) and to say so in one line.
    """

    low: float
    high: float
    low_open: bool = False
    high_open: bool = False
    integer: bool = False

    def holds(self, value: object) -> bool:
        if isinstance(value, bool):
            return False
        if self.integer:
            if not isinstance(value, int):
                return False
        elif not isinstance(value, int | float) or not math.isfinite(value):
            return False
        above = value > self.low if self.low_open else value >= self.low
        below = value < self.high if self.high_open else value <= self.high
        return above and below

    def describe(self) -> str:
        def number(x: float) -> str:
            return f"{x:g}" if not self.integer else f"{int(x)}"

        if self.integer:
            return f"a whole number in [{number(self.low)}, {number(self.high)}]"
        left = "(" if self.low_open else "["
        right = ")" if self.high_open else "]"
        return f"a number in {left}{number(self.low)}, {number(self.high)}{right}"


_Value = TypeVar("_Value", float, int, str)


def _param(default: _Value, help: str) -> _Value:
    """A configuration field whose help text the CLI and docs read from ``metadata["help"]``."""
    return field(default=default, metadata={"help": help})


@dataclass(frozen=True)
class EstimatorConfig:
    """Configuration of :class:`aslam.core.estimator.Estimator`.

    Defaults reproduce the paper's setting (1 m steps, 90° turns, 3 % odometry error) with the
    project's improvements (spatial cells, graph search); ``paper_faithful()`` turns those off.
    """

    # --- keyframing -------------------------------------------------------------------------
    step_m: float = _param(
        1.0, "A keyframe is taken once odometry says the robot moved this far since the last one."
    )
    turn_deg: float = _param(
        90.0, "A keyframe is taken once odometry says the robot turned this many degrees since the last one."
    )
    keyframe_slack: float = _param(
        0.3,
        "Fraction of step_m/turn_deg forgiven: noisy odometry may measure a commanded 1 m as 0.9 m.",
    )
    keyframe_adaptive: str = _param(
        "on",
        "'on': on a dense stream (several poses per step) take the pose nearest the full step or turn"
        " instead of the first within the slack; 'off': the paper's rule.",
    )
    keyframe_window_m: float = _param(
        0.35,
        "On a dense stream, each keyframe is taken among the frames within this distance (and 20°) of the"
        " odometry's choice: the one the hypotheses, by belief, most believe is at a place they predict (by"
        " appearance and odometry), the next due a step from it, so a second lap's keyframes land on the"
        " first lap's places, not between them (0: odometry's choice, only keyframes decoded). On a sparse"
        " stream (frames farther apart) the frame either side of the odometry's choice, within 0.8 of a"
        " step, is taken instead at ten times the odds of being at a place: one the tracking hypotheses"
        " predict, or, while the best one calls the robot somewhere new, the mapped place most like it.",
    )

    # --- observations -------------------------------------------------------------------------
    observation_model: str = _param(
        "thumbnail",
        "How an image is compared with a place: 'histogram' (the paper's gradient-orientation histogram"
        " and χ²) or 'thumbnail' (a patch-normalised 16×12 thumbnail, mean absolute difference over small"
        " horizontal shifts).",
    )
    histogram_bins: int = _param(
        16,
        "Gradient-orientation bins over [-π, π) (histogram model): an even number; bins × cells_x ×"
        " cells_y at most 16384.",
    )
    cells_x: int = _param(
        2, "Columns of spatial cells per image (histogram model; 1 = the paper's single global histogram)."
    )
    cells_y: int = _param(1, "Rows of spatial cells (histogram model).")
    beta: float = _param(3.0, "Sensitivity β of the observation probability P(z|x) = χ²^-β.")
    chi2_floor: float = _param(
        1e-3, "χ² is floored here so that two identical views give a finite likelihood."
    )
    new_state_chi2: float = _param(
        0.08,
        (
            "Reference χ² of an unseen place: P(z|new) = new_state_chi2^-β. A revisit must look more alike"
            " than this (calibrated on rendered recordings, see docs/estimator.md)."
        ),
    )

    thumbnail_beta: float = _param(
        8.0,
        "Sensitivity β of the thumbnail model, P(z|x) = d^-β (its distances span a narrower range than χ²).",
    )
    thumbnail_phases: int = _param(
        4,
        "Sub-column phases a view is compared at by the thumbnail model: the query is also described"
        " shifted by 1/N … (N−1)/N of a column, so a revisit a fraction of a column (3.75° of a 60° field of"
        " view) off the first visit's heading still lines up; the places keep the unshifted view.",
    )
    new_state_reference: str = _param(
        "online",
        "'online': the reference distance of an unseen place is calibrated on the run itself (a fixed"
        " fraction of the running median distance between consecutive keyframes, views about 1 m"
        " apart); 'fixed': new_state_chi2 (histogram) or 0.56 (thumbnail).",
    )

    appearance_veto: float = _param(
        1.25,
        "A revisit whose distance is at least this × the new-place reference is ruled out whatever"
        " the motion model says (0 = never): with the online reference, 1.25 is the median distance"
        " between consecutive keyframes.",
    )
    contradiction_ratio: float = _param(
        0.8,
        "A revisit the motion model proposes is ruled out when a place found by appearance alone (a"
        " relocalisation) is clearly more alike: its distance under this × the proposed place's (0 = never)."
        " Where the robot was carried, the place odometry predicts can still look half alike (past an"
        " odometry jump no old track predicts: what the lines that jumped there predict is not ruled out)."
        " With nothing singled out, the most alike place elsewhere rules out proposed places that look less"
        " alike than the new-place reference, if it looks more.",
    )
    new_state_coverage: float = _param(
        0.9,
        "How much a mapped place at the predicted pose lowers the prior of 'a new place': the prior is"
        " multiplied by 1 − this × the best revisit transition likelihood (1 for a perfect prediction).",
    )

    # --- transitions ----------------------------------------------------------------------------
    odometry_noise: float = _param(
        0.03, "σ of odometry per metre moved and per radian turned (the paper's 3 %)."
    )
    drift_deg_per_m: float = _param(0.5, "σ of heading drift while moving forward, degrees per metre.")
    place_radius_m: float = _param(
        0.35, "Two visits of one place are never at exactly the same pose: σ of that, in position."
    )
    place_heading_deg: float = _param(
        15.0, "Two visits of one place are never at exactly the same pose: σ of that, in heading (degrees)."
    )
    visit_sigma_m: float = _param(
        0.1,
        "Extra σ of a link that starts or ends at a revisit (it was measured from the visit, not the place).",
    )
    visit_sigma_deg: float = _param(
        3.0, "Extra σ of a link that starts or ends at a revisit, in heading (degrees)."
    )
    gate_sigma: float = _param(
        4.0, "Candidates whose Mahalanobis distance from the predicted pose exceeds this are unreachable."
    )
    revisit_radius_m: float = _param(
        0.5,
        "A revisit stands within this distance of the place (the score's radius). From a new place,"
        " where odometry puts the robot to within its own noise, and after a turn in place (under half"
        " a step), a place farther than this by over gate_sigma σ of the chain and odometry is"
        " unreachable; 0: no such bound.",
    )
    geometric_check_m: float = _param(
        0.0,
        "A place is no revisit when two-view geometry puts the view farther than this from it (ORB"
        " features of the place and a linked neighbour triangulated along their link, the view's pose"
        " by PnP; needs the camera's intrinsics). At 0.45 the matrix's off-pose families (jitter, wander,"
        " the paper's noise model) made 45 % fewer wrong claims and 3 % fewer right ones, and an"
        " estimate took 2–2.4 times as long; 0 (default): no check.",
    )
    revisit_prior: float = _param(
        0.5, "Prior probability that a keyframe revisits some place rather than finding a new one."
    )
    candidate_search: str = _param(
        "graph",
        "Where revisit candidates come from: 'graph' searches the hypothesis's map (loop closures give"
        " short chains); 'path' traces its own path back in time, as the paper does.",
    )
    search_sigma_m: float = _param(
        3.0,
        (
            "The graph search stops where the summed link uncertainty (position variance"
            " + (5 m)² × heading variance) exceeds this σ squared."
        ),
    )
    search_nearness: float = _param(
        0.05,
        "The graph search expands states in order of uncertainty + this × (metres from where odometry"
        " puts the robot)², so its budget is spent where revisits can be.",
    )
    search_max_states: int = _param(
        150,
        "The graph search also stops after this many states: the cost per keyframe is bounded.",
    )

    relocalisation_prior: float = _param(
        1e-4,
        "Prior probability that the robot is somewhere the motion model cannot predict (carried,"
        " odometry reset). Each keyframe, a distinctive place found by appearance over the whole map"
        " is proposed with this prior and must be confirmed by the next keyframe (0 = never).",
    )
    relocalisation_lost_prior: float = _param(
        0.1,
        "For lost_window keyframes after the robot lost track (the best hypothesis was at a mapped place"
        " and now at none) or after a pause (odometry standing still for half a keyframe interval, as"
        " while carried), a place appearance alone singles out is proposed with this prior instead of"
        " relocalisation_prior: after a kidnap the right places often look only a little more alike than"
        " a new place (another light, a view off the first visit's line), and at 1e-4 such a jump was"
        " pruned before the next keyframe could confirm it (0 = relocalisation_prior throughout; no jumps"
        " at all while relocalisation_prior is 0).",
    )
    lost_window: int = _param(
        5, "Keyframes after a loss of track or a pause during which relocalisation_lost_prior holds."
    )
    jump_alarm_rate: float = _param(
        0.01,
        "Expected share of keyframes with a false alarm: appearance singling out a place the motion model did"
        " not propose while the robot is not lost, in an episode (alarms at most 2 keyframes apart) of which"
        " no jump was taken. Where the run's own share is higher (an aliased world: look-alike places far"
        " apart), such a view is weaker evidence of a kidnap, and both jump priors are scaled by (this / the"
        " run's share)^jump_alarm_power; the share counts from the run's start with this rate as a prior"
        " worth 1/rate keyframes (0 = never scaled).",
    )
    jump_alarm_power: float = _param(
        4.0,
        "How steeply the jump priors fall as the share of look-alike alarms rises (see jump_alarm_rate).",
    )
    odometry_jump_factor: float = _param(
        4.0,
        "An odometry step whose length in medians of the run's recent steps, plus its turn in turn_deg,"
        " exceeds this is an odometry failure (a reset, a driver restart), not a motion (a keyframe is taken"
        " at a step or a turn, so no motion is both long and turned far; a turn in place is never a jump):"
        " nothing is predicted from it and the robot may be at any of the"
        " map_relocalisation_candidates places most alike. Independent of relocalisation_prior, so a robot"
        " that is never carried can turn appearance jumps off and still survive a reset (0 = never; else"
        " above 1).",
    )
    relocalisation_candidates: int = _param(
        12,
        "Places most similar by the index (exact, or an inverted file beyond 2,048 places) then compared"
        " exactly.",
    )
    relocalisation_skip: int = _param(
        3,
        "The most recent committed keyframes are left out of the appearance search (the motion covers them).",
    )

    # --- a run in a prior map (estimate --map) ----------------------------------------------------
    map_relocalisation_prior: float = _param(
        1e-3,
        "With --map: while the best hypothesis is in the map, prior of a jump elsewhere in it, to one of the"
        " map_relocalisation_candidates most alike places (no distinctiveness test: across sessions one image"
        " is weak evidence; the next keyframes' motion decides). Off the map, entering it anywhere is as"
        " likely as at the first keyframe (0 = no jumps into the map after the first keyframe).",
    )
    map_relocalisation_candidates: int = _param(
        3, "With --map: the map's places proposed by appearance each keyframe (see map_relocalisation_prior)."
    )
    map_reference_scale: float = _param(
        0.0,
        "With --map, for maps of another season or light: a map place is judged against this × the view's"
        " mean distance to the map's places around it (within map_contrast_window; SeqSLAM's local contrast"
        " enhancement), where that is above the run's own new-place reference (e.g. 0.95), and its evidence"
        " weighs map_evidence_weight. Relative, so in ground the map does not cover it makes look-alikes"
        " (docs/real-data.md); 0 = the run's own reference.",
    )
    map_contrast_window: int = _param(
        5,
        "With --map-reference-scale: half-width, in the map's places (in the order they were made), of the"
        " neighbourhood a map place is judged against.",
    )
    map_evidence_weight: float = _param(
        0.5,
        "With --map-reference-scale: what one view's likeness to a map place weighs against the run's own"
        " (log-likelihood ratio to a new place × this): across seasons one view is weak evidence, the"
        " sequence of views decides.",
    )

    # --- hypothesis tree ------------------------------------------------------------------------
    prune_ratio: float = _param(
        0.005, "Hypotheses whose belief is below this fraction of the best are removed."
    )
    max_hypotheses: int = _param(50, "The tree never holds more leaves than this.")
    merge_window: int = _param(
        3, "Leaves at the same state that agree on the last this-many keyframes are merged."
    )

    def __post_init__(self) -> None:
        problems = self.problems()
        if problems:
            raise ConfigError("; ".join(problems))

    def problems(self) -> list[str]:
        """Every invalid value at once (empty when the configuration is usable)."""
        problems = []
        for name, bounds in RANGES.items():
            value = getattr(self, name)
            if not bounds.holds(value):
                problems.append(f"{name} must be {bounds.describe()}, got {value!r}")
        for name, choices in _choices().items():
            value = getattr(self, name)
            if value not in choices:
                problems.append(f"{name} must be {' or '.join(map(repr, choices))}, got {value!r}")
        jump = self.odometry_jump_factor
        if isinstance(jump, float | int) and 0 < jump <= 1:  # every ordinary step would be a jump
            problems.append(f"odometry_jump_factor must be 0 (off) or above 1, got {jump!r}")
        if self.observation_model == "histogram":  # the other models read none of the three
            if isinstance(self.histogram_bins, int) and self.histogram_bins % 2:
                problems.append(f"histogram_bins must be even, got {self.histogram_bins}")
            length = self.histogram_bins * self.cells_x * self.cells_y
            if not problems and length > MAX_OBSERVATION_LENGTH:
                problems.append(
                    f"histogram_bins × cells_x × cells_y must be at most {MAX_OBSERVATION_LENGTH},"
                    f" got {length}"
                )
        return problems

    @classmethod
    def paper_faithful(cls, **overrides: Any) -> EstimatorConfig:
        """The paper's estimator: one global histogram per image, candidates along the path only."""
        paper: dict[str, Any] = {
            "observation_model": "histogram",
            "new_state_reference": "fixed",
            "cells_x": 1,
            "cells_y": 1,
            "candidate_search": "path",
            "relocalisation_prior": 0.0,
            "relocalisation_lost_prior": 0.0,
            "jump_alarm_rate": 0.0,
            "odometry_jump_factor": 0.0,
            "keyframe_adaptive": "off",
            "keyframe_window_m": 0.0,
            "place_radius_m": 0.2,
            "place_heading_deg": 10.0,
            "revisit_radius_m": 0.0,
            "new_state_coverage": 0.0,
            "appearance_veto": 0.0,
            "contradiction_ratio": 0.0,
        }
        return cls(**{**paper, **overrides})

    @classmethod
    def parameters(cls) -> list[tuple[str, type, object, str]]:
        """(name, type, default, help) of every parameter, for the CLI, config files and docs."""
        return [
            (f.name, type(f.default), f.default, _with_range(f.name, f.metadata["help"])) for f in fields(cls)
        ]

    @property
    def histogram(self) -> HistogramConfig:
        return HistogramConfig(bins=self.histogram_bins, cells_x=self.cells_x, cells_y=self.cells_y)

    @property
    def motion_noise(self) -> MotionNoise:
        return MotionNoise(fraction=self.odometry_noise, drift_rad_per_m=math.radians(self.drift_deg_per_m))


CHOICES: dict[str, tuple[str, ...]] = {
    "keyframe_adaptive": ("on", "off"),
    "new_state_reference": ("online", "fixed"),
    "candidate_search": ("graph", "path"),
}
"""The text parameters and the values each may take, but for ``observation_model``: its values are
the names in ``aslam.core.observation.OBSERVATION_MODELS``, where each model is registered."""


def _choices() -> dict[str, tuple[str, ...]]:
    """``CHOICES`` with the registered observation models (imported on use: that module imports this one)."""
    from aslam.core.observation import OBSERVATION_MODELS

    return {"observation_model": tuple(OBSERVATION_MODELS), **CHOICES}


#: Accepted values of every numeric parameter (shown in the option help and docs/usage.md).
RANGES: dict[str, Bounds] = {
    "step_m": Bounds(1e-3, 100),
    "turn_deg": Bounds(1e-3, 360),
    "keyframe_slack": Bounds(0, 1, high_open=True),
    "keyframe_window_m": Bounds(0, 10),
    "histogram_bins": Bounds(2, 360, integer=True),
    "cells_x": Bounds(1, 32, integer=True),
    "cells_y": Bounds(1, 32, integer=True),
    "beta": Bounds(1e-3, 50),
    "chi2_floor": Bounds(1e-12, 1),
    "new_state_chi2": Bounds(1e-9, 10),
    "odometry_noise": Bounds(0, 1),
    "drift_deg_per_m": Bounds(0, 90),
    "place_radius_m": Bounds(1e-3, 100),
    "place_heading_deg": Bounds(1e-3, 180),
    "visit_sigma_m": Bounds(0, 100),
    "visit_sigma_deg": Bounds(0, 180),
    "gate_sigma": Bounds(1e-3, 100),
    "revisit_radius_m": Bounds(0, 100),
    "geometric_check_m": Bounds(0, 100),
    "revisit_prior": Bounds(1e-6, 1 - 1e-6),
    "search_sigma_m": Bounds(1e-3, 10_000),
    "search_nearness": Bounds(0, 1000),
    "search_max_states": Bounds(1, 100_000, integer=True),
    "prune_ratio": Bounds(1e-12, 1, high_open=True),
    "max_hypotheses": Bounds(1, 10_000, integer=True),
    "merge_window": Bounds(1, 1000, integer=True),
    "thumbnail_beta": Bounds(1e-3, 50),
    "thumbnail_phases": Bounds(1, 8, integer=True),
    "appearance_veto": Bounds(0, 100),
    "contradiction_ratio": Bounds(0, 1),
    "new_state_coverage": Bounds(0, 1, high_open=True),
    "relocalisation_prior": Bounds(0, 1, high_open=True),
    "relocalisation_lost_prior": Bounds(0, 1, high_open=True),
    "lost_window": Bounds(0, 100_000, integer=True),
    "jump_alarm_rate": Bounds(0, 1, high_open=True),
    "jump_alarm_power": Bounds(0, 100),
    "odometry_jump_factor": Bounds(0, 1000),
    "relocalisation_candidates": Bounds(1, 10_000, integer=True),
    "relocalisation_skip": Bounds(0, 100_000, integer=True),
    "map_relocalisation_prior": Bounds(0, 1, high_open=True),
    "map_relocalisation_candidates": Bounds(1, 10_000, integer=True),
    "map_reference_scale": Bounds(0, 10),
    "map_contrast_window": Bounds(1, 10_000, integer=True),
    "map_evidence_weight": Bounds(0, 1, low_open=True),
}
#: Length of one observation vector (bins × cells); bounds the memory per keyframe.
MAX_OBSERVATION_LENGTH = 16_384


def _with_range(name: str, help_text: str) -> str:
    bounds = RANGES.get(name)
    if bounds is None:
        return help_text
    accepted = bounds.describe().removeprefix("a number in ").removeprefix("a whole number in ")
    return f"{help_text} Range: {accepted}."


#: Accepted values of `aslam report`'s revisit tolerances (a revisit is within these of the earlier visit).
REVISIT_RADIUS_M = 0.5
"""A keyframe truly revisits an earlier one (and a claim is right) within this distance: the
default of every scorer (``core.metrics``, ``report --radius-m``, a sweep's ``[score]``)."""
REVISIT_HEADING_DEG = 45.0
"""... and within this difference of heading."""

REPORT_RANGES: dict[str, Bounds] = {
    "radius_m": Bounds(0.001, 1000),
    "heading_deg": Bounds(0, 180, low_open=True),
}


def check_report_tolerances(radius_m: float, heading_deg: float) -> None:
    """ConfigError naming every tolerance (``--radius-m``, ``--heading-deg``) outside its range."""
    values = {"radius_m": radius_m, "heading_deg": heading_deg}
    problems = [
        f"--{name.replace('_', '-')} must be {bounds.describe()}, got {values[name]!r}"
        for name, bounds in REPORT_RANGES.items()
        if not bounds.holds(values[name])
    ]
    if problems:
        raise ConfigError("; ".join(problems))
