"""SE(2) algebra and the motion model's covariance propagation."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import example, given, settings
from hypothesis import strategies as st

from aslam.core import se2
from aslam.core.config import MotionNoise
from aslam.core.motion import (
    action_covariance,
    compose_rel,
    inverse_rel,
    rel_covariance,
    to_rel,
)

coordinate = st.floats(-50, 50, allow_nan=False)
angle = st.floats(-math.pi, math.pi, allow_nan=False, exclude_max=True)
poses = st.tuples(coordinate, coordinate, angle).map(np.array)


def close_poses(a: np.ndarray, b: np.ndarray, tol: float = 1e-7) -> bool:
    d = np.asarray(a) - np.asarray(b)
    d[..., 2] = se2.wrap_angle(d[..., 2])
    return bool(np.all(np.abs(d) < tol))


def as_matrix(a: np.ndarray) -> np.ndarray:
    x, y, yaw = np.asarray(a, dtype=float)
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, x], [s, c, y], [0.0, 0.0, 1.0]])


def from_matrix(m: np.ndarray) -> np.ndarray:
    return np.array([m[0, 2], m[1, 2], float(np.arctan2(m[1, 0], m[0, 0]))])


@given(poses, poses)
def test_compose_agrees_with_matrices(a, b):
    expected = from_matrix(as_matrix(a) @ as_matrix(b))
    assert close_poses(se2.compose(a, b), expected, 1e-6)


@given(poses)
def test_inverse_agrees_with_matrices(a):
    expected = from_matrix(np.linalg.inv(as_matrix(a)))
    assert close_poses(se2.inverse(a), expected, 1e-6)
    assert close_poses(se2.compose(a, se2.inverse(a)), np.zeros(3), 1e-6)


@given(poses, poses)
def test_between_recovers_the_second_pose(a, b):
    assert close_poses(se2.compose(a, se2.between(a, b)), b, 1e-6)


@given(st.lists(poses, min_size=2, max_size=6))
def test_compose_broadcasts_over_stacks(stack):
    stack = np.array(stack)
    composed = se2.compose(stack, stack[::-1])
    for i in range(len(stack)):
        assert close_poses(composed[i], se2.compose(stack[i], stack[::-1][i]), 1e-9)


@given(st.lists(poses, min_size=2, max_size=6))
def test_one_pose_is_composed_and_inverted_bit_for_bit_as_in_a_stack(stack):
    """The single-pose path skips np.stack; its float64 arithmetic is the stack's, to the bit."""
    stack = np.array(stack)
    composed, inverted = se2.compose(stack, stack[::-1]), se2.inverse(stack)
    for i in range(len(stack)):
        assert np.array_equal(se2.compose(stack[i], stack[::-1][i]), composed[i])
        assert np.array_equal(se2.inverse(stack[i]), inverted[i])


def _numeric_jacobians(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    eps = 1e-6
    ja, jb = np.zeros((3, 3)), np.zeros((3, 3))
    for i in range(3):
        step = np.zeros(3)
        step[i] = eps
        da = se2.compose(a + step, b) - se2.compose(a - step, b)
        db = se2.compose(a, b + step) - se2.compose(a, b - step)
        da[2], db[2] = se2.wrap_angle(da[2]), se2.wrap_angle(db[2])
        ja[:, i], jb[:, i] = da / (2 * eps), db / (2 * eps)
    return ja, jb


random_cov = st.tuples(*[st.floats(0.01, 1.0)] * 3, st.floats(-0.5, 0.5)).map(
    lambda v: np.array(
        [[v[0], v[3] * math.sqrt(v[0] * v[1]), 0.0], [v[3] * math.sqrt(v[0] * v[1]), v[1], 0.0], [0, 0, v[2]]]
    )
)


@settings(max_examples=60)
@given(poses, poses, random_cov, random_cov)
def test_compose_rel_propagates_covariance_with_the_se2_jacobians(a, b, cov_a, cov_b):
    rel = compose_rel(to_rel(a, cov_a), to_rel(b, cov_b))
    ja, jb = _numeric_jacobians(a, b)
    expected = ja @ cov_a @ ja.T + jb @ cov_b @ jb.T
    assert close_poses(np.array(rel[:3]), se2.compose(a, b), 1e-9)
    np.testing.assert_allclose(rel_covariance(rel), expected, rtol=1e-5, atol=1e-6 * np.abs(expected).max())


@given(poses, random_cov)
def test_inverse_rel_is_an_involution(a, cov):
    twice = inverse_rel(inverse_rel(to_rel(a, cov)))
    assert close_poses(np.array(twice[:3]), a, 1e-7)
    np.testing.assert_allclose(rel_covariance(twice), cov, atol=1e-9)


@given(
    st.lists(
        st.tuples(st.floats(0.0, 2.0), st.floats(-math.pi / 2, math.pi / 2)).map(
            lambda v: np.array([v[0], 0.0, v[1]])
        ),
        min_size=1,
        max_size=30,
    )
)
def test_covariance_grows_along_a_chain(actions):
    noise = MotionNoise()
    rel = to_rel(np.zeros(3), np.zeros((3, 3)))
    previous = rel_covariance(rel)
    for action in actions:
        rel = compose_rel(rel, to_rel(action, action_covariance(action, noise)))
        current = rel_covariance(rel)
        # Each link adds uncertainty: the uncertainty volume (det J₁ = 1, plus a positive
        # definite link term) and the heading variance both grow. Position variance alone may
        # not: a heading error can partly cancel a position error after a turn.
        assert np.linalg.det(current) > np.linalg.det(previous)
        assert current[2, 2] > previous[2, 2]
        previous = current


def test_action_covariance_is_proportional_to_distance_and_angle():
    noise = MotionNoise(fraction=0.03, drift_rad_per_m=0.0, floor_m=0.0, floor_rad=0.0)
    forward = action_covariance(np.array([2.0, 0.0, 0.0]), noise)
    assert math.isclose(math.sqrt(forward[0, 0]), 0.06)
    turn = action_covariance(np.array([0.0, 0.0, math.pi / 2]), noise)
    assert math.isclose(math.sqrt(turn[2, 2]), 0.03 * math.pi / 2)


@given(poses, poses)
def test_interpolate_runs_from_a_to_b_along_the_shorter_turn(a, b):
    assert close_poses(se2.interpolate(a, b, 0.0), a, 1e-9)
    assert close_poses(se2.interpolate(a, b, 1.0), b, 1e-6)
    middle = se2.interpolate(a, b, 0.5)
    np.testing.assert_allclose(middle[:2], (a[:2] + b[:2]) / 2, atol=1e-9)
    turn = abs(se2.wrap_angle(middle[2] - a[2]))
    assert turn <= np.pi / 2 + 1e-9  # half of a turn that is at most π


@given(poses, st.floats(-4 * math.pi, 4 * math.pi), st.floats(-0.3, 0.3), st.floats(0.0, 1.0))
def test_interpolate_sweeps_a_known_turn_the_way_it_went(a, turn, error, fraction):
    """A commanded turn of any size, executed with an error: the heading sweeps the turn made, the
    way it was commanded, not the shorter way between the two end headings."""
    made = turn + error
    b = np.array([a[0], a[1], float(se2.wrap_angle(a[2] + made))])
    pose = se2.interpolate(a, b, fraction, turn_rad=turn)
    assert abs(se2.wrap_angle(pose[2] - (a[2] + fraction * made))) < 1e-6
    assert close_poses(se2.interpolate(a, b, 1.0, turn_rad=turn), b, 1e-6)
    if abs(made) < 3.0:  # within the shorter turn the known turn changes nothing
        np.testing.assert_array_equal(pose, se2.interpolate(a, b, fraction))


@given(st.floats(-1e4, 1e4))
@example(float(np.nextafter(-math.pi, -math.inf)))
@example(-math.pi)
@example(math.pi)
def test_wrap_angle_keeps_the_direction_within_one_turn(angle):
    """The same direction, within [-π, π]: half-open as documented, [-π, π), except for an angle an
    ulp or so below −π, whose remainder rounds up to a whole turn and gives +π (the same direction;
    every caller takes |·| or wraps again)."""
    wrapped = float(se2.wrap_angle(angle))
    assert -math.pi <= wrapped <= math.pi
    assert wrapped < math.pi or angle < -math.pi
    assert math.isclose(math.cos(wrapped), math.cos(angle), abs_tol=1e-9)
    assert math.isclose(math.sin(wrapped), math.sin(angle), abs_tol=1e-9)
    assert np.array_equal(se2.wrap_angle(np.array([angle, angle])), [wrapped, wrapped])


def test_wrap_angle_gives_one_value_for_a_half_turn():
    """π and -π (and the odd multiples of π up to ±11π) are one direction, -π, as documented; the
    float just below -π is the one +π (see above), the float just below π is -π."""
    for k in range(-5, 6):
        assert float(se2.wrap_angle((2 * k + 1) * math.pi)) == -math.pi
    assert float(se2.wrap_angle(math.nextafter(-math.pi, -math.inf))) == math.pi
    assert float(se2.wrap_angle(math.nextafter(math.pi, 0.0))) == -math.pi


# Any covariance: L Lᵀ plus a little, correlations between position and heading included.
full_cov = st.lists(st.floats(-1.0, 1.0), min_size=6, max_size=6).map(
    lambda v: (lambda low: low @ low.T + 1e-3 * np.eye(3))(
        np.array([[v[0], 0.0, 0.0], [v[1], v[2], 0.0], [v[3], v[4], v[5]]])
    )
)
rels = st.tuples(poses, full_cov).map(lambda pc: to_rel(*pc))


def assert_same_rel(a, b, tol: float = 1e-9) -> None:
    assert close_poses(np.array(a[:3]), np.array(b[:3]), tol)
    ca, cb = rel_covariance(a), rel_covariance(b)
    np.testing.assert_allclose(ca, cb, rtol=1e-9, atol=tol * max(1.0, np.abs(cb).max()))


@settings(max_examples=80)
@given(rels, rels, rels)
def test_composing_links_is_associative_covariance_and_all(a, b, c):
    """(a ⊕ b) ⊕ c and a ⊕ (b ⊕ c) are one function of a, b and c, so their first-order covariances
    are one too (the chain rule): the graph search may compose a path from either end."""
    assert_same_rel(compose_rel(compose_rel(a, b), c), compose_rel(a, compose_rel(b, c)), 1e-7)


@settings(max_examples=80)
@given(rels, rels)
def test_a_path_walked_backwards_is_its_links_walked_backwards(a, b):
    """⊖(a ⊕ b) = ⊖b ⊕ ⊖a, covariance included: ``inverse_rel``'s Jacobian agrees with
    ``compose_rel``'s (the involution test alone cannot tell a wrong Jacobian that is its own inverse)."""
    assert_same_rel(inverse_rel(compose_rel(a, b)), compose_rel(inverse_rel(b), inverse_rel(a)), 1e-7)


@settings(max_examples=80)
@given(rels, rels)
def test_the_revisit_residual_is_the_state_walked_back_then_the_action(state, action):
    """``revisit_residuals`` (vectorised, on the χ² gate's path) is ⊖T ⊕ u with the covariance the
    rel algebra gives, for a stack of candidate states at once."""
    from aslam.core.motion import revisit_residuals

    expected = compose_rel(inverse_rel(state), action)
    stack = np.array([state[:3], action[:3]])
    covariances = np.array([rel_covariance(state), rel_covariance(action)])
    residuals, covariance = revisit_residuals(
        stack, covariances, np.array(action[:3]), rel_covariance(action)
    )
    assert close_poses(residuals[0], np.array(expected[:3]), 1e-9)
    np.testing.assert_allclose(covariance[0], rel_covariance(expected), rtol=1e-9, atol=1e-12)
    second = compose_rel(inverse_rel(action), action)
    np.testing.assert_allclose(covariance[1], rel_covariance(second), rtol=1e-9, atol=1e-12)


@settings(max_examples=80)
@given(poses, full_cov, st.tuples(coordinate, coordinate, angle).map(np.array), full_cov)
def test_fusing_two_measurements_is_more_certain_than_either(pose_a, cov_a, pose_b, cov_b):
    """A link traversed again: the fused covariance is positive definite and no larger than either
    measurement's (Σ_a − Σ and Σ_b − Σ positive semidefinite); the order of the two does not matter
    (unless the headings are opposite: then neither way round is the shorter); one measurement
    fused with itself keeps its pose and halves its covariance."""
    from aslam.core.motion import fuse_rel

    a, b = to_rel(pose_a, cov_a), to_rel(pose_b, cov_b)
    fused = fuse_rel(a, b)
    covariance = rel_covariance(fused)
    assert np.linalg.eigvalsh(covariance).min() > 0
    for measured in (cov_a, cov_b):
        assert np.linalg.eigvalsh(measured - covariance).min() >= -1e-9 * np.abs(measured).max()
    if abs(se2.wrap_angle(pose_b[2] - pose_a[2])) < math.pi - 1e-6:  # opposite headings: no short arc
        assert_same_rel(fuse_rel(b, a), fused, 1e-7)
    assert_same_rel(fuse_rel(a, a), to_rel(pose_a, cov_a / 2), 1e-9)
    # Headings uncorrelated with position: the fused heading lies on the short arc between the two.
    block_a, block_b = cov_a.copy(), cov_b.copy()
    block_a[:2, 2] = block_a[2, :2] = block_b[:2, 2] = block_b[2, :2] = 0.0
    arc = se2.wrap_angle(pose_b[2] - pose_a[2])
    along = se2.wrap_angle(fuse_rel(to_rel(pose_a, block_a), to_rel(pose_b, block_b))[2] - pose_a[2])
    assert min(0.0, arc) - 1e-9 <= along <= max(0.0, arc) + 1e-9
