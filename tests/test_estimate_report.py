"""`aslam estimate` and `aslam report` end to end, through `aslam.cli.app.main`, on a tiny recording.

The recording is written with ``RecordingWriter`` from procedurally drawn images (one texture per
place and heading) along a 3 m × 3 m square driven twice, so it needs no renderer.
"""

from __future__ import annotations

import json
import os
import signal
import time
from pathlib import Path

import pytest
from conftest import one_error_line, square_route
from mcap.reader import make_reader

from aslam.app.gates import parse_condition
from aslam.app.plots import PLOT_NAMES
from aslam.cli.app import main
from aslam.core.errors import InputError
from aslam.core.estimator import Estimator, MapLink, MapState
from aslam.data_formats.estimate import (
    ESTIMATE_METADATA,
    GRAPH_TOPIC,
    KEYFRAME_TOPIC,
    TIMING_METADATA,
    iter_keyframes,
    read_estimate,
)

# --- estimate ------------------------------------------------------------------------------------


def test_estimate_file_decodes_with_mcaps_own_reader(estimate_file: Path, recording: Path):
    keyframes, graphs = [], []
    with estimate_file.open("rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None
        ours = [
            c for c in summary.channels.values() if c.topic.startswith("/aslam/") and "metric" not in c.topic
        ]
        for channel in ours:
            assert channel.message_encoding == "json"
            assert summary.schemas[channel.schema_id].encoding == "jsonschema"
            json.loads(summary.schemas[channel.schema_id].data)  # the schema is JSON
        metric = {c.topic: c.message_encoding for c in summary.channels.values() if c not in ours}
        assert metric == dict.fromkeys(
            ["/aslam/metric/scene", "/aslam/metric/trajectory", "/aslam/metric/odometry", "/aslam/metric/tf"],
            "protobuf",
        )  # Foxglove's schemas (tests/test_foxglove_scene.py decodes them)
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}
        for _schema, channel, message in reader.iter_messages(topics=[KEYFRAME_TOPIC, GRAPH_TOPIC]):
            (keyframes if channel.topic == KEYFRAME_TOPIC else graphs).append(json.loads(message.data))
            if channel.topic == KEYFRAME_TOPIC:
                assert message.log_time == keyframes[-1]["stamp_ns"]
    assert set(metadata) == {ESTIMATE_METADATA, TIMING_METADATA}
    meta = metadata[ESTIMATE_METADATA]
    assert meta["recording_path"] == str(recording.absolute())
    assert int(meta["recording_size_bytes"]) == recording.stat().st_size
    assert len(meta["recording_sha256"]) == 64
    assert json.loads(meta["config"])["step_m"] == 1.0
    assert json.loads(meta["topics"])["image"] == "/camera/image/compressed"
    assert float(metadata[TIMING_METADATA]["keyframes_per_second"]) > 0
    assert len(keyframes) == len(square_route())  # every route pose is a keyframe (1 m or 90°)
    assert [k["index"] for k in keyframes] == list(range(len(keyframes)))
    first = keyframes[0]
    assert set(first) == {"index", "stamp_ns", "action", "hypotheses"}
    assert set(first["action"]) == {"x_m", "y_m", "yaw_rad"}
    assert set(first["hypotheses"][0]) == {"id", "parent", "state", "belief", "new_state"}
    for k in keyframes:
        assert abs(sum(h["belief"] for h in k["hypotheses"]) - 1) < 1e-6
    (graph,) = graphs
    assert graph["keyframes"] == len(keyframes)
    assert {"states", "links", "hypotheses", "tree"} <= set(graph)


def test_reader_api_streams_what_was_written(estimate_file: Path):
    info = read_estimate(estimate_file)
    rows = list(iter_keyframes(estimate_file))
    assert len(rows) == info.graph.keyframes
    assert all(isinstance(state, MapState) for state in info.graph.states)
    assert all(isinstance(link, MapLink) and len(link.covariance) == 3 for link in info.graph.links)
    assert info.graph.tree.keyframes == len(rows)
    assert info.timing is not None and info.timing.keyframes == len(rows)
    assert rows[0].hypotheses[0].is_new_state


def test_no_timing_gives_identical_bytes_and_timing_only_changes_metadata(recording: Path, tmp_path: Path):
    a, b, c = tmp_path / "a.mcap", tmp_path / "b.mcap", tmp_path / "c.mcap"
    assert main(["estimate", str(recording), "-o", str(a), "--no-timing"]) == 0
    assert main(["estimate", str(recording), "-o", str(b), "--no-timing"]) == 0
    assert a.read_bytes() == b.read_bytes()
    assert main(["estimate", str(recording), "-o", str(c)]) == 0

    def messages(path: Path) -> list[tuple[str, int, bytes]]:
        with path.open("rb") as f:
            return [(ch.topic, m.log_time, m.data) for _, ch, m in make_reader(f).iter_messages()]

    assert messages(a) == messages(c)
    assert read_estimate(a).timing is None and read_estimate(c).timing is not None


def test_config_file_and_options_precedence(recording: Path, tmp_path: Path):
    config = tmp_path / "c.toml"
    config.write_text('[estimator]\nbeta = 3\nmax_hypotheses = 20\nobservation_model = "thumbnail"\n')
    out = tmp_path / "e.mcap"
    args = ["estimate", str(recording), "-o", str(out), "--config", str(config), "--paper-faithful"]
    assert main([*args, "--max-hypotheses", "10", "--no-timing"]) == 0
    used = read_estimate(out).metadata.config
    assert used["beta"] == 3.0  # file over default
    assert used["max_hypotheses"] == 10  # option over file
    assert used["cells_x"] == 1 and used["cells_y"] == 1  # --paper-faithful base
    assert used["observation_model"] == "thumbnail"  # a word, from the file over --paper-faithful


def test_refuses_to_overwrite_without_force(recording: Path, tmp_path: Path, capsys):
    out = tmp_path / "e.mcap"
    out.write_bytes(b"keep me")
    assert main(["estimate", str(recording), "-o", str(out)]) == 2
    one_error_line(capsys.readouterr().err)
    assert out.read_bytes() == b"keep me"
    assert main(["estimate", str(recording), "-o", str(out), "--force", "--no-timing"]) == 0


def test_interrupted_estimate_leaves_no_file(recording: Path, tmp_path: Path, monkeypatch, capsys):
    calls = {"n": 0}
    original = Estimator.add_keyframe

    def interrupt(self, *args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 5:
            raise KeyboardInterrupt
        return original(self, *args, **kwargs)

    monkeypatch.setattr(Estimator, "add_keyframe", interrupt)
    out = tmp_path / "e.mcap"
    assert main(["estimate", str(recording), "-o", str(out)]) == 130
    assert not out.exists()
    assert os.listdir(tmp_path) == []  # no partial file either
    err = capsys.readouterr().err
    assert "Traceback" not in err
    assert err.strip().endswith("aslam: error: interrupted")


def _native_import() -> None:
    """pybind11 (GTSAM) turns an exception raised while it initialises into ``ImportError:
    initialization failed``."""
    try:
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(1.0)  # the handler raises here, inside the "module's initialisation"
    except KeyboardInterrupt as err:
        raise ImportError("initialization failed") from err
    raise AssertionError("the signal never arrived")


def _swallowing_import() -> None:
    """trimesh imports networkx inside ``except BaseException``: the Ctrl-C is swallowed and the
    next import fails, which the recorder reports as an input error."""
    from aslam.core.errors import InputError

    try:
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(1.0)
    except BaseException:  # what trimesh does
        pass
    raise InputError("cannot load a library: 'Algorithm already exists'")


@pytest.mark.parametrize("library_import", [_native_import, _swallowing_import])
def test_ctrl_c_inside_a_library_import_is_an_interrupt(
    recording: Path, tmp_path: Path, monkeypatch, capsys, library_import
):
    """However a library's import turns a Ctrl-C into an error, the signal arrived: the command
    ends as interrupted (130), not as a bug (70) or bad input (2), and says only that."""
    import aslam.app.metric_view

    monkeypatch.setattr(aslam.app.metric_view, "preload", library_import)
    out = tmp_path / "e.mcap"
    assert main(["estimate", str(recording), "-o", str(out)]) == 130
    assert os.listdir(tmp_path) == []
    err = capsys.readouterr().err
    assert "internal error" not in err and "cannot load" not in err
    assert err.strip().endswith("aslam: error: interrupted")


@pytest.mark.parametrize(
    ("extra", "needle"),
    [
        (["--step-m", "-1"], "step_m"),
        (["--step-m", "abc"], "step-m"),
        (["--max-hypotheses", "0", "--beta", "0"], "beta"),
        (["--odometry-jump-factor", "0.5"], "odometry_jump_factor must be 0 (off) or above 1"),
    ],
)
def test_bad_option_values_are_one_line_exit_2(recording: Path, tmp_path: Path, capsys, extra, needle):
    out = tmp_path / "e.mcap"
    assert main(["estimate", str(recording), "-o", str(out), *extra]) == 2
    err = capsys.readouterr().err
    one_error_line(err)
    assert needle in err
    assert not out.exists()


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ("[estimator]\nstep = 1\nbogus = 2\n", "estimator.step, estimator.bogus"),
        ("step_m = 1\n", "step_m"),
        ("[estimator\nstep_m = 1\n", "not valid TOML"),
        ("[estimator]\nstep_m = " + "1" * 5000 + "\n", "a number of more than 4,300 digits"),
        ('[estimator]\nstep_m = "far"\n', "step_m must be a number"),
        ("[estimator]\nobservation_model = 5\n", "observation_model must be a string"),
        ('[estimator]\nobservation_model = "nope"\n', "observation_model must be 'histogram' or"),
        ("[estimator]\nstep_m = -1.0\nbeta = 0\n", "beta must be a number in [0.001, 50]"),
        # an integer beyond any float: float() raised OverflowError, exit 70
        ("[estimator]\nstep_m = 1" + "0" * 400 + "\n", "step_m must be a number a float can hold"),
        (
            '[estimator]\nobservation_model = "histogram"\nhistogram_bins = 15\n',
            "histogram_bins must be even",
        ),
    ],
)
def test_bad_config_files_are_one_line_exit_2(recording: Path, tmp_path: Path, capsys, text, needle):
    config = tmp_path / "c.toml"
    config.write_text(text)
    assert main(["estimate", str(recording), "-o", str(tmp_path / "e.mcap"), "--config", str(config)]) == 2
    err = capsys.readouterr().err
    one_error_line(err)
    assert needle in err


def test_a_config_file_is_judged_on_its_own_values_and_read_once(recording: Path, tmp_path: Path, capsys):
    """An option's bad value was blamed on the file (``--config b.toml --step-m 0``: "b.toml: …
    step_m", which b.toml does not set); the file's bad value was hidden by an option setting the
    same key; a second ``--config`` replaced the first in silence."""
    good, bad = tmp_path / "good.toml", tmp_path / "bad.toml"
    good.write_text("[estimator]\nturn_deg = 45\n")
    bad.write_text("[estimator]\nstep_m = 0\n")
    out = ["-o", str(tmp_path / "e.mcap")]
    assert main(["estimate", str(recording), *out, "--config", str(good), "--step-m", "0"]) == 2
    err = one_error_line(capsys.readouterr().err)
    assert err.startswith("aslam: error: bad estimator configuration: step_m") and str(good) not in err
    assert main(["estimate", str(recording), *out, "--config", str(bad), "--step-m", "1"]) == 2
    assert one_error_line(capsys.readouterr().err).startswith(
        f"aslam: error: {bad}: bad estimator configuration"
    )
    assert main(["estimate", str(recording), *out, "--config", str(good), "--config", str(bad)]) == 2
    assert "--config given 2 times" in one_error_line(capsys.readouterr().err)
    assert not (tmp_path / "e.mcap").exists()


def test_histogram_settings_bind_only_the_histogram_model():
    """``--histogram-bins 15`` was refused (must be even) with the thumbnail model, which reads no
    histogram; the rules hold for the histogram model, and --help now says them."""
    from aslam.core.config import EstimatorConfig
    from aslam.core.errors import ConfigError

    assert EstimatorConfig(histogram_bins=15, cells_x=32, cells_y=2).histogram_bins == 15
    with pytest.raises(ConfigError, match="histogram_bins must be even"):
        EstimatorConfig(observation_model="histogram", histogram_bins=15)
    with pytest.raises(ConfigError, match="at most 16384"):
        EstimatorConfig(observation_model="histogram", histogram_bins=360, cells_x=32, cells_y=2)


def test_a_config_files_problems_are_reported_together(recording: Path, tmp_path: Path, capsys):
    """An unknown key or a wrong type does not hide another key's value out of range."""
    config = tmp_path / "c.toml"
    config.write_text('[estimator]\nbogus = 1\nbeta = "x"\nmax_hypotheses = 0\nthumbnail_beta = -2\n')
    assert main(["estimate", str(recording), "-o", str(tmp_path / "e.mcap"), "--config", str(config)]) == 2
    err = capsys.readouterr().err
    one_error_line(err)
    assert err.startswith(f"aslam: error: {config}: bad estimator configuration: ")
    for needle in [
        "unknown key estimator.bogus",
        'beta must be a number, got "x"',
        "max_hypotheses must be a whole number in [1, 10000], got 0",
        "thumbnail_beta must be a number in [0.001, 50], got -2.0",
    ]:
        assert needle in err


def test_bad_recordings_are_one_line_exit_2(tmp_path: Path, capsys):
    text = tmp_path / "notes.mcap"
    text.write_text("not an mcap file\n")
    for path in (text, tmp_path / "missing.mcap"):
        assert main(["estimate", str(path), "-o", str(tmp_path / "e.mcap")]) == 2
        err = capsys.readouterr().err
        one_error_line(err)
        assert str(path) in err
    assert main(["report", str(text)]) == 2
    one_error_line(capsys.readouterr().err)


def test_estimate_rejects_a_recording_as_report_input(recording: Path, capsys):
    assert main(["report", str(recording)]) == 2
    err = capsys.readouterr().err
    one_error_line(err)
    assert "not an aslam estimate" in err


# --- report --------------------------------------------------------------------------------------


def _check_summary(summary: dict) -> None:
    assert isinstance(summary["keyframes"], int)
    assert isinstance(summary["states"], int) and isinstance(summary["links"], int)
    h = summary["hypotheses"]
    assert isinstance(h["max"], int) and isinstance(h["mean"], float) and isinstance(h["final"], int)
    r = summary["relocalisation"]
    assert isinstance(r["episodes"], int) if summary["ground_truth"] else r["episodes"] is None
    assert r["first_delay_keyframes"] is None or isinstance(r["first_delay_keyframes"], int)
    assert r["mean_delay_keyframes"] is None or isinstance(r["mean_delay_keyframes"], float)
    lc = summary["loop_closure"]
    assert set(lc) >= {"claims", "correct", "ground_truth_revisits", "precision", "recall"}
    assert isinstance(lc["claims"], int)
    for kind in ("best", "weighted"):
        for axis in ("x_m", "y_m", "heading_deg"):
            assert set(summary["error"][kind][axis]) == {"mean", "median", "max"}
    assert "keyframes_per_second" in summary["timing"]


def test_report_outputs(estimate_file: Path, tmp_path: Path, capsys):
    summary_path, graph_path, plots = tmp_path / "s.json", tmp_path / "g.json", tmp_path / "plots"
    args = ["report", str(estimate_file), "--json", str(summary_path), "--graph", str(graph_path)]
    assert main([*args, "--plots", str(plots)]) == 0
    out = capsys.readouterr().out
    assert "keyframes" in out and "Revisit errors" in out
    summary = json.loads(summary_path.read_text())
    _check_summary(summary)
    assert summary["keyframes"] == len(square_route())
    assert summary["ground_truth"] is True
    assert isinstance(summary["loop_closure"]["ground_truth_revisits"], int)
    assert summary["loop_closure"]["ground_truth_revisits"] > 0
    assert isinstance(summary["timing"]["keyframes_per_second"], float)
    graph = json.loads(graph_path.read_text())
    assert graph["keyframes"] == summary["keyframes"] and len(graph["states"]) == summary["states"]
    state = graph["states"][0]
    assert set(state) == {"id", "keyframes", "stamps_ns", "first_visit_truth"}
    assert set(state["first_visit_truth"]) == {"x_m", "y_m", "yaw_rad"}
    assert {"from", "to", "action", "covariance", "count", "loop_closure"} <= set(graph["links"][0])
    names = {"hypotheses.png", "errors.png", "map.png", "pr.png", "trajectory.png"}
    assert {p.name for p in plots.iterdir()} == names
    assert all(p.read_bytes().startswith(b"\x89PNG") for p in plots.iterdir())
    assert not [p for p in tmp_path.rglob(".*partial*")]


def test_plots_are_the_same_bytes_whatever_the_users_matplotlib_settings(estimate_file: Path, tmp_path: Path):
    """The figures are drawn with matplotlib's defaults. A matplotlibrc in MPLCONFIGDIR, or in the
    folder ``report`` runs from (matplotlib reads that one too), changed every figure's bytes."""
    import matplotlib

    args = ["report", str(estimate_file), "-q", "--plots"]
    assert main([*args, str(tmp_path / "plain")]) == 0
    styled = {"font.size": 17, "axes.grid": True, "lines.linewidth": 3, "savefig.facecolor": "0.8"}
    with matplotlib.rc_context(styled):
        assert main([*args, str(tmp_path / "styled")]) == 0
    for plain in sorted((tmp_path / "plain").iterdir()):
        assert plain.read_bytes() == (tmp_path / "styled" / plain.name).read_bytes(), plain.name


def test_report_json_to_stdout_keeps_stdout_pure(estimate_file: Path, capsys):
    assert main(["report", str(estimate_file), "--json", "-"]) == 0
    captured = capsys.readouterr()
    _check_summary(json.loads(captured.out))
    assert "Revisit errors" in captured.err


def test_fail_on_both_ways(estimate_file: Path, capsys):
    n = len(square_route())
    assert main(["report", str(estimate_file), "--fail-on", f"keyframes<{n}", "--fail-on", "states<1"]) == 0
    capsys.readouterr()
    code = main(["report", str(estimate_file), "--fail-on", f"keyframes>={n}", "--fail-on", "links<1"])
    assert code == 1
    err = capsys.readouterr().err
    one_error_line(err)
    assert f"keyframes>={n}" in err and "links<1" not in err


def test_fail_on_takes_the_short_names_of_sweep_pareto(estimate_file: Path, capsys):
    """``final`` is ``hypotheses.final``, as ``sweep --pareto`` reads it; the failure names the key
    in full. A tail several sections share resolves as there (``precision``: the online best's)."""
    assert main(["report", str(estimate_file), "--fail-on", "final<1"]) == 0
    capsys.readouterr()
    assert main(["report", str(estimate_file), "--fail-on", "final>=1"]) == 1
    err = capsys.readouterr().err
    one_error_line(err)
    assert "hypotheses.final>=1 (is 1)" in err
    assert main(["report", str(estimate_file), "--fail-on", "ground_truth==1"]) == 1
    assert "ground_truth==1 (is true)" in capsys.readouterr().err  # as the summary JSON says it
    assert parse_condition("precision<0.99").key == "loop_closure.precision"
    assert parse_condition("committed.precision<0.99").key == "committed.precision"


@pytest.mark.parametrize(
    ("condition", "needle"),
    [
        ("loop_closure.precision", "malformed"),
        ("loop_closure.precision<<0.9", "malformed"),
        ("loop_closure.prec<0.9", "'loop_closure.prec' is not a summary key"),
        ("max<1", "'max' is ambiguous"),
        (
            "precison<0.9",
            "'precison' is not a summary key (did you mean committed.precision or loop_closure.precision?)",
        ),
        ("first_delay<2", "(did you mean relocalisation.first_delay_keyframes?)"),
        ("zzz<2", "'zzz' is not a summary key (known: committed.claims, committed.correct,"),
        ("keyframes>abc", "not a number"),
        ("keyframes<null", "null"),
    ],
)
def test_bad_fail_on_is_exit_2_before_any_work(tmp_path: Path, capsys, condition, needle):
    missing = tmp_path / "missing.mcap"  # never opened: the condition is checked first
    assert main(["report", str(missing), "--fail-on", condition]) == 2
    err = capsys.readouterr().err
    one_error_line(err)
    assert needle in err and str(missing) not in err
    # Every key only where nothing is close: the ambiguous and the mistyped name their candidates.
    assert ("known:" in err) == condition.startswith("zzz")


def test_report_without_the_recording_warns_and_continues(recording: Path, tmp_path: Path, capsys):
    moved = tmp_path / "moved.mcap"
    moved.write_bytes(recording.read_bytes())
    out = tmp_path / "e.mcap"
    assert main(["estimate", str(moved), "-o", str(out), "--no-timing"]) == 0
    moved.unlink()
    capsys.readouterr()
    plots = tmp_path / "plots"
    args = [
        "report",
        str(out),
        "--json",
        "-",
        "--plots",
        str(plots),
        "--fail-on",
        "loop_closure.precision==null",
    ]
    assert main(args) == 1
    captured = capsys.readouterr()
    # Every figure is drawn, saying what it lacks (the precision-recall curve: no ground truth).
    assert {p.name for p in plots.iterdir()} >= {"hypotheses.png", "errors.png", "map.png", "pr.png"}
    summary = json.loads(captured.out)
    _check_summary(summary)
    assert summary["ground_truth"] is False
    assert summary["loop_closure"]["precision"] is None
    # What needs no truth is still counted: the claims, the online best's and the final map's alike;
    # episodes (runs of true revisits) are not measurable.
    assert summary["loop_closure"]["claims"] > 0
    assert summary["committed"]["claims"] > 0 and summary["committed"]["correct"] is None
    assert summary["relocalisation"]["episodes"] is None
    assert summary["timing"]["keyframes_per_second"] is None
    warnings = [line for line in captured.err.splitlines() if line.startswith("aslam: warning:")]
    assert len(warnings) == 1 and "not found" in warnings[0]
    # Null fails an ordering gate: a measurement that was not made never passes.
    assert main(["report", str(out), "--fail-on", "loop_closure.precision<0.9"]) == 1
    # --recording points elsewhere: ground truth again.
    capsys.readouterr()
    assert main(["report", str(out), "--recording", str(recording), "--json", "-"]) == 0
    assert json.loads(capsys.readouterr().out)["ground_truth"] is True


def test_a_recording_without_truth_is_not_named_as_the_source_of_it(estimate_file: Path, tmp_path: Path):
    """``--recording`` naming a recording with no ground truth in it: the report continues without
    ground truth, so neither the Report nor the graph JSON names that file as where the truth came
    from (both did: ``"recording": ".../notes.mcap"`` beside ``"ground_truth": false``)."""
    from conftest import random_frames, write_recording

    from aslam.app.score import score

    without_truth = write_recording(tmp_path / "notes.mcap", random_frames(3), with_ground_truth=False)
    warnings: list[str] = []
    report = score(estimate_file, recording=without_truth, on_warning=warnings.append)
    assert "reporting without ground truth" in warnings[-1]
    assert report.summary["ground_truth"] is False
    assert report.recording_path is None
    assert report.graph_json()["recording"] is None


# --- the application layer and the CLI conventions ------------------------------------------------


def test_app_layer_gives_what_the_cli_prints(recording: Path, tmp_path: Path, capsys):
    from aslam.app.estimate import estimate
    from aslam.app.score import score
    from aslam.core.config import EstimatorConfig

    progress, warnings = [], []
    summary = estimate(
        recording,
        tmp_path / "api.mcap",
        EstimatorConfig(),
        timing=False,
        on_progress=progress.append,
        on_warning=warnings.append,
    )
    assert summary.output == (tmp_path / "api.mcap").absolute() and summary.keyframes > 0
    assert progress[-1].keyframes == summary.keyframes and warnings == []
    # Once the images are all read, the updates say the map is being written, and each iteration
    # of its pose graph moves them (the bar sat at its end for seconds while GTSAM optimised).
    reading = [p for p in progress if not p.finishing]
    assert progress[: len(reading)] == reading and len(progress) > len(reading)
    iterations = [p.pose_graph_iterations for p in progress[len(reading) :]]
    assert iterations == [*range(len(iterations) - 1), 0] and len(iterations) >= 4  # then the file
    iterations.pop()
    assert main(["estimate", str(recording), "-o", str(tmp_path / "cli.mcap"), "--no-timing", "-q"]) == 0
    assert (tmp_path / "api.mcap").read_bytes() == (tmp_path / "cli.mcap").read_bytes()
    stages: list[str] = []
    report = score(tmp_path / "api.mcap", on_stage=stages.append)
    pose_graph = [f"the metric view (GTSAM): iteration {i}" for i in iterations[1:]]
    assert stages[-len(pose_graph) - 1 :] == [*pose_graph, "the trajectories' errors (evo)"]
    assert main(["report", str(tmp_path / "cli.mcap"), "--json", "-", "-q"]) == 0
    assert json.loads(capsys.readouterr().out) == report.summary


def test_quiet_and_verbose(recording: Path, tmp_path: Path, capsys):
    assert main(["estimate", str(recording), "-o", str(tmp_path / "q.mcap"), "--quiet"]) == 0
    captured = capsys.readouterr()
    assert captured.err == "" and captured.out == ""
    assert main(["estimate", str(recording), "-o", str(tmp_path / "v.mcap"), "--verbose"]) == 0
    err = capsys.readouterr().err
    assert "wrote" in err and "configuration:" in err and "SLAM step" in err
    assert main(["estimate", str(recording), "-o", str(tmp_path / "x.mcap"), "-q", "-v"]) == 2
    one_error_line(capsys.readouterr().err)


def test_estimate_names_its_output_as_given(recording: Path, tmp_path: Path, capsys, monkeypatch):
    """As record, import and report do: a relative -o is echoed relative, not made absolute."""
    monkeypatch.chdir(tmp_path)
    assert main(["estimate", str(recording), "-o", "rel.mcap", "--no-timing"]) == 0
    assert capsys.readouterr().err.startswith("wrote rel.mcap (")


def test_the_summary_line_counts_in_the_singular_where_one(tmp_path: Path, capsys):
    """It said "1 keyframes from 1 images, … 1 hypotheses"."""
    from conftest import random_frames, write_recording

    recording = write_recording(tmp_path / "one.mcap", random_frames(1))
    assert main(["estimate", str(recording), "-o", str(tmp_path / "e.mcap"), "--no-timing"]) == 0
    line = capsys.readouterr().err
    assert "(1 keyframe from 1 image, 1 state, 0 links, 1 hypothesis;" in line, line


def test_report_names_the_files_it_wrote_and_obeys_force(estimate_file: Path, tmp_path: Path, capsys):
    graph, summary = tmp_path / "g.json", tmp_path / "s.json"
    args = ["report", str(estimate_file), "--graph", str(graph), "--json", str(summary)]
    assert main(args) == 0
    err = capsys.readouterr().err
    assert f"wrote {graph}" in err and f"wrote {summary}" in err
    assert main(args) == 2  # both exist now
    assert "--force" in one_error_line(capsys.readouterr().err)
    assert main([*args, "--force"]) == 0


def test_report_graph_to_stdout(estimate_file: Path, capsys):
    assert main(["report", str(estimate_file), "--graph", "-"]) == 0
    captured = capsys.readouterr()
    assert json.loads(captured.out)["version"] == 1 and "aslam report" in captured.err


def test_report_writes_no_negative_zero(tmp_path: Path, capsys):
    """The square route mirrored (y and heading negated): its truth has y = −0.0 and headings of
    −0.0, which the graph JSON wrote as ``"y_m": -0.0`` and the trajectory files as ``-0.000e+00``."""
    import math

    import numpy as np
    from conftest import write_square_recording

    recording, estimate = tmp_path / "mirrored.mcap", tmp_path / "mirrored.est.mcap"
    write_square_recording(recording, [pose * np.array([1.0, -1.0, -1.0]) for pose in square_route()])
    assert main(["estimate", str(recording), "-o", str(estimate), "--no-timing"]) == 0
    graph, summary = tmp_path / "g.json", tmp_path / "s.json"
    args = ["report", str(estimate), "--graph", str(graph), "--json", str(summary)]
    assert main([*args, "--trajectory", str(tmp_path / "t.tum")]) == 0
    assert main(["report", str(estimate), "--trajectory", str(tmp_path / "t.kitti")]) == 0
    capsys.readouterr()

    def floats(value):
        if isinstance(value, dict):
            return [f for item in value.values() for f in floats(item)]
        if isinstance(value, list):
            return [f for item in value for f in floats(item)]
        return [value] if isinstance(value, float) else []

    for document in (graph, summary):
        assert not [f for f in floats(json.loads(document.read_text())) if f == 0 and math.copysign(1, f) < 0]
    for path in tmp_path.glob("t.*"):
        values = np.loadtxt(path, ndmin=2)
        assert not np.any((values == 0) & np.signbit(values)), path


@pytest.mark.parametrize("command", ["record", "estimate", "report", "info"])
def test_help_shows_flags_without_a_value_placeholder(command: str, capsys):
    assert main([command, "--help"]) == 0
    out = capsys.readouterr().out
    assert "--quiet" in out and "--verbose" in out
    assert "<bool>" not in out and "BOOLEAN" not in out


def test_completion_can_be_installed(capsys):
    assert main(["--help"]) == 0
    assert "--install-completion" in capsys.readouterr().out


def test_hypothesis_plot_has_whole_number_axes(estimate_file: Path):
    from aslam.app.plots import _hypotheses_figure
    from aslam.app.score import score

    figure = _hypotheses_figure(score(estimate_file).evaluation, "t")
    ticks = figure.axes[0].get_yticks()
    assert len(ticks) and all(float(t).is_integer() for t in ticks)


def _drawn_figures(report, folder: Path, monkeypatch) -> dict:
    from aslam.app import plots

    drawn: dict = {}
    monkeypatch.setattr(plots, "_save", lambda figure, path: drawn.setdefault(path.name, figure))
    plots.write_plots(folder, report)
    return drawn


def test_error_plot_axes_do_not_magnify_rounding(estimate_file: Path, tmp_path: Path, monkeypatch):
    """The square's right claims have errors of 1e-16 m: each axis went to 9e-16 (drawn as large as
    a metre's error, "1e-16" in a corner); it is at least 0 to 0.05 (m, °), and starts at 0."""
    from aslam.app.score import score

    report = score(estimate_file)
    assert report.summary["error"]["best"]["x_m"]["max"] < 1e-9
    errors = _drawn_figures(report, tmp_path, monkeypatch)["errors.png"]
    assert [ax.get_ylim()[0] for ax in errors.axes] == [0, 0, 0]
    assert all(ax.get_ylim()[1] >= 0.05 for ax in errors.axes)


def test_error_plot_of_a_truth_by_index_draws_no_errors(estimate_file: Path, tmp_path: Path, monkeypatch):
    """By index the "errors" are frame numbers (the summary's are null, the table says not measured);
    errors.png drew them in metres and degrees (15 "m" on the Nordland fixture)."""
    from aslam.app.score import score

    report = score(estimate_file, truth_by_index=True)
    errors = _drawn_figures(report, tmp_path, monkeypatch)["errors.png"]
    assert all(len(line.get_xdata()) == 0 for ax in errors.axes for line in ax.lines)
    assert any("not measured" in text.get_text() for text in errors.axes[0].texts)


def test_the_graph_json_gives_no_true_poses_by_index_and_says_so(estimate_file: Path, tmp_path: Path):
    """By index the truth is frame numbers: ``first_visit_truth`` was {"x_m": 3.0, ...} for place 3
    beside ``"ground_truth": true``. And the flag says whether any place's truth is known: a map
    whose recording has gone had every place null and the flag true."""
    from aslam.app.score import score

    graph = score(estimate_file, truth_by_index=True).graph_json()
    assert graph["ground_truth"] is False
    assert all(state["first_visit_truth"] is None for state in graph["states"])
    assert score(estimate_file).graph_json()["ground_truth"] is True


def test_plots_leave_a_notebooks_matplotlib_as_it_was(estimate_file: Path, tmp_path: Path):
    """``write_plots`` from a notebook: its backend (inline, here svg) and its open figures stay;
    ``matplotlib.use("Agg")`` switched the backend, so the notebook's later figures were not shown."""
    import matplotlib
    import matplotlib.pyplot as plt

    from aslam.app.plots import write_plots
    from aslam.app.score import score

    before = matplotlib.get_backend()
    matplotlib.use("svg")
    try:
        mine = plt.figure()
        written = write_plots(tmp_path / "plots", score(estimate_file))
        assert matplotlib.get_backend() == "svg"
        assert plt.get_fignums() == [mine.number]
        plt.close(mine)
    finally:
        matplotlib.use(before)
    assert [path.name for path in written] == list(PLOT_NAMES)
    assert all(path.read_bytes().startswith(b"\x89PNG") for path in written)


def test_plots_from_python_refuse_an_existing_figure_before_drawing_any(estimate_file: Path, tmp_path: Path):
    """``write_plots`` replaced every figure of a folder without a word, while ``export_trajectories``
    and the other ``aslam.app`` functions refuse an existing output unless ``force``
    (architecture.md, "From Python")."""
    from aslam.app.plots import write_plots
    from aslam.app.score import score

    report = score(estimate_file)
    folder = tmp_path / "plots"
    folder.mkdir()
    (folder / "pr.png").write_bytes(b"mine")
    with pytest.raises(InputError, match=r"pr\.png: already exists; refusing to overwrite it"):
        write_plots(folder, report)
    assert [path.name for path in folder.iterdir()] == ["pr.png"]  # nothing drawn before the refusal
    assert (folder / "pr.png").read_bytes() == b"mine"
    written = write_plots(folder, report, force=True)
    assert [path.name for path in written] == list(PLOT_NAMES)
    assert (folder / "pr.png").read_bytes().startswith(b"\x89PNG")


def test_report_trajectory_files_score_the_same_with_evo_ape(estimate_file: Path, tmp_path: Path, capsys):
    import subprocess
    import sys

    tum = tmp_path / "run.tum"
    assert main(["report", str(estimate_file), "--trajectory", str(tum), "--json", "-", "-q"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert {p.name for p in tmp_path.iterdir()} == {"run.tum", "run.odometry.tum", "run.truth.tum"}
    evo_ape = Path(sys.executable).with_name("evo_ape")
    done = subprocess.run(
        [str(evo_ape), "tum", str(tmp_path / "run.truth.tum"), str(tum), "-a"],
        capture_output=True,
        text=True,
        check=True,
    )
    rmse = float(
        next(line.split()[1] for line in done.stdout.splitlines() if line.strip().startswith("rmse"))
    )
    assert rmse == pytest.approx(summary["trajectory"]["ape_m"]["rmse"], abs=1e-5)
    assert summary["trajectory"]["ape_m"]["rmse"] < summary["trajectory"]["odometry_ape_m"]["rmse"]
    assert (
        main(
            [
                "report",
                str(estimate_file),
                "--trajectory",
                str(tmp_path / "k.txt"),
                "--trajectory-format",
                "kitti",
            ]
        )
        == 0
    )
    assert len((tmp_path / "k.txt").read_text().splitlines()) == summary["keyframes"]


@pytest.mark.parametrize("fmt", ["tum", "kitti"])
def test_report_of_one_keyframe_writes_a_trajectory_of_one_pose(tmp_path: Path, capsys, fmt: str):
    """One keyframe is a trajectory still: one pose at the origin (the view's frame), its truth
    beside it, a valid file for evo. It was exit 2 (`fewer than two keyframes`), after the tables."""
    import numpy as np
    from conftest import random_frames, write_recording

    from aslam.data_formats.pose_files import iter_poses

    frames = random_frames(1)
    recording = write_recording(tmp_path / "one.mcap", frames)
    estimate = tmp_path / "one.est.mcap"
    assert main(["estimate", str(recording), "-o", str(estimate), "-q"]) == 0
    run, plots = tmp_path / f"run.{fmt}", tmp_path / "plots"
    outputs = ["--trajectory", str(run), "--json", str(tmp_path / "s.json"), "--plots", str(plots)]
    assert main(["report", str(estimate), *outputs]) == 0
    assert "warning" not in capsys.readouterr().err
    names = ("", ".odometry", ".truth")
    rows = {name: list(iter_poses(tmp_path / f"run{name}.{fmt}", fmt)) for name in names}
    assert [len(r) for r in rows.values()] == [1, 1, 1]
    np.testing.assert_allclose(rows[""][0].pose, [0, 0, 0], atol=1e-9)
    np.testing.assert_allclose(rows[".odometry"][0].pose, [0, 0, 0], atol=1e-9)
    np.testing.assert_allclose(rows[".truth"][0].pose, frames[0][3], atol=1e-9)
    if fmt == "tum":
        assert rows[""][0].stamp_ns == frames[0][0]
    summary = json.loads((tmp_path / "s.json").read_text())
    assert summary["keyframes"] == 1 and summary["trajectory"]["closures"] == 0
    assert summary["trajectory"]["ape_m"]["rmse"] is None  # nothing to align with one pose
    assert (plots / "trajectory.png").exists()


def test_report_of_no_keyframes_writes_the_rest_and_says_what_it_left_out(tmp_path: Path, capsys):
    """An estimate of no keyframes (every image logged too late for the odometry kept, 30 s after
    its stamp) is an empty result, not bad input: no trajectory files and no trajectory figure, each
    with a warning, the rest written, exit 0 (it was exit 2, the summary and graph unwritten)."""
    from conftest import FRAME_NS, T0_NS, ForeignRecording, random_frames

    from aslam.data_formats.images import encode_image

    png = encode_image(random_frames(1)[0][1]).data
    recording = tmp_path / "late.mcap"
    with ForeignRecording(recording) as rec:
        for k in range(300):
            rec.odometry("/odom", T0_NS + k * FRAME_NS, 0.01 * k, 0.0, 0.0)
        for k in range(3):
            rec.compressed_image(
                "/camera/image/compressed", T0_NS + k * FRAME_NS, png, "png", T0_NS + 300 * FRAME_NS
            )
    estimate = tmp_path / "late.est.mcap"
    assert main(["estimate", str(recording), "-o", str(estimate), "-q"]) == 0
    run, plots = tmp_path / "run.tum", tmp_path / "plots"
    outputs = ["--graph", str(tmp_path / "g.json"), "--json", str(tmp_path / "s.json"), "--plots", str(plots)]
    assert main(["report", str(estimate), "--trajectory", str(run), *outputs]) == 0
    err = capsys.readouterr().err
    assert f"aslam: warning: {run}: not written (nor its .odometry and .truth files): the estimate has" in err
    assert f"aslam: warning: {plots / 'trajectory.png'}: not drawn: the estimate has no keyframes" in err
    assert not list(tmp_path.glob("run*"))
    summary = json.loads((tmp_path / "s.json").read_text())
    assert summary["keyframes"] == 0
    assert summary["hypotheses"] == {"max": None, "mean": None, "final": None}  # not 0: not measurable
    assert (tmp_path / "g.json").exists()
    assert sorted(p.name for p in plots.iterdir()) == ["errors.png", "hypotheses.png", "map.png", "pr.png"]
    # An earlier run's files under those names go with --force: a set is one run's (and kept without).
    for stale in (
        *(tmp_path / f"run{name}.tum" for name in ("", ".odometry", ".truth")),
        plots / "trajectory.png",
    ):
        stale.write_bytes(b"an earlier run's")
    assert main(["report", str(estimate), "--trajectory", str(run), *outputs, "-q"]) == 2
    assert (plots / "trajectory.png").exists()
    assert main(["report", str(estimate), "--trajectory", str(run), *outputs, "-q", "--force"]) == 0
    assert not list(tmp_path.glob("run*")) and not (plots / "trajectory.png").exists()


def test_a_forced_report_without_ground_truth_leaves_no_earlier_truth_file(estimate_file, tmp_path, capsys):
    """`--trajectory run.tum --force` over a run that had ground truth: its `run.truth.tum` stayed
    beside the new trajectory, and evo scored the new trajectory against the old truth."""
    from conftest import random_frames, write_recording

    run = tmp_path / "run.tum"
    assert main(["report", str(estimate_file), "--trajectory", str(run), "-q"]) == 0
    assert (tmp_path / "run.truth.tum").exists()
    recording = write_recording(tmp_path / "notes.mcap", random_frames(4), with_ground_truth=False)
    estimate = tmp_path / "notes.est.mcap"
    assert main(["estimate", str(recording), "-o", str(estimate), "-q"]) == 0
    assert main(["report", str(estimate), "--trajectory", str(run), "-q", "--force"]) == 0
    assert sorted(p.name for p in tmp_path.glob("run*")) == ["run.odometry.tum", "run.tum"]
    assert len(run.read_text().splitlines()) == 4  # the new run's keyframes
    from aslam.app.metric_view import export_trajectories  # from Python, as from the command line
    from aslam.app.score import score

    (tmp_path / "api.truth.tum").write_bytes(b"an earlier run's")
    report = score(estimate)
    export_trajectories(tmp_path / "api.tum", report.embedding, report.stamps_ns, report.true_poses)
    assert (tmp_path / "api.truth.tum").exists()  # not forced: only the files it writes are its own
    export_trajectories(
        tmp_path / "api.tum", report.embedding, report.stamps_ns, report.true_poses, force=True
    )
    assert not (tmp_path / "api.truth.tum").exists()


def test_report_refuses_a_trajectory_format_with_no_trajectory_and_a_stream_before_any_work(
    estimate_file: Path, tmp_path: Path, capsys
):
    assert main(["report", str(estimate_file), "--trajectory-format", "kitti"]) == 2
    assert "--trajectory-format needs --trajectory" in one_error_line(capsys.readouterr().err)
    assert main(["report", str(estimate_file), "--trajectory", "/dev/null"]) == 2
    assert "not stdout or a stream" in one_error_line(capsys.readouterr().err)
    assert not Path("/dev/null.odometry").exists()


@pytest.mark.parametrize("kind", ["fifo", "empty", "text", "folder", "estimate"])
def test_report_refuses_a_recording_given_that_is_none(
    estimate_file: Path, tmp_path: Path, capsys, kind: str
):
    """Given by name, ``--recording`` must be one: a FIFO, an empty or a text file, a folder, an
    estimate were a warning and a report without truth, exit 0."""
    given = {"fifo": tmp_path / "f.mcap", "empty": tmp_path / "e.mcap", "text": tmp_path / "t.mcap"}.get(kind)
    if kind == "fifo":
        os.mkfifo(given)
    elif kind == "empty":
        given.write_bytes(b"")
    elif kind == "text":
        given.write_text("not a recording\n")
    elif kind == "folder":
        given = tmp_path
    else:
        given = estimate_file
    assert main(["report", str(estimate_file), "--recording", str(given), "--json", "-"]) == 2
    assert one_error_line(capsys.readouterr().err).startswith(f"aslam: error: {given}: ")


def test_report_refuses_a_recording_given_that_cannot_be_opened(estimate_file: Path, tmp_path: Path, capsys):
    """A file with MCAP's magic and garbage after it passes for a bag until it is opened; that failure
    was a warning and a report without ground truth, exit 0, as for a topic the file lacks (found by
    an API user's audit). No topic of a file that cannot be opened can be read: exit 2."""
    from aslam.app.score import score
    from aslam.data_formats.errors import BagError
    from aslam.data_formats.files import MCAP_MAGIC

    given = tmp_path / "damaged.mcap"
    given.write_bytes(MCAP_MAGIC + bytes(range(256)) * 12)
    assert main(["report", str(estimate_file), "--recording", str(given), "--json", "-", "-q"]) == 2
    assert one_error_line(capsys.readouterr().err).startswith(f"aslam: error: {given}: cannot open the bag: ")
    with pytest.raises(BagError, match="cannot open the bag"):
        score(estimate_file, recording=given)


def test_report_against_another_recording_says_so(estimate_file: Path, tmp_path: Path, capsys):
    """A ground truth from another file is allowed (a bag with the truth beside an imported
    folder), but not silently: a different file is named in a warning."""
    from conftest import write_square_recording

    other = tmp_path / "other.mcap"
    write_square_recording(other, seed=8)
    assert main(["report", str(estimate_file), "--recording", str(other)]) == 0
    assert "is not the recording the estimate was made from" in capsys.readouterr().err


def test_truth_by_index_refuses_a_recording_from_python_too(estimate_file: Path, recording: Path, capsys):
    """By index no recording is read: one given as well was ignored in silence from Python (the
    command line alone refused it), so a script scored by index what it meant to score by poses."""
    from aslam.app.score import score

    with pytest.raises(InputError, match="reads no recording"):
        score(estimate_file, truth_by_index=True, recording=recording)
    with pytest.raises(InputError, match="reads no recording"):
        score(estimate_file, truth_by_index=True, ground_truth_topic="/ground_truth")
    assert main(["report", str(estimate_file), "--truth-by-index", "--recording", str(recording)]) == 2
    assert "reads no recording" in one_error_line(capsys.readouterr().err)


def test_the_python_functions_take_paths_as_strings(recording: Path, tmp_path: Path):
    """A notebook passes ``"run.mcap"``, not ``Path("run.mcap")``: every public function of
    ``aslam.app`` takes either (``write_plots`` took only a ``Path``: ``str / name`` raised)."""
    from aslam.app.config_file import read_config_file
    from aslam.app.estimate import estimate
    from aslam.app.info import describe
    from aslam.app.metric_view import export_trajectories
    from aslam.app.plots import write_plots
    from aslam.app.score import score
    from aslam.core.config import EstimatorConfig

    assert describe(str(recording)).samples > 0
    run = estimate(str(recording), str(tmp_path / "e.mcap"), EstimatorConfig(), timing=False)
    report = score(str(run.output), recording=str(recording))
    assert report.summary["loop_closure"]["precision"] is not None
    written = write_plots(str(tmp_path / "plots"), report)
    assert [path.name for path in written] == list(PLOT_NAMES)
    (tmp_path / "c.toml").write_text("[estimator]\nbeta = 3.0\n")
    assert read_config_file(str(tmp_path / "c.toml")) == ({"beta": 3.0}, [])
    trajectory = str(tmp_path / "t.tum")
    files = export_trajectories(trajectory, report.embedding, report.stamps_ns, report.true_poses)
    assert sorted(path.name for path in files.values()) == ["t.odometry.tum", "t.truth.tum", "t.tum"]
