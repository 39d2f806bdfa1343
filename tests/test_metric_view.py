"""The metric view: GTSAM pose graph of the best hypothesis, scored with evo.

Synthetic loops (seeded odometry noise drawn from the motion model itself) check the optimiser's
behaviour exactly; one rendered recording checks the whole chain record → estimate → embed → score.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from aslam.app.metric_view import (
    EmbedOptions,
    Kernel,
    RevisitTolerance,
    assignment_from_states,
    check_assignment,
    embed,
    score,
    score_trajectory,
)
from aslam.cli.app import main
from aslam.core import se2
from aslam.core.config import MotionNoise
from aslam.core.motion import action_covariance

NOISE = MotionNoise(fraction=0.05)
# A 6 m × 4 m rectangle, 1 m steps, turning 90° left at the corners: 20 keyframes per lap.
LAP_COMMANDS = (
    [(1.0, 0.0, 0.0)] * 5 + [(1.0, 0.0, math.pi / 2)] + [(1.0, 0.0, 0.0)] * 3 + [(1.0, 0.0, math.pi / 2)]
) * 2
LAP = len(LAP_COMMANDS)


def loop(laps: int, seed: int, noise: MotionNoise = NOISE):
    """True poses, noisy odometry actions and the true assignment of a rectangle driven ``laps`` times."""
    rng = np.random.default_rng(seed)
    commands = [np.array(c) for c in LAP_COMMANDS * laps]
    truth = [np.zeros(3)]
    actions = [np.zeros(3)]
    for command in commands:
        truth.append(se2.compose(truth[-1], command))
        error = rng.multivariate_normal(np.zeros(3), action_covariance(command, noise))
        actions.append(se2.compose(command, error))
    n = len(truth)
    assignment = np.array([k % LAP for k in range(n)])
    return np.array(truth), np.array(actions), assignment, np.arange(n) * 1_000_000_000


def ape(poses: np.ndarray, truth: np.ndarray) -> float:
    """RMSE of position in the frame of keyframe 0 (both start at the origin): no alignment needed."""
    return float(np.sqrt(((poses[:, :2] - truth[:, :2]) ** 2).sum(axis=1).mean()))


OPTIONS = EmbedOptions(noise=NOISE)


def test_closures_pull_a_drifted_loop_back():
    truth, actions, assignment, _ = loop(3, seed=1)
    embedding = embed(actions, assignment, OPTIONS)
    assert embedding.keyframes == len(truth) == 3 * LAP + 1
    assert len(embedding.closures) == 2 * LAP + 1
    assert (embedding.closures[:, 0] == assignment[embedding.closures[:, 1]]).all()
    assert np.allclose(embedding.poses[0], 0.0, atol=1e-6)  # the view's frame is keyframe 0's
    np.testing.assert_allclose(embedding.odometry, se2.dead_reckoning(actions))
    drift, optimised = ape(embedding.odometry, truth), ape(embedding.poses, truth)
    assert drift > 0.5  # odometry alone has drifted
    assert optimised < 0.3 * drift
    assert embedding.closure_sigmas.max() < 3.0  # every closure agrees with the solution


def test_without_closures_the_embedding_is_dead_reckoning():
    _, actions, _, _ = loop(1, seed=2)
    embedding = embed(actions, np.arange(len(actions)), OPTIONS)
    assert len(embedding.closures) == 0
    np.testing.assert_allclose(embedding.poses, embedding.odometry, atol=1e-6)


def test_each_iteration_is_reported_and_an_interrupt_lands_between_them():
    """GTSAM holds the interpreter while it optimises: the reports are where a display moves and
    Ctrl-C lands. Reporting changes no figure."""
    _, actions, assignment, _ = loop(3, seed=5)
    quiet = embed(actions, assignment, OPTIONS)
    reported: list[int] = []
    watched = embed(actions, assignment, OPTIONS, on_iteration=reported.append)
    assert reported == list(range(1, quiet.iterations + 1)) and quiet.iterations >= 2
    assert watched.poses.tobytes() == quiet.poses.tobytes()

    def interrupt(iteration: int) -> None:
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        embed(actions, assignment, OPTIONS, on_iteration=interrupt)


@pytest.mark.parametrize("seed", [3, 4])
def test_one_wrong_closure_does_not_fold_the_map(seed: int):
    truth, actions, assignment, _ = loop(3, seed=seed)
    right = embed(actions, assignment, OPTIONS)
    wrong_assignment = assignment.copy()
    wrong = LAP + 7  # second lap, along the far side of the rectangle...
    wrong_assignment[wrong] = 16  # ...claimed to be a place on the near side, about 3.6 m away
    assert np.hypot(*(truth[wrong, :2] - truth[16, :2])) > 3.0
    robust = embed(actions, wrong_assignment, OPTIONS)
    believed = embed(actions, wrong_assignment, EmbedOptions(noise=NOISE, kernel=Kernel.GAUSSIAN))
    # Without a kernel the wrong closure drags the map (the test would catch a kernel that did nothing).
    assert ape(believed.poses, truth) > ape(right.poses, truth) + 0.1
    # With the default Cauchy kernel the map is as good as without the wrong closure...
    assert ape(robust.poses, truth) < ape(right.poses, truth) + 0.02
    # ...and the wrong closure stands out, far beyond every other.
    index = int(np.flatnonzero(robust.closures[:, 1] == wrong)[0])
    others = np.delete(robust.closure_sigmas, index)
    assert robust.closure_sigmas[index] > 5.0 > 2 * others.max()


def test_both_kernels_resist_a_wrong_closure_that_plain_least_squares_believes():
    truth, actions, assignment, _ = loop(3, seed=3)
    right = ape(embed(actions, assignment, OPTIONS).poses, truth)
    wrong_assignment = assignment.copy()
    wrong_assignment[LAP + 7] = 16
    errors = {
        kernel: ape(embed(actions, wrong_assignment, EmbedOptions(noise=NOISE, kernel=kernel)).poses, truth)
        for kernel in Kernel
    }
    assert errors[Kernel.CAUCHY] < right + 0.02
    assert errors[Kernel.HUBER] < right + 0.02
    assert errors[Kernel.GAUSSIAN] > right + 0.5


@settings(max_examples=15, deadline=None, derandomize=True)
@given(seed=st.integers(0, 2**31 - 1), laps=st.integers(2, 4))
def test_closing_loops_never_makes_the_map_worse_than_odometry(seed: int, laps: int):
    truth, actions, assignment, _ = loop(laps, seed=seed)
    embedding = embed(actions, assignment, OPTIONS)
    assert ape(embedding.poses, truth) <= ape(embedding.odometry, truth) + 1e-9
    # Every revisit ends near its place: the closures hold at the solution.
    gaps = se2.between(embedding.poses[embedding.closures[:, 0]], embedding.poses[embedding.closures[:, 1]])
    assert np.hypot(gaps[:, 0], gaps[:, 1]).max() < 0.5


@settings(max_examples=50, deadline=None)
@given(st.lists(st.integers(0, 30), min_size=1, max_size=30))
def test_check_assignment_accepts_exactly_first_visit_maps(draws: list[int]):
    # Build a valid map: each keyframe is new or revisits an earlier *first* visit.
    assignment: list[int] = []
    for k, draw in enumerate(draws):
        firsts = [s for i, s in enumerate(assignment) if s == i]
        assignment.append(k if k == 0 or draw % 3 == 0 else firsts[draw % len(firsts)])
    valid = np.array(assignment)
    assert check_assignment(valid) == []
    revisits = np.flatnonzero(valid != np.arange(len(valid)))
    if len(revisits):
        broken = valid.copy()
        broken[revisits[0]] = revisits[0] + 1  # a state from the future
        assert check_assignment(broken)


def test_bad_inputs_are_refused():
    _, actions, assignment, _ = loop(2, seed=5)
    with pytest.raises(ValueError, match="shape"):
        embed(actions, assignment[:-1])
    chained = assignment.copy()
    chained[LAP] = LAP - 1  # fine: revisits the first visit of keyframe LAP-1...
    chained[LAP + 1] = LAP  # ...but keyframe LAP is not a first visit any more
    with pytest.raises(ValueError, match="first-visit"):
        embed(actions, chained)
    with pytest.raises(ValueError, match=r"RevisitTolerance\.x_m"):
        RevisitTolerance(x_m=0.0)
    with pytest.raises(ValueError, match="no state"):
        assignment_from_states([(0, [0, 2])], 3)
    with pytest.raises(ValueError, match="states 0 and 1"):
        assignment_from_states([(0, [0, 1]), (1, [1])], 2)


# --- scores (evo) --------------------------------------------------------------------------------


def test_scores_are_invariant_to_where_the_map_is_put():
    truth, actions, _, stamps = loop(2, seed=6)
    odometry = se2.dead_reckoning(actions)
    moved = se2.compose(np.array([3.0, -2.0, 1.0]), odometry)  # the same shape, elsewhere
    a, b = score_trajectory(odometry, truth, stamps), score_trajectory(moved, truth, stamps)
    assert a.ape_m.rmse == pytest.approx(b.ape_m.rmse, abs=1e-9)
    assert a.rpe_m.rmse == pytest.approx(b.rpe_m.rmse, abs=1e-9)
    assert a.ape_m.rmse > 0.1 and a.ape_m.max >= a.ape_m.rmse >= a.ape_m.median * 0.5
    exact = score_trajectory(se2.compose(np.array([1.0, 1.0, 2.0]), truth), truth, stamps)
    assert exact.ape_m.rmse < 1e-9 and exact.rpe_deg.max < 1e-6


def test_rpe_measures_each_step():
    truth, _, _, stamps = loop(1, seed=7)
    bent = truth.copy()
    bent[10:, :2] += [0.0, 0.3]  # one step 0.3 m off sideways, every other step exact
    scores = score_trajectory(bent, truth, stamps)
    assert scores.rpe_m.max == pytest.approx(0.3, abs=1e-9)
    assert scores.rpe_m.median == pytest.approx(0.0, abs=1e-9)


def test_a_straight_run_has_rpe_without_an_alignment():
    """Every true position on one line (a train, a corridor) leaves the rotation about that line
    free, and evo refuses the alignment: APE is None, saying why, while RPE, which no rigid motion
    changes, is scored. Before, every trajectory score of such a run was null."""
    truth = np.column_stack([np.arange(10.0), np.zeros(10), np.zeros(10)])
    stamps = np.arange(10) * 1_000_000_000
    drifted = se2.dead_reckoning(np.tile([1.05, 0.0, 0.01], (10, 1)))
    scores = score_trajectory(drifted, truth, stamps)
    assert scores.ape_m is None and "Umeyama" in (scores.unaligned or "")
    assert scores.rpe_m.max > 0.04 and scores.rpe_deg.max == pytest.approx(0.573, abs=0.01)
    loop_truth, _, _, loop_stamps = loop(1, seed=7)
    looped = score_trajectory(loop_truth, loop_truth, loop_stamps)
    assert looped.ape_m is not None and looped.unaligned is None


def test_keyframes_without_truth_are_not_scored():
    truth, actions, assignment, stamps = loop(2, seed=8)
    truth[[3, 4, 30]] = np.nan
    scores = score(embed(actions, assignment, OPTIONS), truth, stamps)
    assert scores.optimised.keyframes == scores.odometry.keyframes == len(truth) - 3
    assert scores.optimised.ape_m.rmse < scores.odometry.ape_m.rmse
    with pytest.raises(ValueError, match="need 2"):
        score_trajectory(actions, np.full_like(truth, np.nan), stamps)


# --- a rendered recording, end to end ----------------------------------------------------------


@pytest.fixture(scope="module")
def rendered(tmp_path_factory) -> tuple[Path, Path]:
    folder = tmp_path_factory.mktemp("metric")
    recording, estimate = folder / "paper.mcap", folder / "estimate.mcap"
    assert main(["record", "--route", "paper", "--size", "96x72", "--seed", "4", "-o", str(recording)]) == 0
    assert main(["estimate", str(recording), "-o", str(estimate)]) == 0
    return recording, estimate


def test_rendered_paper_route_embeds_within_the_target(rendered):
    recording, estimate = rendered
    from aslam.app.score import score as score_estimate

    report = score_estimate(estimate, recording=recording)
    assert report.embedding is not None and report.metric is not None
    assert len(report.stamps_ns) == 69 and report.embedding.assignment[34] == 0  # lap 2 starts at place 0
    scores = report.metric
    assert report.summary["trajectory"]["ape_m"]["rmse"] == scores.optimised.ape_m.rmse
    assert scores.optimised.ape_m.rmse <= 0.15  # the target
    assert scores.optimised.ape_m.rmse < 0.5 * scores.odometry.ape_m.rmse
    assert scores.optimised.rpe_m.rmse <= scores.odometry.rpe_m.rmse + 0.01


def test_metric_modules_import_no_heavy_library():
    """GTSAM, evo (pandas, scipy) and protobuf load only when an embedding or export is made."""
    import subprocess
    import sys

    code = (
        "import sys\n"
        "import aslam.cli.app, aslam.app.metric_view\n"
        "import aslam.data_formats.trajectory, aslam.data_formats.foxglove\n"
        "heavy = ('gtsam', 'evo', 'pandas', 'scipy', 'matplotlib', 'foxglove_schemas_protobuf',"
        " 'google.protobuf')\n"
        "loaded = [m for m in heavy if m in sys.modules]\n"
        "assert not loaded, loaded\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, capture_output=True)


def test_a_relocalisation_jump_is_no_constraint():
    """After a kidnap the action across the jump is wrong (odometry saw nothing): marked as a jump,
    the closures put the second lap back on the first; trusted, the wrong action wins."""
    lap = [np.array([x, 0.0, 0.0]) for x in range(4)]
    lap += [np.array([3.0, y, np.pi / 2]) for y in range(1, 4)]
    lap += [np.array([x, 3.0, np.pi]) for x in range(2, -1, -1)]
    lap += [np.array([0.0, y, -np.pi / 2]) for y in range(2, 0, -1)]
    truth = np.array(lap + lap)
    actions = np.vstack([np.zeros(3), se2.between(truth[:-1], truth[1:])])
    n = len(lap)
    actions[n] = np.array([50.0, 0.0, 0.0])  # carried back to the start: odometry says 50 m on
    assignment = np.concatenate([np.arange(n), np.arange(n)])
    jumps = np.zeros(2 * n, bool)
    jumps[n] = True
    options = EmbedOptions(kernel=Kernel.CAUCHY)
    marked = embed(actions, assignment, options, jumps)
    np.testing.assert_allclose(marked.poses[n:, :2], marked.poses[:n, :2], atol=0.05)
    trusted = embed(actions, assignment, options)
    assert np.abs(trusted.poses[n:, :2] - trusted.poses[:n, :2]).max() > 10
