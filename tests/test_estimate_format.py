"""Estimate files as a property: whatever the writer is given, the readers give back; and the graph
JSON made from what they read is strict JSON."""

from __future__ import annotations

import json
import math
import tempfile
from pathlib import Path
from unittest import mock

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from aslam.core.estimator import EstimateResult, MapLink, MapState, StepResult
from aslam.core.tree import Hypothesis, TreeStats
from aslam.data_formats import estimate as estimate_format
from aslam.data_formats.graph_json import build_graph_json
from aslam.data_formats.ros_msgs import LAST_STAMP_NS

# What a run can hold: poses within the 10,000 km the readers take, so actions within twice that.
number = st.floats(-2e7, 2e7, allow_nan=False)
small = st.integers(0, 10_000)
text = st.text(max_size=12)
name = st.text(min_size=1, max_size=12)  # a file's name is never empty
digest = st.text("0123456789abcdef", min_size=64, max_size=64)  # SHA-256, hex


@st.composite
def runs(draw):
    first = draw(st.integers(0, 5))  # a prior map's keyframes
    n = draw(st.integers(1, 6))
    keyframes = first + n
    stamps = sorted(draw(st.lists(st.integers(0, LAST_STAMP_NS), min_size=n, max_size=n)))
    hypothesis = st.builds(
        Hypothesis,
        small,
        st.one_of(st.none(), small),
        st.integers(0, keyframes - 1),
        st.floats(0.0, 1.0),
        st.booleans(),
    )
    steps = [
        StepResult(
            first + i, stamps[i], draw(st.tuples(number, number, number)), tuple(draw(st.lists(hypothesis)))
        )
        for i in range(n)
    ]
    # a map: every keyframe in exactly one state, each state named by one of its keyframes
    owner = draw(st.lists(st.integers(0, keyframes - 1), min_size=keyframes, max_size=keyframes))
    groups: dict[int, list[int]] = {}
    for k in draw(st.permutations(range(keyframes))):
        groups.setdefault(owner[k], []).append(k)
    states = tuple(MapState(min(members), tuple(members)) for members in groups.values())
    ids = [state.id for state in states]
    # a covariance: symmetric positive definite, A Aᵀ + a floor, over many orders of magnitude
    root = st.lists(st.floats(-1e3, 1e3, allow_nan=False), min_size=9, max_size=9)
    covariance = st.builds(
        lambda a, floor: tuple(
            tuple(float(v) for v in row)
            for row in (np.reshape(a, (3, 3)) @ np.reshape(a, (3, 3)).T + floor * np.eye(3))
        ),
        root,
        st.floats(1e-6, 1e6),
    )
    links = tuple(
        draw(
            st.lists(
                st.builds(
                    MapLink,
                    st.sampled_from(ids),
                    st.sampled_from(ids),
                    st.tuples(number, number, number),
                    covariance,
                    small,
                ),
                max_size=5,
            )
        )
    )
    stats = TreeStats(
        keyframes, *draw(st.tuples(small, small, st.floats(0, 1e4), small, small, st.floats(0, 1e4)))
    )
    result = EstimateResult(states, links, tuple(draw(st.lists(hypothesis))), tuple(stamps), stats, first)
    metadata = estimate_format.EstimateMetadata(
        draw(text),
        draw(st.dictionaries(text, st.one_of(st.none(), st.booleans(), small, number, text), max_size=4)),
        estimate_format.RecordingIdentity(draw(name), draw(small), draw(digest)),
        draw(st.dictionaries(st.sampled_from(estimate_format.TOPIC_KEYS), st.one_of(st.none(), text))),
        draw(st.none() | st.builds(estimate_format.MapIdentity, name, digest, small, st.none() | digest)),
    )
    timing = draw(
        st.one_of(
            st.none(),
            st.builds(
                estimate_format.Timing, st.floats(0, 1e6), st.floats(0, 1e6), st.floats(0, 1e6), small, small
            ),
        )
    )
    views = None
    if draw(st.booleans()):
        length = draw(st.integers(1, 4))
        values = st.floats(width=32, allow_nan=False, allow_infinity=False)
        rows = np.array(
            draw(
                st.lists(
                    st.lists(values, min_size=length, max_size=length), min_size=len(ids), max_size=len(ids)
                )
            ),
            dtype=np.float32,
        )
        views = estimate_format.PlaceViews(draw(text), np.array(sorted(ids), dtype=np.int64), rows)
    return steps, result, metadata, timing, views


@settings(max_examples=40, deadline=None)
@given(runs())
def test_what_the_estimate_writer_is_given_the_readers_give_back(run):
    steps, result, metadata, timing, views = run
    with (
        tempfile.TemporaryDirectory() as folder,
        mock.patch.object(estimate_format, "PLACES_PER_VIEW_MESSAGE", 2),
    ):
        path = Path(folder) / "run.est.mcap"
        with estimate_format.EstimateWriter(path, tool_version="test") as writer:
            for step in steps:
                writer.write_keyframe(step)
            writer.finish(result, metadata, timing, None, views)
        back = list(estimate_format.iter_keyframes(path))
        read = estimate_format.read_estimate(path)
        stored = estimate_format.read_place_views(path) if views is not None else None

    assert back == [
        estimate_format.EstimateKeyframe(s.keyframe, s.stamp_ns, s.action, s.hypotheses) for s in steps
    ]
    assert read.metadata == metadata and read.timing == timing
    graph = read.graph
    assert (
        graph.keyframes == result.first_keyframe + len(steps)
        and graph.first_keyframe == result.first_keyframe
    )
    assert (graph.states, graph.links, graph.hypotheses, graph.tree) == (
        result.states,
        result.links,
        result.hypotheses,
        result.stats,
    )
    if views is not None:
        assert stored.observation_model == views.observation_model
        assert np.array_equal(stored.states, views.states) and np.array_equal(stored.views, views.views)

    # The graph JSON of what was read: strict JSON (unknown truth is null), each state's stamps its
    # keyframes' in this run.
    truth = np.array(
        [[k, -k, 0.1 * k] if k % 3 else [math.nan] * 3 for k in range(graph.keyframes)], dtype=float
    )
    document = build_graph_json(
        graph, result.keyframe_stamps_ns, truth, estimate_path="e", recording_path=None
    )
    assert json.loads(json.dumps(document, allow_nan=False)) == document
    first = graph.first_keyframe
    for state, shown in zip(graph.states, document["states"], strict=True):
        assert shown["stamps_ns"] == [
            result.keyframe_stamps_ns[k - first] for k in state.keyframes if k >= first
        ]
        assert (shown["first_visit_truth"] is None) == (state.id % 3 == 0)
