"""The hypothesis tree and the estimator on synthetic observations (fast, no rendering)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from aslam.core import se2
from aslam.core.config import EstimatorConfig
from aslam.core.errors import ConfigError
from aslam.core.estimator import FEWEST_MOVES, Estimator, Keyframer
from aslam.core.mapgraph import KeyframeViews
from aslam.core.motion import compose_rel, inverse_rel, link_weight, rel_covariance, revisit_residuals, to_rel
from aslam.core.tree import ALARM_EPISODE_GAP, AlarmCount, HypothesisTree, WindowMedian, _against_travel

BINS = 16
CARRY_TIME = 5
"""Keyframe intervals a synthetic carry takes (the stamps count keyframes): a kidnap is a pause,
odometry standing still all along."""


def carried(i: int, carried_at: int | None) -> tuple[int, int]:
    """Keyframe i's stamp and still clock (``Estimator.add_keyframe``) when the robot was carried
    just before keyframe ``carried_at`` (None: never)."""
    still = CARRY_TIME if carried_at is not None and i >= carried_at else 0
    return i + still, still


def rectangle_actions(laps: int = 2) -> list[np.ndarray]:
    lap = []
    for length in (10, 5, 10, 5):
        lap += [np.array([1.0, 0.0, 0.0])] * length + [np.array([0.0, 0.0, math.pi / 2])]
    return lap * laps


def place_key(pose: np.ndarray) -> tuple[int, int, int]:
    """The synthetic worlds' place of a pose: its position rounded to the metre, its heading to 90°."""
    return (round(pose[0]), round(pose[1]), round(math.degrees(pose[2]) / 90) % 4)


def first_lap_poses() -> list[np.ndarray]:
    """The true poses of the rectangle's first lap, keyframe by keyframe."""
    poses = [np.zeros(3)]
    for action in rectangle_actions(1):
        poses.append(se2.compose(poses[-1], action))
    return poses


class SyntheticWorld:
    """Each place (rounded true pose) has a random histogram; views of it are noisy copies."""

    def __init__(self, seed: int, noise: float = 0.05, alphabet: int | None = None) -> None:
        self.rng = np.random.default_rng(seed)
        self.noise = noise
        self.alphabet = alphabet
        self.places: dict[tuple[int, int, int], np.ndarray] = {}
        self.shared = [self.rng.dirichlet(np.ones(BINS)) for _ in range(alphabet or 0)]

    def observe(self, pose: np.ndarray) -> np.ndarray:
        key = place_key(pose)
        if key not in self.places:
            self.places[key] = (
                self.shared[self.rng.integers(len(self.shared))]
                if self.alphabet
                else self.rng.dirichlet(np.ones(BINS))
            )
        view = np.abs(self.places[key] * (1 + self.noise * self.rng.standard_normal(BINS)))
        return (view / view.sum()).astype(np.float32)


def run(actions, world: SyntheticWorld, config: EstimatorConfig, odometry_noise: float = 0.03, seed: int = 0):
    rng = np.random.default_rng(seed)
    estimator = Estimator(config)
    truth = np.zeros(3)
    results = [estimator.add_keyframe(0, np.zeros(3), world.observe(truth))]
    for i, action in enumerate(actions, start=1):
        truth = se2.compose(truth, action)
        measured = action * (1 + odometry_noise * rng.standard_normal(3))
        results.append(estimator.add_keyframe(i, measured, world.observe(truth)))
    return estimator, results


def synthetic_config(**overrides) -> EstimatorConfig:
    """Histogram observations of synthetic views: the χ² reference fixed (it was fitted to such views)."""
    base = {
        "observation_model": "histogram",
        "new_state_reference": "fixed",
        "histogram_bins": BINS,
        "cells_x": 1,
        "cells_y": 1,
    }
    return EstimatorConfig(**{**base, **overrides})


def test_relocalises_at_the_start_of_the_second_lap_and_never_claims_falsely():
    _, results = run(rectangle_actions(), SyntheticWorld(1), synthetic_config())
    lap = 34
    for result in results[1:lap]:
        assert result.best.is_new_state
    for result in results[lap:]:
        assert not result.best.is_new_state
        assert result.best.state == (result.keyframe - lap) % lap  # the same place on lap 1


def test_the_map_of_the_best_hypothesis_closes_the_loop():
    estimator, _ = run(rectangle_actions(), SyntheticWorld(2), synthetic_config())
    result = estimator.result()
    assert len(result.states) == 34
    assert len(result.links) == 34  # a cycle: every place joined to the next
    counts = sorted(link.count for link in result.links)
    assert counts[0] >= 1 and counts[-1] == 2
    assert result.stats.max_uncommitted <= 6  # shared history is committed, suffixes stay short


@settings(max_examples=25, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    alphabet=st.sampled_from([2, 3, 5]),
    cap=st.integers(1, 8),
    steps=st.lists(
        st.sampled_from(
            [(1.0, 0.0, 0.0), (0.0, 0.0, math.pi / 2), (0.0, 0.0, -math.pi / 2), (2.0, 0.0, 0.0)]
        ),
        min_size=1,
        max_size=40,
    ),
)
def test_beliefs_sum_to_one_and_the_count_respects_the_cap(seed, alphabet, cap, steps):
    config = synthetic_config(max_hypotheses=cap, prune_ratio=1e-6)
    estimator = Estimator(config)
    world = SyntheticWorld(seed, alphabet=alphabet)
    truth = np.zeros(3)
    estimator.add_keyframe(0, np.zeros(3), world.observe(truth))
    for i, action in enumerate(steps, start=1):
        truth = se2.compose(truth, np.array(action))
        result = estimator.add_keyframe(i, np.array(action), world.observe(truth))
        beliefs = [h.belief for h in result.hypotheses]
        assert 1 <= len(beliefs) <= cap
        assert math.isclose(sum(beliefs), 1.0, rel_tol=1e-9)
        assert beliefs == sorted(beliefs, reverse=True)
        assert all(h.state <= result.keyframe for h in result.hypotheses)


def test_identical_views_down_a_straight_corridor_never_revisit():
    """Perfect aliasing, but every earlier place is behind: the motion model rules them out."""
    estimator = Estimator(synthetic_config())
    view = np.full(BINS, 1.0 / BINS, dtype=np.float32)
    for i in range(60):
        result = estimator.add_keyframe(i, np.array([1.0, 0.0, 0.0]) if i else np.zeros(3), view)
        assert all(h.is_new_state for h in result.hypotheses)


@pytest.mark.parametrize("radius_m", [0.5, 0.0])
def test_from_a_new_place_a_look_alike_a_metre_away_is_no_revisit(radius_m):
    """A zigzag: a step turned 60° and the turn back in place face the way the place a metre behind
    faced, and the view is the same. The robot stood at the new place, so odometry says it is a metre
    from that place: beyond the revisit radius (0 turns the bound off, and the Gaussian place term
    lets the view claim it)."""
    estimator = Estimator(synthetic_config(revisit_radius_m=radius_m))
    world = SyntheticWorld(3)
    down_the_corridor, aside = world.observe(np.zeros(3)), world.observe(np.array([5.0, 5.0, 1.0]))
    estimator.add_keyframe(0, np.zeros(3), down_the_corridor)
    estimator.add_keyframe(1, np.array([1.0, 0.0, math.radians(60)]), aside)
    result = estimator.add_keyframe(2, np.array([0.0, 0.0, -math.radians(60)]), down_the_corridor)
    if radius_m > 0:
        assert all(h.is_new_state for h in result.hypotheses)
    else:
        assert result.best.state == 0


@pytest.mark.parametrize("radius_m", [0.5, 0.0])
def test_after_a_turn_in_place_a_look_alike_a_metre_away_is_no_revisit(radius_m):
    """A zigzag's second lap turns in place at a corner where the first lap did not. Tracked at
    that corner's place, the robot now faces the way the place a metre back faced, and the view is
    the same; but a turn in place leaves it where it stood, a metre from that place: beyond the
    revisit radius. (0 turns the bound off, and the Gaussian place term lets the view claim it.)"""
    estimator = Estimator(synthetic_config(revisit_radius_m=radius_m))
    world = SyntheticWorld(5)
    corner, turned, zig, back, returned = (world.observe(np.array([x, 0.0, 0.0])) for x in range(5))
    step, zag = np.array([1.0, 0.0, 0.0]), math.radians(60)
    # Lap 1: at the corner, turn in place and zig a step; turn about, step back, face the way it began.
    first_lap = [
        (np.zeros(3), corner),
        (np.array([0.0, 0.0, -zag]), turned),
        (step, zig),
        (np.array([0.0, 0.0, math.pi]), back),
        (step, returned),
    ]
    for keyframe, (action, view) in enumerate(first_lap):
        estimator.add_keyframe(keyframe, action, view)
    # Lap 2: the same corner, turn and zig, tracked; then at the zig's end a turn in place back to
    # the corner's heading, which the corner's view matches.
    lap_two = [
        (np.array([0.0, 0.0, -2 * zag]), corner, 0),
        (np.array([0.0, 0.0, -zag]), turned, 1),
        (step, zig, 2),
    ]
    for keyframe, (action, view, place) in enumerate(lap_two, start=len(first_lap)):
        assert estimator.add_keyframe(keyframe, action, view).best.state == place
    result = estimator.add_keyframe(8, np.array([0.0, 0.0, zag]), corner)
    if radius_m > 0:
        assert result.best.is_new_state
    else:
        assert result.best.state == 0


@settings(max_examples=30, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    turns=st.lists(st.sampled_from([0.0, 0.3, -0.3, 0.6]), min_size=3, max_size=25),  # never loops back
    last=st.tuples(st.floats(-3, 3), st.floats(-3, 3), st.floats(-math.pi, math.pi)),
)
def test_candidates_are_exactly_the_states_the_motion_model_can_reach(seed, turns, last):
    """On a chain map, the proposals equal a brute-force gate (and revisit radius) over every state."""
    config = synthetic_config()
    tree = HypothesisTree(config)
    rng = np.random.default_rng(seed)
    view = lambda: rng.dirichlet(np.ones(BINS)).astype(np.float32)  # noqa: E731
    tree.add_keyframe(np.zeros(3), view())
    actions = [np.array([1.0, 0.0, turn]) for turn in turns]
    for action in actions:
        tree.add_keyframe(action, view())
    assert len(tree.leaves) == 1 and tree.leaves[0].is_new  # random views: a plain chain
    leaf = tree.leaves[0]
    action = np.array(last)
    from aslam.core.motion import action_covariance

    action_cov = action_covariance(action, config.motion_noise)
    [(proposed, _)] = tree._propose([leaf], action, action_cov)

    # Brute force: walk the chain back from the current state, composing inverted links.
    expected = []
    rel = to_rel(np.zeros(3), np.zeros((3, 3)))
    uncertainty = 0.0
    chain = [(leaf.state, rel, uncertainty)]
    for state in range(leaf.state - 1, -1, -1):
        link = tree.shared.links[(state, state + 1)]
        rel = compose_rel(rel, inverse_rel(link.rel))
        uncertainty += link_weight(link.rel)
        chain.append((state, rel, uncertainty))
    place = np.diag([config.place_radius_m**2] * 2 + [math.radians(config.place_heading_deg) ** 2])
    moved = math.hypot(action[0], action[1]) >= 0.5 or abs(action[2]) >= math.pi / 4
    for state, rel, uncertainty in chain:
        if uncertainty > config.search_sigma_m**2:
            break
        if moved and state == leaf.state:
            continue  # a keyframe after a step or a turn is never where the robot was
        residual, covariance = revisit_residuals(
            np.array([rel[:3]]), rel_covariance(rel)[None], action, action_cov
        )
        m2 = residual[0] @ np.linalg.inv(covariance[0] + place) @ residual[0]
        # The leaf is a new place: the robot stands there, so a state farther than a revisit can be is out.
        excess = math.hypot(residual[0][0], residual[0][1]) - config.revisit_radius_m
        beyond = excess > config.gate_sigma * math.sqrt(covariance[0][0, 0] + covariance[0][1, 1])
        if m2 <= config.gate_sigma**2 and not beyond:
            expected.append(state)
    assert sorted(proposed.tolist()) == sorted(expected)


def test_keyframer_uses_the_paper_thresholds_with_slack():
    keyframer = Keyframer(step_m=1.0, turn_deg=90.0, slack=0.1)
    assert keyframer.action_if_keyframe(np.zeros(3)) is not None  # the first pose
    assert keyframer.action_if_keyframe(np.array([0.5, 0.0, 0.0])) is None
    action = keyframer.action_if_keyframe(np.array([0.97, 0.0, 0.0]))
    assert action is not None and math.isclose(action[0], 0.97)
    assert keyframer.action_if_keyframe(np.array([0.97, 0.0, math.radians(60)])) is None
    turned = keyframer.action_if_keyframe(np.array([0.97, 0.0, math.radians(88)]))
    assert turned is not None and math.isclose(turned[2], math.radians(88))


def test_keyframe_test_needs_odometry_only():
    estimator = Estimator(EstimatorConfig())
    poses = [0.0, 0.3, 0.6, 1.0, 1.2, 2.0]
    actions = [estimator.keyframer.action_if_keyframe(np.array([x, 0.0, 0.0])) for x in poses]
    assert [a is not None for a in actions] == [True, False, False, True, False, True]  # x = 0, 1.0, 2.0


def test_config_reports_every_bad_value_at_once():
    with pytest.raises(ConfigError) as raised:
        EstimatorConfig(beta=-1.0, max_hypotheses=0, prune_ratio=2.0)
    message = str(raised.value)
    assert "beta" in message and "max_hypotheses" in message and "prune_ratio" in message


def test_paper_faithful_path_search_also_relocalises():
    config = synthetic_config(candidate_search="path")
    _, results = run(rectangle_actions(), SyntheticWorld(3), config)
    lap = 34
    assert all(r.best.is_new_state for r in results[1:lap])
    assert all(r.best.state == (r.keyframe - lap) % lap for r in results[lap:])


def test_a_dense_map_is_revisited_from_new_directions_without_duplicate_places():
    """A random walk on a small grid keeps entering known places from new directions; the search
    must reach them (it spends its budget near the robot) rather than invent duplicates."""
    rng = np.random.default_rng(7)
    world = SyntheticWorld(7)
    estimator = Estimator(synthetic_config())
    truth = np.zeros(3)
    estimator.add_keyframe(0, np.zeros(3), world.observe(truth))
    for k in range(1, 1200):
        ahead = se2.compose(truth, np.array([1.0, 0.0, 0.0]))
        blocked = not (0 <= round(ahead[0]) < 8 and 0 <= round(ahead[1]) < 8)
        turn = blocked or rng.random() < 0.25
        action = (
            np.array([0.0, 0.0, math.pi / 2 * rng.choice([-1.0, 1.0])]) if turn else np.array([1.0, 0.0, 0.0])
        )
        truth = se2.compose(truth, action)
        estimator.add_keyframe(k, action * (1 + 0.03 * rng.standard_normal(3)), world.observe(truth))
    places = len(world.places)
    assert places <= len(estimator.result().states) <= places * 1.02


def test_a_dense_stream_keyframes_near_the_full_step_and_turn():
    """At video rate the slack would fire at 0.7 m and mid-turn; adaptive keyframing waits for the step."""
    dense = Keyframer(step_m=1.0, turn_deg=90.0, slack=0.3, adaptive=True)
    plain = Keyframer(step_m=1.0, turn_deg=90.0, slack=0.3)
    stream = [np.array([0.1 * i, 0.0, 0.0]) for i in range(31)]
    stream += [np.array([3.0, 0.0, math.radians(9 * i)]) for i in range(1, 11)]
    fired_dense = [p for p in stream if dense.action_if_keyframe(p) is not None]
    fired_plain = [p for p in stream if plain.action_if_keyframe(p) is not None]
    assert [round(p[0], 1) for p in fired_dense[1:4]] == [1.0, 2.0, 3.0]
    assert round(math.degrees(fired_dense[-1][2])) == 90
    assert [round(p[0], 1) for p in fired_plain[1:4]] == [0.7, 1.4, 2.1]
    assert round(math.degrees(fired_plain[-1][2])) in (63, 72)


def _corner(short_m: float, turn_deg: float, frames_per_turn: int) -> list[np.ndarray]:
    """Frames every 0.1 m to ``short_m`` from the start, a turn in place, then 1.5 m on."""
    stream = [np.array([0.1 * i, 0.0, 0.0]) for i in range(round(short_m / 0.1) + 1)]
    stop = stream[-1]
    for i in range(1, frames_per_turn + 1):
        stream.append(np.array([stop[0], 0.0, math.radians(turn_deg) * i / frames_per_turn]))
    for _ in range(15):
        stream.append(se2.compose(stream[-1], np.array([0.1, 0.0, 0.0])))
    return stream


@pytest.mark.parametrize("short_m", [0.9, 1.0])
@pytest.mark.parametrize("frames_per_turn", [2, 10])
def test_a_turn_in_place_is_keyframed_where_it_begins(short_m, frames_per_turn):
    """A 60° corner (under the turn threshold) reached 0.9 m or 1.0 m from the last keyframe: either
    way the stop is a keyframe, so two passes agree on where the corner's keyframe is."""
    dense = Keyframer(step_m=1.0, turn_deg=90.0, slack=0.3, adaptive=True)
    stream = _corner(short_m, 60.0, frames_per_turn)
    taken = [(i, a) for i, a in dense.keyframes(range(len(stream)), lambda i: stream[i])]
    stop = round(short_m / 0.1)
    assert [i for i, _ in taken[:2]] == [0, stop]
    np.testing.assert_allclose(taken[1][1], [short_m, 0.0, 0.0], atol=1e-9)
    assert math.degrees(taken[2][1][2]) == pytest.approx(60.0)  # the turn goes into the next step
    assert taken[2][0] > stop + frames_per_turn


def test_a_curve_and_a_jittering_standstill_are_not_turns_in_place():
    dense = Keyframer(step_m=1.0, turn_deg=90.0, slack=0.3, adaptive=True)
    arc = [np.array([math.sin(a), 1.0 - math.cos(a), a]) for a in np.linspace(0.0, 1.5, 31)]  # radius 1 m
    taken = [i for i, _ in dense.keyframes(range(len(arc)), lambda i: arc[i])]
    assert len(taken) == 2 and np.hypot(*arc[taken[1]][:2]) >= 0.97 > np.hypot(*arc[taken[1] - 1][:2])
    still = Keyframer(step_m=1.0, turn_deg=90.0, slack=0.3, adaptive=True)
    stream = [np.array([0.1 * i, 0.0, 0.0]) for i in range(9)]
    stream += [np.array([0.8, 0.0, math.radians(0.2 * (-1) ** i)]) for i in range(20)]
    assert [i for i, _ in still.keyframes(range(len(stream)), lambda i: stream[i])] == [0]


@given(st.lists(st.tuples(st.floats(0.8, 1.2), st.sampled_from([0.0, math.pi / 2])), min_size=1, max_size=30))
def test_adaptive_keyframing_changes_nothing_at_one_pose_per_step(moves):
    adaptive = Keyframer(step_m=1.0, turn_deg=90.0, slack=0.3, adaptive=True)
    plain = Keyframer(step_m=1.0, turn_deg=90.0, slack=0.3)
    pose = np.zeros(3)
    for distance, turn in [(0.0, 0.0), *moves]:
        pose = se2.compose(pose, np.array([distance, 0.0, 0.0]) if turn == 0 else np.array([0.0, 0.0, turn]))
        a, b = adaptive.action_if_keyframe(pose), plain.action_if_keyframe(pose)
        assert (a is None) == (b is None)


@settings(max_examples=200)
@given(
    st.floats(0.8, 2.0),
    st.lists(st.floats(0.85, 1.15), min_size=6, max_size=40),
    st.lists(st.floats(0.85, 1.15), min_size=6, max_size=40),
)
def test_on_a_sparse_stream_every_moving_frame_is_a_keyframe_whatever_the_noise(spacing, first, second):
    """Frames about a step apart (0.8–2 steps), each measured with up to 15 % error: after the first
    ``FEWEST_MOVES`` every frame is a keyframe, so two passes with other errors keyframe the same
    frames (a threshold of two-thirds of the step took a 0.75 m frame on one lap and not the next)."""
    for errors in (first, second):
        keyframer = Keyframer(step_m=1.0, turn_deg=90.0, slack=0.3, adaptive=True)
        pose, fired = np.zeros(3), []
        for error in [0.0, *errors]:
            pose = se2.compose(pose, np.array([spacing * error, 0.0, 0.0]))
            fired.append(keyframer.action_if_keyframe(pose) is not None)
        assert all(fired[FEWEST_MOVES:])


def test_short_steps_measured_short_are_keyframes_and_two_frames_a_step_stay_dense():
    """0.75 m steps, one measured 0.62 m (under two-thirds of the 1 m step, which the rule before
    skipped); and two frames a 1 m step with a stretch of 0.7 m frames (a 1.41 m diagonal): a
    keyframe at least 0.7 m on from the last, as before (no single 0.5 m frame taken)."""
    short = Keyframer(step_m=1.0, turn_deg=90.0, slack=0.3, adaptive=True)
    moves = [0.0, 0.75, 0.78, 0.72, 0.75, 0.77, 0.73, 0.62, 0.75, 0.76]
    xs = np.cumsum(moves)
    assert all(short.action_if_keyframe(np.array([x, 0.0, 0.0])) is not None for x in xs)
    dense = Keyframer(step_m=1.0, turn_deg=90.0, slack=0.3, adaptive=True)
    moves = [0.0] + [0.5] * 12 + [0.7] * 4 + [0.5] * 12
    xs = np.cumsum(moves)
    actions = [dense.action_if_keyframe(np.array([x, 0.0, 0.0])) for x in xs]
    taken = [a[0] for a in actions[1:] if a is not None]
    assert len(taken) >= 13 and min(taken) >= 0.7


def test_a_sparse_stream_that_slows_or_strides_keyframes_as_the_step_says():
    """Frames 0.75 m apart, then a crawl of 0.075 m frames: the crawl keyframes about a step apart
    (the sparse rule kept half the fast median and took one every 0.4 m). Frames 3 m apart, then
    1.2 m: every frame a step or more from the last is a keyframe (half a 3 m median skipped every
    other 1.2 m frame)."""
    crawl = Keyframer(step_m=1.0, turn_deg=90.0, slack=0.3, adaptive=True)
    moves = [0.0] + [0.75] * 20 + [0.075] * 200
    xs = np.cumsum(moves)
    taken = [x for x in xs if crawl.action_if_keyframe(np.array([x, 0.0, 0.0])) is not None]
    slow = np.diff([x for x in taken if x > xs[20]])
    assert len(slow) >= 10 and slow.min() >= 0.9
    stride = Keyframer(step_m=1.0, turn_deg=90.0, slack=0.3, adaptive=True)
    moves = [0.0] + [3.0] * 20 + [1.2] * 20
    xs = np.cumsum(moves)
    assert all(stride.action_if_keyframe(np.array([x, 0.0, 0.0])) is not None for x in xs)


def _kidnap_run(config: EstimatorConfig, noise_after: float = 0.05, keyframes_after: int = 8):
    """Carried from the middle of lap 2 to another side of the rectangle, odometry unaware; from
    then on the views are copies of their places with ``noise_after`` (another light). Returns
    the keyframes from the kidnap to the first claim (None: never)."""
    return _kidnap(config, noise_after, keyframes_after)[0]


def _kidnap(config: EstimatorConfig, noise_after: float = 0.05, keyframes_after: int = 8):
    """:func:`_kidnap_run`'s delay and the estimator that ran it."""
    world = SyntheticWorld(3)
    actions = rectangle_actions(2)
    estimator = Estimator(config)
    rng = np.random.default_rng(0)
    truths = [np.zeros(3)]
    results = [estimator.add_keyframe(0, np.zeros(3), world.observe(truths[0]))]
    kidnap_at = 34 + 5
    for i, action in enumerate(actions[: kidnap_at + keyframes_after], start=1):
        truth = se2.compose(truths[-1], action)
        if i == kidnap_at:
            truth = np.array([10.0, 5.0, math.pi])  # the far corner, facing back
            world.noise = noise_after
        truths.append(truth)
        measured = action * (1 + 0.03 * rng.standard_normal(3))
        stamp, still = carried(i, kidnap_at)
        results.append(estimator.add_keyframe(stamp, measured, world.observe(truth), still))
    after = list(range(kidnap_at, len(results)))
    for t in after:
        best = results[t].best
        if not best.is_new_state:  # every claim names the place truly visited on lap 1
            here, there = truths[t], truths[best.state]
            assert math.hypot(*(here[:2] - there[:2])) < 0.5
            assert abs(se2.wrap_angle(here[2] - there[2])) < 0.5
    first = next((t for t in after if not results[t].best.is_new_state), None)
    return (None if first is None else first - kidnap_at), estimator


def test_relocalises_after_a_kidnap_by_appearance():
    delay = _kidnap_run(synthetic_config())  # the default relocalisation priors
    assert delay is not None and delay <= 3, "not relocalised within 3 keyframes"


def test_after_losing_track_a_weaker_match_relocalises():
    """Put down where the views match their places only moderately (another light): for
    ``lost_window`` keyframes after losing track a jump is proposed with ``relocalisation_lost_prior``
    and relocalises within 2 keyframes; with ``relocalisation_prior`` throughout the jump is pruned
    before the next keyframe can confirm it, keyframe after keyframe."""
    delay = _kidnap_run(synthetic_config(), noise_after=0.4, keyframes_after=12)
    assert delay is not None and delay <= 2
    assert (
        _kidnap_run(synthetic_config(relocalisation_lost_prior=0.0), noise_after=0.4, keyframes_after=12)
        is None
    )


def _carried_off_the_map(config: EstimatorConfig) -> int | None:
    """Tracked along lap 2 to the first corner, the robot is carried to the far side where odometry
    says it drove straight on past the corner, off the map (not lost: exploring), and goes on along
    the far side under another light. Keyframes from the carry to the first claim (None: never);
    every claim must name the place truly visited."""
    world = SyntheticWorld(3)
    lap = first_lap_poses()
    estimator = Estimator(config)
    rng = np.random.default_rng(0)
    truths = [lap[0]]
    results = [estimator.add_keyframe(0, np.zeros(3), world.observe(lap[0]))]
    lap2 = rectangle_actions(1)[:10]  # to the first corner, (10, 0), facing on
    for action in rectangle_actions(1) + lap2:
        truths.append(se2.compose(truths[-1], action))
        measured = action * (1 + 0.03 * rng.standard_normal(3))
        results.append(estimator.add_keyframe(len(results), measured, world.observe(truths[-1])))
    carried_at = len(results)
    world.noise = 0.4
    far_side = [p for p in lap if round(p[1]) == 5 and round(math.degrees(p[2])) % 360 == 180][:8]
    for truth in far_side:  # (10, 5) westwards; odometry: straight on, a metre a keyframe
        truths.append(truth)
        measured = np.array([1.0, 0.0, 0.0]) * (1 + 0.03 * rng.standard_normal(3))
        stamp, still = carried(len(results), carried_at)  # the carry took time: odometry saw nothing
        results.append(estimator.add_keyframe(stamp, measured, world.observe(truth), still))
    for t in range(carried_at, len(results)):
        best = results[t].best
        if not best.is_new_state:
            assert math.hypot(*(truths[t][:2] - truths[best.state][:2])) < 0.5
    claims = [t - carried_at for t in range(carried_at, len(results)) if not results[t].best.is_new_state]
    return claims[0] if claims else None


def test_a_robot_carried_as_odometry_leaves_the_map_relocalises_on_a_chain_of_places():
    """Exploring, not lost, a jump gets the small prior and is pruned before it can be confirmed;
    but appearance singling out the first lap's places one after the other at three keyframes in a
    row, just after the robot was tracked, is a kidnap's sign: that jump gets the lost prior (with
    it 0, never)."""
    delay = _carried_off_the_map(synthetic_config())
    assert delay is not None and delay <= 4
    assert _carried_off_the_map(synthetic_config(relocalisation_lost_prior=0.0)) is None


def _carried_while_exploring(pause: bool, blank_at_carry: bool = False) -> tuple[int | None, Estimator, int]:
    """Exploring the first lap (no place mapped where it drives), the robot is carried from the top
    side back to the first lap's place 1 and drives the bottom side again under another light
    (``blank_at_carry``: the first view after the carry matches nothing). Keyframes from the carry
    to the first claim (None: never; every claim must be right), the estimator, and the first
    keyframe after the carry."""
    world = SyntheticWorld(3)
    lap = first_lap_poses()
    estimator = Estimator(synthetic_config())
    rng = np.random.default_rng(0)
    actions = rectangle_actions(1)
    truths = [lap[0]]
    results = [estimator.add_keyframe(0, np.zeros(3), world.observe(lap[0]))]
    for action in actions[:25]:
        truths.append(se2.compose(truths[-1], action))
        measured = action * (1 + 0.03 * rng.standard_normal(3))
        results.append(estimator.add_keyframe(len(results), measured, world.observe(truths[-1])))
    carried_at = len(results)
    world.noise = 0.3
    for k in range(1, 10):
        truths.append(lap[k])
        measured = actions[k - 1] * (1 + 0.03 * rng.standard_normal(3))
        stamp, still = carried(len(results), carried_at if pause else None)
        view = world.observe(lap[k])
        if blank_at_carry and k == 1:
            view = np.random.default_rng(k).dirichlet(np.ones(BINS)).astype(np.float32)
        results.append(estimator.add_keyframe(stamp, measured, view, still))
    claims = [t for t in range(carried_at, len(results)) if not results[t].best.is_new_state]
    for t in claims:
        assert math.hypot(*(truths[t][:2] - truths[results[t].best.state][:2])) < 0.5
    return (claims[0] - carried_at if claims else None), estimator, carried_at


def test_a_carry_leaves_no_odometry_link_across_it_once_the_robot_relocalised():
    """The robot's first view after a carry matches nothing, so that keyframe makes a new place,
    linked by odometry to the place before the carry as if the robot had driven a step. Once a jump
    after the pause is believed, that link is cut: no later lap predicts the carry's far end from
    its near end. The link driven just before the carry keeps its measured uncertainty."""
    delay, estimator, carried_at = _carried_while_exploring(pause=True, blank_at_carry=True)
    assert delay is not None and delay > 0
    mapped = estimator.result()
    place_of = {k: state.id for state in mapped.states for k in state.keyframes}
    assert place_of[carried_at] == carried_at  # the carry's keyframe made a new place
    links = {(link.from_state, link.to_state): link for link in mapped.links}
    assert links[(place_of[carried_at - 1], carried_at)].covariance[0][0] > 1e5  # unknown
    assert links[(place_of[carried_at - 2], place_of[carried_at - 1])].covariance[0][0] < 1.0


def test_a_robot_carried_while_exploring_relocalises_on_a_chain_after_the_pause():
    """Carried while it explored, the robot had not lost track, so the places the index singles out
    get the small prior and, under another light, are pruned before a confirmation. The pause of the
    carry makes a chain of them (``CHAIN_FOR_KIDNAP``, each the place after the last) a kidnap's
    sign, as soon after a track: the lost prior, relocalised within 4 keyframes. With no pause the
    robot drove on, and the chain is a look-alike stretch's as likely. (A pause on new ground alone
    does not lift the prior: a robot that stopped there sees look-alikes as a carried one sees the
    map.)"""
    delay = _carried_while_exploring(pause=True)[0]
    assert delay is not None and delay <= 4
    assert _carried_while_exploring(pause=False)[0] is None


class ThumbnailWorld:
    """Each place has a random thumbnail-length view; views of it are noisy copies."""

    def __init__(self, seed: int, noise: float = 0.2) -> None:
        self.rng = np.random.default_rng(seed)
        self.noise = noise
        self.places: dict[tuple[int, int, int], np.ndarray] = {}

    def observe(self, pose: np.ndarray) -> np.ndarray:
        key = place_key(pose)
        if key not in self.places:
            self.places[key] = self.rng.standard_normal(192).astype(np.float32)
        return (self.places[key] + self.noise * self.rng.standard_normal(192)).astype(np.float32)


def _kidnap_claims(
    seed: int,
    config: EstimatorConfig,
    carried_share: float = 0.7,
    look_alike: bool = False,
    unseen: bool = False,
) -> str:
    """Carried mid-lap 2 to the far corner, where the view still looks 1 − ``carried_share`` like the
    place odometry predicts: per keyframe from the kidnap on, ``X`` a wrong claim, ``+`` a right one,
    ``n`` none. With ``look_alike`` a place on the far side looks 90 % like the corner (an aliased
    world), so appearance cannot single the corner out. With ``unseen`` the first view there is
    otherwise like nothing mapped (the corner under another light, say)."""
    world = ThumbnailWorld(seed)
    fresh = np.random.default_rng(100 + seed).standard_normal(192).astype(np.float32)
    if look_alike:
        corner = world.rng.standard_normal(192).astype(np.float32)
        world.places[(10, 5, 2)] = corner
        world.places[(4, 5, 2)] = (0.9 * corner + 0.1 * world.rng.standard_normal(192)).astype(np.float32)
    estimator = Estimator(config)
    rng = np.random.default_rng(0)
    truths = [np.zeros(3)]
    results = [estimator.add_keyframe(0, np.zeros(3), world.observe(truths[0]))]
    kidnap_at = 34 + 5
    for i, action in enumerate(rectangle_actions(2)[: kidnap_at + 8], start=1):
        truth = se2.compose(truths[-1], action)
        view = world.observe(truth)
        if i == kidnap_at:
            predicted = view
            truth = np.array([10.0, 5.0, math.pi])
            view = (
                carried_share * (fresh if unseen else world.observe(truth)) + (1 - carried_share) * predicted
            )
        truths.append(truth)
        stamp, still = carried(i, kidnap_at)
        results.append(
            estimator.add_keyframe(stamp, action * (1 + 0.03 * rng.standard_normal(3)), view, still)
        )
    marks = ""
    for t in range(kidnap_at, len(results)):
        best = results[t].best
        right = math.hypot(*(truths[t][:2] - truths[best.state][:2])) < 0.5
        marks += "n" if best.is_new_state else "+" if right else "X"
    return marks


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_a_place_found_by_appearance_vetoes_the_half_alike_place_odometry_predicts(seed):
    """The kidnaps of the benchmark matrix: without the contradiction veto the predicted place is
    claimed at the kidnap; with it, nothing wrong is claimed and the true place follows at once."""
    assert _kidnap_claims(seed, EstimatorConfig(contradiction_ratio=0.0))[0] == "X"
    marks = _kidnap_claims(seed, EstimatorConfig())
    assert "X" not in marks and marks[1:6] == "+++++"


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_a_view_that_speaks_against_the_prediction_is_no_revisit_of_it(seed):
    """Carried to a corner that has a look-alike elsewhere: the index finds the corner but cannot
    single it out, and the place odometry predicts looks less alike than the new-place reference
    (though under the appearance veto). That prediction is not claimed, since a place elsewhere looks
    like a revisit and clearly more alike; the corner is found a keyframe later."""
    marks = _kidnap_claims(seed, EstimatorConfig(), carried_share=0.9, look_alike=True)
    assert marks[0] == "n" and "X" not in marks and "+" in marks[1:3]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_after_a_pause_a_view_unlike_the_prediction_is_no_claim_of_it(seed):
    """Carried (a pause while tracked) to where nothing mapped looks like the view, and the place
    odometry predicts looks a little less alike than a new place (1.1–1.16 × the reference, under
    the appearance veto): its prediction's coverage of "a new place" held the track, which claimed
    it (held out: a lollipop's kidnap into the parallel corridor, facing back; two claims 4–5 m off).
    After such a pause a predicted place covers "a new place" only as far as its view looks like a
    revisit: nothing is claimed there, and the corner follows."""
    marks = _kidnap_claims(seed, EstimatorConfig(), carried_share=0.8, unseen=True)
    assert marks[0] == "n" and "X" not in marks and "+" in marks[1:3]


def test_without_relocalisation_a_kidnap_is_never_recovered():
    world = SyntheticWorld(3)
    actions = rectangle_actions(2)
    estimator = Estimator(synthetic_config(relocalisation_prior=0.0))
    rng = np.random.default_rng(0)
    truth = np.zeros(3)
    estimator.add_keyframe(0, np.zeros(3), world.observe(truth))
    kidnap_at = 34 + 5
    results = []
    for i, action in enumerate(actions[: kidnap_at + 8], start=1):
        truth = se2.compose(truth, action)
        if i == kidnap_at:
            truth = np.array([10.0, 5.0, math.pi])
        measured = action * (1 + 0.03 * rng.standard_normal(3))
        stamp, still = carried(i, kidnap_at)
        results.append(estimator.add_keyframe(stamp, measured, world.observe(truth), still))
    assert all(r.best.is_new_state for r in results[kidnap_at:])


def _reset_run(
    world: SyntheticWorld, reset_at: int, config: EstimatorConfig, view_at=None, jump=None, restarted=False
):
    """Two laps of the rectangle; odometry restarts from zero at keyframe ``reset_at`` (or, with
    ``jump``, reads that action there: a restart where odometry's origin lay that far from the robot).
    ``view_at(i, truths, view)`` may replace keyframe i's own view. ``restarted``: the reader saw the
    restart (odometry on its origin) and says so with the keyframe."""
    actions = rectangle_actions(2)
    estimator = Estimator(config)
    rng = np.random.default_rng(0)
    truths, odometry = [np.zeros(3)], [np.zeros(3)]
    results = [estimator.add_keyframe(0, np.zeros(3), world.observe(truths[0]))]
    for i, action in enumerate(actions, start=1):
        truths.append(se2.compose(truths[-1], action))
        measured = action * (1 + 0.03 * rng.standard_normal(3))
        if i != reset_at:
            odometry.append(se2.compose(odometry[-1], measured))
        else:
            odometry.append(np.zeros(3) if jump is None else se2.compose(odometry[-1], np.asarray(jump)))
        step = se2.between(odometry[-2], odometry[-1])
        view = world.observe(truths[-1])
        view = view if view_at is None else view_at(i, truths, view)
        results.append(estimator.add_keyframe(i, step, view, odometry_restarted=restarted and i == reset_at))
    return estimator, results, truths


@pytest.mark.parametrize("relocalisation_prior", [1e-4, 0.0])
def test_an_odometry_reset_is_a_jump_not_a_motion(relocalisation_prior):
    """The reset's action (back to the origin, many metres) predicts nothing: on lap 2 the robot is
    relocalised by appearance within two keyframes, every claim right; on lap 1 the map's link
    across the reset is marked as no constraint. Also with appearance jumps off (a robot that is
    never carried still has odometry that can restart)."""
    reset_at = 34 + 7  # lap 2, on the long side far from the start
    config = synthetic_config(relocalisation_prior=relocalisation_prior)
    _, results, truths = _reset_run(SyntheticWorld(5), reset_at, config)
    claims = [t for t in range(reset_at, len(results)) if not results[t].best.is_new_state]
    assert claims and claims[0] - reset_at <= 2
    for t in claims:
        here, there = truths[t], truths[results[t].best.state]
        assert math.hypot(*(here[:2] - there[:2])) < 0.5
    reset_at = 8  # lap 1: nothing to relocalise to yet
    estimator, _, _ = _reset_run(SyntheticWorld(5), reset_at, config)
    assert _link_across(estimator, reset_at).covariance[0][0] >= 1e5


@pytest.mark.parametrize("jump", [(-2.5, 0.5, math.radians(170)), (2.6, 1.2, math.radians(-120))])
def test_a_reset_near_odometrys_origin_is_a_jump_by_its_turn(jump):
    """A restart where the robot stood 2.6–2.9 m from odometry's origin, turned 120–170° from its
    axes: under 4 steps long, so by length alone a motion (no place fits it, and a look-alike's five
    confirmations came before the map: the reversal route's reset, seed 99, 6 keyframes late). No
    keyframe is both long and turned far (one is taken at a step or a turn, whichever comes first),
    so length in steps plus turn in ``turn_deg`` over 4 is a jump: relocalised within two keyframes,
    every claim right, and on lap 1 the link across it is no constraint."""
    reset_at = 34 + 7
    _, results, truths = _reset_run(SyntheticWorld(5), reset_at, synthetic_config(), jump=jump)
    claims = [t for t in range(reset_at, len(results)) if not results[t].best.is_new_state]
    assert claims and claims[0] - reset_at <= 2
    for t in claims:
        assert math.hypot(*(truths[t][:2] - truths[results[t].best.state][:2])) < 0.5
    estimator, _, _ = _reset_run(SyntheticWorld(5), 8, synthetic_config(), jump=jump)
    assert _link_across(estimator, 8).covariance[0][0] >= 1e5


@pytest.mark.parametrize("reset_at", [34 + 5, 34 + 11, 34 + 20])
def test_a_reset_read_as_a_step_backwards_relocalises_within_two_keyframes(reset_at):
    """A restart where odometry's origin lay 2.8 m ahead of the robot, turned 11°: under the jump
    test's factor, so a motion, and one against the direction of travel (``_against_travel``). The
    track ends there, and the jumps back onto the map that follow are not doubted on the word of
    that link: relocalised within two keyframes, every claim right (before: after 11 or 13
    keyframes, or never; with the merge keeping the first jump's line, after 5)."""
    jump = (-2.51, -1.25, math.radians(11))
    _, results, truths = _reset_run(SyntheticWorld(5), reset_at, synthetic_config(), jump=jump)
    claims = [t for t in range(reset_at, len(results)) if not results[t].best.is_new_state]
    assert claims and claims[0] - reset_at <= 2
    for t in claims:
        assert math.hypot(*(truths[t][:2] - truths[results[t].best.state][:2])) < 0.5


def test_a_reset_read_as_a_step_forwards_relocalises_once_the_first_jump_is_confirmed():
    """A restart read as 2.9 m forwards: a motion, along the direction of travel, that no place
    fits. Each keyframe after it jumps back onto the map by appearance, each jump doubted (five
    confirmations); merged at one belief, the lines keep the first jump's (``_prune``), so the robot
    relocalises after 5 keyframes (it never did when a younger line was kept), every claim right."""
    reset_at, jump = 34 + 11, (2.9, 0.3, math.radians(20))
    _, results, truths = _reset_run(SyntheticWorld(5), reset_at, synthetic_config(), jump=jump)
    claims = [t for t in range(reset_at, len(results)) if not results[t].best.is_new_state]
    assert claims and claims[0] - reset_at <= 5
    for t in claims:
        assert math.hypot(*(truths[t][:2] - truths[results[t].best.state][:2])) < 0.5


@pytest.mark.parametrize("jump", [(2.9, 0.3, math.radians(20)), (-1.2, 0.8, math.radians(60))])
def test_a_restart_the_reader_saw_is_a_jump_however_it_reads(jump):
    """The same restarts, read as a step forwards (five confirmations without the reader's word) and
    as a short step back and aside, with the reader's word that odometry restarted from its origin:
    the action measures nothing, whatever it reads, and the robot relocalises at the next keyframe,
    every claim right; on lap 1 the map's link across the restart is no constraint."""
    reset_at = 34 + 11
    config = synthetic_config()
    _, results, truths = _reset_run(SyntheticWorld(5), reset_at, config, jump=jump, restarted=True)
    claims = [t for t in range(reset_at, len(results)) if not results[t].best.is_new_state]
    assert claims and claims[0] - reset_at <= 1
    for t in claims:
        assert math.hypot(*(truths[t][:2] - truths[results[t].best.state][:2])) < 0.5
    estimator, _, _ = _reset_run(SyntheticWorld(5), 8, synthetic_config(), jump=jump, restarted=True)
    assert _link_across(estimator, 8).covariance[0][0] >= 1e5


@settings(max_examples=200, deadline=None)
@given(
    before=st.floats(-89.9, 89.9),
    after=st.floats(-89.9, 89.9),
    forward=st.floats(0.25, 3.0),
)
def test_driving_forwards_and_turning_is_never_against_the_direction_of_travel(before, after, forward):
    """A turn, a drive forwards and a turn, under half a turn in all (a keyframe is taken at a
    quarter): the chord lies within 90° of the mean heading, under ``AGAINST_TRAVEL_DEG``; a drive
    backwards with a turn of up to a quarter is against it."""
    turned = se2.compose(np.array([0.0, 0.0, math.radians(before)]), np.array([forward, 0.0, 0.0]))
    action = se2.compose(turned, np.array([0.0, 0.0, math.radians(after)]))
    assert not _against_travel(action, step_m=1.0)
    assert _against_travel(np.array([-forward, 0.0, math.radians(after)]), step_m=1.0)
    assert not _against_travel(np.array([0.1, 0.0, math.pi]), step_m=1.0)  # a U-turn in place: no step


@pytest.mark.parametrize(
    "factor, turned", [(4.0, (1.0, 0.2, math.pi / 2)), (1.5, (1.0, 0.0, math.radians(30)))]
)
def test_a_turn_in_place_or_a_turned_step_is_no_jump(factor, turned):
    """A U-turn in place is no step, so no jump, even where the factor is low enough that its turn
    alone would pass it; a step with a corner's turn is a motion at the default factor."""
    estimator = Estimator(synthetic_config(odometry_jump_factor=factor))
    rng = np.random.default_rng(2)
    steps = [np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, math.pi]), np.array(turned)]
    for k in range(30):
        view = rng.dirichlet(np.ones(BINS)).astype(np.float32)
        estimator.add_keyframe(k, steps[k % 3] if k else np.zeros(3), view)
    assert all(link.covariance[0][0] < 1.0 for link in estimator.result().links)


def test_past_an_odometry_jump_a_look_alike_does_not_rule_out_what_the_jumps_predict():
    """After an odometry reset the best leaf jumps back onto its map by appearance, and the next
    keyframe confirms the jump through the motion model, as a revisit of the next place. There the
    view leans towards a look-alike on the far side (lap 1's places 8 and 20 share 70 % of their
    views): the index singles it out, and the next place looks far less alike. The contradiction veto
    rules out such a place when the old track predicts it (a kidnap's); past an odometry jump there
    is no old track, and the line that jumped there keeps its prediction. A jump at an odometry jump
    is a guess, though (``Node.guessed``): with the look-alike as alike as its place, the line stays
    under the ceiling there, and the next view, which singles its place out, confirms it. So every
    claim is right and the robot relocalises at the second keyframe after the reset (at the first
    before guesses were told apart)."""
    world = SyntheticWorld(5)
    first_lap = first_lap_poses()
    own, shared = world.rng.dirichlet(np.ones(BINS)), world.rng.dirichlet(np.ones(BINS))
    world.places[place_key(first_lap[8])] = shared
    world.places[place_key(first_lap[20])] = 0.7 * shared + 0.3 * own
    reset_at = 34 + 7  # lap 2 at place 7; place 8 next

    def view_at(i: int, truths: list[np.ndarray], view: np.ndarray) -> np.ndarray:
        if i != reset_at + 1:
            return view
        return (0.7 * world.places[place_key(first_lap[20])] + 0.3 * shared).astype(np.float32)

    _, results, truths = _reset_run(world, reset_at, synthetic_config(), view_at)
    assert 8 in [h.state for h in results[reset_at + 1].hypotheses]
    assert results[reset_at + 2].best.state == 9
    for t in range(reset_at, len(results)):
        if not results[t].best.is_new_state:
            assert math.hypot(*(truths[t][:2] - truths[results[t].best.state][:2])) < 0.5


def _link_across(estimator: Estimator, keyframe: int):
    """The map's link between the places of ``keyframe - 1`` and ``keyframe``."""
    state_of = {k: s.id for s in estimator.result().states for k in s.keyframes}
    ends = {state_of[keyframe - 1], state_of[keyframe]}
    return next(link for link in estimator.result().links if {link.from_state, link.to_state} == ends)


def test_the_jump_test_can_be_turned_off():
    """``odometry_jump_factor`` 0 (as --paper-faithful): the reset's action is taken for a motion."""
    config = synthetic_config(odometry_jump_factor=0.0)
    estimator, _, _ = _reset_run(SyntheticWorld(5), 8, config)
    assert _link_across(estimator, 8).covariance[0][0] < 1.0
    assert EstimatorConfig.paper_faithful().odometry_jump_factor == 0.0


def test_long_steps_throughout_are_no_jump():
    """Judged against the run's own steps: a dataset whose frames are all 5 m apart is not a reset."""
    estimator = Estimator(synthetic_config())
    rng = np.random.default_rng(1)
    for k in range(30):
        view = rng.dirichlet(np.ones(BINS)).astype(np.float32)
        estimator.add_keyframe(k, np.array([5.0, 0.0, 0.0]) if k else np.zeros(3), view)
    assert all(link.covariance[0][0] < 1.0 for link in estimator.result().links)


@settings(max_examples=100, deadline=None)
@given(
    values=st.lists(st.floats(0.0, 10.0, allow_nan=False), min_size=1, max_size=300),
    window=st.integers(1, 60),
)
def test_the_running_median_is_numpys_median_of_the_window(values, window):
    running = WindowMedian(window)
    for i, value in enumerate(values):
        running.append(value)
        recent = values[max(0, i + 1 - window) : i + 1]
        assert len(running) == len(recent)
        assert running.median == float(np.median(recent))  # the same bits, not just close


def test_a_kidnapped_robots_own_alarms_are_no_false_alarms():
    """Carried while tracked, its views single out the right places until a jump is taken: that
    episode was taken, so it does not count, and the jumps keep their full prior."""
    delay, estimator = _kidnap(synthetic_config())
    assert delay is not None and delay <= 2
    assert estimator._tree._alarms.count == 0
    assert estimator._tree._log_alarm_scale() == 0.0


def test_look_alikes_never_taken_count_and_weaken_the_jumps():
    """A world whose places share 12 views: look-alikes keep turning up far from where the motion
    model puts the robot and are not taken, so the jump priors fall (and never with the scale off)."""
    world = SyntheticWorld(1, alphabet=12)
    estimator, _ = run(rectangle_actions(3), world, synthetic_config(), seed=1)
    assert estimator._tree._alarms.count >= 1
    assert estimator._tree._log_alarm_scale() < 0.0
    world = SyntheticWorld(1, alphabet=12)
    estimator, _ = run(rectangle_actions(3), world, synthetic_config(jump_alarm_rate=0.0), seed=1)
    assert estimator._tree._log_alarm_scale() == 0.0


@given(
    gaps=st.lists(st.integers(1, 6), min_size=1, max_size=30),
    taken=st.booleans(),
)
def test_alarms_close_together_are_one_episode_counted_once_unless_taken(gaps, taken):
    alarms = AlarmCount()
    keyframe = 0
    episodes = 1 + sum(gap > ALARM_EPISODE_GAP for gap in gaps[1:])  # the first alarm opens one
    for gap in gaps:
        keyframe += gap
        alarms.close_before(keyframe, lambda k, place: taken)
        alarms.add(keyframe, 7, lost=False)
    alarms.close_before(keyframe + ALARM_EPISODE_GAP + 1, lambda k, place: taken)
    assert alarms.count == (0 if taken else episodes)
    assert alarms.keyframes == len(gaps)
    assert not alarms.episode


def test_an_episode_begins_only_while_the_robot_is_tracked():
    alarms = AlarmCount()
    alarms.add(1, 5, lost=True)  # lost: no episode begins, no tracked keyframe
    assert alarms.episode == [] and alarms.keyframes == 0
    alarms.add(2, 5, lost=False)
    alarms.add(3, 6, lost=True)  # once begun, it runs on while lost
    assert alarms.episode == [(2, 5), (3, 6)]


@given(
    keyframes=st.integers(0, 5000),
    alarms=st.integers(0, 5000),
    rate=st.floats(1e-4, 0.5),
    power=st.floats(0, 10),
)
def test_the_alarm_scale_is_one_until_alarms_outrun_their_expected_rate(keyframes, alarms, rate, power):
    tree = HypothesisTree(synthetic_config(jump_alarm_rate=rate, jump_alarm_power=power))
    tree._alarms.keyframes, tree._alarms.count = keyframes, min(alarms, keyframes)
    share = (tree._alarms.count + 1) / (keyframes + 1 / rate)
    scale = tree._log_alarm_scale()
    assert scale <= 0.0
    if share <= rate:
        assert scale == 0.0
    else:
        assert scale == pytest.approx(power * math.log(rate / share))
    tree._alarms.count += 1  # one more alarm never strengthens a jump
    assert tree._log_alarm_scale() <= scale + 1e-12


@pytest.mark.parametrize(
    "keyframes, alarms, rate, power, expected",
    [
        (100, 0, 0.02, 1.0, 0.0),  # no alarm: the prior's 1 in 150 is under the expected 1 in 50
        (100, 2, 0.02, 1.0, 0.0),  # 3 in 150 = 0.02 exactly: as expected, no weakening
        (100, 9, 0.02, 1.0, math.log(0.3)),  # 10 in 150, 3⅓ × the expected rate: jumps × 0.3
        (100, 9, 0.02, 2.0, 2.0 * math.log(0.3)),  # the same at power 2: × 0.09
        (1000, 99, 0.05, 1.0, math.log(0.05 / (100 / 1020))),  # 100 in 1,020 against 1 in 20
    ],
)
def test_the_alarm_scale_by_hand(keyframes, alarms, rate, power, expected):
    """Worked by hand: share = (alarms + 1) / (keyframes + 1/rate), scale = power × log(rate/share)
    when that is negative, else 0."""
    tree = HypothesisTree(synthetic_config(jump_alarm_rate=rate, jump_alarm_power=power))
    tree._alarms.keyframes, tree._alarms.count = keyframes, alarms
    assert tree._log_alarm_scale() == pytest.approx(expected, abs=1e-12)


@pytest.mark.parametrize(("blank_at_carry", "pause"), [(False, False), (True, False), (False, True)])
def test_a_jump_is_born_below_the_new_place_and_nearer_it_once_lost(blank_at_carry, pause):
    """A jump by appearance is never the best at birth: ``JUMP_CEILING`` of the best leaf's "new
    place" where the robot was tracked and drove on (a teleport whose first view already matches),
    but ``JUMP_CEILING_LOST`` within ``lost_window`` of losing track (the carry's first view matched
    nothing) or of a pause (the carry took time, odometry standing still), so after a carry a
    moderately alike confirmation wins at the next keyframe."""
    from aslam.core.tree import JUMP_CEILING, JUMP_CEILING_LOST

    world = SyntheticWorld(3)
    estimator = Estimator(synthetic_config())
    rng = np.random.default_rng(0)
    truth = np.zeros(3)
    estimator.add_keyframe(0, np.zeros(3), world.observe(truth))
    born = None
    for i, action in enumerate(rectangle_actions(2)[:41], start=1):
        truth = se2.compose(truth, action) if i != 39 else np.array([10.0, 5.0, math.pi])
        blank = blank_at_carry and i == 39
        view = (
            np.random.default_rng(i).dirichlet(np.ones(BINS)).astype(np.float32)
            if blank
            else world.observe(truth)
        )
        step = action * (1 + 0.03 * rng.standard_normal(3))
        stamp, still = carried(i, 39 if pause else None)
        hypotheses = estimator.add_keyframe(stamp, step, view, still).hypotheses
        if i >= 39 and born is None and len(hypotheses) == 2 and hypotheses[0].is_new_state:
            born = hypotheses[1].belief / hypotheses[0].belief
    lost = blank_at_carry or pause
    assert born == pytest.approx(JUMP_CEILING_LOST if lost else JUMP_CEILING, rel=1e-6)
    assert (born > 1.5 * JUMP_CEILING) == lost
    if pause:
        assert not hypotheses[0].is_new_state  # confirmed at the next keyframe


def _look_alike_pair_run(confirmations: int, monkeypatch, pause: bool = True) -> tuple[list[bool], bool]:
    """Lap 2 passes places 5 and 6 while lap 1's places 20 and 21, a forward step apart on the far
    side, share 70 % of their views: for two keyframes the views lean towards 20 and 21 (still
    alike to 5 and 6, more alike to 20 and 21), as a periodic wallpaper at two corners does; with
    ``pause`` one comes before them, so the robot may have been carried (odometry's word is not
    final). Returns whether each keyframe's best claim is wrong (over 0.5 m off), from one before the
    pair on, and whether the last keyframe is claimed (the track goes on)."""
    import aslam.core.tree as tree_module

    monkeypatch.setattr(tree_module, "JUMP_CONFIRMATIONS", confirmations)
    world = SyntheticWorld(3)
    first_lap = first_lap_poses()
    for step in (0, 1):
        own, shared = world.rng.dirichlet(np.ones(BINS)), world.rng.dirichlet(np.ones(BINS))
        world.places[place_key(first_lap[5 + step])] = shared
        world.places[place_key(first_lap[20 + step])] = 0.7 * shared + 0.3 * own

    def view_at(i: int, truths: list[np.ndarray], view: np.ndarray) -> np.ndarray:
        if i not in (39, 40):  # lap 2 at places 5 and 6: leaning towards 20 and 21
            return view
        look_alike = world.places[place_key(first_lap[20 + i - 39])]
        return (0.7 * look_alike + 0.3 * world.places[place_key(truths[-1])]).astype(np.float32)

    truths, results, _ = _drive_with_views(world, 44, view_at, pause_at=39 if pause else None)
    return _wrong_claims(truths, results, range(38, 45)), not results[-1].best.is_new_state


def _drive_with_views(
    world: SyntheticWorld, keyframes: int, view_at, pause_at: int | None = None
) -> tuple[list[np.ndarray], list, Estimator]:
    """Drive the rectangle's first ``keyframes`` actions (3 % odometry noise) through the estimator;
    ``view_at(i, truths, view)`` may replace keyframe i's own view; keyframe ``pause_at`` comes after
    a carry's time (``CARRY_TIME``). The true poses, the results and the estimator."""
    estimator = Estimator(synthetic_config())
    rng = np.random.default_rng(0)
    truths = [np.zeros(3)]
    results = [estimator.add_keyframe(0, np.zeros(3), world.observe(truths[0]))]
    for i, action in enumerate(rectangle_actions(2)[:keyframes], start=1):
        truths.append(se2.compose(truths[-1], action))
        view = view_at(i, truths, world.observe(truths[-1]))
        stamp, still = carried(i, pause_at)
        results.append(
            estimator.add_keyframe(stamp, action * (1 + 0.03 * rng.standard_normal(3)), view, still)
        )
    return truths, results, estimator


def _wrong_claims(truths: list[np.ndarray], results: list, keyframes: range) -> list[bool]:
    """Whether each keyframe's best claim names a place over 0.5 m from where the robot truly is."""
    return [
        not results[i].best.is_new_state
        and math.hypot(*(truths[i][:2] - truths[results[i].best.state][:2])) > 0.5
        for i in keyframes
    ]


def test_a_jump_the_left_track_still_explains_waits_for_a_second_confirmation(monkeypatch):
    """A look-alike pair of places a step apart fits two views in a row: the jump to the first is
    capped at birth, and the motion model confirms it at the next keyframe. While the track it left
    still explains the view with another place (one it predicts looks like a revisit), the jump's
    line stays under
    the ceiling one keyframe more (``JUMP_CONFIRMATIONS``): no wrong claim, and the track goes on."""
    assert any(_look_alike_pair_run(1, monkeypatch)[0])  # confirmed once: the look-alike is claimed
    wrong, tracked = _look_alike_pair_run(2, monkeypatch)
    assert not any(wrong) and tracked


def test_a_tracked_robot_that_drove_on_takes_no_jump_odometry_rules_out_at_once(monkeypatch):
    """The same pair with no pause before it: the robot drove on, so it was not carried, and the
    look-alike places lie 5 m and 180° from where odometry puts it (over ``RULED_OUT_SIGMA``): the
    jump's line waits ``DOUBTED_CONFIRMATIONS`` keyframes, so not even a jump believed at its first
    confirmation would claim it."""
    wrong, tracked = _look_alike_pair_run(1, monkeypatch, pause=False)
    assert not any(wrong) and tracked


def test_a_places_own_neighbours_are_no_rivals_in_the_distinctiveness_test():
    """Lowe's ratio compares the best place with the most alike place *elsewhere*: the places first
    seen just before or after it look alike too (a video-rate stream's neighbours 0.4 m apart) and
    must not hide it, while a look-alike elsewhere still does."""
    from aslam.core.tree import RUNNER_UP_GAP

    estimator, _ = run(rectangle_actions(1)[:20], SyntheticWorld(1), synthetic_config())
    tree = estimator._tree
    alike = 0.5 * tree.reference.value
    order = np.arange(2)
    neighbour = np.array([10, 10 + RUNNER_UP_GAP])
    elsewhere = np.array([10, 11 + RUNNER_UP_GAP])
    distances = np.array([alike, 1.05 * alike])
    assert tree._distinctive(np.array([10, 11, 30]), np.append(distances, 1.0), np.arange(3), math.inf) == [
        10
    ]
    assert tree._distinctive(neighbour, distances, order, math.inf) == []  # only a neighbour
    assert tree._distinctive(elsewhere, distances, order, math.inf) == []
    assert tree._distinctive(elsewhere, np.array([alike, 2 * alike]), order, math.inf) == [10]


def _drive_off_the_map(monkeypatch, in_map_steps: float) -> tuple[HypothesisTree, list]:
    """One lap of the rectangle, then the second lap's first side and on, straight past the corner
    where the first lap turned: four steps onto ground the map has no place on."""
    import aslam.core.tree as tree_module

    monkeypatch.setattr(tree_module, "IN_MAP_STEPS", in_map_steps)
    forward = np.array([1.0, 0.0, 0.0])
    estimator, results = run(rectangle_actions(1) + [forward] * 14, SyntheticWorld(1), synthetic_config())
    return estimator._tree, results


def test_driving_off_the_end_of_the_map_is_exploring_not_losing_track(monkeypatch):
    """Losing track (a kidnap, views the track no longer explains) raises the jump priors for a few
    keyframes; stepping past the last mapped place onto new ground does not: nothing mapped lies
    where odometry puts the robot (``IN_MAP_STEPS``), so a look-alike there gets the ordinary prior."""
    tree, results = _drive_off_the_map(monkeypatch, 0.75)
    lap = 34
    assert all(not r.best.is_new_state for r in results[lap + 1 : lap + 11])  # tracked along the side
    assert all(r.best.is_new_state for r in results[lap + 11 :])  # then new ground
    assert tree._lost_at == -math.inf
    tree, _ = _drive_off_the_map(monkeypatch, math.inf)  # every place counts as near: the old rule
    assert tree._lost_at == lap + 11


def _look_alike_while_exploring(
    monkeypatch, stretches: tuple[tuple[int, int, int], ...], pause: bool, **constants: int
) -> tuple[list[bool], bool, float]:
    """On the first lap, all of it new ground, the views at keyframes ``first`` to ``last`` of each
    stretch are views of the places ``shift`` keyframes earlier (``(20, 21, 15)``: the far side,
    heading west, showing places 5 and 6 of the near side, heading east, 5 m away), as a world of
    shared surfaces makes two stretches look alike. With ``pause`` a carry's time passes before the
    first stretch (odometry sees nothing new: the robot may have been carried). ``constants`` patch
    the tree's. Returns whether each keyframe's best claim from 19 to 31 is wrong (over 0.5 m off),
    whether the second lap is tracked at its keyframe 40, and the keyframe the robot last lost track."""
    import aslam.core.tree as tree_module

    for name, value in constants.items():
        monkeypatch.setattr(tree_module, name, value)
    world = SyntheticWorld(3)

    def view_at(i: int, truths: list[np.ndarray], view: np.ndarray) -> np.ndarray:
        for first, last, shift in stretches:
            if first <= i <= last:
                return world.observe(truths[i - shift])
        return view

    pause_at = stretches[0][0] if pause else None
    truths, results, estimator = _drive_with_views(world, 40, view_at, pause_at)
    lost_at = estimator._tree._lost_at
    return _wrong_claims(truths, results, range(19, 32)), not results[40].best.is_new_state, lost_at


def test_a_jump_born_while_exploring_after_a_pause_waits_for_a_second_confirmation(monkeypatch):
    """Exploring (the best leaf a new place) and not lost, the robot knows where it is: a look-alike
    stretch that fits two views in a row is likelier than a kidnap. Such a jump's line stays under
    the ceiling at its first confirmation too, although no other line predicts anything there (the
    rule for a track that still explains the view cannot fire on new ground). So even after a pause,
    when the robot may have been carried."""
    pair = ((20, 21, 15),)
    assert any(_look_alike_while_exploring(monkeypatch, pair, True, JUMP_CONFIRMATIONS=1)[0])
    wrong, tracked, _ = _look_alike_while_exploring(monkeypatch, pair, True, JUMP_CONFIRMATIONS=2)
    assert not any(wrong) and tracked


def test_a_robot_that_drove_on_was_not_carried_so_a_look_alike_stretch_waits_longer(monkeypatch):
    """With no pause before it, a jump born while exploring cannot be a carry: its line stays under
    the ceiling for ``DOUBTED_CONFIRMATIONS`` keyframes, longer than a look-alike stretch of four
    (the figure-8's lobes at aliasing 1.0 fit five). After a pause the same views are believed at
    the second confirmation, as a kidnap's must be to relocalise within issue 9's five keyframes."""
    import aslam.core.tree as tree_module
    from aslam.core.tree import DOUBTED_CONFIRMATIONS, JUMP_CONFIRMATIONS

    four = ((20, 23, 15),)
    assert DOUBTED_CONFIRMATIONS > 4 > JUMP_CONFIRMATIONS
    # As after a revisit: with none yet, a line odometry rules out never settles (the test below).
    monkeypatch.setattr(tree_module.HypothesisTree, "_map_is_one_chain", lambda _self: False)
    wrong, tracked, _ = _look_alike_while_exploring(monkeypatch, four, False)
    assert not any(wrong) and tracked
    assert any(_look_alike_while_exploring(monkeypatch, four, True)[0])  # after a pause: a carry
    # the rule before it (every doubted jump confirmed twice) claimed the stretch
    assert any(_look_alike_while_exploring(monkeypatch, four, False, DOUBTED_CONFIRMATIONS=2)[0])


def test_before_any_revisit_a_look_alike_stretch_odometry_rules_out_is_never_believed(monkeypatch):
    """The map is then one odometry chain: a jump it rules out, with no pause to be carried in,
    never settles, however long the stretch (a rectangle at aliasing 1.0 showed its near half turned
    round for seven keyframes, more than ``DOUBTED_CONFIRMATIONS``: held out, longsteps, seed 84).
    Nor do its new places after the stretch: they stay under the ceiling too, or its history (the
    look-alike's claims) would become the best map and bend it (the second lap went unrecognised).
    Counted as after a revisit, with two confirmations, the same stretch is claimed."""
    import aslam.core.tree as tree_module

    seven = ((20, 26, 15),)
    wrong, tracked, _ = _look_alike_while_exploring(monkeypatch, seven, False)
    assert not any(wrong) and tracked
    monkeypatch.setattr(tree_module.HypothesisTree, "_map_is_one_chain", lambda _self: False)
    assert any(_look_alike_while_exploring(monkeypatch, seven, False, DOUBTED_CONFIRMATIONS=2)[0])


def test_a_stop_on_new_ground_is_not_taken_for_a_carry(monkeypatch):
    """A pause that begins while the robot explores (a stop on new ground) does not lift the jump
    prior: the look-alike stretch after it is no map the robot was carried to, and the second lap
    is tracked. Counted as a possible carry there, the stretch's jump was believed and bent the
    map so that the second lap went unrecognised (held out: a stop on the figure-8, seed 71)."""
    three = ((24, 26, 15),)
    wrong, tracked, _ = _look_alike_while_exploring(monkeypatch, three, True)
    assert not any(wrong) and tracked


def test_the_end_of_a_look_alike_line_that_never_settled_is_no_loss_of_track(monkeypatch):
    """A doubted line that ends within ``lost_window`` keyframes of settling was a look-alike, so
    the robot never was on the map it named: its end raises no jump prior (on the figure-8 at
    aliasing 1.0, seed 35, a second look-alike jump born just after such an end was believed at its
    first confirmation). Here the four-keyframe stretch is believed (two confirmations) and ends."""
    import aslam.core.tree as tree_module

    four = ((20, 23, 15),)
    monkeypatch.setattr(tree_module.HypothesisTree, "_map_is_one_chain", lambda _self: False)
    wrong, _, lost_at = _look_alike_while_exploring(monkeypatch, four, False, DOUBTED_CONFIRMATIONS=2)
    assert any(wrong) and lost_at == -math.inf
    monkeypatch.setattr(tree_module.HypothesisTree, "_unsettled", lambda *_: False)
    assert _look_alike_while_exploring(monkeypatch, four, False, DOUBTED_CONFIRMATIONS=2)[2] == 24


def test_the_index_is_searched_only_where_the_track_does_not_explain_the_view(monkeypatch):
    """A revisit whose predicted place fits the view well (under ``WELL_EXPLAINED`` × the new-place
    reference) is no occasion to look elsewhere: the index, the part of a step that grows with the
    map, is not searched there. Where the prediction fails (a kidnap) it is, and the robot relocalises."""
    from aslam.core.place_index import PlaceIndex

    searched: list[int] = []  # the keyframes at which the index was searched
    current = [0]
    search, add_keyframe = PlaceIndex.search, HypothesisTree.add_keyframe

    def counting(self, observation, keyframes, count):
        searched.append(current[0])
        return search(self, observation, keyframes, count)

    def stepping(self, action, observation, *clocks):
        current[0] = len(self.views)
        return add_keyframe(self, action, observation, *clocks)

    monkeypatch.setattr(PlaceIndex, "search", counting)
    monkeypatch.setattr(HypothesisTree, "add_keyframe", stepping)
    _, results = run(rectangle_actions(2), SyntheticWorld(1, noise=0.02), synthetic_config())
    lap = 34
    revisits = [k for k in range(lap + 1, len(results)) if not results[k].best.is_new_state]
    assert len(revisits) > 25
    assert len(set(revisits) & set(searched)) < len(revisits) // 2
    searched.clear()
    delay, _ = _kidnap(synthetic_config())
    assert delay is not None and delay <= 3
    assert set(range(34 + 5, 34 + 5 + delay + 1)) <= set(searched)  # from the carry until relocalised


def test_the_views_held_follow_the_places_not_the_keyframes():
    """A keyframe committed as a revisit is no place in any hypothesis: its view is let go. Four
    laps hold about one lap of views (the places, and the keyframes still uncommitted), and every
    place still has its first visit's view."""
    estimator, results = run(rectangle_actions(4), SyntheticWorld(1, noise=0.02), synthetic_config())
    tree = estimator._tree
    result = estimator.result()
    assert len(results) > 130 and len(result.states) < 40
    assert tree.views.rows <= len(result.states) + tree.stats().max_uncommitted + 1
    places = np.array([state.id for state in result.states])
    assert estimator.place_views(result.states).shape == (len(places), tree.model.length)
    revisit = next(k for k, state in enumerate(tree.committed_state_of_keyframe.view) if state != k)
    with pytest.raises(KeyError, match="no view is kept"):
        tree.views[revisit]


@given(st.lists(st.booleans(), min_size=1, max_size=60), st.integers(0, 2**32 - 1))
def test_keyframe_views_give_back_what_was_stored_whatever_was_released(release, seed):
    """Released rows are reused for later keyframes; a kept keyframe's view never changes."""
    rng = np.random.default_rng(seed)
    views = KeyframeViews(4)
    stored = {}
    for keyframe, let_go in enumerate(release):
        view = rng.random(4).astype(np.float32)
        assert views.append(view) == keyframe
        stored[keyframe] = view
        if let_go and keyframe > 0:
            gone = int(rng.integers(0, keyframe))
            views.release(gone)
            stored.pop(gone, None)
    for keyframe, view in stored.items():
        assert np.array_equal(views[keyframe], view)
    assert views.rows == len(stored)
    if stored:
        kept = np.array(sorted(stored))
        assert np.array_equal(views[kept], np.stack([stored[k] for k in kept.tolist()]))
