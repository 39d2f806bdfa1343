"""Keyframes on a dense stream: the frames worth describing (``dense_samples``), the keyframes
taken among them next to the map (``keyframes_taken``) and the estimator's choice
(``Estimator.choose_keyframe``)."""

from __future__ import annotations

import itertools
import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from test_core_tree import SyntheticWorld, rectangle_actions, run, synthetic_config

from aslam.app.pipeline import (
    FRAME_SPACING,
    MAX_WINDOW_FRAMES,
    SPARSE_NEIGHBOUR_STEPS,
    WINDOW_HEADING_DEG,
    Frame,
    PipelineCounts,
    dense_samples,
    keyframes_taken,
)
from aslam.core import estimator as estimator_module
from aslam.core import se2
from aslam.core.estimator import STILL_DEG_PER_S, STILL_M_PER_S, Estimator, Keyframer, StillClock
from aslam.data_formats.pose_sync import Sample


def _poses(increments: list[tuple[float, float]]) -> list[np.ndarray]:
    """Poses along a path of (forward metres, turn degrees) increments."""
    pose = np.zeros(3)
    poses = [pose.copy()]
    for forward, turn in increments:
        pose = se2.compose(pose, np.array([forward, 0.0, math.radians(turn)]))
        poses.append(pose.copy())
    return poses


def _frames(increments: list[tuple[float, float]]) -> list[Frame]:
    """Frames whose "view" is their own stamp: a chooser can tell them apart without images."""
    return [Frame(i, pose, np.array([i], np.float32), 0) for i, pose in enumerate(_poses(increments))]


def _pose(frame: Frame) -> np.ndarray:
    return frame.odometry_pose


class _Chooser:
    """What ``keyframes_taken`` uses of an estimator: a real keyframe test and a choice that takes
    the ``pick``-th option (clipped), recording what it was offered."""

    def __init__(self, pick: int = 0) -> None:
        self.keyframer = Keyframer(1.0, 90.0, 0.3, adaptive=True)
        self.pick = pick
        self.offered: list[list[int]] = []

    def choose_keyframe(
        self, actions: list[np.ndarray], observations: list[np.ndarray], *, sparse: bool = False
    ) -> int:
        assert len(actions) == len(observations)
        self.offered.append([int(o[0]) for o in observations])
        return min(self.pick, len(observations) - 1)


increments = st.lists(
    st.one_of(
        st.tuples(st.floats(0.02, 0.6), st.just(0.0)),
        st.tuples(st.just(0.0), st.sampled_from([15.0, 30.0, 45.0, -30.0])),
    ),
    min_size=1,
    max_size=120,
)


@settings(max_examples=60, deadline=None)
@given(steps=increments, window_m=st.sampled_from([0.2, 0.35, 0.5]), pick=st.integers(0, 4))
def test_keyframes_are_taken_near_the_odometrys_choice_and_due_a_step_from_the_frame_taken(
    steps, window_m, pick
):
    frames = _frames(steps)
    chooser = _Chooser(pick)
    taken = list(keyframes_taken(frames, chooser, window_m))  # type: ignore[arg-type]
    stamps = [frame.stamp_ns for frame, _ in taken]
    assert stamps and stamps[0] == 0 and stamps == sorted(set(stamps))  # in time order, never twice
    for (before, _), (frame, action) in itertools.pairwise(taken):
        np.testing.assert_allclose(action, se2.between(before.odometry_pose, frame.odometry_pose), atol=1e-12)
    reach = SPARSE_NEIGHBOUR_STEPS * chooser.keyframer.step_m
    for options in chooser.offered:  # each option near the odometry's choice (the first one)
        key = options[0]
        for stamp in options[1:]:
            offset = se2.between(frames[key].odometry_pose, frames[stamp].odometry_pose)
            distance = math.hypot(offset[0], offset[1])
            # within the window, or (a sparse stream) the frame just before or after, within reach
            assert distance <= window_m + 1e-12 or (abs(stamp - key) == 1 and distance <= reach + 1e-12)
            assert abs(math.degrees(offset[2])) <= WINDOW_HEADING_DEG + 1e-9
        assert len(options) <= 1 + 2 * MAX_WINDOW_FRAMES
    # The keyframe test runs again from each frame taken: between two keyframes taken, no frame
    # was due a keyframe from the first (so the windows follow the frames taken, not a schedule).
    for (first, _), (second, _) in itertools.pairwise(taken):
        test = Keyframer(1.0, 90.0, 0.3, adaptive=True)
        test.anchor(first.odometry_pose)
        due = [f.stamp_ns for f, _ in test.keyframes(frames[first.stamp_ns + 1 :], _pose)]
        assert due
        offset = se2.between(frames[due[0]].odometry_pose, second.odometry_pose)
        near = reach if abs(second.stamp_ns - due[0]) == 1 else window_m  # a sparse neighbour, or the window
        assert math.hypot(offset[0], offset[1]) <= near + 1e-12


@settings(max_examples=40, deadline=None)
@given(steps=increments)
def test_taking_the_odometrys_choice_gives_the_odometrys_keyframes(steps):
    frames = _frames(steps)
    plain = Keyframer(1.0, 90.0, 0.3, adaptive=True)
    expected = [f.stamp_ns for f, _ in plain.keyframes(frames, _pose)]
    taken = keyframes_taken(frames, _Chooser(0), 0.35)  # type: ignore[arg-type]
    assert [frame.stamp_ns for frame, _ in taken] == expected


def test_a_taken_frame_moves_the_next_keyframe_and_its_action_with_it():
    """Frames every 0.1 m: the odometry's keyframe is at 1.0 m; taking the frame 0.3 m later puts
    the next keyframe a step from there (2.3 m, not 2.0 m), its action measured from the frame taken."""
    frames = _frames([(0.1, 0.0)] * 30)
    chooser = _Chooser(pick=0)
    stream = keyframes_taken(frames, chooser, 0.35)  # type: ignore[arg-type]
    first, _ = next(stream)
    assert first.stamp_ns == 0
    chooser.pick = 1 + 3 + 3  # options: the keyframe, the 3 frames before it, then the 3 after
    second, action = next(stream)
    assert chooser.offered[-1] == [10, 7, 8, 9, 11, 12, 13]
    assert second.stamp_ns == 13
    np.testing.assert_allclose(action, [1.3, 0.0, 0.0], atol=1e-9)
    chooser.pick = 0
    third, action = next(stream)
    assert third.stamp_ns == 23
    np.testing.assert_allclose(action, [1.0, 0.0, 0.0], atol=1e-9)


def test_a_robot_standing_still_or_creeping_is_described_a_few_centimetres_apart():
    """Thousands of frames at one pose, then a creep of 1 mm a frame: only frames at least
    ``FRAME_SPACING`` of the window apart are described, so a window stays small. The time stood
    still is clocked on every frame, the skipped ones too."""
    poses = _poses([(1.0, 0.0)] + [(0.0, 0.0)] * 5000 + [(0.001, 0.0)] * 1000)
    samples = [Sample(i * 5 * 10**7, None, pose, None) for i, pose in enumerate(poses)]  # type: ignore[arg-type]
    counts = PipelineCounts()
    clocked = list(dense_samples(samples, 0.35, counts))
    kept = [c.sample for c in clocked]
    assert [c.still_ns for c in clocked[:3]] == [0, 0, 5000 * 5 * 10**7]
    assert clocked[-1].still_ns == 5000 * 5 * 10**7  # a creep of 2 cm/s is no standing still
    assert counts.samples == len(samples)
    assert [s.stamp_ns for s in kept[:2]] == [0, 5 * 10**7]
    gaps = np.diff([float(s.odometry_pose[0]) for s in kept])
    assert gaps.min() >= FRAME_SPACING * 0.35 - 1e-9 and len(kept) == 2 + 1.0 // (FRAME_SPACING * 0.35)


@settings(max_examples=60, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.integers(1, 3 * 10**9),  # time to the next sample, ns
            st.sampled_from([0.0, 0.3, 1.0]),  # speed, as a share of ``STILL_M_PER_S``…
            st.sampled_from([0.0, 2.0, 50.0]),  # …or many times it
            st.sampled_from([0.0, 0.5, 3.0]),  # turn rate, as a share of ``STILL_DEG_PER_S``
        ),
        max_size=40,
    )
)
def test_the_still_clock_counts_exactly_the_intervals_below_both_speeds(steps):
    """Whatever the stream, the clock counts an interval's time in full where odometry moved slower
    than both thresholds and none of it elsewhere; a carry (no motion at all) is still time,
    however long."""
    clock, pose, stamp = StillClock(), np.zeros(3), 10**9
    readings, expected = [clock.tick(stamp, pose)], 0
    for elapsed, slow, fast, turn in steps:
        seconds = elapsed * 1e-9
        speed = (slow * 0.9 + fast) * STILL_M_PER_S  # 0.9: clear of the threshold's rounding
        rate = (
            math.radians(turn * 0.9 * STILL_DEG_PER_S) if turn < 1 else math.radians(turn * STILL_DEG_PER_S)
        )
        pose = se2.compose(pose, np.array([speed * seconds, 0.0, rate * seconds]))
        stamp += elapsed
        if fast == 0 and turn < 1:
            expected += elapsed
        readings.append(clock.tick(stamp, pose))
    assert readings[-1] == expected
    assert all(b >= a for a, b in itertools.pairwise(readings)) and readings[-1] <= stamp - 10**9


def test_on_a_sparse_stream_the_frames_either_side_of_a_keyframe_are_its_alternatives():
    """Frames 0.75 m apart (outside the 0.35 m window): a keyframe's neighbours, 0.75 m away, are
    offered (one pass keyframes a frame that another, its odometry a few centimetres short, skips);
    taking the one after skips the keyframe. One frame per step (1 m) offers nothing."""
    sparse = _frames([(0.75, 0.0)] * 2 + [(0.68, 0.0)] + [(0.75, 0.0)] * 3)  # frame 3 due at 0.68 m: skipped
    chooser = _Chooser(pick=0)
    taken = [frame.stamp_ns for frame, _ in keyframes_taken(sparse, chooser, 0.35)]  # type: ignore[arg-type]
    assert taken == [0, 1, 2, 4, 5, 6]
    assert chooser.offered == [[1, 2], [2, 3], [4, 3, 5], [5, 6], [6]][: len(chooser.offered)]
    chooser = _Chooser(pick=1)  # the second option: the frame after, or with none after the one before
    taken = [frame.stamp_ns for frame, _ in keyframes_taken(sparse, chooser, 0.35)]  # type: ignore[arg-type]
    assert taken == [0, 2, 3, 5, 6]  # 1 skipped for 2; 4 (the odometry's, 3 skipped) for 3; 4 for 5
    chooser = _Chooser(pick=1)
    steps = [frame.stamp_ns for frame, _ in keyframes_taken(_frames([(1.0, 0.0)] * 5), chooser, 0.35)]  # type: ignore[arg-type]
    assert steps == [0, 1, 2, 3, 4, 5] and chooser.offered == []


def test_a_second_lap_keyframe_is_taken_where_the_first_lap_looked_most_alike():
    """On the second lap the best hypothesis predicts lap 1's next place; of three frames near the
    odometry's keyframe the one showing that place is taken, and nothing is chosen without a map."""
    world = SyntheticWorld(5)
    lap = 34
    estimator, results = run(rectangle_actions()[: lap + 3], world, synthetic_config())
    assert results[-1].best.state == 3  # tracking lap 1 on lap 2
    rng = np.random.default_rng(0)
    stranger = [rng.dirichlet(np.ones(16)).astype(np.float32) for _ in range(2)]
    place = world.observe(np.array([4.0, 0.0, 0.0]))  # lap 1's place 4, the next one
    steps = [np.array([x, 0.0, 0.0]) for x in (1.0, 0.9, 1.1)]
    assert estimator.choose_keyframe(steps, [stranger[0], place, stranger[1]]) == 1
    assert estimator.choose_keyframe(steps[:2], [place, stranger[0]]) == 0
    assert run([], world, synthetic_config())[0].choose_keyframe(steps[:2], [stranger[0], place]) == 0


def _first_revisit_still_new(world: SyntheticWorld) -> tuple[Estimator, np.ndarray]:
    """An estimator at the first revisit of a rectangle whose view half matches the start: the best
    hypothesis is still a new place, a revisit holds a fifth of the belief; and a view of nowhere."""
    actions = rectangle_actions()
    estimator, _ = run(actions[:33], world, synthetic_config())
    rng = np.random.default_rng(1)
    strangers = [rng.dirichlet(np.ones(16)).astype(np.float32) for _ in range(2)]
    ambiguous = (0.7 * world.observe(np.zeros(3)) + 0.3 * strangers[0]).astype(np.float32)
    hypotheses = estimator.add_keyframe(34, actions[33], ambiguous).hypotheses
    assert hypotheses[0].is_new_state and not hypotheses[1].is_new_state and hypotheses[1].belief > 0.1
    return estimator, strangers[1]


def test_a_sparse_neighbour_is_taken_only_when_far_more_likely_at_a_place():
    """A sparse stream's neighbour is half a step from the keyframe: taken when it shows the
    predicted place and the keyframe does not, kept out when the two are near alike (under
    ``SPARSE_CHOICE_ODDS``). While the best hypothesis is a new place (a lap's first revisit, which
    nothing tracks yet) the place is the mapped one most like the frame, by the index."""
    world = SyntheticWorld(5)
    estimator, results = run(rectangle_actions()[:37], world, synthetic_config())
    assert not results[-1].best.is_new_state  # tracking lap 1 on lap 2
    stranger = np.random.default_rng(0).dirichlet(np.ones(16)).astype(np.float32)
    place = world.observe(np.array([4.0, 0.0, 0.0]))  # lap 1's next place, a step ahead
    keyframe, neighbour = np.array([0.75, 0.0, 0.0]), np.array([1.0, 0.0, 0.0])
    assert estimator.choose_keyframe([keyframe, neighbour], [stranger, place], sparse=True) == 1
    assert estimator.choose_keyframe([keyframe, neighbour], [place, place], sparse=False) == 1
    assert estimator.choose_keyframe([keyframe, neighbour], [place, place], sparse=True) == 0
    # The best hypothesis a new place, a revisit with a fifth of the belief: a dense window follows
    # the revisit; a sparse neighbour is taken for looking far more like a mapped place.
    estimator, stranger = _first_revisit_still_new(world)
    at_place_1 = world.observe(np.array([1.0, 0.0, 0.0]))
    frames = [stranger, at_place_1]  # the neighbour shows place 1
    assert estimator.choose_keyframe([keyframe, neighbour], frames) == 1
    assert estimator.choose_keyframe([keyframe, neighbour], frames, sparse=True) == 1
    assert estimator.choose_keyframe([keyframe, neighbour], [at_place_1, at_place_1], sparse=True) == 0
    assert estimator.choose_keyframe([keyframe, neighbour], [stranger, stranger], sparse=True) == 0


class _SecondLap:
    """Lap 2 of the synthetic rectangle, tracked; views of nowhere, and ``mapped``: a view of lap 1's
    keyframe 14, a mapped place elsewhere. ``carry_off`` shows two views of nowhere: the best
    hypothesis is then a new place and the robot lost."""

    def __init__(self) -> None:
        self.world = SyntheticWorld(5)
        self.actions = rectangle_actions()
        self.estimator, _ = run(self.actions[:37], self.world, synthetic_config())
        self.tree = self.estimator._tree
        rng = np.random.default_rng(2)
        self.nowhere = [rng.dirichlet(np.ones(16)).astype(np.float32) for _ in range(3)]
        self.pose = np.zeros(3)
        for action in self.actions[:14]:
            self.pose = se2.compose(self.pose, np.asarray(action, dtype=float))
        self.mapped = self.world.observe(self.pose)

    def carry_off(self) -> None:
        for keyframe, view in ((38, self.nowhere[0]), (39, self.nowhere[1])):
            assert self.estimator.add_keyframe(keyframe, self.actions[keyframe - 1], view).best.is_new_state
        assert self.tree.lost_off_the_map()


def test_while_lost_the_window_takes_the_frame_most_like_a_mapped_place():
    """Carried off on the second lap, the hypotheses predict from the lost track; of the frames near
    the keyframe the one that shows a mapped place elsewhere is taken. Tracking, it is not."""
    lap = _SecondLap()
    step = np.array([1.0, 0.0, 0.0])
    frames = [lap.nowhere[2], lap.mapped, lap.nowhere[0]]
    assert not lap.tree.lost_off_the_map()
    assert lap.estimator.choose_keyframe([step, 0.9 * step, 1.1 * step], frames) != 1
    lap.carry_off()
    assert lap.estimator.choose_keyframe([step, 0.9 * step, 1.1 * step], frames) == 1


def test_while_lost_a_sparse_stream_takes_a_neighbour_only_if_far_more_like_a_mapped_place():
    """On a sparse stream the alternatives are the keyframe's neighbours, half a step off: lost, the
    one showing a mapped place is taken over a view of nowhere, but not over a keyframe that shows
    a mapped place itself nearly as well (a brief loss of track must not shift the keyframes' phase)."""
    lap = _SecondLap()
    steps = [np.array([1.0, 0.0, 0.0]), np.array([0.5, 0.0, 0.0])]
    choose = lap.estimator.choose_keyframe
    assert choose(steps, [lap.nowhere[2], lap.mapped], sparse=True) == 0  # tracking
    lap.carry_off()
    assert choose(steps, [lap.nowhere[2], lap.mapped], sparse=True) == 1
    also_mapped = lap.world.observe(lap.pose)  # another view of the same place, as alike within noise
    assert choose(steps, [also_mapped, lap.mapped], sparse=True) == 0


def test_where_odometry_puts_a_frame_weighs_with_how_alike_it_looks():
    """Of two frames that look equally like the predicted place (lap 1's place 4, a step ahead),
    the one odometry puts at the place is taken, not the one half a step short of it."""
    world = SyntheticWorld(5)
    estimator, _ = run(rectangle_actions()[:37], world, synthetic_config())
    stranger = np.random.default_rng(0).dirichlet(np.ones(16)).astype(np.float32)
    place = world.observe(np.array([4.0, 0.0, 0.0]))
    keyframe, short, at_place = (np.array([x, 0.0, 0.0]) for x in (0.8, 0.5, 1.1))
    assert estimator.choose_keyframe([keyframe, short, at_place], [stranger, place, place]) == 2
    assert estimator.choose_keyframe([keyframe, at_place, short], [stranger, place, place]) == 1


def test_a_likely_revisit_says_where_to_look_when_the_best_hypothesis_is_a_new_place():
    """At the first revisit the best hypothesis may still be a new place that predicts none, while a
    revisit holds a fifth of the belief: the keyframe is taken where that revisit expects the next
    place (the wrong claims of held-out video-rate runs were such keyframes, 0.6 m from every place).
    The tree's own predictions stand in for a case where the new place's map reaches no place."""
    world = SyntheticWorld(5)
    estimator, stranger = _first_revisit_still_new(world)
    tree = estimator._tree
    predict = tree.predicted_revisit
    steps = [np.array([x, 0.0, 0.0]) for x in (1.0, 0.9)]
    frames = [stranger, world.observe(np.array([1.0, 0.0, 0.0]))]  # the second shows place 1
    tree.predicted_revisit = lambda actions, leaf=None: (
        None if leaf is None or leaf is tree.leaves[0] else predict(actions, leaf)
    )
    assert estimator.choose_keyframe(steps, frames) == 1
    tree.predicted_revisit = lambda actions, leaf=None: None
    assert estimator.choose_keyframe(steps, frames) == 0


def test_of_two_frames_near_alike_the_one_at_the_predicted_place_is_taken(monkeypatch):
    """A frame 0.4 m past the predicted place that looks a little more like it (near a wall a view
    changes quickly) is not taken over the frame at the place: within a window odometry ranks the
    frames ``WINDOW_MOTION_SHARPNESS`` times as sharply as a claim (the hexagon's last keyframe at
    10 frames per metre was such a frame, 0.52 m from the place it named). Ranked like a claim, it was."""
    world = SyntheticWorld(5)
    estimator, _ = run(rectangle_actions()[:37], world, synthetic_config())
    stranger = np.random.default_rng(0).dirichlet(np.ones(16)).astype(np.float32)
    place = world.observe(np.array([4.0, 0.0, 0.0]))  # lap 1's place 4, a step ahead
    at_place, past = ((share * place + (1 - share) * stranger).astype(np.float32) for share in (0.7, 0.8))
    steps = [np.array([1.0, 0.0, 0.0]), np.array([1.4, 0.0, 0.0])]
    assert estimator.choose_keyframe(steps, [at_place, past]) == 0
    assert estimator.choose_keyframe(steps[::-1], [past, at_place]) == 1
    monkeypatch.setattr(estimator_module, "WINDOW_MOTION_SHARPNESS", 1.0)
    assert estimator.choose_keyframe(steps, [at_place, past]) == 1
