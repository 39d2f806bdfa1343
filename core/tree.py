"""The tree of path hypotheses (paper section V): split, weigh, prune, commit.

Each leaf is one hypothesis about the robot's whole path. At every keyframe each leaf splits
into a child saying "a new place" and one child per earlier place reachable under the motion
model *in that leaf's own map*. Children are weighed by ``θ = α P(z|x) P(x|x',u) θ_parent``.

Memory stays O(states + hypotheses × ambiguity): the history every leaf shares (up to their
deepest common ancestor) is committed into one :class:`SharedMap`; a leaf's own map is that map
plus the short suffix of tree nodes below the commit point. Nodes point only at their parents,
so a branch with no surviving leaf is freed by reference counting the moment it is pruned.
"""

from __future__ import annotations

import heapq
import math
import sys
from bisect import bisect_left, insort
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from aslam.core import portable_math
from aslam.core.config import EstimatorConfig
from aslam.core.geometry import GeometricCheck, PinholeCamera, ViewFeatures
from aslam.core.mapgraph import GrowableArray, KeyframeViews, PriorMap, SharedMap
from aslam.core.motion import (
    IDENTITY_REL,
    Rel,
    action_covariance,
    compose_rel,
    inverse_rel,
    link_weight,
    mahalanobis2_and_logdet,
    rel_covariance,
    revisit_residuals,
    to_rel,
)
from aslam.core.observation import ObservationModel, observation_model
from aslam.core.place_index import PlaceIndex


class Node:
    """One tree node: keyframe t was at ``state``; ``rel`` is the link from the parent's state."""

    __slots__ = (
        "carried_at",
        "doubted",
        "guessed",
        "id",
        "inverse_rel",
        "is_new",
        "keyframe",
        "log_belief",
        "parent",
        "rel",
        "settled_at",
        "state",
        "weight",
    )

    def __init__(
        self,
        id: int,
        keyframe: int,
        state: int,
        parent: Node | None,
        log_belief: float,
        is_new: bool,
        rel: Rel,
    ) -> None:
        self.id = id
        self.keyframe = keyframe
        self.state = state
        self.parent = parent
        self.log_belief = log_belief
        self.is_new = is_new
        self.rel = rel
        self.inverse_rel = inverse_rel(rel)
        self.weight = link_weight(rel)
        # The keyframe from which this line's revisits may be the best (a jump by appearance is
        # believed once the motion model has confirmed it: ``JUMP_CONFIRMATIONS``).
        self.settled_at: int = 0 if parent is None else parent.settled_at
        # A line that began with a doubted jump: born while the best line explored new ground without
        # having lost track (docs/estimator.md, "Exploring, not lost"), or to a place odometry rules
        # out. Its jump is confirmed whatever the other lines predict, and until it settles it is no
        # proof the robot was ever on the map.
        self.doubted: bool = parent is not None and parent.doubted
        # A line that began with a jump to a place proposed untested at an odometry jump, and no view
        # has singled out a place of it since (``_distinct``): a guess, under the ceiling however
        # well its places fit (docs/estimator.md, "A guess is confirmed only by a view that singles
        # it out").
        self.guessed: bool = parent is not None and parent.guessed
        # A line that began with a jump soon after a pause: the keyframe the pause ended (a carry's
        # far end, if the jump is believed), else None.
        self.carried_at: int | None = None if parent is None else parent.carried_at

    def unlink(self) -> None:
        """Odometry did not measure the motion into this node's place (a carry): no prediction
        crosses its link."""
        self.rel = self.rel[:3] + _UNKNOWN_LINK
        self.inverse_rel = inverse_rel(self.rel)
        self.weight = link_weight(self.rel)


@dataclass(frozen=True)
class Hypothesis:
    """A leaf as reported to callers: which state it assigns to the latest keyframe, and how sure."""

    id: int
    parent_id: int | None
    state: int
    belief: float
    is_new_state: bool


@dataclass(frozen=True)
class TreeStats:
    keyframes: int
    nodes_created: int
    max_hypotheses: int
    mean_hypotheses: float
    committed_keyframes: int
    max_uncommitted: int
    searched_states_mean: float


class WindowMedian:
    """The median of the last ``window`` values, exactly as ``np.median`` gives it, kept sorted as
    they come (a step's cost does not depend on the window: ``np.median`` of 200 values twice a
    step was 7 % of a SLAM step)."""

    def __init__(self, window: int) -> None:
        self._window = window
        self._recent: deque[float] = deque()
        self._sorted: list[float] = []

    def __len__(self) -> int:
        return len(self._recent)

    def append(self, value: float) -> None:
        if len(self._recent) == self._window:
            del self._sorted[bisect_left(self._sorted, self._recent.popleft())]
        self._recent.append(value)
        insort(self._sorted, value)

    @property
    def median(self) -> float:
        ordered, middle = self._sorted, len(self._sorted) // 2
        return ordered[middle] if len(ordered) % 2 else (ordered[middle - 1] + ordered[middle]) / 2


@dataclass
class AlarmCount:
    """Keyframes at which the robot was not lost, and the look-alike alarms that were never taken.

    Alarms come in episodes (keyframes at most ``ALARM_EPISODE_GAP`` apart). An episode counts
    once, when it is over, and only if the best hypothesis took none of its jumps: a kidnapped
    robot's views single out the right places keyframe after keyframe until one is taken, and a
    place a jump rightly found is no false alarm either.
    """

    keyframes: int = 0
    count: int = 0
    episode: list[tuple[int, int]] = field(default_factory=list)
    """(keyframe, place) of each jump the open episode proposed."""

    def close_before(self, keyframe: int, taken: Callable[[int, int], bool]) -> None:
        """End the open episode if its last alarm is over ``ALARM_EPISODE_GAP`` keyframes before
        ``keyframe``; ``taken(k, place)``: whether the best hypothesis now puts keyframe k there."""
        if self.episode and keyframe - self.episode[-1][0] > ALARM_EPISODE_GAP:
            if not any(taken(k, place) for k, place in self.episode):
                self.count += 1
            self.episode.clear()

    def add(self, keyframe: int, place: int | None, lost: bool) -> None:
        """One keyframe's jump test: ``place`` the place it singled out, if any. An episode begins
        only while the robot is tracked; once begun, it runs on while the robot is lost."""
        if not lost:
            self.keyframes += 1
        if place is not None and (self.episode or not lost):
            self.episode.append((keyframe, place))

    def share(self, rate: float) -> float:
        """The run's share of false alarms, with ``rate`` as a prior worth 1/``rate`` keyframes."""
        return (self.count + 1.0) / (self.keyframes + 1.0 / rate)


class NewPlaceReference:
    """The distance an unseen place is taken to have: fixed, or calibrated on the run's own views.

    "A new place" has no stored view to compare with, so it is weighed as a view at a reference
    distance. A constant fitted to one kind of scene is wrong in another (other textures,
    lighting, image noise); the distance between *consecutive* keyframes — two views about a
    step apart, so of different but neighbouring places — is measured on every run for free. The
    online reference is ``scale`` × the median of those distances over the last ``window``
    keyframes (the fixed value until ``warmup`` of them are in): a revisit must look more alike
    than the place one step away typically does.
    """

    def __init__(self, fixed: float, scale: float, floor: float, window: int = 200, warmup: int = 5) -> None:
        self.fixed = fixed
        self.scale = scale
        self._floor = floor
        self._recent = WindowMedian(window)
        self._warmup = warmup

    def observe(self, consecutive_distance: float) -> None:
        """One distance between consecutive keyframes. Views closer than the likelihood's floor are
        one scene seen twice (a robot standing still, a repeated frame), not neighbouring places:
        they are left out, or a stop would drive the reference to zero and make every view new."""
        if self.scale > 0 and math.isfinite(consecutive_distance) and consecutive_distance > self._floor:
            self._recent.append(consecutive_distance)

    @property
    def value(self) -> float:
        if self.scale <= 0 or len(self._recent) < self._warmup:
            return self.fixed
        return self.scale * self._recent.median


class HypothesisTree:
    """The hypotheses and the shared map, advanced one keyframe at a time."""

    def __init__(
        self,
        config: EstimatorConfig,
        model: ObservationModel | None = None,
        prior: PriorMap | None = None,
        *,
        relocalise_within: bool = True,
        camera: PinholeCamera | None = None,
    ) -> None:
        """``relocalise_within=False``: no jumps by appearance to this run's own places (see
        :class:`aslam.core.estimator.Estimator`'s ``odometry_known``); a prior map's still.
        ``camera``: the images' intrinsics, which ``geometric_check_m`` needs (ValueError without)."""
        self.config = config
        self._geometry: GeometricCheck | None = None
        if config.geometric_check_m > 0:
            if camera is None:
                raise ValueError("geometric_check_m needs the camera's intrinsics")
            self._geometry = GeometricCheck(camera)
        self._features: dict[int, ViewFeatures] = {}
        """Each keyframe's features, while the geometric check is on: any may become a place."""
        self._offsets: dict[int, float | None] = {}
        """The current keyframe's geometric checks so far, by place."""
        self.model = model if model is not None else observation_model(config)
        observation_length = self.model.length
        self.shared = SharedMap()
        self.views = KeyframeViews(observation_length)
        self._previous_view: np.ndarray | None = None
        self.committed_state_of_keyframe = GrowableArray((), np.int64)
        self.committed_rel_of_keyframe = GrowableArray((9,), np.float64)
        """The link each committed keyframe arrived by: the path, for ``candidate_search="path"``."""
        self.leaves: list[Node] = []
        self.commit_root: Node | None = None
        self._next_id = 0
        self._noise = config.motion_noise
        self._place_cov = np.diag(
            [config.place_radius_m**2, config.place_radius_m**2, math.radians(config.place_heading_deg) ** 2]
        )
        # LAPACK, unlike the motion model (core/motion.py): a diagonal matrix's LU multiplies by zeros
        # only, and numpy sums the C library's logs, so every CPU's kernel gives these bits.
        self._place_logdet = float(np.linalg.slogdet(self._place_cov)[1])
        self._place_position_trace = 2.0 * config.place_radius_m**2
        self._place_heading_variance = math.radians(config.place_heading_deg) ** 2
        self._visit_cov = np.diag(
            [config.visit_sigma_m**2, config.visit_sigma_m**2, math.radians(config.visit_sigma_deg) ** 2]
        )
        self._search_bound = config.search_sigma_m**2
        self._gate = config.gate_sigma**2
        self._log_new_prior = math.log1p(-config.revisit_prior)
        self.reference = NewPlaceReference(
            self.model.fixed_reference,
            self.model.online_scale if config.new_state_reference == "online" else 0.0,
            self.model.floor,
        )
        self._log_revisit = math.log(config.revisit_prior)
        self._log_relocalise = (
            math.log(config.revisit_prior) + math.log(config.relocalisation_prior)  # no underflow
            if config.relocalisation_prior > 0 and relocalise_within
            else -math.inf
        )
        self._log_relocalise_lost = (
            math.log(config.revisit_prior) + math.log(config.relocalisation_lost_prior)
            if config.relocalisation_lost_prior > 0 and relocalise_within
            else self._log_relocalise
        )
        self._lost_at = -math.inf
        """The keyframe the robot last lost track: the best hypothesis went from a mapped place to a
        new one where its map has places (a kidnap, a stretch the views no longer explain), or
        odometry jumped. Driving off the end of mapped ground is exploring, not losing track."""
        self._odometry_jumped_at = -1
        """The keyframe odometry last jumped (a reset): no track leads past it."""
        self._lost_against_travel = False
        """Whether the action of the keyframe the robot last lost track at was a step against the
        direction of travel (``_against_travel``): odometry, not the robot, is then what failed."""
        self._paused_at = -math.inf
        """The keyframe that last came after a pause (``PAUSE_SHARE``): time for a carry."""
        self._paused_tracked = False
        """Whether the best hypothesis named a mapped place when that pause began."""
        self._intervals = WindowMedian(JUMP_WINDOW)
        """Recent times between keyframes, nanoseconds."""
        self._best_in_map = True
        """Whether the best leaf's map has a place within ``IN_MAP_STEPS`` steps of where odometry
        puts the robot now (set by each graph search of the best leaf)."""
        self._best_paths: dict[int, tuple[int, Rel, float, float]] = {}
        """The best leaf's graph search this step: each state it reached (but its own) with the state
        and link it was reached through; empty when nothing was searched."""
        self._paths: dict[int, tuple[int, Rel, float, float]] = {}
        """The same for the last graph search."""
        self._in_map2 = (IN_MAP_STEPS * config.step_m) ** 2
        self._nearest2 = 0.0
        """Squared distance from the prediction to the nearest place the last graph search reached."""
        self._alarms = AlarmCount()
        self._alarm_chain = (-1, -1, 0)  # keyframe, place, length
        self._tracked_at = -math.inf
        self._log_map_relocalise = (
            math.log(config.revisit_prior) + math.log(config.map_relocalisation_prior)
            if config.map_relocalisation_prior > 0
            else -math.inf
        )
        self._log_enter_map = self._log_revisit - math.log(config.relocalisation_candidates)
        """Prior of entering a prior map at one of the places appearance proposes (the revisit prior
        shared among ``relocalisation_candidates``): at the session's start, and whenever the best
        hypothesis is off the map."""
        self._jump_factor = config.odometry_jump_factor if relocalise_within else 0.0
        """Odometry jumps are looked for only where there is odometry to fail."""
        self._recent_steps = WindowMedian(JUMP_WINDOW)
        self._map_states = np.zeros(0, np.int64)
        """The prior map's places in the order they were made: each one's neighbourhood for
        ``map_reference_scale``."""
        self._index = PlaceIndex(
            self.model.index_key_parts, config.relocalisation_skip, key=self.model.index_key
        )
        self._relocalised: set[int] = set()
        # statistics
        self._count_sum = 0
        self._count_max = 0
        self._max_uncommitted = 0
        self._searched_sum = 0
        self._first_keyframe = 0 if prior is None else prior.keyframes
        if prior is not None:
            self._seed(prior)

    def _seed(self, prior: PriorMap) -> None:
        """Start in ``prior``'s map: its places, views and links committed, the robot nowhere yet.

        The leaves start as one *session start* node (state ``SESSION_START``), already committed:
        the session's first keyframe is then placed by appearance alone (:meth:`_start_session`).
        How the earlier keyframes arrived at their places is not stored, so the paper's path search
        (``candidate_search="path"``) does not walk back into the prior.
        """
        if prior.views.shape[1:] != (self.model.length,):
            raise ValueError(
                f"the map's views have length {prior.views.shape[1]},"
                f" this observation model's {self.model.length}"
            )
        view_of_state = dict(zip(prior.states.tolist(), prior.views, strict=True))
        for keyframe in range(prior.keyframes):
            self.views.append(view_of_state.get(keyframe))
        self.committed_state_of_keyframe.extend(prior.state_of_keyframe)
        self.committed_rel_of_keyframe.extend(np.tile(np.array(UNKNOWN_REL), (prior.keyframes, 1)))
        for state, view in zip(prior.states.tolist(), prior.views, strict=True):
            self.shared.add_state(state)
            if self.model.recognisable(view):
                self._index.add(state, view, searchable=True)
        for from_state, to_state, rel, count in prior.links:
            self.shared.add_link(from_state, to_state, rel, count)
        if self.config.map_reference_scale > 0:
            self._map_states = np.sort(prior.states)
        start = self._new_node(prior.keyframes - 1, SESSION_START, None, 0.0, False, IDENTITY_REL)
        self.leaves = [start]
        self.commit_root = start

    # ------------------------------------------------------------------ the step
    def add_keyframe(
        self,
        action: np.ndarray,
        observation: np.ndarray,
        elapsed_ns: int | None = None,
        still_ns: int = 0,
        features: ViewFeatures | None = None,
        odometry_restarted: bool = False,
    ) -> list[Hypothesis]:
        """Advance every hypothesis by one keyframe; returns the surviving leaves, best first.

        ``elapsed_ns``: the time since the keyframe before (None: unknown, as at a session's first);
        ``still_ns``: how much of it odometry stood still. Together they tell a robot that may have
        been carried from one that drove on (``PAUSE_SHARE``). ``features``: the image's, for the
        geometric check (``geometric_check_m``); without them this keyframe is not checked.
        ``odometry_restarted``: odometry started again from its origin since the keyframe before
        (``aslam.data_formats.pose_sync.PoseTrack``), so ``action`` measures no motion: an odometry
        jump, however short or straight it reads.
        """
        view = self.model.view(observation)  # what the place keeps; the whole observation is the query
        keyframe = self.views.append(view)
        self._offsets = {}
        if self._geometry is None:
            features = None
        elif features is not None:
            self._features[keyframe] = features
        if elapsed_ns is not None:
            if len(self._intervals) >= JUMP_WARMUP and still_ns >= PAUSE_SHARE * self._intervals.median:
                self._paused_at = keyframe
                self._paused_tracked = bool(self.leaves) and not self.leaves[0].is_new
            self._intervals.append(float(elapsed_ns))
        previous, self._previous_view = self._previous_view, np.array(view, dtype=np.float32)
        if keyframe == 0:
            self._index_place(0)
            root = self._new_node(0, 0, None, 0.0, True, IDENTITY_REL)
            self.leaves = [root]
            self.commit_root = root
            self.shared.add_state(0)
            self.committed_state_of_keyframe.append(0)
            self.committed_rel_of_keyframe.append(IDENTITY_REL)
            self._record_count(1)
            return [Hypothesis(root.id, None, 0, 1.0, True)]
        if self.leaves[0].state == SESSION_START:
            return self._start_session(observation, keyframe)

        # A keyframe before this one set ``previous`` (the first of a run or a session returned above).
        self.reference.observe(float(self.model.distances(observation, previous[None, :])[0]))  # type: ignore[index]
        log_reference = float(self.model.log_likelihood(self.reference.value))
        log_new = self._log_new_prior + log_reference
        action = np.asarray(action, dtype=float)
        action_cov = action_covariance(action, self._noise)
        jumped = self._jump_factor > 0 and (odometry_restarted or self._odometry_jumped(action))
        after_odometry_jump = self._odometry_jumped_at == keyframe - 1
        self._best_paths = {}
        if jumped:  # not a motion: nothing to predict from it
            self._odometry_jumped_at = keyframe
            proposals = [(np.zeros(0, np.int64), np.zeros(0)) for _ in self.leaves]
        else:
            proposals = self._propose(self.leaves, action, action_cov)

        relocalisation, relocalisation_priors, distinctive, elsewhere = self._relocalisation_candidates(
            observation, keyframe, proposals[0][0], untested=jumped, features=features
        )
        # Sorted and unique, as np.unique would give (which imports numpy.ma on first use: 10 ms).
        candidate_ids = np.array(
            sorted({state for p in proposals for state in p[0].tolist()} | set(relocalisation.tolist())),
            dtype=np.int64,
        )
        log_obs_of: dict[int, float] = {}
        unvetoed_of: dict[int, float] | None = None  # before the contradiction veto, where it applies
        distances = np.zeros(0)
        if len(candidate_ids):
            distances = self._distances(observation, candidate_ids, features)
            log_obs = self.model.log_likelihood(distances)
            if self.config.appearance_veto > 0:
                # A view as unlike the place as views a step apart are is no revisit, whatever
                # odometry predicts (a kidnap, a reset, a wrong chain).
                vetoed = distances >= self.config.appearance_veto * self.reference.value
                log_obs = np.where(vetoed, -np.inf, log_obs)
            ratio = self.config.contradiction_ratio
            if ratio > 0 and (distinctive is not None or elsewhere < self.reference.value):
                if after_odometry_jump:  # the lines that jumped there are spared (below)
                    unvetoed_of = dict(zip(candidate_ids.tolist(), log_obs.tolist(), strict=True))
                if distinctive is not None:
                    # Appearance singles out a place the motion model did not propose, and the places
                    # it did propose look far less alike: the robot was carried (the matrix's kidnaps:
                    # the predicted place still half alike, the true place found by the index).
                    found = distances[int(np.searchsorted(candidate_ids, distinctive))]
                    vetoed = (distances * ratio >= found) & (candidate_ids != distinctive)
                else:
                    # Nothing singled out (look-alikes), but a place elsewhere looks like a revisit and
                    # clearly more alike than a proposed place that does not: the view speaks against
                    # that prediction (a kidnap into an aliased stretch). Not claimed; no jump either.
                    found_elsewhere = set(relocalisation.tolist())  # a prior map's own candidates
                    vetoed = (
                        (distances >= self.reference.value)
                        & (distances * ratio >= elsewhere)
                        & np.array([state not in found_elsewhere for state in candidate_ids.tolist()])
                    )
                log_obs = np.where(vetoed, -np.inf, log_obs)
            log_obs_of = dict(zip(candidate_ids.tolist(), log_obs.tolist(), strict=True))

        # (log θ, parent, state, is_new) for every child; the new-state child first for each leaf.
        children: list[tuple[float, Node, int, bool]] = []
        coverage = self.config.new_state_coverage
        carried = self._carried_by_pause(keyframe)
        for leaf, (states, log_transition) in zip(self.leaves, proposals, strict=True):
            leaf_log_new = log_new
            obs_of = log_obs_of
            if unvetoed_of is not None and leaf.settled_at > keyframe:
                # The veto is for the old track's prediction; past an odometry jump there is none:
                # the lines that jumped there by appearance are all the robot has, and their
                # predictions are the jumps' tests.
                obs_of = unvetoed_of
            if coverage > 0 and len(log_transition):
                # A mapped place where the robot is predicted to stand makes "a new place" unlikely,
                # unless a veto ruled it out: the view says the robot is not there (held out: a
                # corner's predicted place ruled out, a place 4.1 m off reached round a whole lap
                # was claimed). After a pause the robot may have been carried, and the prediction
                # proves nothing: then only as far as the place also looks like a revisit (held out:
                # carried into a lollipop's parallel corridor, facing back, tracks claimed places
                # 4–6 m off whose views measured 1.0–1.2 × the reference, kept by this coverage).
                pairs = zip(states.tolist(), log_transition.tolist(), strict=True)
                if carried:
                    covered = max(log_t + min(0.0, obs_of[state] - log_reference) for state, log_t in pairs)
                else:
                    remaining = [log_t for state, log_t in pairs if obs_of[state] > -math.inf]
                    covered = max(remaining, default=-math.inf)
                leaf_log_new += math.log1p(-coverage * math.exp(min(0.0, covered)))
            children.append((leaf.log_belief + leaf_log_new, leaf, keyframe, True))
            for state, log_t in zip(states.tolist(), log_transition.tolist(), strict=True):
                children.append(
                    (leaf.log_belief + self._log_revisit + log_t + obs_of[state], leaf, state, False)
                )
        # Relocalisation: the best leaf may also jump to a place found by appearance alone, with a
        # small prior and no motion term (a kidnap, an odometry reset, a stretch the motion missed).
        # It is never the best at birth (at most JUMP_CEILING of the best leaf's new-place child,
        # JUMP_CEILING_LOST while lost): the next keyframe must confirm it through the motion model,
        # as a revisit of the next place.
        best = self.leaves[0]
        lost_track = keyframe - self._lost_at <= self.config.lost_window
        ceiling = children[0][0] + math.log(
            JUMP_CEILING_LOST if self._maybe_carried(keyframe) else JUMP_CEILING
        )
        # A jump's line is believed once the motion model confirmed it, unless the track it left
        # still explains the view otherwise (a settled line predicts another place that looks like a
        # revisit) or it was born while the robot explored without having lost track (``doubted``):
        # then it must be confirmed again (an aliased stretch can fit a look-alike track twice in a
        # row). Where the settled lines predict the same place, they agree with it. A guess's line (an
        # untested place at an odometry jump) stays under the ceiling, new places too, until a view
        # singles out the place it predicts; until then it explains nothing.
        distinct: set[int] = set()
        if any(leaf.guessed for leaf in self.leaves):
            distinct = self._distinct(observation, candidate_ids, distances, features)
        if any(leaf.settled_at > keyframe or leaf.guessed for leaf in self.leaves):
            alike = set(candidate_ids[distances < self.reference.value].tolist())  # look like a revisit
            explained = set().union(
                *(
                    alike.intersection(states.tolist())
                    for leaf, (states, _) in zip(self.leaves, proposals, strict=True)
                    if leaf.settled_at <= keyframe and not leaf.guessed
                )
            )
            # A line that never settles stays under the ceiling through its new places too: its
            # history (the look-alike's claims) must never become the best map after the stretch.
            children = [
                (min(log_belief, ceiling), parent, state, is_new)
                if (not is_new and parent.settled_at > keyframe and (parent.doubted or explained - {state}))
                or parent.settled_at == NEVER_SETTLED
                or (parent.guessed and (is_new or state not in distinct))
                else (log_belief, parent, state, is_new)
                for log_belief, parent, state, is_new in children
            ]
        for state, log_prior in zip(relocalisation.tolist(), relocalisation_priors, strict=True):
            log_belief = best.log_belief + log_prior + log_obs_of[state]
            children.append((min(log_belief, ceiling), best, state, False))
        self._relocalised = set(relocalisation.tolist())

        survivors = self._prune(children)
        action_rel = to_rel(action, action_cov)
        leaves = []
        for log_belief, parent, state, is_new in survivors:
            rel = action_rel if not jumped else UNKNOWN_REL
            if not (is_new and parent.is_new):  # measured from or to a visit, not the place itself
                rel = rel[:3] + tuple(np.add(rel[3:], _flat(self._visit_cov)).tolist())
            jump = parent is best and state in self._relocalised
            jump = jump and not self._proposed(parent, state, proposals)
            if jump:  # odometry does not link the places: the search never crosses it
                rel = rel[:3] + _UNKNOWN_LINK
            node = self._new_node(keyframe, state, parent, log_belief, is_new, rel)
            if parent.guessed and not is_new and state in distinct:
                node.guessed = False  # the view singled the guess's place out: confirmed
            if jump:
                # A place odometry rules out, with no pause in which the robot could have been
                # carried, is a look-alike stretch until it outlasts one. Born while exploring, or
                # from a doubted line not yet settled, a jump is doubted too (confirmed twice).
                drove_on = keyframe - self._paused_at > self.config.lost_window
                # Lost at a step against the direction of travel, odometry's own map is no proof:
                # a reset read as a motion (under the jump test's factor) links the map wrongly.
                trusted = not (lost_track and self._lost_against_travel)
                ruled_out = drove_on and trusted and self._ruled_out_by_odometry(state, action, action_cov)
                node.doubted = (
                    ruled_out or (best.is_new and not lost_track) or self._unsettled(best, keyframe)
                )
                if ruled_out and self._map_is_one_chain():
                    # A place one odometry chain rules out, unpaused, is no place the robot can be
                    # however long the views fit.
                    node.settled_at = NEVER_SETTLED
                else:
                    node.settled_at = keyframe + (DOUBTED_CONFIRMATIONS if ruled_out else JUMP_CONFIRMATIONS)
                if not drove_on:
                    node.carried_at = int(self._paused_at)
                # Proposed untested at an odometry jump: even a place the view singles out is a guess
                # (held out: one 5.4 m off, singled out just under Lowe's ratio, was claimed 3 times).
                node.guessed = jumped
            leaves.append(node)
        was_best = self.leaves[0]
        # The end of an unsettled doubted line is no loss of track: the robot was never shown to be there.
        if not was_best.is_new and leaves[0].is_new and not self._unsettled(was_best, keyframe):
            # A step against the direction of travel where the track ends is odometry failing (a reset
            # under the jump test's factor), not the robot driving off its map's end, wherever it says.
            against_travel = (
                self._jump_factor > 0 and not jumped and _against_travel(action, self.config.step_m)
            )
            if jumped or against_travel or self._best_in_map:
                self._lost_at = keyframe
                self._lost_against_travel = against_travel
        if not leaves[0].is_new:
            self._tracked_at = keyframe
        self.leaves = leaves
        carried_at = leaves[0].carried_at
        if (
            carried_at is not None
            and leaves[0].settled_at <= keyframe <= carried_at + 2 * self.config.lost_window
        ):
            self._unlink_carry(leaves[0], carried_at)
        self._commit_shared_history()
        self._record_count(len(leaves))
        return self.hypotheses()

    def _map_is_one_chain(self) -> bool:
        """Whether the best hypothesis has never named a mapped place, in a run with no prior map
        (``--map``, whose links another session measured): its map is then one odometry chain,
        wrong only by odometry's own noise (``NEVER_SETTLED``)."""
        return self._tracked_at == -math.inf and self._first_keyframe == 0

    def _ruled_out_by_odometry(self, state: int, action: np.ndarray, action_cov: np.ndarray) -> bool:
        """Whether the best leaf's map puts ``state`` so far from where odometry says the robot is
        (over ``RULED_OUT_SIGMA``) that only a carry could have brought it there. Beyond the reach of
        its search (a long drift, a lap's loop not yet closed) odometry cannot tell."""
        if state not in self._best_paths:
            return False
        rel = _rel_along(self._best_paths, state, {self.leaves[0].state: IDENTITY_REL})
        pose, covariance = np.array([rel[:3]]), rel_covariance(rel)[None]
        mahalanobis2 = float(self._transition(pose, covariance, action, action_cov)[1][0])
        return mahalanobis2 > RULED_OUT_SIGMA**2

    def _unlink_carry(self, leaf: Node, carried_at: int) -> None:
        """The best line relocalised by a jump soon after the pause that ended at keyframe
        ``carried_at``: the robot was carried. If that keyframe made a new place, odometry linked it
        to the place before as if the robot had driven a step; the link is cut, so that no later
        lap predicts the carry's far end from its near end (held out: a zigzag's kidnap, seed 69,
        claimed it 6 m off on the next lap). Committed already, only a link no other pass has
        measured is cut."""
        node = leaf
        while node is not self.commit_root and node.keyframe > carried_at:
            node = node.parent  # type: ignore[assignment]  # commit_root is an ancestor of every leaf
        if node is not self.commit_root:
            if node.keyframe == carried_at and node.is_new and node.rel[3:] != _UNKNOWN_LINK:
                node.unlink()
            return
        states = self.committed_state_of_keyframe.view
        if not 0 < carried_at < len(states) or int(states[carried_at]) != carried_at:
            return  # not a place made at that keyframe
        before = int(states[carried_at - 1])
        link = self.shared.links.get((min(before, carried_at), max(before, carried_at)))
        if link is not None and link.count == 1 and link.rel[3:] != _UNKNOWN_LINK:
            self.shared.add_link(link.from_state, link.to_state, link.rel[:3] + _UNKNOWN_LINK, 1)
            self.committed_rel_of_keyframe.view[carried_at, 3:] = _UNKNOWN_LINK

    def _unsettled(self, leaf: Node, keyframe: int) -> bool:
        """Whether ``leaf``'s line began with a doubted jump that settled under ``lost_window``
        keyframes ago (or has not yet): a look-alike stretch ends about then, a kidnap's track goes on."""
        return leaf.doubted and leaf.settled_at > keyframe - self.config.lost_window

    def _start_session(self, observation: np.ndarray, keyframe: int) -> list[Hypothesis]:
        """The first keyframe in a prior map: anywhere in it, or somewhere new.

        Candidates come from appearance over the whole map (the relocalisation index, bounded
        cost); the revisit prior is shared evenly among them. Nothing links them to the map by
        odometry, so the next keyframes must confirm one through the motion model.
        """
        start = self.leaves[0]
        log_new = self._log_new_prior + float(self.model.log_likelihood(self.reference.value))
        children: list[tuple[float, Node, int, bool]] = [(log_new, start, keyframe, True)]
        view = self.model.view(observation)
        top = self._index.search(view, keyframe, self.config.relocalisation_candidates)
        if len(top):
            top = np.sort(top)
            distances = self._distances(observation, top)
            log_obs = self.model.log_likelihood(distances)
            if self.config.appearance_veto > 0:
                log_obs = np.where(
                    distances >= self.config.appearance_veto * self.reference.value, -np.inf, log_obs
                )
            log_prior = self._log_enter_map
            children += [
                (log_prior + lo, start, state, False)
                for state, lo in zip(top.tolist(), log_obs.tolist(), strict=True)
                if lo > -math.inf
            ]
        self.leaves = [
            self._new_node(keyframe, state, parent, log_belief, is_new, UNKNOWN_REL)
            for log_belief, parent, state, is_new in self._prune(children)
        ]
        self._commit_shared_history()
        self._record_count(len(self.leaves))
        return self.hypotheses()

    def _proposed(self, leaf: Node, state: int, proposals: list[tuple[np.ndarray, np.ndarray]]) -> bool:
        """Whether ``state`` was a motion candidate of ``leaf`` this step."""
        index = next(i for i, other in enumerate(self.leaves) if other is leaf)
        return bool(np.any(proposals[index][0] == state))

    def _odometry_jumped(self, action: np.ndarray) -> bool:
        """Whether ``action`` is an odometry failure rather than a motion (an odometry reset, a driver
        restart): a step whose length in medians of the run's recent keyframe steps, plus its turn in
        ``turn_deg``, exceeds ``odometry_jump_factor``. Judged against the run's own steps, so a dataset
        with long steps between frames is not flagged. The turn counts because a keyframe is taken at
        a step or a turn, whichever comes first, so no motion is both long and turned far; but a reset
        near odometry's origin is (3.3 m and 176°, where the run's steps were 1 m: taken for a motion,
        no place fitted it, and the robot relocalised only after a look-alike's five confirmations).
        A turn in place is no step, and no jump."""
        length = math.hypot(float(action[0]), float(action[1]))
        recent = self._recent_steps
        is_step = length >= STEP_SHARE * self.config.step_m
        jumped = False
        if is_step and len(recent) >= JUMP_WARMUP:
            turns = abs(math.remainder(float(action[2]), math.tau)) / math.radians(self.config.turn_deg)
            jumped = length / recent.median + turns > self._jump_factor
        if is_step and not jumped:
            recent.append(length)
        return jumped

    def _relocalisation_candidates(
        self,
        observation: np.ndarray,
        keyframe: int,
        proposed: np.ndarray,
        *,
        untested: bool = False,
        features: ViewFeatures | None = None,
    ) -> tuple[np.ndarray, list[float], int | None, float]:
        """Committed places that look like ``observation``, found over the whole map at bounded cost,
        with the log prior of a jump to each, which of them appearance alone singled out (or None),
        and the distance of the most alike place elsewhere (not proposed, not held; inf if none).

        The index (:class:`aslam.core.place_index.PlaceIndex`: an exact scan up to 2,048 places, an
        inverted file of k-means cells beyond) shortlists the ``relocalisation_candidates`` most
        similar committed places; they are then compared exactly. The best is returned if it looks
        more alike than the new-place reference, clearly more alike than the runner-up, and the
        motion model did not propose it; its prior is ``relocalisation_lost_prior`` for
        ``lost_window`` keyframes after the robot lost track or paused (``_maybe_carried``), or at a
        chain of places (``CHAIN_FOR_KIDNAP``), ``relocalisation_prior`` otherwise.
        In a prior map, the ``map_relocalisation_candidates`` most alike of the map's own places are
        returned too, untested (``map_relocalisation_prior``): the sequence that follows decides.
        After an odometry jump (``untested``) the robot may be anywhere: as at a session's start,
        the ``map_relocalisation_candidates`` most alike places are all returned, untested.
        Where the best leaf's prediction already fits the view well (``WELL_EXPLAINED``), the index
        is not searched and nothing is returned; not in a map judged across seasons
        (``map_reference_scale``), whose distances the fit was not measured on.
        """
        none: tuple[np.ndarray, list[float], int | None, float] = (np.zeros(0, np.int64), [], None, math.inf)
        appearance_off = self._log_relocalise == -math.inf and self._log_map_relocalise == -math.inf
        if not self.leaves or (appearance_off and not untested):
            return none
        # How well the best leaf's motion model explains the view: its most alike proposed place.
        fit = float(self._distances(observation, proposed, features).min()) if len(proposed) else math.inf
        if not untested and not len(self._map_states) and fit < WELL_EXPLAINED * self.reference.value:
            # Tracked this well, the robot was not carried: nothing to look for elsewhere (and the
            # index's query, the part of a step that grows with the map, is spared). The run's
            # alarm count still counts the keyframe, as a search that singled out nothing would.
            if self._log_relocalise > -math.inf:
                self._alarms.close_before(keyframe, lambda k, place: self._best_state_at(k) == place)
                self._alarms.add(keyframe, None, self._maybe_carried(keyframe))
            return none
        top = self._shortlist(observation)
        if not len(top):
            return none
        held = [leaf.state for leaf in self.leaves]  # already hypotheses: nothing to relocalise to
        excluded = set(proposed.tolist()).union(held)
        top = top[[state not in excluded for state in top.tolist()]]
        if not len(top):
            return none
        distances = self._distances(observation, top, features)
        order = np.lexsort((top, distances))
        elsewhere = float(distances[order[0]])
        if untested:
            anywhere = top[order][: self.config.map_relocalisation_candidates].tolist()
            return np.array(anywhere, dtype=np.int64), [self._log_enter_map] * len(anywhere), None, elsewhere
        from_map = top[order] < self._first_keyframe
        found: list[int] = []
        priors: list[float] = []
        if self._log_map_relocalise > -math.inf:
            found = top[order][from_map][: self.config.map_relocalisation_candidates].tolist()
            # Tracked in the map, a jump elsewhere in it is a relocalisation; not yet (or no longer)
            # in it, the robot may enter it anywhere, as at the session's start.
            in_map = self.leaves[0].state < self._first_keyframe
            priors = [self._log_map_relocalise if in_map else self._log_enter_map] * len(found)
            order = order[~from_map]
        distinctive = None
        if self._log_relocalise > -math.inf:
            own = self._distinctive(top, distances, order, fit)
            found += own
            lost = self._maybe_carried(keyframe)
            self._alarms.close_before(keyframe, lambda k, place: self._best_state_at(k) == place)
            # A chain: each keyframe singles out the place after the one the keyframe before did.
            last_keyframe, last_place, length = self._alarm_chain
            length = length + 1 if own and (last_keyframe, last_place) == (keyframe - 1, own[0] - 1) else 1
            self._alarm_chain = (keyframe, own[0], length) if own else (-1, -1, 0)
            recent = min(keyframe - self._tracked_at, keyframe - self._paused_at)
            chained = length >= CHAIN_FOR_KIDNAP and recent <= self.config.lost_window
            log_prior = self._log_relocalise_lost if lost or chained else self._log_relocalise
            log_prior += self._log_alarm_scale()
            priors += [log_prior] * len(own)
            distinctive = own[0] if own else None
            self._alarms.add(keyframe, distinctive, lost)
        return np.array(found, dtype=np.int64), priors, distinctive, elsewhere

    def lost_off_the_map(self) -> bool:
        """Whether the next keyframe comes while the robot may have been carried (``_maybe_carried``)
        and the best hypothesis still calls it somewhere new."""
        best = self.leaves[0] if self.leaves else None
        if best is None or not best.is_new or best.state == SESSION_START:
            return False
        return self._maybe_carried(len(self.views))

    def _maybe_carried(self, keyframe: int) -> bool:
        """Whether ``keyframe`` comes within ``lost_window`` keyframes of losing track, or of a pause
        (``PAUSE_SHARE``) that began while the robot was tracked: what the track predicts is then no
        proof of where the robot is, and a jump by appearance gets the lost prior and ceiling. A
        pause while exploring is not enough: a robot that stopped on new ground sees look-alikes as a
        carried one sees the map (held out: a stop on the figure-8's first lap, seed 71, believed a
        three-keyframe look-alike stretch and lost the second lap's start)."""
        return keyframe - self._lost_at <= self.config.lost_window or self._carried_by_pause(keyframe)

    def _carried_by_pause(self, keyframe: int) -> bool:
        """Whether ``keyframe`` comes within ``lost_window`` keyframes of a pause that began while the
        robot was tracked (``PAUSE_SHARE``): it may have been carried meanwhile."""
        return self._paused_tracked and keyframe - self._paused_at <= self.config.lost_window

    def nearest_mapped_distance(self, observation: np.ndarray) -> float:
        """Distance from ``observation`` to the most alike committed place the relocalisation index
        shortlists (inf if none): how much a view looks like somewhere mapped."""
        top = self._shortlist(observation)
        return float(self._distances(observation, top).min()) if len(top) else math.inf

    def _shortlist(self, observation: np.ndarray) -> np.ndarray:
        """The committed places the relocalisation index finds most like ``observation``."""
        return self._index.search(
            self.model.view(observation),
            len(self.committed_state_of_keyframe),
            self.config.relocalisation_candidates,
        )

    def _best_state_at(self, keyframe: int) -> int:
        """The state the best hypothesis assigns to ``keyframe``."""
        node = self.leaves[0]
        while node.keyframe > keyframe and node is not self.commit_root:
            node = node.parent  # type: ignore[assignment]  # commit_root is an ancestor of every leaf
        if node.keyframe == keyframe:
            return node.state
        return int(self.committed_state_of_keyframe.view[keyframe])

    def _log_alarm_scale(self) -> float:
        """The log of what the jump priors are scaled by: (expected / the run's share of alarms)^power,
        at most 1. An alarm is a place appearance alone singled out while the robot was not lost (see
        :class:`AlarmCount`); in a world where such look-alikes keep turning up and are never taken,
        the next one is little evidence of a kidnap."""
        rate = self.config.jump_alarm_rate
        if rate <= 0:
            return 0.0
        return self.config.jump_alarm_power * min(0.0, math.log(rate / self._alarms.share(rate)))

    def _distinctive(
        self, top: np.ndarray, distances: np.ndarray, order: np.ndarray, fit: float
    ) -> list[int]:
        """The best of ``top`` (ranked by ``order``) if appearance alone singles it out, else none;
        ``fit`` is the distance of the most alike place the motion model proposed (inf: none)."""
        # Distinctive only (Lowe's ratio test): in an aliased stretch, where several places look
        # alike, appearance alone must not move the robot.
        if len(order) < 2:
            return []
        best = int(top[order[0]])
        # The runner-up is the most alike place elsewhere: the best place's neighbours on its first
        # visit look alike too, and tell nothing against it. Only when no place elsewhere is among
        # the candidates is a neighbour the runner-up.
        elsewhere = (i for i in order[1:].tolist() if abs(int(top[i]) - best) > RUNNER_UP_GAP)
        runner_up = next(elsewhere, int(order[1]))
        if not distances[order[0]] < RELOCALISATION_RATIO * distances[runner_up]:
            return []
        if not distances[order[0]] < self.reference.value:
            return []
        if not distances[order[0]] < RELOCALISATION_RATIO * fit:  # clearly more alike than predicted
            return []
        return [best]

    def _distinct(
        self,
        observation: np.ndarray,
        states: np.ndarray,
        distances: np.ndarray,
        features: ViewFeatures | None,
    ) -> set[int]:
        """Those of ``states`` (at ``distances`` from ``observation``) the view singles out, as
        ``_distinctive`` does: they look like a revisit, and no place elsewhere fits nearly as well
        (among ``states`` and the index's shortlist, none but their neighbours within Lowe's ratio)."""
        known = set(states.tolist())
        extra = np.array([s for s in self._shortlist(observation).tolist() if s not in known], dtype=np.int64)
        pool = np.concatenate([states, extra])
        pool_distances = np.concatenate([distances, self._distances(observation, extra, features)])
        distinct = set()
        for state, distance in zip(states.tolist(), distances.tolist(), strict=True):
            rivals = pool_distances[np.abs(pool - state) > RUNNER_UP_GAP]
            alike = distance < self.reference.value
            if alike and (not len(rivals) or distance < RELOCALISATION_RATIO * float(rivals.min())):
                distinct.add(state)
        return distinct

    def _distances(
        self, observation: np.ndarray, states: np.ndarray, features: ViewFeatures | None = None
    ) -> np.ndarray:
        """Distances of ``observation`` to ``states``' views; a prior map's judged across sessions
        when ``map_reference_scale`` is set (:meth:`_across_sessions`). With the view's ``features``
        (the geometric check on), a place two-view geometry puts out of reach is infinitely unlike."""
        distances = self.model.distances(observation, self.views[states])
        if features is not None:
            distances = self._out_of_reach(features, states, distances)
        if not len(self._map_states):
            return distances
        in_map = states < self._first_keyframe
        if in_map.any():
            distances = distances.copy()
            distances[in_map] = self._across_sessions(observation, states[in_map], distances[in_map])
        return distances

    def _out_of_reach(self, features: ViewFeatures, states: np.ndarray, distances: np.ndarray) -> np.ndarray:
        """``distances`` with inf for each place that looks like a revisit (under the new-place
        reference) but whose images put the view over ``geometric_check_m`` from it: appearance
        cannot tell a view at the place from one half a metre off its line, the map's scale can
        (:mod:`aslam.core.geometry`; docs/estimator.md, "Two views measure the offset"). Places
        whose images cannot say (too few matches, no linked neighbour in the shared map) keep theirs."""
        assert self._geometry is not None  # features are kept only while the check is on
        out = distances.copy()
        reference = self.reference.value
        for i, state in enumerate(states.tolist()):
            place = self._features.get(state)
            if distances[i] >= reference or place is None:
                continue
            if state not in self._offsets:
                neighbours = [
                    (other, self._features[other], rel[:3])
                    for other, (rel, _weight) in self.shared.adjacency.get(state, {}).items()
                    if other in self._features
                ]
                self._offsets[state] = self._geometry.offset_m(state, place, neighbours, features)
            offset = self._offsets[state]
            if offset is not None and offset > self.config.geometric_check_m:
                out[i] = math.inf
        return out

    def _across_sessions(
        self, observation: np.ndarray, states: np.ndarray, distances: np.ndarray
    ) -> np.ndarray:
        """Distances to a prior map's places put on this run's scale, for a map of another season or light.

        Another season moves every distance to the map's views, those of the right place too, so
        the run's own new-place reference (views a step apart, same session) would call every map
        place unseen. Each place is judged against its neighbourhood instead (SeqSLAM's local
        contrast enhancement): its level is the view's mean distance to the map's places within
        ``map_contrast_window`` of it, and a distance of ``map_reference_scale`` × that level counts
        as the run's reference. On Nordland a global level (the median over a sample of the whole
        map) left the right summer place and a look-alike stretch 1,400 places away equally likely
        (the right one closer in 51 % of winter views); their local levels tell them apart in 80 %.
        The result is drawn towards the reference by ``map_evidence_weight`` (the log-likelihood
        ratio to a new place scaled by it): one view across seasons is weak evidence, and at full
        weight a single dark frame among bright ones (a short tunnel) outweighed a long track.
        Measured on Nordland (docs/real-data.md): window 3/5/8 and weight 0.5–0.8 all give recall
        at 100 % precision 0.89–0.98; the global level gave 0.65.
        """
        window = self.config.map_contrast_window
        count = len(self._map_states)
        width = min(2 * window + 1, count)
        low = np.clip(np.searchsorted(self._map_states, states) - window, 0, count - width)
        slots = low[:, None] + np.arange(width)[None, :]
        around, inverse = np.unique(slots, return_inverse=True)
        near = self.model.distances(observation, self.views[self._map_states[around]])
        levels = near[inverse.reshape(slots.shape)].mean(axis=1)
        reference = self.reference.value
        scaled = distances * np.minimum(
            1.0, reference / np.maximum(self.config.map_reference_scale * levels, 1e-12)
        )
        weight = self.config.map_evidence_weight
        return np.maximum(scaled, 1e-12) ** weight * reference ** (1.0 - weight)

    def _index_place(self, state: int) -> None:
        """Add a committed place (its first view) to the relocalisation index, if it can be recognised."""
        view = self.views[state]
        if self.model.recognisable(view):
            self._index.add(state, view)

    def hypotheses(self) -> list[Hypothesis]:
        return [
            Hypothesis(
                leaf.id,
                None if leaf.parent is None or leaf.parent.state == SESSION_START else leaf.parent.id,
                leaf.state,
                math.exp(leaf.log_belief),
                leaf.is_new,
            )
            for leaf in self.leaves
        ]

    # ------------------------------------------------------------------ prediction
    def predicted_revisit(
        self, actions: list[np.ndarray], leaf: Node | None = None
    ) -> tuple[int, np.ndarray] | None:
        """The mapped place ``leaf`` (default: the best hypothesis) most expects the robot at after
        ``actions[0]`` (by the motion model alone), and ``log P(x = that place | x', u)`` under each
        of ``actions`` (the frames near a keyframe); None in new ground, before the first keyframe,
        at a session's start."""
        if not self.leaves or self.leaves[0].state == SESSION_START:
            return None
        leaf = self.leaves[0] if leaf is None else leaf
        first = np.asarray(actions[0], dtype=float)
        first_cov = action_covariance(first, self._noise)
        searched = self._searched_sum  # a look ahead, not a step: the statistics stay the steps'
        if self.config.candidate_search == "path":
            states, rels = self._search_path(leaf)
        else:
            states, rels = self._search(leaf, first, first_cov)
        self._searched_sum = searched
        if not states:
            return None
        table = np.array(rels)
        poses = table[:, :3]
        covs = table[:, [3, 4, 5, 4, 6, 7, 5, 7, 8]].reshape(-1, 3, 3)
        log_transition, mahalanobis2, beyond = self._transition(poses, covs, first, first_cov)
        keep = mahalanobis2 <= self._gate
        if self._within_radius_only(leaf, first):
            keep &= ~beyond
        if self._moved(first):
            keep &= np.asarray(states, np.int64) != leaf.state
        if not keep.any():
            return None
        best = int(np.argmax(np.where(keep, log_transition, -np.inf)))
        scores = np.empty(len(actions))
        for i, action in enumerate(actions):
            action = np.asarray(action, dtype=float)
            cov = action_covariance(action, self._noise)
            scores[i] = self._transition(poses[best : best + 1], covs[best : best + 1], action, cov)[0][0]
        return int(states[best]), scores

    def _transition(
        self, poses: np.ndarray, covariances: np.ndarray, action: np.ndarray, action_cov: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``log P(x = k | x', u)`` of candidates at ``poses`` (with ``covariances``) seen from the
        previous state, their squared Mahalanobis distances (which the gate tests), and whether each
        is beyond the revisit radius (which bounds the proposals of a new place's leaf, and of any
        leaf after a turn in place: :meth:`_within_radius_only`).

        The place term is a Gaussian, whose tail lets appearance claim a place a metre from where
        odometry puts the robot. From a new place that is no revisit: the robot stood at that place,
        so the residual is its offset from the candidate but for the chain's and odometry's noise
        (a zigzag's keyframe, turned in place, claimed the place a metre behind that faced the same
        way: held-out default render, docs/estimator.md "A revisit is within reach").
        """
        residual, covariance = revisit_residuals(poses, covariances, action, action_cov)
        radius = self.config.revisit_radius_m
        if radius > 0:
            excess = np.hypot(residual[:, 0], residual[:, 1]) - radius
            beyond = excess > self.config.gate_sigma * np.sqrt(covariance[:, 0, 0] + covariance[:, 1, 1])
        else:
            beyond = np.zeros(len(residual), dtype=bool)
        covariance += self._place_cov
        mahalanobis2, logdet = mahalanobis2_and_logdet(residual, covariance)
        # Normalised so a perfectly predicted revisit with no chain uncertainty scores log 1.
        return 0.5 * (self._place_logdet - logdet) - 0.5 * mahalanobis2, mahalanobis2, beyond

    def _moved(self, action: np.ndarray) -> bool:
        """A keyframe is taken because the robot moved a step or turned: it is not where it was."""
        return math.hypot(action[0], action[1]) >= 0.5 * self.config.step_m or abs(action[2]) >= 0.5 * (
            math.radians(self.config.turn_deg)
        )

    def _within_radius_only(self, leaf: Node, action: np.ndarray) -> bool:
        """Whether ``leaf`` may propose only places within the revisit radius of where odometry puts
        the robot (``beyond`` of :meth:`_transition`): from a new place, where the robot stood at the
        place; and after a turn in place (under half a step), which leaves the robot where it stood
        at its place and brings into view places a lap before saw from elsewhere: on a zigzag, the
        corner a metre back that faced the same way (docs/estimator.md, "A turn in place stays
        within reach")."""
        return leaf.is_new or math.hypot(action[0], action[1]) < 0.5 * self.config.step_m

    def _propose(
        self, leaves: list[Node], action: np.ndarray, action_cov: np.ndarray
    ) -> list[tuple[np.ndarray, np.ndarray]]:
        """For each leaf, the earlier states it could have reached and ``log P(x=k | x', u)``.

        The searches are per leaf (each in its own map); the Gaussian algebra runs once over
        all their candidates together.
        """
        if self.config.candidate_search == "path":
            searches = [self._search_path(leaf) for leaf in leaves]
        else:
            searches = [self._search(leaves[0], action, action_cov)]
            self._best_in_map = self._nearest2 <= self._in_map2
            self._best_paths = self._paths
            searches += [self._search(leaf, action, action_cov) for leaf in leaves[1:]]
        sizes = [len(states) for states, _ in searches]
        if not any(sizes):
            return [(np.zeros(0, np.int64), np.zeros(0)) for _ in leaves]
        table = np.array([rel for _, found in searches for rel in found])
        poses = table[:, :3]
        covs = table[:, [3, 4, 5, 4, 6, 7, 5, 7, 8]].reshape(-1, 3, 3)
        log_transition, mahalanobis2, beyond = self._transition(poses, covs, action, action_cov)
        reachable = mahalanobis2 <= self._gate
        moved = self._moved(action)
        proposals = []
        start = 0
        for leaf, (states, _), size in zip(leaves, searches, sizes, strict=True):
            keep = reachable[start : start + size]
            if self._within_radius_only(leaf, action):
                keep = keep & ~beyond[start : start + size]
            if moved:
                keep = keep & (np.asarray(states, np.int64) != leaf.state)
            proposals.append((np.asarray(states, np.int64)[keep], log_transition[start : start + size][keep]))
            start += size
        return proposals

    def _search(self, leaf: Node, action: np.ndarray, action_cov: np.ndarray) -> tuple[list[int], list[Rel]]:
        """Best-first search outward from the leaf's state through its own map.

        Returns the states that may pass the motion gate and each one's pose (with covariance)
        seen from the leaf's state, composed along the path that reached it. A state is reached
        only through paths whose summed link uncertainty stays within the bound, and at most
        ``search_max_states`` are expanded: those, not the map's size, decide the cost.

        The order favours low uncertainty *and* nearness to where odometry says the robot now is
        (priority = uncertainty + ``search_nearness`` × distance²): in a dense map the budget is
        spent around the robot, where revisits can be, not far down cheap straight corridors.

        Full covariances are composed only for states that can pass the gate. Along the way each
        state carries its pose and two scalars: the heading variance ``V`` (exact) and an upper
        bound ``U`` on √(trace of the position covariance). Composing a link of length ℓ gives
        ``U' ≤ √((U + ℓ√V)² + tr Σ_link,pos)`` (Cauchy–Schwarz on the SE(2) Jacobian). The residual
        of a state at distance D from the prediction then has a position covariance of trace at most
        ``(U + D√V)² + tr Σ_u,pos + tr Σ_place,pos`` and a heading variance of exactly
        ``V + σ²_u,yaw + σ²_place,yaw``; its Mahalanobis distance is at least each block's own, so
        ``m² ≥ D² / position trace`` and ``m² ≥ Δyaw² / heading variance``. Both tests together
        leave about one candidate in four that their sum did (the sum let a state facing the other
        way through wherever the position was uncertain), and never one that can pass the gate.
        """
        overlay = self._suffix_overlay(leaf)
        shared = self.shared.adjacency
        start = leaf.state
        tx, ty, tyaw = float(action[0]), float(action[1]), float(action[2])
        # Each bound gets a relative slack far above rounding: the gate itself decides, these only skip.
        gate = self._gate * (1.0 + 1e-9)
        fixed_position = float(action_cov[0, 0] + action_cov[1, 1]) + self._place_position_trace
        fixed_heading = float(action_cov[2, 2]) + self._place_heading_variance
        nearness = self.config.search_nearness
        cost_of: dict[int, float] = {start: 0.0}
        via: dict[int, tuple[int, Rel, float, float]] = {}  # from, link, x, y
        reached: dict[int, tuple[float, float, float]] = {}  # yaw, U, V
        heap = [(nearness * (tx * tx + ty * ty), start)]
        expanded = 0
        nearest2 = math.inf
        candidates: list[int] = []
        limit = self.config.search_max_states
        bound = self._search_bound
        empty: dict[int, tuple[Rel, float]] = {}
        # Local names: this loop is most of a SLAM step.
        cos, sin, sqrt, hypot, inf = math.cos, math.sin, math.sqrt, math.hypot, math.inf
        pi, two_pi = math.pi, 2.0 * math.pi
        push, pop, cost_so_far = heapq.heappush, heapq.heappop, cost_of.get
        shared_links, suffix_links = shared.get, overlay.get
        while heap and expanded < limit:
            state = pop(heap)[1]
            if state in reached:
                continue
            if state == start:
                x = y = yaw = u_bound = v = 0.0
            else:
                previous, edge, x, y = via[state]  # the position was composed when it was queued
                pyaw, pu, pv = reached[previous]
                yaw = pyaw + edge[2]
                grown = pu + hypot(edge[0], edge[1]) * sqrt(pv)
                u_bound = sqrt(grown * grown + edge[3] + edge[6])
                v = pv + edge[8]
            reached[state] = (yaw, u_bound, v)
            expanded += 1
            dx, dy = tx - x, ty - y
            distance2 = dx * dx + dy * dy
            if distance2 < nearest2:
                nearest2 = distance2
            dyaw = (tyaw - yaw + pi) % two_pi - pi
            if dyaw * dyaw <= gate * (v + fixed_heading):
                spread = u_bound + sqrt(distance2 * v)
                if distance2 <= gate * (spread * spread + fixed_position):
                    candidates.append(state)
            cost = cost_of[state]
            c, s = cos(yaw), sin(yaw)
            for edges in (shared_links(state, empty).items(), suffix_links(state, ())):
                for neighbour, (edge, weight) in edges:
                    total = cost + weight
                    if total > bound or neighbour in reached or total >= cost_so_far(neighbour, inf):
                        continue
                    cost_of[neighbour] = total
                    nx = x + c * edge[0] - s * edge[1]
                    ny = y + s * edge[0] + c * edge[1]
                    via[neighbour] = (state, edge, nx, ny)
                    ex, ey = nx - tx, ny - ty
                    push(heap, (total + nearness * (ex * ex + ey * ey), neighbour))
        self._searched_sum += expanded
        self._nearest2 = nearest2
        self._paths = via
        rels: dict[int, Rel] = {start: IDENTITY_REL}
        return candidates, [_rel_along(via, state, rels) for state in candidates]

    def _search_path(self, leaf: Node) -> tuple[list[int], list[Rel]]:
        """The paper's transition: trace the leaf's own path back in time, composing its actions.

        Each earlier state is reached the way the robot came, never through a shortcut that a
        loop closure made; the first (most recent) visit of each state counts.
        """
        found: dict[int, Rel] = {leaf.state: IDENTITY_REL}
        rel, cost = IDENTITY_REL, 0.0
        limit, bound = self.config.search_max_states, self._search_bound
        node = leaf
        while node is not self.commit_root and node.parent is not None:  # the uncommitted suffix
            rel, cost = compose_rel(rel, node.inverse_rel), cost + node.weight
            if cost > bound or len(found) >= limit:
                return list(found), list(found.values())
            found.setdefault(node.parent.state, rel)
            node = node.parent
        states = self.committed_state_of_keyframe.view
        arrivals = self.committed_rel_of_keyframe.view
        for keyframe in range(len(states) - 1, 0, -1):  # then the committed history
            arrival: Rel = tuple(arrivals[keyframe].tolist())  # type: ignore[assignment]
            rel, cost = compose_rel(rel, inverse_rel(arrival)), cost + link_weight(arrival)
            if cost > bound or len(found) >= limit:
                break
            found.setdefault(int(states[keyframe - 1]), rel)
        return list(found), list(found.values())

    def _suffix_overlay(self, leaf: Node) -> dict[int, list[tuple[int, tuple[Rel, float]]]]:
        """The links this leaf has that the shared map does not (its uncommitted suffix)."""
        overlay: dict[int, list[tuple[int, tuple[Rel, float]]]] = {}
        node = leaf
        while node is not self.commit_root and node.parent is not None:
            a, b = node.parent.state, node.state
            if a != b and a != SESSION_START:
                overlay.setdefault(a, []).append((b, (node.rel, node.weight)))
                overlay.setdefault(b, []).append((a, (node.inverse_rel, node.weight)))
            node = node.parent
        return overlay

    # ------------------------------------------------------------------ update, prune, commit
    def _prune(self, children: list[tuple[float, Node, int, bool]]) -> list[tuple[float, Node, int, bool]]:
        """Merge look-alikes, normalise, drop children far below the best, cap the count.

        Children that sit at the same state and agree on the states of the last
        ``merge_window`` keyframes predict the same future: the evidence to come can never
        separate them, so they are merged into the likelier one (their beliefs add up). At one
        belief (lines under the jump ceiling) the one that settles first is kept: the others are the
        same jump made later, and keeping one of them would throw the first's confirmations away.
        """
        merged: dict[tuple[int, ...], list] = {}
        for log_belief, parent, state, is_new in children:
            key = (state, *_recent_states(parent, self.config.merge_window - 1))
            entry = merged.get(key)
            if entry is None:
                merged[key] = [log_belief, parent, state, is_new, log_belief]
            else:
                total = np.logaddexp(entry[4], log_belief)
                kept = entry[1]
                if (log_belief, -parent.settled_at, -parent.id) > (entry[0], -kept.settled_at, -kept.id):
                    entry[:4] = [log_belief, parent, state, is_new]
                entry[4] = total
        candidates = [(entry[4], *entry[1:4]) for entry in merged.values()]
        log_beliefs = np.array([c[0] for c in candidates])
        best = log_beliefs.max()
        keep = log_beliefs >= best + math.log(self.config.prune_ratio)
        # Deterministic order: belief, then older parent, then smaller state id.
        order = sorted(
            (i for i in range(len(candidates)) if keep[i]),
            key=lambda i: (-log_beliefs[i], candidates[i][1].id, candidates[i][2]),
        )[: self.config.max_hypotheses]
        kept = log_beliefs[order]
        normaliser = best + math.log(portable_math.exp(kept - best).sum())
        return [(float(log_beliefs[i] - normaliser), *candidates[i][1:]) for i in order]

    def _commit_shared_history(self) -> None:
        """Move everything above the leaves' deepest common ancestor into the shared map."""
        level = self.leaves
        while len({id(n) for n in level}) > 1:
            level = [n.parent for n in level]  # type: ignore[misc]  # all leaves share one depth
        ancestor = level[0]
        path = []
        node = ancestor
        while node is not self.commit_root:
            path.append(node)
            node = node.parent  # type: ignore[assignment]  # commit_root is an ancestor of every leaf
        for node in reversed(path):
            if node.is_new:
                self.shared.add_state(node.state)
                self._index_place(node.state)
            parent: Node = node.parent  # type: ignore[assignment]  # an uncommitted node has one
            if parent.state != SESSION_START:  # sessions are not linked by odometry
                self.shared.add_traversal(parent.state, node.state, node.rel)
            self.committed_state_of_keyframe.append(node.state)
            self.committed_rel_of_keyframe.append(node.rel)
            if not node.is_new and node.state != SESSION_START:
                self.views.release(node.keyframe)
                self._features.pop(node.keyframe, None)  # a revisit's keyframe is no place
        if path:
            ancestor.parent = None  # frees the committed nodes
            self.commit_root = ancestor
        uncommitted = self.leaves[0].keyframe - self.commit_root.keyframe
        self._max_uncommitted = max(self._max_uncommitted, uncommitted)

    # ------------------------------------------------------------------ bookkeeping
    def _new_node(
        self, keyframe: int, state: int, parent: Node | None, log_belief: float, is_new: bool, rel: Rel
    ) -> Node:
        node = Node(self._next_id, keyframe, state, parent, log_belief, is_new, rel)
        self._next_id += 1
        return node

    def _record_count(self, count: int) -> None:
        self._count_sum += count
        self._count_max = max(self._count_max, count)

    def best_leaf(self) -> Node:
        return self.leaves[0]

    def suffix(self, leaf: Node) -> list[Node]:
        """The leaf's uncommitted nodes, oldest first."""
        nodes = []
        node = leaf
        while node is not self.commit_root:
            nodes.append(node)
            node = node.parent  # type: ignore[assignment]  # commit_root is an ancestor of every leaf
        return nodes[::-1]

    def stats(self) -> TreeStats:
        keyframes = len(self.views) - self._first_keyframe
        return TreeStats(
            keyframes=keyframes,
            nodes_created=self._next_id,
            max_hypotheses=self._count_max,
            mean_hypotheses=self._count_sum / max(keyframes, 1),
            committed_keyframes=len(self.committed_state_of_keyframe) - self._first_keyframe,
            max_uncommitted=self._max_uncommitted,
            searched_states_mean=self._searched_sum / max(keyframes - 1, 1),
        )


def _recent_states(node: Node | None, count: int) -> tuple[int, ...]:
    """States of ``node`` and its ancestors, newest first, at most ``count`` of them."""
    states: list[int] = []
    while node is not None and len(states) < count:
        states.append(node.state)
        node = node.parent
    return tuple(states)


RELOCALISATION_RATIO = 0.8
"""A place found by appearance alone must be this much closer than the next best (Lowe's ratio)."""

RUNNER_UP_GAP = 2
"""Places first seen within this many keyframes of the best one are its neighbours, not rivals, in
the distinctiveness test."""
JUMP_CEILING = 0.5
"""A jump by appearance is born with at most this share of the best leaf's "new place" belief: never
the best at birth, so the next keyframe must confirm it through the motion model."""
JUMP_CEILING_LOST = 0.9
"""The same within ``lost_window`` keyframes of losing track. Still never the best at birth, but a
moderately alike confirmation then wins at the next keyframe: after a kidnap under another light the
confirming views are only a little more alike than a new place (docs/estimator.md, "After losing
track, a larger prior for a few keyframes")."""
IN_MAP_STEPS = 0.75
"""The robot is on mapped ground when a place of the best leaf's map lies within this many steps
(``step_m``) of where odometry puts it, whatever its heading: a track that fails there is lost (a
kidnap, a turn the map never saw from there); one stepping a whole step past its last mapped place
is exploring (docs/estimator.md, "Leaving the map is not losing track")."""
CHAIN_FOR_KIDNAP = 3
"""Places singled out at this many keyframes in a row, each the place after the last, soon after the
robot was tracked or paused, are taken as a kidnap's sign even where odometry says it left the map
or explored: their jump gets the lost prior (``relocalisation_lost_prior``)."""

STEP_SHARE = 0.25
"""An action is a step when it moves at least this share of ``step_m``; shorter, a turn in place."""
AGAINST_TRAVEL_DEG = 120.0
"""A step whose chord points more than this far from the mean of its start and end headings goes
against the direction of travel (``_against_travel``)."""

JUMP_CONFIRMATIONS = 2
"""Keyframes a jump's line stays under the ceiling while the track it left still explains the view
with another place, or when it was born while the robot explored without having lost track: born
there, and at the next keyframe, the motion model's first confirmation, too. In an aliased stretch
two views in a row can fit a look-alike track (a periodic wallpaper at two corners); a third rarely
does (docs/estimator.md, "A jump the left track still explains" and "Exploring, not lost")."""
DOUBTED_CONFIRMATIONS = 5
"""Keyframes the line of a jump to a place odometry rules out (``RULED_OUT_SIGMA``) stays under the
ceiling when no pause came before it: the robot drove on, so it was not carried, and the line is a
look-alike stretch until it outlasts one. The figure-8's two lobes, every wall from one set of
textures, fit a look-alike track five keyframes in a row (docs/estimator.md, "Where two
confirmations are not enough")."""
NEVER_SETTLED = sys.maxsize
"""``settled_at`` of a jump's line that stays under the ceiling for good: one to a place odometry
rules out, with no pause before it, while the robot has never revisited a place. Its map is then one
odometry chain, which can be wrong only by odometry's own noise (``RULED_OUT_SIGMA`` allows for it),
so only a carry could have brought the robot there, and a carry takes a pause. The line's new
places stay under the ceiling too, so its history never becomes the best map. A rectangle walked
at aliasing 1.0 (bench/routes/longsteps.json, seed 84) shows its far half as the near half turned
round: seven keyframes in a row fitted the first lap's start, more than any count of
confirmations would wait (docs/estimator.md, "A look-alike before any revisit")."""
RULED_OUT_SIGMA = 8.0
"""A place whose pose through the best leaf's map is this many σ from where odometry puts the robot
is ruled out by odometry: the figure-8's look-alike lobe at aliasing 1.0 was 12–26 σ away (seeds 35,
43, 44), a lap's start reached by a jump at 10 % odometry noise 4.4 σ (the gate is ``gate_sigma``, 4)."""
PAUSE_SHARE = 0.5
"""A keyframe before which odometry stood still for at least this share of the run's median
keyframe interval ends a pause (:class:`aslam.core.estimator.StillClock`). A kidnap takes one: the
robot is lifted, carried and set down while its wheels turn no further (in the recorder a carry
takes one action's second, during which odometry holds; a bag cut where the robot was carried skips
the carry's time with odometry unmoved). A continuous drive has none, however slowly its keyframes
come (the recorder's arcs of 15° actions: one every six to eight seconds). For ``lost_window``
keyframes after a pause that began while the robot was tracked, it may have been carried, as after
losing track: a jump by appearance gets the lost prior and ceiling at once (``_maybe_carried``).
After one that began while it explored, a chain of places singled out (``CHAIN_FOR_KIDNAP``) must
lift the prior: a robot that stopped on new ground sees look-alikes as a carried one sees the map."""
WELL_EXPLAINED = 0.5
"""A view the best leaf's predicted place fits at under this share of the new-place reference is
explained: the index is not searched for a jump at that keyframe. A kidnap's first view fits the
place odometry predicts at 0.88–1.11 × the reference (the matrix's two closest calls); right revisits
at 0.16–0.74 (docs/estimator.md, "Not searched where the track explains the view")."""
_UNKNOWN_LINK = (1e6, 0.0, 0.0, 1e6, 0.0, 1e6)
"""Covariance of a relocalisation link: so uncertain that no search crosses it (weight ≫ bound)."""
UNKNOWN_REL: Rel = (0.0, 0.0, 0.0, *_UNKNOWN_LINK)
"""A link odometry did not measure (a session's first keyframe, a prior map's arrivals)."""
ALARM_EPISODE_GAP = 2
"""Alarms at most this many keyframes apart are one episode (see :class:`AlarmCount`)."""
JUMP_WINDOW = 50
"""Recent keyframe steps the median is taken over."""
JUMP_WARMUP = 5
"""Steps seen before any action can count as a jump."""
SESSION_START = -1
"""State of the node a session in a prior map starts from: the robot is nowhere yet."""


def _rel_along(paths: dict[int, tuple[int, Rel, float, float]], state: int, rels: dict[int, Rel]) -> Rel:
    """``state``'s pose (with covariance) seen from a graph search's start, composed along the path
    the search reached it by (``paths``: state → the state and link it came through); ``rels`` holds
    the start's identity and memoises every state composed on the way."""
    chain = []
    while state not in rels:
        chain.append(state)
        state = paths[state][0]
    for node in reversed(chain):
        rels[node] = compose_rel(rels[paths[node][0]], paths[node][1])
    return rels[chain[0]] if chain else rels[state]


def _against_travel(action: np.ndarray, step_m: float) -> bool:
    """Whether ``action`` is a step against the direction of travel. A robot that drives forward
    and turns, in any order and under half a turn in all (a keyframe is taken at a quarter), moves
    along a chord within 90° of the mean of its start and end headings; an odometry reset reads as
    a step in any direction (the inverse of the pose it left), half the time backwards (the
    figure-8's at 75 %, seed 5: 152° off; the B-shaped route's at 55 %, seed 100: 159°)."""
    if math.hypot(float(action[0]), float(action[1])) < STEP_SHARE * step_m:
        return False
    chord = math.atan2(float(action[1]), float(action[0]))
    mean_heading = math.remainder(float(action[2]), math.tau) / 2
    return abs(math.remainder(chord - mean_heading, math.tau)) > math.radians(AGAINST_TRAVEL_DEG)


def _flat(covariance: np.ndarray) -> list[float]:
    c = covariance
    return [c[0, 0], c[0, 1], c[0, 2], c[1, 1], c[1, 2], c[2, 2]]
