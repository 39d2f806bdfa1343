"""``score()``: an estimate against its recording's ground truth — the summary, tables' data, plots' data.

Reads the estimate file (keyframes streamed, kept as small per-keyframe rows), takes the ground
truth at the keyframe stamps from the recording, and scores with ``aslam.core.metrics``. The
summary JSON (``docs/usage.md``) is what ``--fail-on`` gates test (``aslam.app.gates``).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from contextlib import closing
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from aslam.app.metric_view import (
    Embedding,
    MetricScores,
    TrajectoryScores,
    embed_run,
    estimator_config,
)
from aslam.app.metric_view import score as score_trajectories
from aslam.core import se2
from aslam.core.config import REVISIT_HEADING_DEG, REVISIT_RADIUS_M, check_report_tolerances
from aslam.core.errors import InputError
from aslam.core.mapgraph import GrowableArray
from aslam.core.metrics import AssignmentScore, Evaluation, evaluate, score_assignment
from aslam.data_formats.errors import CutWhileReadError, EstimateError, RecordingError, UnopenableBag
from aslam.data_formats.estimate import EstimateFile, iter_keyframes, map_digest, open_estimate, read_estimate
from aslam.data_formats.files import file_name_from_utf8, full_path, real_path, source_size_bytes
from aslam.data_formats.graph_json import build_graph_json
from aslam.data_formats.mcap_file import McapFile
from aslam.data_formats.pose_sync import TRUTH_MAX_GAP_NS
from aslam.data_formats.recording import world_identity
from aslam.data_formats.sources import RecordingInput, TopicChoice, open_input

# --- ground truth ----------------------------------------------------------------------------------


def truth_at_stamps(stamps_ns: Sequence[int], truth: Iterable[tuple[int, np.ndarray]]) -> np.ndarray:
    """(n, 3) true poses at ``stamps_ns`` (ascending), NaN where unknown.

    ``truth`` is a time-ordered stream of ``(stamp_ns, (x_m, y_m, yaw_rad))``, read once. A stamp
    matching a message exactly takes its pose; between two messages at most ``TRUTH_MAX_GAP_NS`` apart
    the pose is interpolated (heading along the shorter arc); outside the messages it is unknown.
    """
    n = len(stamps_ns)
    poses = np.full((n, 3), np.nan)
    i = 0
    previous: tuple[int, np.ndarray] | None = None
    for stamp, pose in truth:
        pose = np.asarray(pose, dtype=float)
        while i < n and stamps_ns[i] <= stamp:
            target = stamps_ns[i]
            if target == stamp:
                poses[i] = pose
            elif previous is not None and stamp - previous[0] <= TRUTH_MAX_GAP_NS:
                t0, p0 = previous
                poses[i] = se2.interpolate(p0, pose, (target - t0) / (stamp - t0))
            i += 1
        previous = (stamp, pose)
        if i >= n:
            break
    return poses


# --- the summary -----------------------------------------------------------------------------------


def _stats(values: dict[str, Any], measured: bool = True) -> dict[str, dict[str, float | None]]:
    if not measured:
        return {axis: dict.fromkeys(("mean", "median", "max")) for axis in values}
    return {axis: {"mean": s.mean, "median": s.median, "max": s.max} for axis, s in values.items()}


def build_summary(
    evaluation: Evaluation,
    *,
    states: int,
    links: int,
    keyframes_per_second: float | None,
    embedding: Embedding | None = None,
    metric: MetricScores | None = None,
    committed: AssignmentScore | None = None,
    slam_ms_per_keyframe: float | None = None,
    pose_errors: bool = True,
) -> dict[str, Any]:
    """The summary JSON (every key always present; null where not measurable).

    ``committed`` scores the final map's assignment (what the hypotheses agreed on) beside the
    online best hypothesis; the precision–recall curve is over the best hypothesis's belief.
    Without ``pose_errors`` (a truth by index: frame numbers, not poses) the errors are null.
    """
    counts = evaluation.hypothesis_counts
    has_truth = evaluation.has_ground_truth
    curve = evaluation.pr_curve() if has_truth else None
    return {
        "keyframes": int(evaluation.keyframes),
        "states": int(states),
        "links": int(links),
        "ground_truth": bool(has_truth),
        "hypotheses": {  # null without keyframes: not measurable, as every figure of an empty run
            "max": int(counts.max()) if counts.size else None,
            "mean": float(counts.mean()) if counts.size else None,
            "final": int(counts[-1]) if counts.size else None,
        },
        "relocalisation": {
            "episodes": len(evaluation.episodes) if has_truth else None,  # runs of true revisits
            "first_delay_keyframes": evaluation.first_delay,
            "mean_delay_keyframes": evaluation.mean_delay,
        },
        "loop_closure": {
            "claims": int(evaluation.claims.sum()),
            "unjudged_claims": int((evaluation.claims & ~evaluation.judged_claims).sum())
            if has_truth
            else None,
            "correct": int(evaluation.correct.sum()) if has_truth else None,
            "ground_truth_revisits": int(evaluation.true_revisit.sum()) if has_truth else None,
            "precision": evaluation.precision,
            "recall": evaluation.recall,
            "recall_at_full_precision": None if curve is None else curve.recall_at_full_precision,
            "auc": None if curve is None else curve.auc,
        },
        "committed": {
            "claims": None if committed is None else int(committed.claims.sum()),
            "correct": None if committed is None or not has_truth else int(committed.correct.sum()),
            "precision": None if committed is None or not has_truth else committed.precision,
            "recall": None if committed is None or not has_truth else committed.recall,
        },
        "error": {
            "best": _stats(evaluation.error_stats(weighted=False), pose_errors),
            "weighted": _stats(evaluation.error_stats(weighted=True), pose_errors),
        },
        "trajectory": _trajectory_summary(embedding, metric),
        "timing": {
            "keyframes_per_second": keyframes_per_second,
            "slam_ms_per_keyframe": slam_ms_per_keyframe,
        },
    }


def _trajectory_summary(embedding: Embedding | None, metric: MetricScores | None) -> dict[str, Any]:
    """evo's APE/RPE of the embedded (optimised) and the odometry-only trajectory; null without truth."""

    def stats(scores: TrajectoryScores | None, name: str) -> dict[str, float | None]:
        part = None if scores is None else getattr(scores, name)
        values = None if part is None else asdict(part)
        return {stat: None if values is None else values[stat] for stat in ("rmse", "mean", "median", "max")}

    optimised = None if metric is None else metric.optimised
    odometry = None if metric is None else metric.odometry
    return {
        "ape_m": stats(optimised, "ape_m"),
        "rpe_m": stats(optimised, "rpe_m"),
        "rpe_deg": stats(optimised, "rpe_deg"),
        "odometry_ape_m": stats(odometry, "ape_m"),
        "odometry_rpe_m": stats(odometry, "rpe_m"),
        "odometry_rpe_deg": stats(odometry, "rpe_deg"),
        "closures": None if embedding is None else len(embedding.closures),
        "closures_outvoted": None if embedding is None else int(embedding.outvoted.sum()),
    }


PREFERRED_SECTIONS = ("loop_closure.", "timing.", "trajectory.")
"""Where a short name several sections share resolves (``precision``: the online best hypothesis's,
not the final map's ``committed.precision``)."""


def summary_key(name: str, known: set[str]) -> str:
    """The summary key ``name`` stands for: the key itself or its tail (``precision``,
    ``first_delay_keyframes``, ``best.x_m.max``), a tail several keys share resolving to the first of
    ``PREFERRED_SECTIONS`` that has it. ValueError saying why there is none (unknown, ambiguous).
    One rule for every command taking figure names (``report --fail-on``, ``sweep --pareto``)."""
    matches = [key for key in sorted(known) if key == name] or [
        key for key in sorted(known) if key.endswith("." + name)
    ]
    for section in PREFERRED_SECTIONS if len(matches) > 1 else ():
        in_section = [key for key in matches if key.startswith(section)]
        if len(in_section) == 1:
            matches = in_section
            break
    if len(matches) > 1:
        raise ValueError(f"is ambiguous ({', '.join(matches)})")
    if not matches:
        raise ValueError(f"is not a summary key ({_keys_like(name, known)})")
    return matches[0]


def _keys_like(name: str, known: set[str]) -> str:
    """The keys a mistyped ``name`` may have meant (by the whole key or its last part), or, where
    none is close, every key: the one-line error says what to type either way."""
    import difflib

    tails: dict[str, list[str]] = {}
    for key in sorted(known):
        tails.setdefault(key.rsplit(".", 1)[-1], []).append(key)
    close = [key for key in sorted(known) if key.startswith(name) or ("." + name) in key]  # cut short
    close += difflib.get_close_matches(name, sorted(known), n=3, cutoff=0.75)
    close += [key for tail in difflib.get_close_matches(name, tails, n=3, cutoff=0.75) for key in tails[tail]]
    close = list(dict.fromkeys(close))[:6]
    if close:
        return f"did you mean {' or '.join(close)}?"
    return f"known: {', '.join(sorted(known))}"


#: The summary's whole-number figures (and its one boolean): their type whether measured or null,
#: so the tables of a sweep whose every task failed keep the columns' types.
COUNT_KEYS = frozenset(
    {
        "keyframes", "states", "links", "hypotheses.max", "hypotheses.final",
        "relocalisation.episodes", "relocalisation.first_delay_keyframes",
        "loop_closure.claims", "loop_closure.unjudged_claims", "loop_closure.correct",
        "loop_closure.ground_truth_revisits", "committed.claims", "committed.correct",
        "trajectory.closures", "trajectory.closures_outvoted",
    }
)  # fmt: skip
BOOLEAN_KEYS = frozenset({"ground_truth"})
#: Figures better small besides the errors and delays: a step's cost and what could not be scored.
LOWER_IS_BETTER = frozenset(
    {"timing.slam_ms_per_keyframe", "trajectory.closures_outvoted", "loop_closure.unjudged_claims"}
)


def lower_is_better(key: str) -> bool:
    """Errors (revisit errors, APE and RPE), delays, a step's cost, outvoted and unjudged claims are
    better small; every other figure (precision, recall, speed, counts) large: ``--pareto``'s
    direction."""
    trajectory_error = key.startswith("trajectory.") and key.split(".")[1].endswith(("_m", "_deg"))
    return key.startswith("error.") or trajectory_error or "delay" in key or key in LOWER_IS_BETTER


def summary_keys() -> set[str]:
    """Every dotted leaf key of the summary (what ``--fail-on`` may test)."""
    empty = Evaluation(
        0,
        np.zeros(0, np.int64),
        np.zeros(0, bool),
        False,
        np.zeros(0, bool),
        np.zeros(0, bool),
        np.zeros((0, 3)),
        np.zeros((0, 3)),
        (),
    )
    return set(leaves(build_summary(empty, states=0, links=0, keyframes_per_second=None)))


def leaves(tree: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in tree.items():
        if isinstance(value, dict):
            out.update(leaves(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = value
    return out


# --- scoring ---------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Report:
    """An estimate scored: everything the tables, plots, graph JSON and gates are made from."""

    estimate_path: Path
    estimate: EstimateFile
    recording_path: Path | None
    """The recording the ground truth came from; None when reporting without ground truth."""
    stamps_ns: tuple[int, ...]
    actions: np.ndarray
    """(n, 3) keyframe actions (x_m, y_m, yaw_rad) from odometry."""
    true_poses: np.ndarray | None
    """(n, 3) true poses at this run's keyframes; None without ground truth (or by index)."""
    evaluation: Evaluation
    embedding: Embedding | None
    """The best map embedded as a pose graph (GTSAM); None without keyframes."""
    metric: MetricScores | None
    """evo's scores of the embedding and of odometry alone; None without ground truth."""
    summary: dict[str, Any]
    map_truth: np.ndarray | None = None
    """(first_keyframe + n, 3) truth of every keyframe of the map, prior sessions first."""

    @property
    def truth_by_index(self) -> bool:
        """Scored by keyframe index (``truth_by_index``): frame numbers, not poses, so no errors."""
        return self.evaluation.has_ground_truth and self.recording_path is None

    def graph_json(self) -> dict[str, Any]:
        # By index the truth is frame numbers, not poses: none for the places (it was written as
        # ``first_visit_truth`` {"x_m": 3.0, ...} for place 3).
        return build_graph_json(
            self.estimate.graph,
            self.stamps_ns,
            None if self.truth_by_index else self.map_truth,
            estimate_path=str(full_path(self.estimate_path)),
            recording_path=None if self.recording_path is None else str(self.recording_path),
        )


def score(
    estimate: Path | str,
    *,
    recording: Path | str | None = None,
    radius_m: float = REVISIT_RADIUS_M,
    heading_deg: float = REVISIT_HEADING_DEG,
    truth_by_index: bool = False,
    ground_truth_topic: str | None = None,
    on_warning: Callable[[str], None] | None = None,
    on_stage: Callable[[str], None] | None = None,
) -> Report:
    """Score ``estimate`` against the ground truth of ``recording`` (default: the one it names).

    Without ground truth (no recording found, none in it) it scores what needs none, with one
    warning line saying why. A run in a prior map (``estimate --map``) is scored against the prior
    map's places too, with the truth of the recordings each map session names. ``truth_by_index``:
    for datasets whose sessions are aligned frame by frame (Nordland), the k-th keyframe of every
    session is at x = k, so ``radius_m`` counts keyframes; no recording is read. ``on_stage(text)``
    says what it is doing (a progress display: a long run's report takes a while).
    """
    check_report_tolerances(radius_m, heading_deg)
    if truth_by_index and (recording is not None or ground_truth_topic is not None):
        raise InputError(
            "--truth-by-index reads no recording; leave out --recording and --ground-truth-topic"
        )
    warn = on_warning or (lambda _line: None)
    stage = on_stage or (lambda _text: None)
    estimate = Path(estimate)
    recording = None if recording is None else Path(recording)
    stage("reading the estimate")
    # Opened once: every pass below reads this file, even if another process replaces it meanwhile
    # (read by name each time, a rewrite between passes mixed two estimates in one report).
    source = open_estimate(estimate)
    info = read_estimate(source)
    # Two passes over the keyframes: the stamps and actions first (the truth is read at the stamps),
    # then the hypotheses, scored as they stream, never all held (a second read of the keyframes
    # costs 20 µs each; holding every keyframe's hypotheses cost 0.5 KiB each at 1.8 of them).
    stamps: list[int] = []
    moves = GrowableArray((3,), np.float64)
    with closing(iter_keyframes(source)) as keyframes:
        for keyframe in keyframes:
            stamps.append(keyframe.stamp_ns)
            moves.append(np.asarray(keyframe.action, dtype=float))
    action_array = moves.view.copy()
    first = info.graph.first_keyframe
    stage("reading the ground truth")
    # every keyframe of the map: the prior map's, then this run's
    true_poses, run = _session_truth(
        info, estimate, stamps, truth_by_index, recording, warn, ground_truth_topic
    )
    recording_path = run.recording
    sessions: list[_Session] = []
    if true_poses is not None and first:
        earlier, sessions = _map_truth(info, estimate, truth_by_index, warn, ground_truth_topic)
        true_poses = np.concatenate([earlier, true_poses])
    read = {session.ground_truth_topic for session in [*sessions, run]}
    if (
        ground_truth_topic is not None
        and run.ground_truth_topic is not None
        and ground_truth_topic not in read
        and all(session.recording is not None for session in sessions)
    ):
        # this run lacks the topic named (its own read instead), and so does every session of its
        # map; a session whose recording was not found (its warning said so) may have had it
        raise RecordingError(
            f"no ground-truth topic '{ground_truth_topic}' in it or in any session of its map",
            path=recording_path,
        )
    worlds = None if truth_by_index or not sessions else _worlds([*sessions, run], warn)
    stage("scoring the claims")
    with closing(iter_keyframes(source)) as keyframes:
        evaluation = evaluate(
            ((keyframe.index, keyframe.hypotheses) for keyframe in keyframes),
            true_poses,
            radius_m=radius_m,
            heading_deg=heading_deg,
            first_keyframe=first,
            count=len(stamps),
            worlds=worlds,
        )
    if not evaluation.has_ground_truth:
        true_poses = None
    run_truth = None if true_poses is None or truth_by_index else true_poses[first:]
    stage("the metric view (GTSAM)")
    try:
        embedding = embed_run(
            action_array,
            info.graph.states,
            info.graph.links,
            estimator_config(info.metadata.config),
            first,
            on_iteration=lambda iteration: stage(f"the metric view (GTSAM): iteration {iteration}"),
        )
    except ValueError as err:
        raise EstimateError(f"no metric view of the map ({err})", path=estimate) from err
    metric = None
    if embedding is not None and run_truth is not None and np.isfinite(run_truth).all(axis=1).sum() >= 2:
        stage("the trajectories' errors (evo)")
        try:
            metric = score_trajectories(embedding, run_truth, stamps)
        except ValueError as err:
            warn(f"{estimate}: no trajectory scores: {err}")
        else:
            if metric.optimised.unaligned is not None:
                warn(
                    f"{estimate}: no APE: the trajectory cannot be aligned to the ground truth"
                    f" ({metric.optimised.unaligned}); RPE, which needs no alignment, is scored"
                )
    # The map's claims need no truth: without it none is judged (its correct, precision, recall null).
    assignment = map_assignment(info.graph.states, first + len(stamps))
    committed = score_assignment(
        assignment,
        np.full((len(assignment), 3), np.nan) if true_poses is None else true_poses,
        radius_m=radius_m,
        heading_deg=heading_deg,
        first_keyframe=first,
        worlds=worlds,
    )
    summary = build_summary(
        evaluation,
        states=len(info.graph.states),
        links=len(info.graph.links),
        keyframes_per_second=None if info.timing is None else info.timing.keyframes_per_second,
        embedding=embedding,
        metric=metric,
        committed=committed,
        slam_ms_per_keyframe=None
        if info.timing is None or not info.timing.keyframes
        else 1e3 * info.timing.slam_s / info.timing.keyframes,
        pose_errors=not truth_by_index,
    )
    return Report(
        estimate_path=estimate,
        estimate=info,
        # the recording read is no source of truth when it held none (a bag without it, not a recording)
        recording_path=recording_path if evaluation.has_ground_truth else None,
        stamps_ns=tuple(stamps),
        actions=_read_only(action_array),
        true_poses=None if run_truth is None else _read_only(run_truth),
        evaluation=evaluation,
        embedding=embedding,
        metric=metric,
        summary=summary,
        map_truth=None if true_poses is None else _read_only(true_poses),
    )


def _read_only(array: np.ndarray) -> np.ndarray:
    """A report's arrays cannot be written, as its fields cannot be set (the run's truth is a view of
    the map's: writing into one changed the other)."""
    view = array.view()
    view.setflags(write=False)
    return view


def index_truth(keyframes: int) -> np.ndarray:
    """(n, 3) poses for ``--truth-by-index``: the k-th keyframe of a session at x = k."""
    return np.column_stack([np.arange(keyframes, dtype=float), np.zeros(keyframes), np.zeros(keyframes)])


def _session_truth(
    info: EstimateFile,
    estimate: Path,
    stamps: list[int],
    truth_by_index: bool,
    recording: Path | None,
    warn: Callable[[str], None],
    ground_truth_topic: str | None = None,
    *,
    of_the_map: bool = False,
) -> tuple[np.ndarray | None, _Session]:
    """One session's truth at its keyframe stamps, and the session (the recording and topic it came
    from): by index, or from ``recording`` (default: the one the estimate ``info`` of file
    ``estimate`` names), on ``ground_truth_topic`` where it has that topic, else on the topic the
    estimate was made with; (None, …) with a warning if none. A session of a map chain may lack the
    named topic (sessions recorded or imported with other topic names): ``score`` refuses a topic
    that none has. With a topic named, this run's truth not found is an error, not a warning."""
    if truth_by_index:
        return index_truth(len(stamps)), _Session(len(stamps), None, None)
    without = _MAP_UNSCORED if of_the_map else "reporting without ground truth"
    path = _find_recording(recording, info, estimate, warn, without)
    if path is None:
        return None, _Session(len(stamps), None, None)
    topics = TopicChoice.from_record(info.metadata.topics)
    alone = not of_the_map and info.metadata.prior_map is None

    def unopened(err: UnopenableBag) -> tuple[None, _Session]:
        """The run's own recording that cannot be opened is an error; a prior map's session goes
        unscored, with a warning, as one whose recording is gone: the run is still scored."""
        if not of_the_map:
            raise err
        warn(f"{err}; {without}")
        return None, _Session(len(stamps), None, None)

    try:
        named = ground_truth_topic is not None and (alone or _has_topic(path, ground_truth_topic))
    except UnopenableBag as err:
        return unopened(err)
    if named:
        topics = replace(topics, ground_truth=ground_truth_topic)
    elif of_the_map and ground_truth_topic is not None and topics.ground_truth is None:
        # A map session (a bag estimated with no truth topic) without the topic named: it said
        # "no ground-truth topic named for this bag", though one was.
        warn(f"{path}: no topic '{ground_truth_topic}' in it; {without}")
        return None, _Session(len(stamps), path, None)
    strict = ground_truth_topic is not None and not of_the_map
    try:
        poses = _ground_truth(path, topics, stamps, warn, strict=strict, without=without)
    except UnopenableBag as err:
        return unopened(err)
    except RecordingError as err:
        if named:
            raise
        raise RecordingError(
            f"no ground-truth topic '{ground_truth_topic}'; on its own topic: {err.problem}", path=path
        ) from err
    topic = None if poses is None else topics.recording_topics().ground_truth
    return poses, _Session(len(stamps), path, topic)


def _has_topic(path: Path, topic: str) -> bool:
    """Whether the recording or bag at ``path`` has ``topic``; False where it cannot be read (the
    read of its own topic then says why). A bag that cannot be opened at all is ``UnopenableBag``."""
    try:
        return open_input(path).has_topic(topic)
    except UnopenableBag:
        raise
    except InputError:
        return False


_MAP_UNSCORED = "the map's keyframes from it are not scored"
_MAP_LOST = "the keyframes of that map are not scored"


def _map_truth(
    info: EstimateFile,
    path: Path,
    truth_by_index: bool,
    warn: Callable[[str], None],
    ground_truth_topic: str | None = None,
) -> tuple[np.ndarray, list[_Session]]:
    """(first_keyframe, 3) truth of the prior map's keyframes, session by session back to the first
    map (each prior estimate names its recording and its own prior), and the sessions. A session
    whose truth cannot be had gives NaN rows (its places' claims are not judged), with a warning:
    its recording or its estimate missing, or an estimate that is no longer the map this run started
    in (estimated again since). ``ground_truth_topic`` is read in every session that has it (bags
    estimated without one), the others on their own topic."""
    # Walked back link by link, not recursively: a chain of a thousand sessions (a robot estimating
    # each run in the last one's map) exceeded Python's recursion limit, exit 70.
    links: list[tuple[Path, EstimateFile, list[int]]] = []  # the maps' estimates, newest first
    current, current_path = info, path
    lost = 0  # keyframes of the sessions before the oldest map found: unscored
    seen = {real_path(path)}
    while (prior := current.metadata.prior_map) is not None:
        found = _find_map(current, current_path, warn)
        if found is None:
            lost = prior.keyframes
            break
        prior_path, prior_source, prior_info = found
        if real_path(prior_path) in seen:  # a damaged chain that names itself again
            warn(f"{prior_path}: the chain of maps comes back to this file; {_MAP_LOST}")
            lost = prior.keyframes
            break
        seen.add(real_path(prior_path))
        try:
            with closing(iter_keyframes(prior_source)) as keyframes:
                stamps = [keyframe.stamp_ns for keyframe in keyframes]
        except CutWhileReadError:
            raise
        except InputError as err:
            warn(f"{err}; {_MAP_LOST}")
            lost = prior.keyframes
            break
        if prior_info.graph.first_keyframe + len(stamps) != prior.keyframes:
            warn(
                f"{prior_path}: {len(stamps)} keyframes where its map says"
                f" {prior.keyframes - prior_info.graph.first_keyframe}; {_MAP_LOST}"
            )
            lost = prior.keyframes
            break
        links.append((prior_path, prior_info, stamps))
        current, current_path = prior_info, prior_path
    truths = [np.full((lost, 3), np.nan)]
    sessions = [_Session(lost, None, None)] if lost else []
    for prior_path, prior_info, stamps in reversed(links):
        own, session = _session_truth(
            prior_info, prior_path, stamps, truth_by_index, None, warn, ground_truth_topic, of_the_map=True
        )
        truths.append(np.full((len(stamps), 3), np.nan) if own is None else own)
        sessions.append(session)
    return np.concatenate(truths), sessions


@dataclass(frozen=True)
class _Session:
    """One session of a map: its keyframes, its recording (None: not found), and the topic its truth
    came from (None: no truth)."""

    keyframes: int
    recording: Path | None
    ground_truth_topic: str | None


def _worlds(sessions: list[_Session], warn: Callable[[str], None]) -> np.ndarray | None:
    """(keyframes,) the world of each keyframe of the map (-1: unknown), where its sessions were
    rendered in worlds that share no place (``data_formats.recording.world_identity``), with a
    warning naming them; None where they are all one world, as far as the recordings say."""
    keys = [
        None
        if session.recording is None or session.ground_truth_topic is None
        else _world_of(session.recording)
        for session in sessions
    ]
    known = list(dict.fromkeys(key for key in keys if key is not None))
    if len(known) < 2:
        return None
    names: dict[str, dict[str, None]] = {key: {} for key in known}
    for session, key in zip(sessions, keys, strict=True):
        if key is not None and session.recording is not None:
            names[key][session.recording.name] = None
    groups = "; ".join(", ".join(world) for world in names.values())
    warn(
        f"the map's sessions were rendered in {len(known)} worlds that share no place ({groups}):"
        " no keyframe revisits another world's places, and a claim of one is wrong"
    )
    ids = [-1 if key is None else known.index(key) for key in keys]
    return np.repeat(np.array(ids, dtype=np.int64), [session.keyframes for session in sessions])


def _world_of(recording: Path) -> str | None:
    """The world a recording's truth is in, as the recorder says it (None: not said, a bag)."""
    try:
        source = open_input(recording)
    except InputError:
        return None
    return world_identity(source.recording.metadata()) if isinstance(source, RecordingInput) else None


def _find_map(
    info: EstimateFile, path: Path, warn: Callable[[str], None]
) -> tuple[Path, McapFile, EstimateFile] | None:
    """The prior map the estimate ``info`` (file ``path``) was made in: its path, the file opened
    (read again for its keyframes: the same file) and what it holds; None with a warning when it is
    missing, unreadable, or another map now (estimated again since: another graph).

    Looked for where the estimate names it, else by its name beside ``path`` (a folder of sessions
    moved or copied elsewhere). A file whose bytes changed but whose map is the same keyframe for
    keyframe (estimated again with other topics or timing) is the same map.
    """
    prior = info.metadata.prior_map
    assert prior is not None
    named = file_name_from_utf8(prior.path)
    candidates = [c for c in dict.fromkeys((named, full_path(path).parent / named.name)) if c.exists()]
    if not candidates:
        warn(f"map {prior.path} (named in {path}) not found; {_MAP_LOST}")
        return None
    problems = []
    for candidate in candidates:
        try:
            candidate_source = open_estimate(candidate)
            candidate_info = read_estimate(candidate_source)
            same = candidate_source.sha256() == prior.sha256
            if not same and prior.graph_sha256 is not None:
                same = map_digest(candidate_info.graph) == prior.graph_sha256
            elif not same:  # an estimate written before the map's digest was stored
                same = _same_map(candidate_info, info, prior.keyframes)
        except CutWhileReadError:
            raise
        except InputError as err:  # EstimateError among them: damaged, not an estimate
            problems.append(str(err))
            continue
        if same:
            return candidate, candidate_source, candidate_info
        problems.append(f"map {candidate} is not the map {path} was estimated in (estimated again since?)")
    warn(f"{problems[0]}; {_MAP_LOST}")
    return None


def _same_map(prior: EstimateFile, extended: EstimateFile, keyframes: int) -> bool:
    """Whether ``prior``'s map is the one ``extended`` started in: its ``keyframes`` keyframes, each
    at the place ``extended`` has it at (a run in a map never moves the map's keyframes), and its
    links there as measured (a run adds to a link's count and fuses its action, else leaves it as
    the map had it): another run of the route mapped alike has its own odometry in every link."""
    if prior.graph.keyframes != keyframes or not np.array_equal(
        map_assignment(prior.graph.states, keyframes), map_assignment(extended.graph.states, keyframes)
    ):
        return False
    links = {(link.from_state, link.to_state): link for link in extended.graph.links}
    for link in prior.graph.links:
        found = links.get((link.from_state, link.to_state))
        if found is None or found.count < link.count:
            return False
        if found.count == link.count and not np.allclose(found.action, link.action, rtol=1e-9, atol=1e-12):
            return False
    return True


def map_assignment(states: Iterable[Any], keyframes: int) -> np.ndarray:
    """(n,) the state of each keyframe in a map (``MapState``s with their keyframes); -1 if none."""
    assignment = np.full(keyframes, -1, dtype=np.int64)
    for state in states:
        for keyframe in state.keyframes:
            if 0 <= keyframe < keyframes:
                assignment[keyframe] = state.id
    return assignment


def _find_recording(
    given: Path | None,
    info: EstimateFile,
    estimate: Path,
    warn: Callable[[str], None],
    without: str = "reporting without ground truth",
) -> Path | None:
    """The recording to take ground truth from, or None (with one warning line) if it is missing.

    The recording the estimate names is looked for where it was, else by its name beside the
    estimate file (a folder of recordings and estimates moved or copied elsewhere) if its size is
    the one recorded."""
    if given is not None:
        if not given.exists():
            raise InputError("no such recording", path=given)
        # Given by name, it must be one: a FIFO, an empty or a non-MCAP file, an image folder was
        # a warning and a report without truth, exit 0 (a FIFO's size said "0 bytes").
        open_input(given)
        size = source_size_bytes(given)
        if size != info.metadata.recording.size_bytes:  # another file: a bag with the truth, or a mistake
            warn(
                f"{given} is not the recording the estimate was made from ({size} bytes, that one"
                f" {info.metadata.recording.size_bytes}): its ground truth is taken at the keyframes' stamps"
            )
        return full_path(given)
    # Only a file of the recorded size is that recording: one made again in its place (another seed)
    # was scored against, a perfect run at precision 0, after a warning alone.
    named, size_bytes = info.metadata.recording.path, info.metadata.recording.size_bytes
    path = file_name_from_utf8(named)
    beside = full_path(estimate).parent / path.name
    sizes = {candidate: _size_or_none(candidate) for candidate in dict.fromkeys([path, beside])}
    for candidate, found_size in sizes.items():
        if found_size == size_bytes:
            return candidate
    if sizes[path] is not None:
        warn(
            f"recording {named} has changed since the estimate ({sizes[path]} bytes, was {size_bytes});"
            f" {without}"
        )
    elif sizes[beside] is not None:
        warn(
            f"recording {named} (named in {estimate}) not found, and {beside} beside it is"
            f" another file ({sizes[beside]} bytes, the recording {size_bytes}); {without}"
        )
    else:
        warn(f"recording {named} (named in {estimate}) not found; {without}")
    return None


def _size_or_none(path: Path) -> int | None:
    """The size of a recording or bag at ``path``, or None where there is none to read."""
    try:
        return source_size_bytes(path) if path.exists() else None
    except (InputError, OSError):  # a folder of no bag, a file we may not read
        return None


def _ground_truth(
    path: Path,
    topics: TopicChoice,
    stamps: list[int],
    warn: Callable[[str], None],
    *,
    strict: bool = False,
    without: str = "reporting without ground truth",
) -> np.ndarray | None:
    """The truth at ``stamps``; None with a warning ending in ``without`` when there is none
    (``strict``: an error). A file that cannot be opened at all is ``UnopenableBag`` either way."""
    try:
        with closing(open_input(path, topics, on_warning=warn).ground_truth()) as truth:
            poses = truth_at_stamps(stamps, truth)
    except RecordingError as err:
        if strict or isinstance(err, UnopenableBag):  # a damaged file, not a topic it lacks
            raise
        warn(f"{err}; {without}")
        return None
    if not len(poses) or not (poses == poses).all(axis=1).any():
        if strict:
            raise RecordingError(
                f"no ground truth on '{topics.ground_truth}' at the keyframe stamps", path=path
            )
        warn(f"{path}: no ground truth at the keyframe stamps; {without}")
        return None
    return poses
