"""The estimator on real rendered recordings (pyrender → MCAP → reader → SLAM → metrics).

Small images keep this fast; the full-size, five-seed figures live in bench/.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from aslam.cli.app import main
from aslam.core.config import EstimatorConfig
from aslam.core.estimator import Estimator
from aslam.core.metrics import evaluate
from aslam.data_formats.recording import Recording

LAP = 34  # the paper route: 30 forward steps and 4 turns per lap


def record(folder: Path, name: str, *extra: str, route: str = "paper") -> Path:
    path = folder / f"{name}.mcap"
    code = main(["record", "--route", route, "--size", "96x72", "-o", str(path), *extra])
    assert code == 0
    return path


def estimate(path: Path, config: EstimatorConfig):
    estimator = Estimator(config)
    steps, truth = [], []
    samples = Recording(path).samples()
    for sample, action in estimator.keyframer.keyframes(samples, lambda sample: sample.odometry_pose):
        observation = estimator.observation_model.describe(sample.image.decode_gray())
        result = estimator.add_keyframe(sample.stamp_ns, action, observation)
        steps.append((result.keyframe, result.hypotheses))
        truth.append(sample.ground_truth_pose)
    return estimator, evaluate(steps, np.array(truth))


@pytest.fixture(scope="module")
def recordings(tmp_path_factory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("rendered")
    return {
        "paper": record(folder, "paper", "--seed", "4"),
        "aliased": record(folder, "aliased", "--seed", "5", "--aliasing", "0.5"),
        "off-pose": record(folder, "off-pose", "--seed", "41", "--jitter-m", "0.15", "--jitter-deg", "4"),
    }


def test_paper_route_relocalises_at_the_start_of_the_second_lap(recordings):
    estimator, evaluation = estimate(recordings["paper"], EstimatorConfig())
    assert evaluation.keyframes == 2 * LAP + 1
    assert evaluation.true_revisit[LAP:].all() and not evaluation.true_revisit[:LAP].any()
    assert evaluation.first_delay is not None and evaluation.first_delay <= 2
    assert evaluation.precision == 1.0
    assert evaluation.recall >= 0.85
    assert not evaluation.claims[:LAP].any()  # nothing claimed on the first lap
    result = estimator.result()
    assert LAP - 2 <= len(result.states) <= LAP + 4  # lap 2 reused lap 1's places
    assert max(link.count for link in result.links) >= 2


def test_aliased_textures_keep_precision(recordings):
    _, evaluation = estimate(recordings["aliased"], EstimatorConfig())
    assert evaluation.precision is not None and evaluation.precision >= 0.98
    assert evaluation.recall >= 0.8
    assert evaluation.hypothesis_counts.max() <= EstimatorConfig().max_hypotheses


def test_paper_faithful_is_the_papers_estimator_on_the_same_recording(recordings):
    config = EstimatorConfig.paper_faithful()
    estimator, evaluation = estimate(recordings["paper"], config)
    assert estimator.observation_model.length == config.histogram_bins  # one global histogram
    assert evaluation.precision is not None and evaluation.precision >= 0.9
    assert evaluation.recall >= 0.8


def test_off_pose_revisits_are_better_recognised_than_by_the_previous_defaults(recordings):
    """Revisits 0.15 m / 4° off the first visit (seed 41, as in issue 9): the thumbnail model and the
    online reference beat the calibrated histogram on the same recording, on the precision–recall
    curve and in recall; a wrong claim of theirs names the right place of the route from under 1 m
    (beyond the 0.5 m a claim is right within: what no view comparison tells, docs/estimator.md).
    Precision alone is one claim of 30 either way (0.93 and 0.91 with the view's four phases)."""
    before = EstimatorConfig(
        observation_model="histogram",
        new_state_reference="fixed",
        new_state_coverage=0.0,
        relocalisation_prior=0.0,
        appearance_veto=0.0,
        place_radius_m=0.2,
        place_heading_deg=10.0,
    )
    _, old = estimate(recordings["off-pose"], before)
    _, new = estimate(recordings["off-pose"], EstimatorConfig())
    print(f"before P {old.precision} R {old.recall} AUC {old.pr_curve().auc}")
    print(f"after  P {new.precision} R {new.recall} AUC {new.pr_curve().auc}")
    assert new.pr_curve().auc > old.pr_curve().auc and new.recall > old.recall >= 0.7
    assert (np.hypot(*new.best_error[new.wrong, :2].T) < 1.0).all()


def _scored(recording: Path, folder: Path):
    """The estimate of ``recording`` as ``aslam estimate`` makes it (the pipeline, its still clock
    included), scored as ``aslam report`` scores it."""
    from aslam.app.estimate import estimate as run_estimate
    from aslam.app.score import score

    out = folder / f"{recording.stem}-estimate.mcap"
    run_estimate(recording, out, EstimatorConfig(), timing=False, reader_process=False)
    return score(out, recording=recording)


def test_a_carry_relocalises_at_the_next_keyframe(tmp_path):
    """Rendered and read back through the pipeline: a robot carried back half a lap (the recorder's
    kidnap: odometry holds for the carry's second, a pause) names a right place at the keyframe
    after the carry's and nothing wrong after it. (A stop is no carry: ``test_robust_matrix``.)"""
    from aslam.recorder import routes

    route = routes.kidnapped(routes.preset("paper").repeated(2), 44, 20)
    route_file = tmp_path / "carried.json"
    route_file.write_text(route.to_json())
    carried = record(tmp_path, "carried", "--seed", "4", "--laps", "1", route=str(route_file))
    report = _scored(carried, tmp_path)
    evaluation = report.evaluation
    assert report.true_poses is not None
    jumps = np.hypot(*np.diff(report.true_poses[:, :2], axis=0).T)
    carry = int(np.argmax(jumps)) + 1  # the first keyframe after the carry
    assert jumps[carry - 1] > 3.0 and not evaluation.wrong[carry:].any()
    assert evaluation.correct[
        carry : carry + 2
    ].any()  # at the next keyframe (after 4 before a pause counted)


def test_a_look_alike_stretch_before_any_revisit_is_never_believed(tmp_path):
    """A rectangle at aliasing 1.0 whose far half looks like its near half turned round (seed 84 of
    the held-out matrix): on the first lap, before any revisit, a jump odometry rules out fitted seven
    keyframes in a row, outlasted its five confirmations, and merged the second lap into the wrong
    half (precision 0.10). With no revisit yet the map is one odometry chain: such a jump never settles."""
    route = Path(__file__).resolve().parents[1] / "bench" / "routes" / "longsteps.json"
    symmetric = record(
        tmp_path, "symmetric", "--seed", "84", "--laps", "2", "--aliasing", "1.0", route=str(route)
    )
    loop_closure = _scored(symmetric, tmp_path).summary["loop_closure"]
    assert loop_closure["precision"] == 1.0 and loop_closure["recall"] >= 0.9


def test_odometry_restarted_from_its_origin_is_no_motion_however_short_it_reads(tmp_path):
    """``aslam record --odometry-reset-at 3``: odometry starts again from its origin three steps on,
    so the reset reads as a 3 m step backwards, short enough to pass for a motion (and too early:
    the jump test waits for five steps). Read through the pipeline, odometry landing on its origin
    says it restarted: the estimate's link across it is no constraint. The same recording without
    the reset has no such link."""
    from aslam.app.estimate import estimate as run_estimate
    from aslam.app.metric_view import JUMP_VARIANCE
    from aslam.data_formats.estimate import read_estimate

    for name, extra, loose in (("restarted", ["--odometry-reset-at", "3"], [(2, 3)]), ("plain", [], [])):
        recording = record(tmp_path, name, "--seed", "4", "--laps", "1", *extra)
        out = tmp_path / f"{name}-estimate.mcap"
        summary = run_estimate(recording, out, EstimatorConfig(), timing=False, reader_process=False)
        assert summary.odometry_restarts == len(loose)
        links = read_estimate(out).graph.links
        assert len(links) == LAP
        unconstrained = [
            (link.from_state, link.to_state) for link in links if link.covariance[0][0] >= JUMP_VARIANCE
        ]
        assert unconstrained == loose


def test_estimate_says_when_odometry_restarted(tmp_path, capsys):
    """The command's last line says the odometry restarted, and how often: a user of a bag learns
    why a link is missing from the map. Without a restart it says nothing of the kind."""
    for name, extra in (("restarted", ["--odometry-reset-at", "40"]), ("plain", [])):
        recording = record(tmp_path, name, "--seed", "4", *extra)
        capsys.readouterr()
        assert main(["estimate", str(recording), "-o", str(tmp_path / f"{name}.est.mcap")]) == 0
        said = capsys.readouterr()
        line = said.err + said.out
        assert ("odometry restarted on its origin 1×, each an odometry jump" in line) == (name == "restarted")
