"""How well a run went, against ground truth (design notes, "Measuring").

* A hypothesis that says "revisit of state k" at keyframe t is scored by the error between the
  true pose at t and the true pose at k's first visit (state ids are first-visit keyframes).
  New-state hypotheses are excluded, as in the paper.
* Keyframe t is a ground-truth revisit when some earlier keyframe lies within ``radius_m`` and
  ``heading_deg``; a claim by the best hypothesis is correct under the same test. A claim where
  the truth is unknown (at the keyframe or at the place's first visit: a gap in a real dataset's
  ground truth) is not judged: precision counts only the claims the truth can score.
* A relocalisation episode is a run of consecutive ground-truth revisits; its delay is the number
  of keyframes from its start until the best hypothesis first names a correct state.
* Sessions of a map in different worlds (``worlds``: rendered worlds that share no place, whose
  true poses are in frames of their own) are never near each other: no keyframe revisits another
  world's place, and a claim of one is wrong.
* As place-recognition work reports it, each claim has a confidence (the belief of the best
  hypothesis that makes it): sweeping a threshold over it gives a precision–recall curve, its
  area (average precision) and the recall reached with no wrong claim at all.
* The *committed* map (each keyframe's place once the hypotheses agreed on it, the map
  ``Estimator.result()`` returns) is scored with the same test as the online best hypothesis.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from aslam.core import se2
from aslam.core.config import REVISIT_HEADING_DEG, REVISIT_RADIUS_M
from aslam.core.tree import Hypothesis


@dataclass(frozen=True)
class ErrorStats:
    mean: float | None
    median: float | None
    max: float | None

    @classmethod
    def of(cls, values: np.ndarray) -> ErrorStats:
        values = np.abs(values[np.isfinite(values)])
        if values.size == 0:
            return cls(None, None, None)
        return cls(float(values.mean()), float(np.median(values)), float(values.max()))


@dataclass(frozen=True)
class Episode:
    start: int
    length: int
    delay: int | None
    """Keyframes from the start until the best hypothesis named a correct state; None if it never did."""


@dataclass(frozen=True)
class Evaluation:
    keyframes: int
    hypothesis_counts: np.ndarray
    claims: np.ndarray
    """bool (n,): the best hypothesis says "revisit" at this keyframe."""
    has_ground_truth: bool
    true_revisit: np.ndarray
    """bool (n,): an earlier keyframe was truly here (all False without ground truth)."""
    correct: np.ndarray
    """bool (n,): the best hypothesis's claim is right."""
    best_error: np.ndarray
    """(n, 3) signed x_m, y_m, heading_deg of the best hypothesis's claim; NaN where it claims none."""
    weighted_error: np.ndarray
    """(n, 3) belief-weighted mean absolute error over the revisit hypotheses; NaN where there are none."""
    episodes: tuple[Episode, ...]
    confidence: np.ndarray | None = None
    """(n,) belief of the best hypothesis where it claims a revisit, NaN elsewhere."""
    judged: np.ndarray | None = None
    """bool (n,): a claim the truth can score, known at the keyframe and at the place's first visit
    (None: every claim). Claims in a gap of the ground truth are neither right nor wrong."""

    @property
    def judged_claims(self) -> np.ndarray:
        """bool (n,): the claims precision counts."""
        return self.claims if self.judged is None else self.claims & self.judged

    @property
    def wrong(self) -> np.ndarray:
        """bool (n,): judged claims that are not right."""
        return self.judged_claims & ~self.correct

    @property
    def scored_revisits(self) -> np.ndarray:
        """bool (n,): the true revisits recall counts: not those where the claim made cannot be judged
        (a revisit of this run named as the map's place, whose truth is unknown, is no miss)."""
        return scored_revisits(self.true_revisit, self.claims, self.judged_claims)

    @property
    def precision(self) -> float | None:
        claims = int(self.judged_claims.sum())
        return None if not self.has_ground_truth or claims == 0 else float(self.correct.sum() / claims)

    @property
    def recall(self) -> float | None:
        revisits = int(self.scored_revisits.sum())
        return None if not self.has_ground_truth or revisits == 0 else float(self.correct.sum() / revisits)

    @property
    def first_delay(self) -> int | None:
        return self.episodes[0].delay if self.episodes else None

    @property
    def mean_delay(self) -> float | None:
        delays = [e.delay for e in self.episodes if e.delay is not None]
        return float(np.mean(delays)) if delays else None

    def pr_curve(self) -> PRCurve:
        """Precision and recall of the claims whose confidence reaches each threshold."""
        confidence = self.confidence if self.confidence is not None else np.where(self.claims, 1.0, np.nan)
        confidence = np.where(self.judged_claims, confidence, np.nan)
        return precision_recall_curve(confidence, self.correct, int(self.scored_revisits.sum()))

    def error_stats(self, weighted: bool) -> dict[str, ErrorStats]:
        errors = self.weighted_error if weighted else self.best_error
        return {name: ErrorStats.of(errors[:, i]) for i, name in enumerate(("x_m", "y_m", "heading_deg"))}


@dataclass(frozen=True)
class PRCurve:
    """A precision–recall curve over a confidence threshold, highest threshold first.

    Point i keeps the claims with confidence ≥ ``thresholds[i]``. Empty arrays when there is no
    claim. ``revisits`` is the number of ground-truth revisits recall is counted against.
    """

    thresholds: np.ndarray
    precision: np.ndarray
    recall: np.ndarray
    revisits: int

    @property
    def recall_at_full_precision(self) -> float | None:
        """The highest recall with no wrong claim (0 when the most confident claim is wrong)."""
        if self.revisits == 0:
            return None
        perfect = self.precision >= 1.0
        return float(self.recall[perfect].max()) if perfect.any() else 0.0

    @property
    def auc(self) -> float | None:
        """Area under the curve as average precision: Σ (R_i − R_{i−1}) P_i, from R = 0."""
        if self.revisits == 0:
            return None
        steps = np.diff(np.concatenate([[0.0], self.recall]))
        return float((steps * self.precision).sum())


def precision_recall_curve(confidence: np.ndarray, correct: np.ndarray, revisits: int) -> PRCurve:
    """The curve of claims (finite ``confidence``) ranked by confidence; ties enter together.

    ``correct`` (n,) says which claims are right; recall counts against ``revisits``.
    """
    confidence = np.asarray(confidence, dtype=float)
    claimed = np.flatnonzero(np.isfinite(confidence))
    if claimed.size == 0:
        empty = np.zeros(0)
        return PRCurve(empty, empty, empty, revisits)
    order = claimed[np.argsort(-confidence[claimed], kind="stable")]
    ranked = confidence[order]
    true_positives = np.cumsum(np.asarray(correct, dtype=bool)[order])
    # the last claim of each group of equal confidence closes a threshold
    last = np.flatnonzero(np.append(ranked[1:] != ranked[:-1], True))
    claims = last + 1
    precision = true_positives[last] / claims
    recall = true_positives[last] / revisits if revisits else np.zeros(len(last))
    return PRCurve(ranked[last], precision.astype(float), recall.astype(float), revisits)


@dataclass(frozen=True)
class AssignmentScore:
    """A map's keyframe-to-place assignment scored like the best hypothesis's claims."""

    claims: np.ndarray
    correct: np.ndarray
    true_revisit: np.ndarray
    judged: np.ndarray
    """bool (n,): a claim the truth can score (see ``Evaluation.judged``)."""

    @property
    def precision(self) -> float | None:
        claims = int((self.claims & self.judged).sum())
        return None if claims == 0 else float(self.correct.sum() / claims)

    @property
    def recall(self) -> float | None:
        revisits = int(scored_revisits(self.true_revisit, self.claims, self.claims & self.judged).sum())
        return None if revisits == 0 else float(self.correct.sum() / revisits)


def worlds_apart(worlds: np.ndarray | None, a: np.ndarray | int, b: np.ndarray | int) -> np.ndarray:
    """bool: keyframes ``a`` and ``b`` are known to be in different worlds (``worlds`` (n,) int per
    keyframe, -1 where unknown; None: one world)."""
    if worlds is None:
        return np.zeros(np.broadcast(np.asarray(a), np.asarray(b)).shape, dtype=bool)
    wa, wb = worlds[a], worlds[b]
    return (wa != wb) & (wa >= 0) & (wb >= 0)


def scored_revisits(true_revisit: np.ndarray, claims: np.ndarray, judged_claims: np.ndarray) -> np.ndarray:
    """bool (n,): the true revisits recall counts: all but those whose claim cannot be judged (a
    revisit named as a place of a map session without truth is no miss)."""
    return true_revisit & ~(claims & ~judged_claims)


def score_assignment(
    state_of_keyframe: np.ndarray,
    true_poses: np.ndarray,
    *,
    radius_m: float = REVISIT_RADIUS_M,
    heading_deg: float = REVISIT_HEADING_DEG,
    first_keyframe: int = 0,
    worlds: np.ndarray | None = None,
) -> AssignmentScore:
    """Score a map: keyframe t claims a revisit when its state is an earlier keyframe's place.

    ``state_of_keyframe`` (n,) holds state ids (first-visit keyframes; -1 where unassigned). A
    claim is correct when the true pose at t is within ``radius_m`` and ``heading_deg`` of the
    true pose at the state's first visit. Only keyframes from ``first_keyframe`` on are scored
    (a run in a prior map: the map's own keyframes were scored with it). ``worlds``: see
    :func:`evaluate`.
    """
    states = np.asarray(state_of_keyframe, dtype=np.int64)
    n = len(states)
    index = np.arange(n)
    claims = (states >= 0) & (states < index)
    correct = np.zeros(n, dtype=bool)
    judged = np.zeros(n, dtype=bool)
    heading_rad = math.radians(heading_deg)
    poses = np.asarray(true_poses, float)
    claimed = index[claims]
    apart = worlds_apart(worlds, claimed, states[claimed]) & np.isfinite(poses[claimed]).all(axis=1)
    deltas = poses[claimed] - poses[states[claimed]]
    for t, other_world, delta in zip(claimed.tolist(), apart.tolist(), deltas.tolist(), strict=True):
        if other_world:
            judged[t] = True  # another world's place: wrong
        elif all(math.isfinite(v) for v in delta):
            judged[t] = True
            dx_m, dy_m, dyaw_rad = delta
            correct[t] = same_place(dx_m, dy_m, dyaw_rad, radius_m, heading_rad)
    true_revisit = ground_truth_revisits(true_poses, radius_m, heading_deg, worlds)
    run = slice(first_keyframe, None)
    return AssignmentScore(claims[run], correct[run], true_revisit[run], judged[run])


def same_place(dx_m: float, dy_m: float, dyaw_rad: float, radius_m: float, heading_rad: float) -> bool:
    """The one test of "the same place", for the truth's revisits, the claims and the committed map:
    ``(dx_m, dy_m, dyaw_rad)`` is the true pose now minus the true pose then. One formula for all
    three: two (``np.hypot`` or ``math.hypot``, the heading difference taken one way or the other, in
    degrees or radians) disagree within an ulp of the radius or the heading, and a claim judged
    right was then at no ground-truth revisit (a recall of 2)."""
    return math.hypot(dx_m, dy_m) <= radius_m and abs(float(se2.wrap_angle(dyaw_rad))) <= heading_rad


def pose_error(true_now: np.ndarray, true_then: np.ndarray) -> np.ndarray:
    """Signed (x_m, y_m, heading_deg) of the true pose now minus the true pose then."""
    delta = np.asarray(true_now, float) - np.asarray(true_then, float)
    delta[..., 2] = np.degrees(se2.wrap_angle(delta[..., 2]))
    return delta


def ground_truth_revisits(
    true_poses: np.ndarray, radius_m: float, heading_deg: float, worlds: np.ndarray | None = None
) -> np.ndarray:
    """bool (n,): keyframe t has an earlier keyframe within ``radius_m`` and ``heading_deg`` (and not
    in another world: ``worlds``, see :func:`evaluate`).

    A spatial hash keeps this O(n · local density) rather than O(n²).
    """
    n = len(true_poses)
    revisit = np.zeros(n, dtype=bool)
    cells: dict[tuple[int, int], list[int]] = {}
    heading_rad = math.radians(heading_deg)
    # Cells a hair larger than the radius: points whose rounded distance equals the radius
    # always share or neighbour a cell.
    cell = radius_m * (1.0 + 1e-9)
    world = None if worlds is None else np.asarray(worlds).tolist()
    for t in range(n):
        x, y, yaw = true_poses[t]
        if not np.isfinite(true_poses[t]).all():
            continue
        cx, cy = math.floor(x / cell), math.floor(y / cell)
        for i in (cx - 1, cx, cx + 1):
            for j in (cy - 1, cy, cy + 1):
                for earlier in cells.get((i, j), ()):
                    ex, ey, eyaw = true_poses[earlier]
                    if same_place(x - ex, y - ey, yaw - eyaw, radius_m, heading_rad) and (
                        world is None or world[earlier] in (world[t], -1) or world[t] == -1
                    ):
                        revisit[t] = True
                        break
                if revisit[t]:
                    break
            if revisit[t]:
                break
        cells.setdefault((cx, cy), []).append(t)
    return revisit


def evaluate(
    steps: Iterable[tuple[int, Sequence[Hypothesis]]],
    true_poses: np.ndarray | None,
    *,
    radius_m: float = REVISIT_RADIUS_M,
    heading_deg: float = REVISIT_HEADING_DEG,
    first_keyframe: int = 0,
    count: int | None = None,
    worlds: np.ndarray | None = None,
) -> Evaluation:
    """Score a run: ``steps`` are (keyframe, hypotheses best first); ``true_poses`` (first + n, 3) or None.

    Rows of ``true_poses`` may be NaN where the truth is unknown for that keyframe. A run in a
    prior map starts at keyframe ``first_keyframe``: the rows before are the prior map's keyframes,
    which its claims may name and which count as earlier visits. ``steps`` is read once, in order:
    a stream (``count`` then says how many), so a long run's hypotheses need not all be held.
    ``worlds`` (first + n,) int: the world each keyframe's truth is in, for a map whose sessions were
    in worlds that share no place (-1: unknown; None: all one world). A keyframe never revisits a
    place of another world, and a claim of one is wrong (no pose error: the frames differ).
    """
    n = len(steps) if count is None else count  # type: ignore[arg-type]
    first = first_keyframe
    counts = np.zeros(n, dtype=np.int64)
    claims = np.zeros(n, dtype=bool)
    confidence = np.full(n, np.nan)
    best_error = np.full((n, 3), np.nan)
    weighted_error = np.full((n, 3), np.nan)
    correct = np.zeros(n, dtype=bool)
    judged = np.zeros(n, dtype=bool)
    has_truth = (
        true_poses is not None
        and len(true_poses) == first + n
        and bool(np.isfinite(true_poses[first:]).any())
    )
    if has_truth:
        assert true_poses is not None
        true_revisit = ground_truth_revisits(true_poses, radius_m, heading_deg, worlds)[first:]
    heading_rad = math.radians(heading_deg)
    seen = 0
    for t, (_, hypotheses) in enumerate(steps):
        if t >= n:
            raise ValueError(f"more steps than the {n} counted")
        seen += 1
        counts[t] = len(hypotheses)
        if hypotheses and not hypotheses[0].is_new_state:
            claims[t] = True
            confidence[t] = hypotheses[0].belief
        if not has_truth:
            continue
        assert true_poses is not None
        revisits = [h for h in hypotheses if not h.is_new_state and 0 <= h.state < first + n]
        if not revisits or not np.isfinite(true_poses[first + t]).all():
            continue
        named = [h.state for h in revisits]
        errors = pose_error(true_poses[first + t], true_poses[named])
        apart = None if worlds is None else worlds_apart(worlds, first + t, np.array(named))
        if apart is not None:
            errors[apart] = np.nan  # poses in two worlds' frames: no error to measure
        weights = np.array([h.belief for h in revisits])
        finite = np.isfinite(errors).all(axis=1)
        if finite.any() and weights[finite].sum() > 0:
            weighted_error[t] = (np.abs(errors[finite]) * weights[finite, None]).sum(0) / weights[
                finite
            ].sum()
        if claims[t] and apart is not None and apart[0] and hypotheses[0] is revisits[0]:
            judged[t] = True  # another world's place: wrong
        elif claims[t] and finite[0] and hypotheses[0] is revisits[0]:
            judged[t] = True
            best_error[t] = errors[0]
            dx_m, dy_m, dyaw_rad = (true_poses[first + t] - true_poses[revisits[0].state]).tolist()
            correct[t] = same_place(dx_m, dy_m, dyaw_rad, radius_m, heading_rad)
    if seen != n:
        raise ValueError(f"{seen} steps, {n} counted")
    if not has_truth:
        return Evaluation(
            n, counts, claims, False, np.zeros(n, bool), correct, best_error, weighted_error, (), confidence
        )
    return Evaluation(
        n,
        counts,
        claims,
        True,
        true_revisit,
        correct,
        best_error,
        weighted_error,
        _episodes(scored_revisits(true_revisit, claims, claims & judged), correct),
        confidence,
        judged,
    )


def true_runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """(start, stop) of each maximal run of True in ``mask``, stop exclusive."""
    padded = np.concatenate([[False], np.asarray(mask, dtype=bool), [False]])
    edges = np.flatnonzero(padded[1:] != padded[:-1])
    return [(int(start), int(stop)) for start, stop in zip(edges[::2], edges[1::2], strict=True)]


def _episodes(true_revisit: np.ndarray, correct: np.ndarray) -> tuple[Episode, ...]:
    episodes = []
    for start, stop in true_runs(true_revisit):
        hits = np.flatnonzero(correct[start:stop])
        episodes.append(Episode(start, stop - start, int(hits[0]) if hits.size else None))
    return tuple(episodes)
