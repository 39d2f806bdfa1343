"""Multi-session maps (``estimate --map``): a run starts in an earlier run's map with its place in
it unknown, relocalises by appearance, tracks and extends it; ``report`` scores its claims against
the earlier run's places with both runs' ground truth.

The sessions drive the procedurally textured square of ``conftest`` (no renderer): the second
starts elsewhere on the square, with its own image and odometry noise.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
from conftest import one_error_line, square_route, write_square_bag, write_square_recording
from hypothesis import given, settings
from hypothesis import strategies as st
from test_core_tree import carried

from aslam.cli.app import main
from aslam.core.config import EstimatorConfig
from aslam.core.estimator import Estimator, MapLink, MapState, prior_map
from aslam.core.tree import HypothesisTree
from aslam.data_formats.estimate import iter_keyframes, read_estimate, read_place_views

FIRST_LAP = 16  # poses per lap of the square (4 sides × (3 steps + a turn))


def second_session_route(start: int) -> list[np.ndarray]:
    """One lap of the square from pose ``start`` of the first lap, on to where it began."""
    lap = square_route()[: FIRST_LAP + 1]
    return lap[start:] + lap[1 : start + 1]


@pytest.fixture(scope="module")
def sessions(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("sessions")
    first, second = folder / "first.mcap", folder / "second.mcap"
    write_square_recording(first)
    write_square_recording(second, second_session_route(5), seed=11)
    out = {"first": first, "second": second}
    for name, recording in (("first", first), ("second", second)):
        estimate = folder / f"{name}.est.mcap"
        args = ["estimate", str(recording), "-o", str(estimate), "-q", "--no-timing"]
        if name == "second":
            args += ["--map", str(out["first.est"])]
        assert main(args) == 0
        out[f"{name}.est"] = estimate
    return out


def _estimate(recording: Path, output: Path, *options: str) -> None:
    """``aslam estimate RECORDING -o OUTPUT -q OPTIONS…``, which must succeed."""
    assert main(["estimate", str(recording), "-o", str(output), "-q", *options]) == 0


def report_json(estimate: Path, *extra: str, capsys: pytest.CaptureFixture[str]) -> dict:
    capsys.readouterr()
    assert main(["report", str(estimate), "--json", "-", "-q", *extra]) == 0
    return json.loads(capsys.readouterr().out)


def test_the_second_session_relocalises_in_the_first_map_and_extends_it(sessions):
    before = read_estimate(sessions["first.est"]).graph
    after = read_estimate(sessions["second.est"]).graph
    assert after.first_keyframe == before.keyframes
    assert after.keyframes == before.keyframes + len(second_session_route(5))
    keyframes = [k.index for k in iter_keyframes(sessions["second.est"])]
    assert keyframes == list(range(before.keyframes, after.keyframes))
    # The earlier map survives whole: every place with all its visits, every link.
    places = {state.id: state.keyframes for state in after.states}
    for state in before.states:
        assert places[state.id][: len(state.keyframes)] == state.keyframes
    assert {(link.from_state, link.to_state) for link in before.links} <= {
        (link.from_state, link.to_state) for link in after.links
    }
    views = read_place_views(sessions["second.est"])
    assert views.states.tolist() == sorted(places)


def test_progress_counts_this_runs_keyframes_not_the_maps(sessions, tmp_path, monkeypatch):
    """With ``--map`` the keyframes are numbered on from the map's; the progress bar showed that
    number (the map's keyframes plus this run's, and keyframes per second to match)."""
    import aslam.app.estimate as app_estimate

    monkeypatch.setattr(app_estimate, "PROGRESS_INTERVAL_S", -1.0)  # every keyframe
    progress: list[tuple[int, bool]] = []
    summary = app_estimate.estimate(
        sessions["second"],
        tmp_path / "second.est.mcap",
        EstimatorConfig(),
        timing=False,
        prior=sessions["first.est"],
        on_progress=lambda p: progress.append((p.keyframes, p.finishing)),
    )
    run = len(second_session_route(5))
    assert summary.keyframes == run
    assert [k for k, finishing in progress if not finishing] == list(range(1, run + 1))
    assert {k for k, finishing in progress if finishing} == {run}


@pytest.mark.parametrize("scale", [0.0, 0.95])
def test_a_run_that_never_enters_the_map_says_so(sessions, tmp_path, scale):
    """Across seasons without --map-reference-scale a --map run finds nothing, quietly: every
    keyframe a new place. It now says so, with the option to try where it was not given; a run
    that did enter the map says nothing."""
    from conftest import random_frames, write_recording

    from aslam.app.estimate import estimate

    elsewhere = write_recording(tmp_path / "elsewhere.mcap", random_frames(6, seed=3))
    config = EstimatorConfig(map_reference_scale=scale)
    heard: list[str] = []
    estimate(
        elsewhere,
        tmp_path / "e.mcap",
        config,
        timing=False,
        prior=sessions["first.est"],
        on_warning=heard.append,
    )
    assert len(heard) == 1 and "no keyframe was placed in the map of" in heard[0], heard
    assert ("--map-reference-scale" in heard[0]) == (scale == 0)
    heard.clear()
    estimate(
        sessions["second"],
        tmp_path / "s.mcap",
        config,
        timing=False,
        prior=sessions["first.est"],
        on_warning=heard.append,
    )
    assert heard == []


@settings(max_examples=40, deadline=None)
@given(data=st.data())
def test_a_map_with_a_changed_byte_reads_as_written_or_not_at_all(sessions, tmp_path_factory, data):
    """Every byte of every chunk, changed: the map (its graph and place views) reads exactly as
    written or is an EstimateError, never other values (zstd decompressed a damaged chunk to other
    bytes, and ``--map`` ran on them: other claims, exit 0)."""
    from mcap.reader import SeekingReader

    from aslam.data_formats.errors import EstimateError

    path = sessions["first.est"]
    original = path.read_bytes()
    with path.open("rb") as f:
        chunks = SeekingReader(f).get_summary().chunk_indexes  # type: ignore[union-attr]
    chunk = data.draw(st.sampled_from(chunks))
    end = chunk.chunk_start_offset + chunk.chunk_length  # the chunk's (compressed) records close it
    at = data.draw(st.integers(end - chunk.compressed_size, end - 1))
    damaged = bytearray(original)
    damaged[at] ^= data.draw(st.integers(1, 255))
    copy = tmp_path_factory.mktemp("flip") / "map.est.mcap"
    copy.write_bytes(damaged)

    def read(map_file: Path) -> tuple[object, bytes, bytes]:
        views = read_place_views(map_file)
        return read_estimate(map_file).graph, views.states.tobytes(), views.views.tobytes()

    try:
        got = read(copy)
    except EstimateError as err:
        assert str(copy) in str(err)
    else:
        assert got == read(path)


def test_report_scores_the_claims_against_the_first_sessions_places(sessions, capsys):
    summary = report_json(sessions["second.est"], capsys=capsys)
    assert summary["ground_truth"] is True
    closure = summary["loop_closure"]
    # Every keyframe of the second session revisits the first session's square.
    assert closure["ground_truth_revisits"] == summary["keyframes"]
    assert closure["precision"] == 1.0
    assert closure["recall"] >= 0.8
    assert summary["relocalisation"]["first_delay_keyframes"] <= 2


def test_the_graph_json_names_the_first_keyframe_and_the_truth_of_every_place(sessions, tmp_path):
    graph_path = tmp_path / "graph.json"
    assert main(["report", str(sessions["second.est"]), "--graph", str(graph_path), "-q"]) == 0
    graph = json.loads(graph_path.read_text())
    first = read_estimate(sessions["first.est"]).graph.keyframes
    assert graph["first_keyframe"] == first
    assert all(state["first_visit_truth"] is not None for state in graph["states"])


def test_the_map_plot_draws_every_place_of_the_map_where_it_is(sessions, tmp_path, monkeypatch):
    """map.png of a run in a prior map: every place at its first visit's true position (state ids
    are keyframes of the whole map). It drew the places whose ids were below this run's keyframe
    count, each at this run's truth of that index (another place), and none of the others."""
    from aslam.app import plots
    from aslam.app.score import score

    drawn = {}
    monkeypatch.setattr(plots, "_save", lambda figure, path: drawn.setdefault(path.name, figure))
    report = score(sessions["second.est"])
    plots.write_plots(tmp_path, report)
    states = report.estimate.graph.states
    assert report.map_truth is not None and len(states) > len(report.stamps_ns) - 2
    for line in drawn["map.png"].axes[0].lines:  # each place, in id order, at its own first visit
        again = {"place": False, "place visited again": True}.get(str(line.get_label()))
        if again is not None:
            expected = [report.map_truth[s.id][:2] for s in states if (len(s.keyframes) > 1) == again]
            np.testing.assert_allclose(np.column_stack(line.get_data()), np.reshape(expected, (-1, 2)))


def test_the_map_plot_draws_places_whose_first_visit_has_no_truth_at_a_later_visit(
    sessions, tmp_path, monkeypatch
):
    """The first session's recording gone (its truth unknown), map.png drew no place of it, though
    this run revisited them all with its truth known: each is now drawn at its first visit that has
    one, and the title says how many."""
    from aslam.app import plots
    from aslam.app.score import score

    drawn = {}
    monkeypatch.setattr(plots, "_save", lambda figure, path: drawn.setdefault(path.name, figure))
    report = score(sessions["second.est"])
    assert report.map_truth is not None
    first = report.estimate.graph.first_keyframe
    map_truth = report.map_truth.copy()
    map_truth[:first] = np.nan  # as when the first session's recording cannot be read
    report = dataclasses.replace(report, map_truth=map_truth)
    plots.write_plots(tmp_path, report)
    axes = drawn["map.png"].axes[0]
    states = report.estimate.graph.states
    revisited = [s for s in states if s.id < first and any(k >= first for k in s.keyframes)]
    assert revisited
    drawn_at = {
        tuple(np.round(xy, 9))
        for line in axes.lines
        if str(line.get_label()) in ("place", "place visited again")
        for xy in np.column_stack(line.get_data())
    }
    for state in revisited:
        later = min(k for k in state.keyframes if k >= first)
        assert tuple(np.round(report.map_truth[later][:2], 9)) in drawn_at
    assert f"{len(revisited)} at a later visit" in axes.get_title()


def test_without_a_map_the_same_recording_is_a_new_map(sessions, tmp_path, capsys):
    """The control: without --map only the lap's own closing keyframe can be a revisit."""
    alone = tmp_path / "alone.est.mcap"
    assert main(["estimate", str(sessions["second"]), "-o", str(alone), "-q"]) == 0
    assert report_json(alone, capsys=capsys)["loop_closure"]["claims"] <= 1
    with_map = report_json(sessions["second.est"], capsys=capsys)["loop_closure"]
    assert with_map["claims"] >= 0.8 * len(second_session_route(5))


def test_an_estimate_with_a_map_is_byte_identical_on_a_rerun(sessions, tmp_path):
    again = tmp_path / "again.est.mcap"
    args = ["estimate", str(sessions["second"]), "--map", str(sessions["first.est"]), "--no-timing", "-q"]
    assert main([*args, "-o", str(again)]) == 0
    assert again.read_bytes() == sessions["second.est"].read_bytes()


def test_a_chain_of_sessions_reports_with_every_sessions_truth(sessions, tmp_path, capsys):
    third_recording = tmp_path / "third.mcap"
    write_square_recording(third_recording, second_session_route(9), seed=23)
    third = tmp_path / "third.est.mcap"
    args = ["estimate", str(third_recording), "--map", str(sessions["second.est"]), "-o", str(third), "-q"]
    assert main(args) == 0
    summary = report_json(third, capsys=capsys)
    assert summary["ground_truth"] is True
    assert summary["loop_closure"]["precision"] == 1.0


def _chain(folder: Path) -> dict[str, Path]:
    """Three sessions of the square in ``folder``, each in the map of the one before, as estimated
    there: recordings and estimates side by side."""
    folder.mkdir()
    files: dict[str, Path] = {}
    previous = None
    for name, start, seed in (("first", None, 7), ("second", 5, 11), ("third", 9, 23)):
        files[name] = folder / f"{name}.mcap"
        write_square_recording(files[name], None if start is None else second_session_route(start), seed)
        files[f"{name}.est"] = folder / f"{name}.est.mcap"
        args = ["estimate", str(files[name]), "-o", str(files[f"{name}.est"]), "-q", "--no-timing"]
        assert main(args + ([] if previous is None else ["--map", str(previous)])) == 0
        previous = files[f"{name}.est"]
    return files


def _report_and_warnings(estimate: Path, capsys: pytest.CaptureFixture[str]) -> tuple[dict, list[str]]:
    capsys.readouterr()
    assert main(["report", str(estimate), "--json", "-"]) == 0
    captured = capsys.readouterr()
    warnings = [line for line in captured.err.splitlines() if line.startswith("aslam:")]
    return json.loads(captured.out), warnings


def test_a_chain_moved_to_another_folder_is_scored_as_before(tmp_path, capsys):
    """The estimates name their maps and recordings by absolute path; a folder of sessions copied
    elsewhere (another machine) is found beside the estimate, and scored as where it was made."""
    files = _chain(tmp_path / "made")
    before, warnings = _report_and_warnings(files["third.est"], capsys)
    assert warnings == [] and before["loop_closure"]["precision"] == 1.0
    (tmp_path / "made").rename(tmp_path / "moved")
    after, warnings = _report_and_warnings(tmp_path / "moved" / "third.est.mcap", capsys)
    assert warnings == []
    assert after == before


@pytest.fixture(scope="module")
def mixed(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Sessions of the square with their truth on other topics: our recordings (the recorder's
    ``/ground_truth/pose``) and bags (``/ground_truth``) estimated without naming it, each in the
    other's map."""
    folder = tmp_path_factory.mktemp("mixed")
    files = {"recording": folder / "first.mcap", "bag": folder / "first_bag.mcap"}
    write_square_recording(files["recording"])
    write_square_bag(files["bag"], square_route(), 7, ground_truth_topic="/ground_truth")
    files["second recording"] = folder / "second.mcap"
    files["second bag"] = folder / "second_bag.mcap"
    write_square_recording(files["second recording"], second_session_route(5), seed=11)
    write_square_bag(files["second bag"], second_session_route(5), 11, ground_truth_topic="/ground_truth")
    for name in ("recording", "bag"):
        files[f"{name}.est"] = folder / f"{name}.est.mcap"
        assert main(["estimate", str(files[name]), "-o", str(files[f"{name}.est"]), "-q"]) == 0
    for run, the_map in (("bag", "recording"), ("recording", "bag")):
        files[f"{run} in {the_map}"] = out = folder / f"{run}_in_{the_map}.est.mcap"
        _estimate(files[f"second {run}"], out, "--map", str(files[f"{the_map}.est"]))
    return files


@pytest.mark.parametrize("chain", ["bag in recording", "recording in bag"])
def test_sessions_with_their_truth_on_other_topics_are_all_scored(mixed, chain, capsys):
    """A bag's truth topic named at report time is read where a session has it, every other session
    on the topic it was estimated with. It was read in every session: a recording's map session was
    unscored (17 claims unjudged, a warning), and a recording run in a bag's map an error, exit 2."""
    capsys.readouterr()
    args = ["report", str(mixed[chain]), "--json", "-", "--ground-truth-topic", "/ground_truth"]
    assert main(args) == 0
    captured = capsys.readouterr()
    assert "warning" not in captured.err
    closure = json.loads(captured.out)["loop_closure"]
    assert closure["claims"] >= 0.8 * len(second_session_route(5))
    assert closure["unjudged_claims"] == 0 and closure["precision"] == 1.0


@pytest.mark.parametrize(
    ("chain", "words"),
    [
        ("bag in recording", "no ground-truth topic '/typo'; on its own topic: no ground-truth topic named"),
        ("recording in bag", "no ground-truth topic '/typo' in it or in any session of its map"),
    ],
)
def test_a_truth_topic_no_session_has_is_an_error(mixed, chain, words, tmp_path, capsys):
    """One line naming this run's recording, exit 2: a typo, not a report without truth."""
    estimate = mixed[chain]
    run = "second bag" if chain == "bag in recording" else "second recording"
    if chain == "recording in bag":  # its map estimated with its truth topic: no warning about it
        the_map = tmp_path / "bag.est.mcap"
        _estimate(mixed["bag"], the_map, "--ground-truth-topic", "/ground_truth")
        estimate = tmp_path / "run.est.mcap"
        assert main(["estimate", str(mixed[run]), "--map", str(the_map), "-o", str(estimate), "-q"]) == 0
    capsys.readouterr()
    assert main(["report", str(estimate), "--ground-truth-topic", "/typo", "-q"]) == 2
    line = one_error_line(capsys.readouterr().err)
    assert f"{mixed[run]}: {words}" in line


def test_a_map_bag_without_the_topic_named_says_so(mixed, capsys):
    """A map session that is a bag estimated with no truth topic, and a report naming a topic it
    lacks: the warning said "no ground-truth topic named for this bag", though one was."""
    capsys.readouterr()
    args = [
        "report",
        str(mixed["recording in bag"]),
        "--json",
        "-",
        "--ground-truth-topic",
        "/ground_truth/pose",
    ]
    assert main(args) == 0
    err = capsys.readouterr().err
    assert f"{mixed['bag']}: no topic '/ground_truth/pose' in it" in err
    assert "no ground-truth topic named" not in err


def _a_run_in_a_bags_map(tmp_path: Path) -> tuple[Path, Path]:
    """A bag with /ground_truth made a map, and a recording's run in it: (the bag, the run's estimate)."""
    bag, run = tmp_path / "first_bag.mcap", tmp_path / "second.mcap"
    write_square_bag(bag, square_route(), 7, ground_truth_topic="/ground_truth")
    write_square_recording(run, second_session_route(5), seed=11)
    the_map, estimate = tmp_path / "bag.est.mcap", tmp_path / "run.est.mcap"
    assert main(["estimate", str(bag), "-o", str(the_map), "-q"]) == 0
    assert main(["estimate", str(run), "--map", str(the_map), "-o", str(estimate), "-q"]) == 0
    return bag, estimate


def test_a_truth_topic_only_a_missing_map_session_had_is_no_error(tmp_path, capsys):
    """The map's bag, the one session with /ground_truth, deleted: the report said no session has
    the topic (exit 2, as for a typo) though it cannot know. The run is now scored on its own topic,
    the map's keyframes unscored, as the warning about the missing bag says."""
    bag, estimate = _a_run_in_a_bags_map(tmp_path)
    bag.unlink()
    capsys.readouterr()
    assert main(["report", str(estimate), "--json", "-", "--ground-truth-topic", "/ground_truth"]) == 0
    captured = capsys.readouterr()
    warnings = [line for line in captured.err.splitlines() if line.startswith("aslam:")]
    the_map = bag.with_name("bag.est.mcap")
    assert warnings == [
        f"aslam: warning: recording {bag} (named in {the_map}) not found; the map's keyframes from it"
        " are not scored"
    ]
    summary = json.loads(captured.out)
    assert summary["ground_truth"] is True and summary["loop_closure"]["claims"] > 0


@pytest.mark.parametrize("change", ["missing", "damaged", "another map", "the same map again"])
def test_a_map_no_longer_there_leaves_its_keyframes_unscored_and_says_so(tmp_path, capsys, change):
    """The second session's estimate, the third's map, deleted, cut short, or estimated again into
    another map: the third session's claims of the map's places are not judged (against a truth
    that is not theirs), one warning names the map, and the run's own truth still scores the rest.
    Estimated again into the same map (another file: timing metadata), it is the same map."""
    files = _chain(tmp_path / "chain")
    the_map = files["second.est"]
    if change == "missing":
        the_map.unlink()
    elif change == "damaged":
        the_map.write_bytes(the_map.read_bytes()[:2000])
    elif change == "another map":  # the second recording in a map of its own
        assert main(["estimate", str(files["second"]), "-o", str(the_map), "-q", "--force"]) == 0
    else:
        args = ["estimate", str(files["second"]), "--map", str(files["first.est"]), "-o", str(the_map)]
        assert main([*args, "-q", "--force"]) == 0  # with timing: other bytes, the same map
    summary, warnings = _report_and_warnings(files["third.est"], capsys)
    closure = summary["loop_closure"]
    assert summary["ground_truth"] is True
    if change == "the same map again":
        assert warnings == [] and closure["unjudged_claims"] == 0 and closure["precision"] == 1.0
        return
    assert len(warnings) == 1 and str(the_map) in warnings[0], warnings
    assert "the keyframes of that map are not scored" in warnings[0]
    assert closure["claims"] > 0 and closure["unjudged_claims"] == closure["claims"]
    assert closure["correct"] == 0 and closure["precision"] is None


def test_a_map_sessions_recording_missing_names_the_estimate_that_names_it(tmp_path, capsys):
    files = _chain(tmp_path / "chain")
    files["second"].unlink()
    summary, warnings = _report_and_warnings(files["third.est"], capsys)
    assert len(warnings) == 1 and str(files["second"]) in warnings[0]
    assert f"named in {files['second.est']}" in warnings[0]
    assert "reporting without ground truth" not in warnings[0]
    assert "the map's keyframes from it are not scored" in warnings[0]
    assert summary["ground_truth"] is True


@pytest.mark.parametrize(
    ("make_map", "words"),
    [
        ("recording", "not an aslam estimate file"),
        ("missing", "no such map"),
        ("histogram", "give this run the map's options"),
        ("empty", "the map is empty (its run had no keyframes)"),  # was: views 'not stored'
    ],
)
def test_a_map_that_cannot_be_used_is_one_line_and_exit_2(sessions, tmp_path, capsys, make_map, words):
    if make_map == "recording":
        the_map = sessions["first"]
    elif make_map == "missing":
        the_map = tmp_path / "nowhere.est.mcap"
    elif make_map == "empty":  # the estimate of a run without a keyframe, as `estimate` writes it
        from aslam.data_formats import estimate as estimate_format

        the_map = tmp_path / "empty.est.mcap"
        estimator = Estimator()
        metadata = estimate_format.EstimateMetadata(
            "test", {}, estimate_format.RecordingIdentity("/nowhere.mcap", 0, "0" * 64), {}
        )
        views = estimate_format.PlaceViews("thumbnail", np.zeros(0, np.int64), estimator.place_views(()))
        with estimate_format.EstimateWriter(the_map, tool_version="test") as writer:
            writer.finish(estimator.result(), metadata, None, None, views)
    else:
        the_map = tmp_path / "histogram.est.mcap"
        _estimate(sessions["first"], the_map, "--observation-model", "histogram")
    out = tmp_path / "out.est.mcap"
    capsys.readouterr()
    code = main(["estimate", str(sessions["second"]), "--map", str(the_map), "-o", str(out)])
    line = one_error_line(capsys.readouterr().err)
    assert code == 2
    assert str(the_map) in line and words in line
    assert not out.exists()


def test_a_map_of_another_registered_model_is_refused_naming_both(sessions, tmp_path, capsys, monkeypatch):
    """A model added to OBSERVATION_MODELS has a descriptor key of its own: a histogram map is refused
    with exit 2 (a key that fell through to the histogram's took the map, then failed on the views'
    lengths: internal error, exit 70)."""
    from aslam.core.observation import OBSERVATION_MODELS, ObservationModelChoice, ThumbnailModel

    coarse = ObservationModelChoice(lambda config: ThumbnailModel(width_px=8, height_px=6))
    monkeypatch.setitem(OBSERVATION_MODELS, "coarse", coarse)
    the_map = tmp_path / "histogram.est.mcap"
    _estimate(sessions["first"], the_map, "--observation-model", "histogram")
    out = tmp_path / "out.est.mcap"
    capsys.readouterr()
    args = [
        "estimate",
        str(sessions["second"]),
        "--map",
        str(the_map),
        "-o",
        str(out),
        "--observation-model",
        "coarse",
    ]
    code = main(args)
    line = one_error_line(capsys.readouterr().err)
    assert code == 2 and not out.exists()
    assert "made with --observation-model histogram --histogram-bins 16 --cells-x 2 --cells-y 1" in line
    assert "this run's would be made with --observation-model coarse: give this run the map's options" in line


def test_two_maps_are_one_line_and_exit_2_not_the_last_in_silence(sessions, tmp_path, capsys):
    """A run starts in one map; a second --map was taken and the first dropped without a word."""
    out = tmp_path / "out.est.mcap"
    first, second = str(sessions["first.est"]), str(sessions["second.est"])
    capsys.readouterr()
    code = main(["estimate", str(sessions["second"]), "--map", first, "--map", second, "-o", str(out)])
    line = one_error_line(capsys.readouterr().err)
    assert code == 2 and "--map given 2 times" in line and "chain" in line and not out.exists()
    same = str(sessions["first.est"].parent / "." / sessions["first.est"].name)  # one file, twice
    args = ["estimate", str(sessions["second"]), "--map", first, "--map", same, "-o", str(out)]
    assert main([*args, "-q", "--no-timing"]) == 0
    assert out.read_bytes() == sessions["second.est"].read_bytes()


def test_the_paths_candidate_search_in_a_map_warns_that_it_cannot_follow_it(sessions, tmp_path, capsys):
    """The paper's path search walks only this run's path back: past the first keyframe no place
    of the map is ever predicted, so a session in the map claims almost nothing, in silence."""
    out = tmp_path / "path.est.mcap"
    args = ["estimate", str(sessions["second"]), "--map", str(sessions["first.est"]), "-o", str(out)]
    capsys.readouterr()
    assert main([*args, "--candidate-search", "path"]) == 0
    warnings = [line for line in capsys.readouterr().err.splitlines() if line.startswith("aslam: warning:")]
    assert len(warnings) == 1 and "--candidate-search graph" in warnings[0]
    along_the_path = report_json(out, capsys=capsys)["loop_closure"]["claims"]
    through_the_map = report_json(sessions["second.est"], capsys=capsys)["loop_closure"]["claims"]
    assert along_the_path <= 3 < 0.8 * len(second_session_route(5)) <= through_the_map


@pytest.mark.parametrize("command", ["estimate --map", "report"])
def test_an_estimate_of_another_format_is_one_line_naming_its_aslam(
    sessions, tmp_path, monkeypatch, capsys, command
):
    """An estimate file of another format version (a later aslam's) was read as if it were this one's."""
    from aslam.data_formats import estimate as estimate_format

    monkeypatch.setattr(estimate_format, "FORMAT_VERSION", "2")
    later = tmp_path / "later.est.mcap"
    assert main(["estimate", str(sessions["first"]), "-o", str(later), "-q"]) == 0
    monkeypatch.undo()
    out = tmp_path / "out.est.mcap"
    args = ["estimate", str(sessions["second"]), "--map", str(later), "-o", str(out)]
    capsys.readouterr()
    assert main(args if command != "report" else ["report", str(later)]) == 2
    line = one_error_line(capsys.readouterr().err)
    assert str(later) in line and "estimate file format '2', written by aslam" in line
    assert "this aslam reads format '1'" in line


# --- the core --------------------------------------------------------------------------------------


def test_prior_map_refuses_parts_that_do_not_fit():
    views = np.zeros((2, 4), np.float32)
    states = (MapState(0, (0,)), MapState(1, (1, 2)))
    link = MapLink(0, 1, (1.0, 0.0, 0.0), ((0.01, 0, 0), (0, 0.01, 0), (0, 0, 0.001)), 1)
    assert prior_map(3, states, (link,), views).keyframes == 3
    with pytest.raises(ValueError, match="outside"):
        prior_map(2, states, (link,), views)
    with pytest.raises(ValueError, match="in no place"):
        prior_map(4, states, (link,), views)
    with pytest.raises(ValueError, match="do not match"):
        prior_map(3, states, (link,), views[:1])
    with pytest.raises(ValueError, match="not both"):
        prior_map(
            3,
            states,
            (MapLink(0, 5, link.action, link.covariance, 1),),
            views,
        )


def test_a_session_with_no_keyframes_leaves_the_map_as_it_was():
    config = EstimatorConfig(observation_model="histogram", cells_x=1)
    first = Estimator(config)
    rng = np.random.default_rng(0)
    for k in range(6):
        first.add_keyframe(
            k,
            np.array([1.0, 0, 0]) if k else np.zeros(3),
            rng.random(first.observation_model.length).astype(np.float32),
        )
    done = first.result()
    start = prior_map(len(done.keyframe_stamps_ns), done.states, done.links, first.place_views(done.states))
    result = Estimator(config, start).result()
    assert result.states == done.states and result.hypotheses == () and result.first_keyframe == 6


def _random_run(
    estimator: Estimator,
    count: int,
    seed: int = 0,
    repeat: dict[int, int] | None = None,
    pause_at: int | None = None,
) -> list:
    """``count`` keyframes one metre apart straight ahead, with random views; ``repeat`` maps a
    keyframe to an earlier one whose view it shows again (a look-alike); keyframe ``pause_at`` comes
    after a carry's time (the robot may have been carried)."""
    rng = np.random.default_rng(seed)
    views: list[np.ndarray] = []
    steps = []
    for k in range(count):
        view = rng.normal(0, 1, estimator.observation_model.length).astype(np.float32)
        if repeat and k in repeat:
            view = views[repeat[k]]
        views.append(view)
        stamp, still = carried(k, pause_at)
        steps.append(estimator.add_keyframe(stamp, np.array([1.0, 0, 0]) if k else np.zeros(3), view, still))
    return steps


def test_without_odometry_a_run_never_jumps_to_its_own_places():
    """Equal steps (no odometry): one pass along a route, so a view seen again is a look-alike, even
    after a pause in which a robot with odometry may have been carried."""
    look_alikes = {20: 4, 21: 5, 22: 6, 23: 7}

    def claims(odometry_known: bool) -> list[int]:
        estimator = Estimator(odometry_known=odometry_known)
        steps = _random_run(estimator, 26, repeat=look_alikes, pause_at=20)
        return [s.keyframe for s in steps if not s.best.is_new_state]

    assert claims(odometry_known=True)  # with odometry, after a pause, appearance alone may move the robot
    assert claims(odometry_known=False) == []


def test_place_views_are_written_in_blocks_and_read_back(tmp_path, monkeypatch):
    from aslam.app.estimate import load_prior_map
    from aslam.data_formats import estimate as estimate_format
    from aslam.data_formats.errors import EstimateError

    monkeypatch.setattr(estimate_format, "PLACES_PER_VIEW_MESSAGE", 4)
    estimator = Estimator()
    _random_run(estimator, 10)
    result = estimator.result()
    metadata = estimate_format.EstimateMetadata(
        "test", {}, estimate_format.RecordingIdentity("/nowhere.mcap", 0, "0" * 64), {}
    )
    views = estimate_format.PlaceViews(
        "thumbnail", np.array([s.id for s in result.states]), estimator.place_views(result.states)
    )
    with_views, without = tmp_path / "with.est.mcap", tmp_path / "without.est.mcap"
    for path, stored in ((with_views, views), (without, None)):
        with estimate_format.EstimateWriter(path, tool_version="test") as writer:
            writer.finish(result, metadata, None, None, stored)
    back = read_place_views(with_views)
    assert back.observation_model == "thumbnail"
    np.testing.assert_array_equal(back.states, views.states)
    np.testing.assert_array_equal(back.views, views.views)
    assert load_prior_map(with_views, EstimatorConfig())[0].keyframes == 10
    with pytest.raises(EstimateError, match="not stored"):
        load_prior_map(without, EstimatorConfig())


@pytest.mark.parametrize(
    ("damage", "words"),
    [
        ({"views": "not base64!"}, "corrupt place views"),
        ({"length": 7}, "wrong size"),
        ({"states": "all"}, "invalid place views message"),
    ],
)
def test_damaged_place_views_are_one_error_naming_the_map(
    sessions, tmp_path, monkeypatch, capsys, damage, words
):
    from aslam.data_formats import estimate as estimate_format

    honest = estimate_format.PlaceViews.messages

    def damaged(self):
        for message in honest(self):
            yield {**message, **damage}

    monkeypatch.setattr(estimate_format.PlaceViews, "messages", damaged)
    the_map = tmp_path / "damaged.est.mcap"
    assert main(["estimate", str(sessions["first"]), "-o", str(the_map), "-q"]) == 0
    monkeypatch.undo()
    out = tmp_path / "out.est.mcap"
    capsys.readouterr()
    code = main(["estimate", str(sessions["second"]), "--map", str(the_map), "-o", str(out)])
    line = one_error_line(capsys.readouterr().err)
    assert code == 2 and str(the_map) in line and words in line
    assert not out.exists()


def _rendered(seed: int, aliasing: float = 0.0) -> dict[str, str]:
    """A recording's metadata as the recorder writes it for a generated world (``aslam record``)."""
    world = {
        "kind": "generated", "cell_m": 0.25, "corridor_width_m": 2.0, "height_m": 2.5,
        "free_area_m2": 77.5, "wall_panels": 47, "doors": round(5 * (1 - aliasing)), "alcoves": 7,
        "lights": 8, "aliasing": aliasing, "shared_textures": 3, "aliased_panels": round(47 * aliasing),
    }  # fmt: skip
    return {"world": json.dumps(world, separators=(",", ":")), "seed": str(seed), "route": "square"}


@pytest.mark.parametrize("looks", ["unlike the map", "like the map"])
def test_a_session_rendered_in_another_world_is_scored_in_its_own(tmp_path, capsys, looks):
    """Rendered worlds of other seeds share no place, but every world's truth starts at the route's
    start: the same square driven in another world is at the map's true poses. None of its
    keyframes revisits the map (it was every one of them, and recall the share it did not claim),
    and a claim of the map's places, however alike they look, is wrong (it was right)."""
    the_map, session = tmp_path / "map.mcap", tmp_path / "session.mcap"
    write_square_recording(the_map, square_route()[: FIRST_LAP + 1], metadata=_rendered(seed=1))
    offset = (100.0, 100.0) if looks == "unlike the map" else (0.0, 0.0)
    write_square_recording(
        session, second_session_route(5), seed=11, metadata=_rendered(seed=2), view_offset=offset
    )
    map_estimate, out = tmp_path / "map.est.mcap", tmp_path / "session.est.mcap"
    assert main(["estimate", str(the_map), "-o", str(map_estimate), "-q"]) == 0
    assert main(["estimate", str(session), "--map", str(map_estimate), "-o", str(out), "-q"]) == 0
    summary, warnings = _report_and_warnings(out, capsys)
    assert len(warnings) == 1 and "2 worlds that share no place (map.mcap; session.mcap)" in warnings[0]
    closure = summary["loop_closure"]
    assert closure["ground_truth_revisits"] <= 1  # the lap's last keyframe, at its own start
    if looks == "unlike the map":
        assert closure["claims"] <= 1 and closure["precision"] in (None, 1.0)
    else:  # the estimator takes the look-alike world for the map
        assert closure["claims"] >= 10 and closure["unjudged_claims"] == 0
        assert closure["precision"] < 0.2 and summary["committed"]["precision"] < 0.2
        assert all(v is None for v in summary["error"]["best"]["x_m"].values())  # two frames: no error
    # Rendered in the same world (another aliasing: the same rooms), the same files score as one world.
    same = tmp_path / "same.mcap"
    write_square_recording(same, second_session_route(5), seed=11, metadata=_rendered(1, 0.5))
    assert main(["estimate", str(same), "--map", str(map_estimate), "-o", str(out), "-q", "--force"]) == 0
    summary, warnings = _report_and_warnings(out, capsys)
    assert warnings == [] and summary["loop_closure"]["ground_truth_revisits"] == summary["keyframes"]


@pytest.mark.parametrize("again", ["its own recording", "another run of its route"])
def test_a_map_estimated_again_from_another_run_is_another_map(tmp_path, capsys, again):
    """A map replaced by the estimate of another run of its route (the same keyframes at the same
    places, other odometry) is not the map a session in it started in, where the session left the
    map's links as they were: its keyframes are not scored against that run's truth (they were, in
    silence); estimated again from its own recording (no timing: other bytes) it is the same map."""
    the_map, session = tmp_path / "map.mcap", tmp_path / "session.mcap"
    write_square_recording(the_map, square_route()[: FIRST_LAP + 1], metadata=_rendered(seed=1))
    write_square_recording(
        session, second_session_route(5), seed=11, metadata=_rendered(seed=2), view_offset=(100.0, 100.0)
    )
    map_estimate, out = tmp_path / "map.est.mcap", tmp_path / "session.est.mcap"
    assert main(["estimate", str(the_map), "-o", str(map_estimate), "-q"]) == 0
    assert main(["estimate", str(session), "--map", str(map_estimate), "-o", str(out), "-q"]) == 0
    source = the_map
    if again == "another run of its route":
        source = tmp_path / "other.mcap"
        write_square_recording(source, square_route()[: FIRST_LAP + 1], seed=8, metadata=_rendered(seed=1))
    args = ["estimate", str(source), "-o", str(map_estimate), "-q", "--force", "--no-timing"]
    assert main(args) == 0
    _, warnings = _report_and_warnings(out, capsys)
    replaced = [line for line in warnings if "is not the map" in line]
    if again == "its own recording":
        assert replaced == []
    else:
        assert len(replaced) == 1 and str(map_estimate) in replaced[0]
        assert "the keyframes of that map are not scored" in replaced[0]


def test_a_map_replaced_by_another_run_is_known_even_where_the_session_drove_every_link(tmp_path, capsys):
    """A session that drives the whole map again leaves no link as the map had it, so a map file
    replaced by another run's estimate of the same layout looked like the map (the same keyframes
    at the same places); the estimate now names the map by a digest of its places and links."""
    the_map, session = tmp_path / "map.mcap", tmp_path / "session.mcap"
    write_square_recording(the_map, square_route()[: FIRST_LAP + 1], metadata=_rendered(seed=1))
    write_square_recording(session, second_session_route(5), seed=11, metadata=_rendered(seed=1))
    map_estimate, out = tmp_path / "map.est.mcap", tmp_path / "session.est.mcap"
    assert main(["estimate", str(the_map), "-o", str(map_estimate), "-q"]) == 0
    assert main(["estimate", str(session), "--map", str(map_estimate), "-o", str(out), "-q"]) == 0
    summary, warnings = _report_and_warnings(out, capsys)
    assert warnings == [] and summary["loop_closure"]["correct"] >= FIRST_LAP - 2  # the whole map driven
    for source, replaced in ((the_map, False), (tmp_path / "other.mcap", True)):
        if replaced:  # another run of the same route: the same layout, its own odometry
            lap = square_route()[: FIRST_LAP + 1]
            write_square_recording(source, lap, seed=8, metadata=_rendered(seed=1))
        args = ["estimate", str(source), "-o", str(map_estimate), "-q", "--force", "--no-timing"]
        assert main(args) == 0
        _, warnings = _report_and_warnings(out, capsys)
        flagged = [line for line in warnings if "is not the map" in line]
        assert len(flagged) == replaced, warnings


def test_worlds_apart_in_the_metrics():
    """Keyframes 0–1 of world 0, 2–3 of world 1 at the same true poses, 4 of an unknown world."""
    from aslam.core.metrics import evaluate, ground_truth_revisits, score_assignment
    from aslam.core.tree import Hypothesis

    poses = np.array([[0.0, 0, 0], [1, 0, 0], [0, 0, 0], [1, 0, 0], [1, 0, 0]])
    worlds = np.array([0, 0, 1, 1, -1])
    assert ground_truth_revisits(poses, 0.5, 45).tolist() == [False, False, True, True, True]
    assert ground_truth_revisits(poses, 0.5, 45, worlds).tolist() == [False, False, False, False, True]
    steps = [(2, (Hypothesis(1, None, 0, 0.9, False),)), (3, (Hypothesis(2, 1, 3, 1.0, True),))]
    steps += [(4, (Hypothesis(3, 2, 1, 1.0, False),))]  # a claim of world 0 from an unknown world: right
    result = evaluate(iter(steps), poses, first_keyframe=2, count=3, worlds=worlds)
    assert result.claims.tolist() == [True, False, True]
    assert result.judged_claims.tolist() == [True, False, True]
    assert result.correct.tolist() == [False, False, True] and result.precision == 0.5
    assert np.isnan(result.best_error[0]).all() and result.true_revisit.tolist() == [False, False, True]
    committed = score_assignment(np.array([0, 1, 0, 3, 1]), poses, first_keyframe=2, worlds=worlds)
    assert committed.correct.tolist() == [False, False, True] and committed.precision == 0.5


def test_world_identity_of_a_recording():
    from aslam.data_formats.recording import world_identity

    assert world_identity({}) is None  # an imported folder, a bag: one world assumed
    assert world_identity(_rendered(1)) == world_identity(_rendered(1, aliasing=1.0))  # the same rooms
    assert world_identity(_rendered(1)) != world_identity(_rendered(2))
    scene = {"world": '{"kind":"scene-file","file":"a.glb","triangles":12}', "seed": "1"}
    assert world_identity(scene) == world_identity({**scene, "seed": "2"})  # the seed is the noise's
    assert world_identity({"world": "test"}) == "test"


def test_new_ground_shaped_like_the_map_gets_no_claim_into_it(sessions, tmp_path, capsys):
    """The same square driven elsewhere (other views, the same odometry): nothing is the map."""
    elsewhere = [pose + np.array([100.0, 100.0, 0.0]) for pose in second_session_route(5)]
    recording = tmp_path / "elsewhere.mcap"
    write_square_recording(recording, elsewhere, seed=31)
    out = tmp_path / "elsewhere.est.mcap"
    args = ["estimate", str(recording), "--map", str(sessions["first.est"]), "-o", str(out), "-q"]
    assert main(args) == 0
    first = read_estimate(out).graph.first_keyframe
    claimed = [
        k.hypotheses[0].state
        for k in iter_keyframes(out)
        if not k.hypotheses[0].is_new_state and k.hypotheses[0].state < first
    ]
    assert claimed == []


def test_from_new_ground_into_the_map_it_relocalises_on_entering(sessions, tmp_path, capsys):
    """Four steps toward the square from outside it (never mapped), then one lap of it."""
    lap = square_route()[: FIRST_LAP + 1]
    approach = [np.array([-4.0 + k, 0.0, 0.0]) for k in range(4)]
    recording = tmp_path / "approach.mcap"
    write_square_recording(recording, approach + lap, seed=41)
    out = tmp_path / "approach.est.mcap"
    args = ["estimate", str(recording), "--map", str(sessions["first.est"]), "-o", str(out), "-q"]
    assert main(args) == 0
    first = read_estimate(out).graph.first_keyframe
    best = [k.hypotheses[0] for k in iter_keyframes(out)]
    assert all(h.is_new_state or h.state >= first for h in best[: len(approach)])  # nothing claimed outside
    summary = report_json(out, capsys=capsys)
    assert summary["loop_closure"]["precision"] == 1.0
    assert summary["relocalisation"]["first_delay_keyframes"] <= 2


@pytest.mark.parametrize("command", ["info", "estimate"])
def test_an_estimate_given_as_a_recording_is_one_line(sessions, tmp_path, capsys, command):
    from aslam.data_formats.estimate import ESTIMATE_METADATA
    from aslam.data_formats.rosbag_source import ESTIMATE_METADATA_NAME

    assert ESTIMATE_METADATA_NAME == ESTIMATE_METADATA
    args = [command, str(sessions["first.est"])]
    if command == "estimate":
        args += ["-o", str(tmp_path / "out.est.mcap")]
    capsys.readouterr()
    assert main(args) == 2
    line = one_error_line(capsys.readouterr().err)
    assert "an aslam estimate file, not a recording" in line and str(sessions["first.est"].name) in line


def _season_change(views: list[np.ndarray], seed: int) -> list[np.ndarray]:
    """The same places in another season: every view faded under one strong seasonal pattern, so the
    season's views are nearer each other than any is to its summer view, yet each is nearer its own
    summer view than the places around it."""
    rng = np.random.default_rng(seed)
    season = rng.normal(0, 1.0, views[0].shape)
    return [(0.5 * v + season + rng.normal(0, 0.3, v.shape)).astype(np.float32) for v in views]


def test_a_map_of_another_season_is_followed_by_local_contrast():
    """``--map-reference-scale``: the second session's views are all further from the map than the
    run's own new-place reference, so judged on that reference no map place is ever claimed; judged
    against each place's neighbourhood the session follows the map, and names no wrong place."""
    first = Estimator(odometry_known=False)
    rng = np.random.default_rng(3)
    summer = [rng.normal(0, 1, first.observation_model.length).astype(np.float32) for _ in range(60)]
    for k, view in enumerate(summer):
        first.add_keyframe(k, np.array([1.0, 0, 0]) if k else np.zeros(3), view)
    done = first.result()
    the_map = prior_map(len(done.keyframe_stamps_ns), done.states, done.links, first.place_views(done.states))
    winter = _season_change(summer, seed=4)

    def claims(scale: float) -> list[tuple[int, int]]:
        second = Estimator(EstimatorConfig(map_reference_scale=scale), the_map, odometry_known=False)
        steps = [
            second.add_keyframe(60 + k, np.array([1.0, 0, 0]) if k else np.zeros(3), view)
            for k, view in enumerate(winter)
        ]
        return [(s.keyframe - 60, s.best.state) for s in steps if not s.best.is_new_state]

    assert claims(0.0) == []
    across = claims(0.95)
    assert len(across) >= 40
    assert all(abs(state - k) <= 1 for k, state in across)


@given(
    weight=st.floats(0.05, 1.0),
    distances=st.lists(st.floats(0.01, 3.0), min_size=1, max_size=8),
)
@settings(max_examples=40, deadline=None)
def test_the_evidence_weight_scales_the_log_likelihood_ratio_to_a_new_place(weight, distances):
    """A map place's log-likelihood ratio to a new place is ``map_evidence_weight`` × its full-weight one."""
    rng = np.random.default_rng(0)
    views = rng.normal(0, 1, (12, 192)).astype(np.float32)
    states = tuple(MapState(k, (k,)) for k in range(12))
    the_map = prior_map(12, states, (), views)
    observation = rng.normal(0, 1, 192).astype(np.float32)
    picked = np.arange(len(distances), dtype=np.int64)
    raw = np.array(distances)

    def judged(w: float) -> np.ndarray:
        tree = HypothesisTree(EstimatorConfig(map_reference_scale=0.95, map_evidence_weight=w), prior=the_map)
        return tree._across_sessions(observation, picked, raw), tree.reference.value

    full, reference = judged(1.0)
    weighted, _ = judged(weight)
    np.testing.assert_allclose(np.log(weighted / reference), weight * np.log(full / reference), atol=1e-9)


def test_a_long_chain_of_sessions_is_scored_without_recursion(tmp_path, monkeypatch):
    """``report`` walked a chain of maps recursively, a level per session: at about 960 sessions
    (a robot estimating each run in the last one's map) RecursionError, exit 70. The chain is now
    walked in one call, however long."""
    from conftest import random_frames, write_recording

    import aslam.app.score as score_module
    from aslam.app.estimate import estimate

    recording = write_recording(tmp_path / "r.mcap", random_frames(2))
    previous = None
    for i in range(6):
        out = tmp_path / f"e{i}.mcap"
        estimate(recording, out, EstimatorConfig(), timing=False, reader_process=False, prior=previous)
        previous = out
    walk, depth, deepest = score_module._map_truth, [0], [0]

    def counted(*args, **kwargs):
        depth[0] += 1
        deepest[0] = max(deepest[0], depth[0])
        try:
            return walk(*args, **kwargs)
        finally:
            depth[0] -= 1

    monkeypatch.setattr(score_module, "_map_truth", counted)
    report = score_module.score(previous)
    assert deepest[0] == 1
    assert report.summary["keyframes"] == 2 and report.summary["ground_truth"] is True


def test_a_recording_made_again_in_its_place_is_no_truth(tmp_path):
    """A map session's recording made again (another seed, another size) was taken as its truth:
    a perfect run scored precision 0 after a warning. Only the recorded size is that recording; a
    copy of it beside the estimate still is."""
    from conftest import random_frames, write_recording

    from aslam.app.estimate import estimate
    from aslam.app.score import score

    (tmp_path / "a").mkdir()
    first = write_recording(tmp_path / "a" / "s1.mcap", random_frames(3))
    second = write_recording(tmp_path / "s2.mcap", random_frames(3))
    first_estimate, second_estimate = tmp_path / "e1.mcap", tmp_path / "e2.mcap"
    estimate(first, first_estimate, EstimatorConfig(), timing=False, reader_process=False)
    estimate(
        second, second_estimate, EstimatorConfig(), timing=False, reader_process=False, prior=first_estimate
    )
    before = score(second_estimate).summary["loop_closure"]
    kept = first.read_bytes()
    first.unlink()
    write_recording(first, random_frames(4, seed=9))  # made again in its place: another size
    warnings: list[str] = []
    after = score(second_estimate, on_warning=warnings.append).summary["loop_closure"]
    assert any("s1.mcap has changed since the estimate" in w and "not scored" in w for w in warnings)
    assert after["unjudged_claims"] == before["claims"] and after["correct"] == 0
    (tmp_path / "s1.mcap").write_bytes(kept)  # the original, beside the estimate: taken
    warnings.clear()
    assert score(second_estimate, on_warning=warnings.append).summary["loop_closure"] == before
    assert not any("s1.mcap" in w for w in warnings)


@pytest.mark.parametrize("topic", [[], ["--ground-truth-topic", "/ground_truth"]])
def test_a_map_session_that_cannot_be_opened_leaves_the_map_unscored_and_the_run_scored(
    tmp_path: Path, capsys, topic: list[str]
):
    """A map's session whose bag was damaged since (MCAP's magic, garbage, the same size, so found
    as that recording): the run is scored and the map's keyframes not, with a warning naming the
    problem, as when the bag is gone. With a truth topic named it was exit 2, "no ground-truth topic
    … in any session of its map" (a code review's finding)."""
    from aslam.data_formats.files import MCAP_MAGIC

    bag, estimate = _a_run_in_a_bags_map(tmp_path)
    size = bag.stat().st_size
    bag.write_bytes((MCAP_MAGIC + bytes(range(256)) * (size // 256 + 1))[:size])
    capsys.readouterr()
    assert main(["report", str(estimate), "--json", "-", *topic]) == 0
    out, err = capsys.readouterr()
    (said,) = [line for line in err.splitlines() if "first_bag" in line]
    assert said.startswith(f"aslam: warning: {bag}: ")
    assert said.endswith("; the map's keyframes from it are not scored")
    if topic:  # (without one, the session's bag has no truth topic named: the warning says so first)
        assert "cannot open the bag" in said
    assert json.loads(out)["ground_truth"] is True  # the run itself is scored
