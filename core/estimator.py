"""The streaming API: odometry and images in, hypotheses and a map of places out."""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from typing import TypeVar

import numpy as np

from aslam.core import se2
from aslam.core.config import EstimatorConfig
from aslam.core.geometry import PinholeCamera, ViewFeatures
from aslam.core.mapgraph import PriorMap, SharedMap
from aslam.core.motion import rel_covariance
from aslam.core.observation import ObservationModel, observation_model
from aslam.core.tree import SESSION_START, Hypothesis, HypothesisTree, Node, TreeStats

T = TypeVar("T")

TURN_IN_PLACE_M_PER_RAD = 0.3
"""A motion between two poses is a turn in place when it advances less than this per radian turned
(a turning circle of 30 cm: a corner, not a curve)."""
MIN_TURN_RAD = math.radians(0.5)
"""...and turns at least this much: a robot standing still, its heading jittering, is not turning."""
SPARSE_STREAM_STEPS = 0.6
"""A stream is sparse when even its shorter moves (the lower quartile of the last ``TYPICAL_MOVES``,
once there are ``FEWEST_MOVES``) are at least this many steps: about a frame a step. Then every
frame that moved at least half its median move is a keyframe, whatever the step's slack says: where
frames come 0.75 m apart and odometry is noisy, a threshold of two-thirds of a 1 m step took a frame
on one lap and skipped it on the next, so a second lap's keyframes stood where the first had none
(the held-out short steps at 10 % noise, seeds 123 and 127). A frame that moved less (a robot
slowing to a crawl) keeps the rule before, and the threshold is never above that rule's (frames
three steps apart, then one). Two frames a step (0.5) stays dense, and so does a route of two
frames a step with a stretch of longer steps."""
TYPICAL_MOVES = 31
"""Moving frames whose spacing makes a stream's typical spacing (quantiles: one odd frame, a stop or a
frame dropped, does not move them)."""
FEWEST_MOVES = 5
"""Moves seen before a stream may be judged sparse: its first two or three say little."""
MOVING_STEPS = 0.1
"""A frame that advanced less than this many steps (or turned in place) does not count in the typical
spacing: a robot standing or turning is not a stream's pace."""


class Keyframer:
    """Decides from odometry alone when to look: after ``step_m`` metres or ``turn_deg`` of turning.

    Odometry is noisy, so a commanded step may be measured short: ``slack`` forgives that
    fraction. On a dense stream (many poses per step, e.g. video) that slack would fire early,
    every 0.7–0.8 m and mid-turn, so a second lap's keyframes fall between the first lap's places.
    With ``adaptive`` the threshold is also at least ``step − increment/2`` (and likewise for the
    turn), ``increment`` being the motion since the previous pose: the keyframe is the pose
    nearest the full step that the stream offers. With one pose per step it changes nothing, but
    that on a sparse stream (``SPARSE_STREAM_STEPS``) every moving frame is a keyframe, a step
    measured short too.

    A robot that stops to turn in place comes no nearer the full step until the turn is done, and
    one pass may reach the stop a few centimetres short of the step and take the turn into its next
    keyframe while another keyframes the stop: at a turn of less than ``turn_deg`` (60° corners,
    say), the two laps' keyframes then lie on either side of the corner. So with ``adaptive`` a
    turn in place that begins at least the slack's step from the last keyframe is a keyframe.
    """

    def __init__(self, step_m: float, turn_deg: float, slack: float, *, adaptive: bool = False) -> None:
        self._full_step_m = step_m
        self._full_turn_rad = math.radians(turn_deg)
        self._step_m = step_m * (1.0 - slack)
        self._turn_rad = math.radians(turn_deg) * (1.0 - slack)
        self._adaptive = adaptive
        self._moves: deque[float] = deque(maxlen=TYPICAL_MOVES)
        self._last: np.ndarray | None = None
        self._previous: np.ndarray | None = None
        self.at_previous = False
        """The keyframe just found is the pose tested before this one, where a turn in place began
        (adaptive only): the caller takes that pose, then tests this one again."""

    @property
    def step_m(self) -> float:
        """The full step a keyframe is due after (the slack aside)."""
        return self._full_step_m

    def action_if_keyframe(self, odometry_pose: np.ndarray) -> np.ndarray | None:
        """The odometry action since the last keyframe if this pose is a keyframe, else None
        (if :attr:`at_previous`, the action to the pose tested before, which is the keyframe).

        The first pose is always a keyframe, with a zero action.
        """
        pose = np.asarray(odometry_pose, dtype=float)
        previous, self._previous = self._previous, pose
        self.at_previous = False
        if self._last is None:
            self._last = pose
            return np.zeros(3)
        action = se2.between(self._last, pose)
        step_m, turn_rad = self._step_m, self._turn_rad
        if self._adaptive and previous is not None:
            increment = se2.between(previous, pose)
            advance, turn = math.hypot(increment[0], increment[1]), abs(float(increment[2]))
            if (
                previous is not self._last
                and turn >= MIN_TURN_RAD
                and advance < TURN_IN_PLACE_M_PER_RAD * turn
            ):
                to_stop = se2.between(self._last, previous)
                if math.hypot(to_stop[0], to_stop[1]) >= step_m:
                    self._last = self._previous = previous  # this pose is tested again from the stop
                    self.at_previous = True
                    return to_stop
            step_m = max(step_m, self._full_step_m - 0.5 * advance)
            turn_rad = max(turn_rad, self._full_turn_rad - 0.5 * turn)
            if advance >= MOVING_STEPS * self._full_step_m and advance >= TURN_IN_PLACE_M_PER_RAD * turn:
                self._moves.append(advance)
            if len(self._moves) >= FEWEST_MOVES:
                moves = sorted(self._moves)
                half_median = 0.5 * moves[len(moves) // 2]
                sparse = moves[len(moves) // 4] >= SPARSE_STREAM_STEPS * self._full_step_m
                if sparse and advance >= half_median:
                    step_m = min(step_m, half_median)
        if math.hypot(action[0], action[1]) >= step_m or abs(action[2]) >= turn_rad:
            self._last = pose
            return action
        return None

    def keyframes(
        self, items: Iterable[T], pose_of: Callable[[T], np.ndarray]
    ) -> Iterator[tuple[T, np.ndarray]]:
        """``(item, action)`` for each keyframe of a stream of ``items`` (``pose_of(item)``: its
        odometry pose), holding one item back for a turn in place that began there."""
        previous: T | None = None
        for item in items:
            pose = pose_of(item)
            action = self.action_if_keyframe(pose)
            if action is not None and self.at_previous:
                assert previous is not None
                yield previous, action
                action = self.action_if_keyframe(pose)
            if action is not None:
                yield item, action
            previous = item

    def anchor(self, odometry_pose: np.ndarray) -> None:
        """The keyframe was taken at ``odometry_pose`` (a frame near the one this test chose): the
        next one is due a step from there, and the poses after it are tested again from there."""
        pose = np.asarray(odometry_pose, dtype=float)
        self._last = pose
        self._previous = pose


STILL_M_PER_S = 0.01
"""Odometry moving slower than this (and turning slower than ``STILL_DEG_PER_S``) between two samples
is standing still: a parked robot's wheel odometry moves not at all, a fused one drifts by
millimetres a second; a robot creeping forward moves centimetres a second."""
STILL_DEG_PER_S = 0.5


class StillClock:
    """The time a stream's odometry has stood still so far: a robot carried to another place (a
    kidnap) measures no motion while it is carried, whether its camera sees the carry or the stream
    skips it. Counted over every sample, not keyframes: a slow stretch (a route's tight arcs, a
    keyframe every six seconds) keeps moving and counts nothing."""

    def __init__(self) -> None:
        self._last: tuple[int, float, float, float] | None = None
        self.still_ns = 0

    def tick(self, stamp_ns: int, odometry_pose: np.ndarray) -> int:
        """Count the sample at ``stamp_ns``; returns the time stood still up to it, nanoseconds."""
        x, y, yaw = (float(v) for v in odometry_pose)
        if self._last is not None:
            last_stamp, last_x, last_y, last_yaw = self._last
            elapsed = int(stamp_ns) - last_stamp
            seconds = elapsed * 1e-9
            if (
                elapsed > 0
                and math.hypot(x - last_x, y - last_y) < STILL_M_PER_S * seconds
                and abs(float(se2.wrap_angle(yaw - last_yaw))) < math.radians(STILL_DEG_PER_S) * seconds
            ):
                self.still_ns += elapsed
        self._last = (int(stamp_ns), x, y, yaw)
        return self.still_ns


WINDOW_LEAF_BELIEF = 0.05
"""Hypotheses with at least this belief (and the best) say where a dense stream's keyframe is taken."""
SPARSE_CHOICE_ODDS = 10.0
"""On a sparse stream a neighbour of the odometry's keyframe is taken only when this many times as
likely (summed over the hypotheses) to be at a predicted place as the keyframe itself."""
WINDOW_MOTION_SHARPNESS = 4.0
"""A dense window's frames are centimetres apart, and the question is which of them is *at* the
predicted place, not whether the place is revisited: each hypothesis ranks them by its motion model
this many times as sharply as the tree weighs a claim (its σ halved about its best frame), while its
best frame's fit still weighs it against the other hypotheses (docs/estimator.md, "Which frame is at
the place")."""


def keyframer(config: EstimatorConfig) -> Keyframer:
    """The keyframe test ``config`` describes."""
    return Keyframer(
        config.step_m, config.turn_deg, config.keyframe_slack, adaptive=config.keyframe_adaptive == "on"
    )


@dataclass(frozen=True)
class StepResult:
    """What one keyframe did to the hypotheses; ``hypotheses[0]`` is the best."""

    keyframe: int
    stamp_ns: int
    action: tuple[float, float, float]
    hypotheses: tuple[Hypothesis, ...]

    @property
    def best(self) -> Hypothesis:
        return self.hypotheses[0]


@dataclass(frozen=True)
class MapState:
    id: int
    keyframes: tuple[int, ...]


@dataclass(frozen=True)
class MapLink:
    from_state: int
    to_state: int
    action: tuple[float, float, float]
    covariance: tuple[tuple[float, float, float], ...]
    count: int


@dataclass(frozen=True)
class EstimateResult:
    """The best hypothesis's map of places, the final hypotheses and the tree's statistics."""

    states: tuple[MapState, ...]
    links: tuple[MapLink, ...]
    hypotheses: tuple[Hypothesis, ...]
    keyframe_stamps_ns: tuple[int, ...]
    stats: TreeStats
    first_keyframe: int = 0
    """Index of this session's first keyframe: the prior map's keyframes come before it."""


def prior_map(
    keyframes: int, states: tuple[MapState, ...], links: tuple[MapLink, ...], views: np.ndarray
) -> PriorMap:
    """A stored map (an estimate's final graph and place views) as the start of a new session.

    Raises ValueError when the parts do not fit together (a keyframe outside the map, a state
    without its view, a keyframe in no place, a link to an unknown place).
    """
    views = np.asarray(views, dtype=np.float32)
    ids = np.array([state.id for state in states], dtype=np.int64)
    if len(ids) != len(views) or np.any(np.diff(ids) <= 0):
        raise ValueError("the map's places and stored views do not match")
    assignment = np.full(keyframes, -1, dtype=np.int64)
    for state in states:
        for keyframe in state.keyframes:
            if not 0 <= keyframe < keyframes:
                raise ValueError(f"place {state.id} names keyframe {keyframe}, outside the map's {keyframes}")
            assignment[keyframe] = state.id
    if keyframes and (assignment < 0).any():
        raise ValueError(f"keyframe {int(np.flatnonzero(assignment < 0)[0])} of the map is in no place")
    known = set(ids.tolist())
    rels = []
    for link in links:
        if link.from_state not in known or link.to_state not in known:
            raise ValueError(f"a link joins place {link.from_state} to {link.to_state}, not both in the map")
        c = link.covariance
        rel = (*link.action, c[0][0], c[0][1], c[0][2], c[1][1], c[1][2], c[2][2])
        rels.append((link.from_state, link.to_state, tuple(float(v) for v in rel), link.count))
    return PriorMap(keyframes, assignment, ids, views, tuple(rels))  # type: ignore[arg-type]


class Estimator:
    """Appearance-based SLAM over a stream of (stamp, odometry pose, image); optionally starting in
    the map of an earlier session (``prior``), with the robot's place in it unknown."""

    def __init__(
        self,
        config: EstimatorConfig | None = None,
        prior: PriorMap | None = None,
        *,
        odometry_known: bool = True,
        camera: PinholeCamera | None = None,
    ) -> None:
        """``odometry_known=False``: the actions are the equal steps assumed for frames without
        odometry (``aslam import`` of a bare image folder: one pass along a route, SeqSLAM's
        assumption). With no odometry to fail and no loop in one pass, a jump by appearance to a
        place of this run could only be a look-alike, so none is proposed; a prior map's places
        still are (``--map``). ``camera``: the images' intrinsics, which
        ``geometric_check_m`` needs."""
        self.config = config or EstimatorConfig()
        self.camera = camera if self.config.geometric_check_m > 0 else None
        """The images' intrinsics where the geometric check needs features of them (None: no features)."""
        self.observation_model: ObservationModel = observation_model(self.config)
        self._keyframer = keyframer(self.config)
        self._tree = HypothesisTree(
            self.config, self.observation_model, prior, relocalise_within=odometry_known, camera=camera
        )
        self._first_keyframe = 0 if prior is None else prior.keyframes
        self._stamps: list[int] = []
        self._still_ns = 0

    @property
    def keyframer(self) -> Keyframer:
        """This run's keyframe test, from odometry alone (so callers decode only keyframes)."""
        return self._keyframer

    def choose_keyframe(
        self, actions: list[np.ndarray], observations: list[np.ndarray], *, sparse: bool = False
    ) -> int:
        """Which of a dense stream's frames near the odometry's keyframe to take (``actions``: each
        frame's odometry since the keyframe taken before, the odometry's keyframe first;
        ``observations``: their vectors): the one most believed to be at a place the hypotheses
        predict — by appearance and by where odometry puts the frame (ranked ``WINDOW_MOTION_SHARPNESS``
        times as sharply as a claim), summed over the best hypothesis and those holding
        ``WINDOW_LEAF_BELIEF`` of the belief, each weighed by its belief — or the
        first (the odometry's) when none predicts a place. Not the best hypothesis's alone: at the
        first revisit after new ground it is often still a new place, whose map predicts a place
        vaguely or not at all, while a revisit with a fifth of the belief knows where the next place
        is (held-out video-rate runs, seeds 9–10: two of four wrong claims were such keyframes,
        0.57–0.62 m from the place named, with a right place 0.41–0.43 m away).

        Without it a second lap keyframed by distance alone falls anywhere between the first lap's
        places, up to half a step from the nearest: on video-rate recordings that was where the wrong
        claims were (0.50–0.56 m from the place named). Appearance alone is not enough near a wall,
        where a view 0.6 m from the place can look more like it than one at the place.

        ``sparse``: the alternatives are a sparse stream's neighbours of the keyframe, a good part of a
        step from it (two frames per metre, a frame every 0.75 m). A wrong choice there puts the
        keyframe half a step from every place, so a neighbour is taken only when ``SPARSE_CHOICE_ODDS``
        times as likely as the odometry's keyframe (docs/estimator.md, "A sparse stream's
        neighbours"): at a place the tracking hypotheses predict, or, while the best hypothesis calls
        the robot somewhere new, at the mapped place most like it by the relocalisation index (a
        lap's first revisit, which nothing tracks yet, fell half a step between two places:
        docs/estimator.md, "A sparse stream's first revisit looks for the map too").

        While the robot is lost and the best hypothesis calls it somewhere new (after a kidnap or a
        reset), the hypotheses predict from the track it lost: a dense window then takes the frame
        most like any mapped place the relocalisation index finds (docs/estimator.md, "While lost, the
        window looks for the map"), and a sparse stream its neighbour, if ``SPARSE_CHOICE_ODDS``
        times as likely as the keyframe by that measure (otherwise a reset's keyframes keep whatever
        phase odometry gave them, half a step from the places in about half the runs).
        """
        tree = self._tree
        if len(observations) < 2:
            return 0
        best_leaf = tree.leaves[0] if tree.leaves else None
        exploring = best_leaf is not None and best_leaf.is_new and best_leaf.state != SESSION_START
        if tree.lost_off_the_map() or (sparse and exploring):
            # Lost, the hypotheses' predictions are the old track's; on new ground no track phases a
            # sparse stream's first revisit: take the frame that looks most like somewhere mapped, so
            # the index can single the place out.
            distances = np.array([tree.nearest_mapped_distance(o) for o in observations])
            if np.isfinite(distances).any():
                best = int(np.argmin(distances))
                if not sparse:
                    return best
                log_likelihoods = self.observation_model.log_likelihood(distances)
                return (
                    best if log_likelihoods[best] - log_likelihoods[0] >= math.log(SPARSE_CHOICE_ODDS) else 0
                )
        if sparse and (best_leaf is None or best_leaf.is_new):
            return 0
        weighed = []  # log (belief × P(frame at the leaf's predicted place)) per frame, one row a leaf
        looks: dict[int, np.ndarray] = {}  # log P(frame | place) per predicted place: leaves often share one
        for leaf in tree.leaves:
            if math.exp(leaf.log_belief) < WINDOW_LEAF_BELIEF and leaf is not tree.leaves[0]:
                continue
            predicted = tree.predicted_revisit(actions, leaf)
            if predicted is None:
                continue
            place, log_transition = predicted
            if not sparse:
                peak = float(np.max(log_transition))
                log_transition = peak + WINDOW_MOTION_SHARPNESS * (log_transition - peak)
            if place not in looks:
                view = tree.views[place][None, :]
                distances = np.array(
                    [float(self.observation_model.distances(o, view)[0]) for o in observations]
                )
                looks[place] = self.observation_model.log_likelihood(distances)
            weighed.append(leaf.log_belief + log_transition + looks[place])
        if not weighed:
            return 0
        total = np.logaddexp.reduce(np.array(weighed), axis=0)
        best = int(np.argmax(total))
        if sparse and not total[best] - total[0] >= math.log(SPARSE_CHOICE_ODDS):
            return 0
        return best

    def add_keyframe(
        self,
        stamp_ns: int,
        action: np.ndarray,
        observation: np.ndarray,
        still_ns: int = 0,
        features: ViewFeatures | None = None,
        odometry_restarted: bool = False,
    ) -> StepResult:
        """The SLAM step proper, on an observation vector (``observation_model.describe`` of the image).

        ``still_ns``: the stream's :class:`StillClock` at this keyframe (the time its odometry had
        stood still so far), which tells a robot that may have been carried from one that drove on.
        ``features``: the image's (:func:`aslam.core.geometry.view_features`), for ``geometric_check_m``.
        ``odometry_restarted``: odometry restarted on its origin since the keyframe before
        (``aslam.data_formats.pose_sync.PoseTrack``).
        """
        elapsed = int(stamp_ns) - self._stamps[-1] if self._stamps else None
        still = int(still_ns) - self._still_ns
        hypotheses = self._tree.add_keyframe(
            action, observation, elapsed, still, features, odometry_restarted
        )
        self._stamps.append(int(stamp_ns))
        self._still_ns = int(still_ns)
        a = tuple(float(v) for v in action)
        keyframe = self._first_keyframe + len(self._stamps) - 1
        return StepResult(keyframe, int(stamp_ns), a, tuple(hypotheses))  # type: ignore[arg-type]

    def result(self) -> EstimateResult:
        """The best hypothesis's map: shared history plus its own suffix."""
        tree = self._tree
        if not tree.leaves:
            return EstimateResult((), (), (), (), tree.stats())
        best = tree.best_leaf()
        graph: SharedMap = tree.shared.copy()
        assignment = list(tree.committed_state_of_keyframe.view.tolist())
        for node in tree.suffix(best):
            if node.is_new:
                graph.add_state(node.state)
            parent: Node = node.parent  # type: ignore[assignment]  # an uncommitted node has one
            if parent.state != SESSION_START:
                graph.add_traversal(parent.state, node.state, node.rel)
            assignment.append(node.state)
        keyframes_of: dict[int, list[int]] = {}
        for keyframe, state in enumerate(assignment):
            keyframes_of.setdefault(state, []).append(keyframe)
        states = tuple(MapState(s, tuple(keyframes_of.get(s, ()))) for s in sorted(graph.states))
        links = []
        for key in sorted(graph.links):
            link = graph.links[key]
            x, y, yaw = link.rel[:3]
            covariance = tuple(tuple(float(v) for v in row) for row in rel_covariance(link.rel))
            links.append(MapLink(link.from_state, link.to_state, (x, y, yaw), covariance, link.count))  # type: ignore[arg-type]
        hypotheses = tuple(h for h in tree.hypotheses() if h.state != SESSION_START)
        return EstimateResult(
            states, tuple(links), hypotheses, tuple(self._stamps), tree.stats(), self._first_keyframe
        )

    def place_views(self, states: tuple[MapState, ...]) -> np.ndarray:
        """(len(states), length) float32: the view stored with each place (its first keyframe's)."""
        ids = np.array([state.id for state in states], dtype=np.int64)
        return self._tree.views[ids].copy()
