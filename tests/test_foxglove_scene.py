"""Foxglove's well-known schemas in MCAP: decoded by mcap's reader with the schemas the file carries,
and checked against Foxglove's published schema package."""

from __future__ import annotations

import errno
import itertools
import json
import math
from pathlib import Path

import numpy as np
import pytest
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.PosesInFrame_pb2 import PosesInFrame
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from mcap.reader import make_reader
from mcap.writer import Writer
from mcap_protobuf.decoder import DecoderFactory
from mcap_protobuf.schema import build_file_descriptor_set

from aslam.app.metric_view import EmbedOptions, Kernel, embed, metric_scene
from aslam.core import se2
from aslam.data_formats import foxglove
from aslam.data_formats.foxglove import (
    GROWTH_STEPS,
    ODOMETRY_TOPIC,
    SCENE_TOPIC,
    TF_TOPIC,
    TRAJECTORY_TOPIC,
    MetricScene,
    SceneError,
    write_scene,
)

PACKAGE_CLASSES = {
    SCENE_TOPIC: SceneUpdate,
    TRAJECTORY_TOPIC: PosesInFrame,
    ODOMETRY_TOPIC: PosesInFrame,
    TF_TOPIC: FrameTransform,
}


def square_run(laps: int = 2, wrong: bool = False):
    """A 4 m square driven ``laps`` times with a little drift; optionally one wrong closure."""
    commands = ([(1.0, 0.0, 0.0)] * 3 + [(1.0, 0.0, math.pi / 2)]) * 4 * laps
    actions = [np.zeros(3)] + [np.array(c) * [1.02, 1.0, 1.01] for c in commands]
    n = len(actions)
    assignment = np.array([k % 16 for k in range(n)])
    if wrong:
        assignment[16 + 9] = 2  # claims a place across the square
    stamps = 1_600_000_000_000_000_000 + np.arange(n, dtype=np.int64) * 1_000_000_000
    embedding = embed(np.array(actions), assignment, EmbedOptions(kernel=Kernel.CAUCHY))
    return embedding, stamps


def read_all(path: Path) -> dict[str, list]:
    """Every message, decoded with the schema stored in the file (not with our classes)."""
    out: dict[str, list] = {}
    with path.open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        assert summary is not None
        for channel in summary.channels.values():
            if channel.topic in PACKAGE_CLASSES:
                schema = summary.schemas[channel.schema_id]
                package = PACKAGE_CLASSES[channel.topic]
                assert channel.message_encoding == "protobuf"
                assert schema.encoding == "protobuf"
                assert schema.name == package.DESCRIPTOR.full_name
                # The schema in the file is Foxglove's published one, byte for byte.
                assert schema.data == build_file_descriptor_set(package).SerializeToString()
        for _schema, channel, message, decoded in reader.iter_decoded_messages(topics=list(PACKAGE_CLASSES)):
            out.setdefault(channel.topic, []).append((message, decoded))
    return out


def as_package(decoded, package):
    """Re-parse a message with the schema package's class: it must be a valid, complete message."""
    parsed = package()
    parsed.ParseFromString(decoded.SerializeToString())
    assert parsed.IsInitialized()
    return parsed


def test_scene_file_decodes_and_validates(tmp_path: Path):
    embedding, stamps = square_run()
    path = tmp_path / "scene.mcap"
    write_scene(path, metric_scene(embedding, stamps))
    messages = read_all(path)
    assert set(messages) == set(PACKAGE_CLASSES)
    assert len(messages[TF_TOPIC]) == len(stamps)
    assert [m.log_time for m, _ in messages[TF_TOPIC]] == stamps.tolist()

    # The map as it grew (lap 1: a place and a link per keyframe, then 15 → 0), then all of it.
    scenes = messages[SCENE_TOPIC]
    assert [m.log_time for m, _ in scenes] == [*stamps[:17].tolist(), stamps[-1]]
    early = {e.id: e for e in as_package(scenes[4][1], SceneUpdate).entities}
    assert len(early["places"].spheres) == 5 and len(early["links"].lines[0].points) == 2 * 4
    _, decoded = scenes[-1]
    scene = as_package(decoded, SceneUpdate)
    entities = {e.id: e for e in scene.entities}
    assert set(entities) == {"places", "links", "loop_closures", "outvoted_closures"}
    assert all(e.frame_id == "map" for e in entities.values())
    places = entities["places"].spheres
    assert len(places) == 16
    first = places[1].pose.position  # place 1 is at keyframe 1's embedded pose
    assert (first.x, first.y) == pytest.approx(tuple(embedding.poses[1, :2]))
    assert len(entities["links"].lines[0].points) == 2 * 15  # 0-1, 1-2, ... 14-15
    assert len(entities["loop_closures"].lines[0].points) == 2 * 1  # 15 → 0 closes the square
    assert not entities["outvoted_closures"].lines

    ((_, trajectory),) = messages[TRAJECTORY_TOPIC]
    poses = as_package(trajectory, PosesInFrame).poses
    assert len(poses) == len(stamps)
    last = poses[-1]
    yaw = 2 * math.atan2(last.orientation.z, last.orientation.w)
    assert (last.position.x, last.position.y) == pytest.approx(tuple(embedding.poses[-1, :2]))
    assert se2.wrap_angle(yaw - embedding.poses[-1, 2]) == pytest.approx(0.0, abs=1e-9)
    ((_, odometry),) = messages[ODOMETRY_TOPIC]
    assert as_package(odometry, PosesInFrame).poses[-1].position.x == pytest.approx(embedding.odometry[-1, 0])
    transform = as_package(messages[TF_TOPIC][5][1], FrameTransform)
    assert (transform.parent_frame_id, transform.child_frame_id) == ("map", "base_link")
    assert transform.translation.x == pytest.approx(embedding.poses[5, 0])


def test_an_outvoted_closure_is_drawn_red(tmp_path: Path):
    embedding, stamps = square_run(wrong=True)
    assert embedding.outvoted.sum() == 1 and embedding.outvoted[16 + 9]
    path = tmp_path / "scene.mcap"
    write_scene(path, metric_scene(embedding, stamps))
    scenes = read_all(path)[SCENE_TOPIC]
    assert all(  # drawn in the complete map only
        not e.lines for _, d in scenes[:-1] for e in d.entities if e.id == "outvoted_closures"
    )
    entities = {e.id: e for e in as_package(scenes[-1][1], SceneUpdate).entities}
    points = entities["outvoted_closures"].lines[0].points
    assert len(points) == 2
    assert math.dist((points[0].x, points[0].y), (points[1].x, points[1].y)) > 2.0  # left apart


def test_scene_appends_to_a_writer_that_carries_other_channels(tmp_path: Path):
    """As the estimate file will: JSON topics first, then the scene channels on the same writer."""
    embedding, stamps = square_run()
    path = tmp_path / "estimate_like.mcap"
    with path.open("wb") as f:
        writer = Writer(f)
        writer.start(profile="", library="test")
        schema = writer.register_schema("aslam.Keyframe", "jsonschema", b'{"type":"object"}')
        channel = writer.register_channel("/aslam/keyframe", "json", schema)
        for i, stamp in enumerate(stamps.tolist()):
            writer.add_message(
                channel, log_time=stamp, publish_time=stamp, data=json.dumps({"index": i}).encode()
            )
        write_scene(writer, metric_scene(embedding, stamps))
        writer.finish()
    with path.open("rb") as f:
        reader = make_reader(f)
        topics = [c.topic for _s, c, _m in reader.iter_messages()]
    assert topics.count("/aslam/keyframe") == len(stamps)
    messages = read_all(path)
    assert len(messages[SCENE_TOPIC]) == 18 and len(messages[TF_TOPIC]) == len(stamps)


def test_without_growth_one_scene(tmp_path: Path):
    embedding, stamps = square_run()
    path = tmp_path / "scene.mcap"
    write_scene(path, metric_scene(embedding, stamps), growth=False)
    assert len(read_all(path)[SCENE_TOPIC]) == 1


def test_same_input_same_bytes(tmp_path: Path):
    """Determinism end to end: two embeddings of the same run, two scene files, the same bytes."""
    a, b = tmp_path / "a.mcap", tmp_path / "b.mcap"
    for path in (a, b):
        embedding, stamps = square_run(wrong=True)
        write_scene(path, metric_scene(embedding, stamps), tool_version="0")
    assert a.read_bytes() == b.read_bytes()


def test_scene_file_refuses_to_overwrite_and_leaves_nothing_on_failure(tmp_path: Path):
    embedding, stamps = square_run()
    path = tmp_path / "scene.mcap"
    path.write_bytes(b"keep")
    with pytest.raises(SceneError, match="already exists"):
        write_scene(path, metric_scene(embedding, stamps))
    assert path.read_bytes() == b"keep"
    with pytest.raises(ValueError, match="poses"):
        MetricScene(stamps_ns=stamps, poses=embedding.poses[:-1], assignment=embedding.assignment)
    with pytest.raises(ValueError, match="NaN"):
        MetricScene(stamps_ns=stamps, poses=embedding.poses * np.nan, assignment=embedding.assignment)
    assert [p.name for p in tmp_path.iterdir()] == ["scene.mcap"]  # no partial file left behind


def test_a_scene_failing_halfway_leaves_nothing(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    """The keyframes are written (to the temporary file, or the writer's chunk for it), then the disk
    fills: nothing stays."""
    embedding, stamps = square_run()
    partial: list[str] = []

    def disk_full(_channels, _scene, _stamp_ns) -> None:
        partial.extend(p.name for p in tmp_path.iterdir())
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(foxglove.SceneChannels, "write_map", disk_full)
    with pytest.raises(OSError, match="No space left"):
        write_scene(tmp_path / "scene.mcap", metric_scene(embedding, stamps))
    assert len(partial) == 1 and partial[0].startswith(".scene.mcap.partial-")  # the temporary file
    assert list(tmp_path.iterdir()) == []


def test_a_large_map_grows_in_bounded_steps(tmp_path: Path):
    """One whole-map scene per growth would sum to O(places²) entities; the spaced scenes grow with
    the map's size by at least 1/GROWTH_STEPS each, so their count is logarithmic in it."""
    n = 1500
    poses = np.stack([np.arange(n, dtype=float), np.zeros(n), np.zeros(n)], axis=1)
    stamps = np.arange(n, dtype=np.int64) * 10**9
    path = tmp_path / "scene.mcap"
    write_scene(path, MetricScene(stamps, poses, np.arange(n, dtype=np.int64)))
    scenes = read_all(path)[SCENE_TOPIC]
    places = [
        len({e.id: e for e in as_package(scene, SceneUpdate).entities}["places"].spheres)
        for _, scene in scenes
    ]
    assert places[-1] == n and all(b > a for a, b in itertools.pairwise(places))
    growth = places[:-1]  # the last scene is the whole map, written at the end whatever it grew
    assert growth[: GROWTH_STEPS // 2] == list(range(1, GROWTH_STEPS // 2 + 1))  # every growth, early
    drawn = [2 * p - 1 for p in growth]  # places and the links between consecutive ones
    steps = [(a, b) for a, b in itertools.pairwise(drawn) if a >= GROWTH_STEPS]
    assert steps and all((b - a) * GROWTH_STEPS >= b for a, b in steps)
    assert len(scenes) <= GROWTH_STEPS * (1 + math.log(2 * n / GROWTH_STEPS)) + 1


def test_a_loop_closing_in_a_large_map_is_drawn_when_it_closes(tmp_path: Path):
    """40 places (79 places and links, past GROWTH_STEPS), then the loop closes and is driven
    again: each first closure link is one item, under 1/64 of the map, yet it is drawn at once."""
    places, laps = 40, 2
    n = places * laps
    angle = np.arange(n) * 2 * np.pi / places
    poses = np.stack([10 * np.cos(angle), 10 * np.sin(angle), angle + np.pi / 2], axis=1)
    assignment = np.arange(n, dtype=np.int64) % places
    stamps = np.arange(n, dtype=np.int64) * 10**9
    path = tmp_path / "scene.mcap"
    write_scene(path, MetricScene(stamps, poses, assignment))
    scenes = {message.log_time: as_package(m, SceneUpdate) for message, m in read_all(path)[SCENE_TOPIC]}
    closing = int(stamps[places])  # keyframe 40 revisits place 0: the link 39 → 0 closes the loop
    assert closing in scenes
    entities = {e.id: e for e in scenes[closing].entities}
    assert len(entities["loop_closures"].lines[0].points) == 2  # that one closure, drawn as one segment
