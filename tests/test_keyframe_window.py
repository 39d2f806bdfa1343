"""Keyframes on a dense stream: the frames near each odometry keyframe (``keyframe_windows``) and
the estimator's choice among them (``Estimator.choose_keyframe``)."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from test_core_tree import SyntheticWorld, rectangle_actions, run, synthetic_config

from aslam.app.pipeline import (
    MAX_WINDOW_SAMPLES,
    WINDOW_HEADING_DEG,
    Alternative,
    Keyframe,
    PipelineCounts,
    _take_keyframe,
    keyframe_windows,
)
from aslam.core import se2
from aslam.core.estimator import Keyframer
from aslam.data_formats.pose_sync import Sample


def _stream(increments: list[tuple[float, float]]) -> list[Sample]:
    """Samples along a path of (forward metres, turn degrees) increments; no images needed."""
    pose = np.zeros(3)
    samples = [Sample(0, None, pose.copy(), None)]  # type: ignore[arg-type]
    for i, (forward, turn) in enumerate(increments, start=1):
        pose = se2.compose(pose, np.array([forward, 0.0, math.radians(turn)]))
        samples.append(Sample(i, None, pose.copy(), None))  # type: ignore[arg-type]
    return samples


def _keyframer() -> Keyframer:
    return Keyframer(1.0, 90.0, 0.3, adaptive=True)


increments = st.lists(
    st.one_of(
        st.tuples(st.floats(0.02, 0.6), st.just(0.0)),
        st.tuples(st.just(0.0), st.sampled_from([15.0, 30.0, 45.0, -30.0])),
    ),
    min_size=1,
    max_size=120,
)


@settings(max_examples=60, deadline=None)
@given(steps=increments, window_m=st.sampled_from([0.0, 0.2, 0.35, 0.5]))
def test_windows_keep_the_odometry_keyframes_and_add_only_frames_near_them(steps, window_m):
    samples = _stream(steps)
    keyframer = _keyframer()
    plain = [s.stamp_ns for s in samples if keyframer.action_if_keyframe(s.odometry_pose) is not None]
    counts = PipelineCounts()
    windows = list(keyframe_windows(samples, _keyframer().action_if_keyframe, window_m, counts))
    assert [key.stamp_ns for key, _, _ in windows] == plain  # the odometry still chooses which keyframes
    assert counts.samples == len(samples)
    seen: set[int] = set()
    for key, _, others in windows:
        stamps = [o.stamp_ns for o in others]
        assert stamps == sorted(stamps) and not (set(stamps) & set(plain)) and not (set(stamps) & seen)
        seen |= set(stamps)
        for other in others:
            offset = se2.between(key.odometry_pose, other.odometry_pose)
            assert math.hypot(offset[0], offset[1]) <= window_m + 1e-12
            assert abs(math.degrees(offset[2])) <= WINDOW_HEADING_DEG + 1e-9
        if window_m == 0:
            assert others == ()


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
    step = np.array([1.0, 0.0, 0.0])
    assert estimator.choose_keyframe(step, [stranger[0], place, stranger[1]]) == 1
    assert estimator.choose_keyframe(step, [place, stranger[0]]) == 0
    assert run([], world, synthetic_config())[0].choose_keyframe(step, [stranger[0], place]) == 0


def test_a_taken_alternative_moves_the_next_action_with_it():
    """The action of a keyframe is odometry since the frame actually taken before it."""
    world = SyntheticWorld(5)
    estimator, _ = run(rectangle_actions()[:37], world, synthetic_config())

    def odometry(x: float) -> np.ndarray:  # any origin: only differences count
        return np.array([37.0 + x, 0.0, 0.0])

    def view(x: float) -> np.ndarray:
        return world.observe(np.array([x, 0.0, 0.0]))

    step = np.array([1.0, 0.0, 0.0])
    previous = Keyframe(37, np.zeros(3), view(3.0), None, odometry(0.0))
    near = Alternative(39, odometry(1.2), view(4.0))
    keyframe = Keyframe(38, step, np.zeros(16, np.float32), None, odometry(1.0), (near,))
    taken, action = _take_keyframe(estimator, keyframe, previous)
    assert taken is near
    np.testing.assert_allclose(action, [1.2, 0.0, 0.0])
    after = Keyframe(40, step, view(5.0), None, odometry(2.0))
    taken, action = _take_keyframe(estimator, after, near)
    assert taken is after
    np.testing.assert_allclose(action, [0.8, 0.0, 0.0])


def test_a_robot_standing_still_holds_a_bounded_window():
    """Thousands of frames at one pose after a keyframe: the window keeps a bounded number, and the
    keyframe still comes out once the robot moves on."""
    samples = _stream([(1.0, 0.0)] + [(0.0, 0.0)] * 5000 + [(1.0, 0.0)])
    windows = list(keyframe_windows(samples, _keyframer().action_if_keyframe, 0.35, PipelineCounts()))
    assert [key.stamp_ns for key, _, _ in windows] == [0, 1, 5002]
    assert max(len(others) for _, _, others in windows) <= 2 * MAX_WINDOW_SAMPLES
