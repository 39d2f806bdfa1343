"""The metric view as Foxglove's well-known schemas, in MCAP (protobuf encoding).

Foxglove's 3D panel draws ``foxglove.SceneUpdate``, ``foxglove.PosesInFrame`` and
``foxglove.FrameTransform`` without any plug-in. The message classes, and the schemas written
into the file, come from Foxglove's own published package ``foxglove-schemas-protobuf`` (the
schema record is the package's ``FileDescriptorSet``, built by ``mcap-protobuf-support``), so
nothing here restates a schema by hand. Chosen over ``foxglove-sdk``: the SDK writes MCAP through
its own (Rust) writer and global log context, so it cannot add channels to an ``mcap.writer.Writer``
that another part of the tool is already writing, and its message objects cannot be decoded
back for tests; the schema package is plain protobuf, 0.6 MB, and decodes with mcap's reader.

Topics (all in frame ``map``, the embedding's frame: keyframe 0 at the origin, REP 103):

* ``/aslam/metric/scene`` ``foxglove.SceneUpdate``: places as spheres at their first visit's
  embedded pose, links as lines (exploration grey, loop closures green), and closures the
  robust kernel outvoted as red lines from the revisiting keyframe to the place it claimed;
  one message per keyframe that added a place or a link (the map growing, drawn at the final
  embedded poses), and the complete map at the last keyframe;
* ``/aslam/metric/trajectory`` and ``/aslam/metric/odometry`` ``foxglove.PosesInFrame``: the
  optimised and the odometry-only keyframe poses;
* ``/aslam/metric/tf`` ``foxglove.FrameTransform``: ``map`` → ``base_link`` at every keyframe.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from aslam.core import se2
from aslam.data_formats import files
from aslam.data_formats.errors import SceneError
from aslam.data_formats.graph_json import is_loop_closure_link

SCENE_TOPIC = "/aslam/metric/scene"
TRAJECTORY_TOPIC = "/aslam/metric/trajectory"
ODOMETRY_TOPIC = "/aslam/metric/odometry"
TF_TOPIC = "/aslam/metric/tf"
MAP_FRAME = "map"
BASE_FRAME = "base_link"
CHUNK_SIZE_BYTES = 256 * 1024

PLACE_DIAMETER_M = 0.25
LINE_THICKNESS_M = 0.04
PLACE_RGBA = (0.2, 0.45, 0.9, 1.0)
LINK_RGBA = (0.6, 0.6, 0.6, 1.0)
LOOP_RGBA = (0.1, 0.75, 0.3, 1.0)
OUTVOTED_RGBA = (0.9, 0.15, 0.1, 1.0)


@dataclass(frozen=True, eq=False)
class MetricScene:
    """What the scene draws: plain arrays, so the writer does not depend on how they were made."""

    stamps_ns: np.ndarray
    """(n,) keyframe stamps."""
    poses: np.ndarray
    """(n, 3) embedded ``(x_m, y_m, yaw_rad)`` per keyframe."""
    assignment: np.ndarray
    """(n,) state (first-visit keyframe) per keyframe."""
    odometry: np.ndarray | None = None
    """(n, 3) odometry-only poses, drawn as a second trajectory when given."""
    outvoted: np.ndarray | None = None
    """(n,) True for keyframes whose closure the robust kernel outvoted."""

    def __post_init__(self) -> None:
        n = len(self.stamps_ns)
        shapes = {"poses": (n, 3), "assignment": (n,), "odometry": (n, 3), "outvoted": (n,)}
        for name, shape in shapes.items():
            value = getattr(self, name)
            if value is not None and np.shape(value) != shape:
                raise ValueError(f"MetricScene.{name} has shape {np.shape(value)}, expected {shape}")
        for name in ("poses", "odometry"):
            value = getattr(self, name)
            if value is not None and not np.isfinite(value).all():
                raise ValueError(f"MetricScene.{name} contains NaN or infinity")


def _time(stamp_ns: int) -> Any:
    from google.protobuf.timestamp_pb2 import Timestamp

    stamp = Timestamp()
    stamp.FromNanoseconds(int(stamp_ns))
    return stamp


def _pose(x: float, y: float, yaw: float) -> Any:
    from foxglove_schemas_protobuf.Pose_pb2 import Pose

    pose = Pose()
    pose.position.x, pose.position.y, pose.position.z = float(x), float(y), 0.0
    orientation = pose.orientation
    orientation.w, orientation.x, orientation.y, orientation.z = se2.yaw_quaternion(yaw)
    return pose


def _color(target: Any, rgba: tuple[float, float, float, float]) -> None:
    target.r, target.g, target.b, target.a = rgba


class _GrowingScene:
    """The map as one ``foxglove.SceneUpdate``, extended keyframe by keyframe.

    Each growth scene is the one before plus what is new, so it is extended in place and
    serialised, instead of rebuilt: rebuilding made O(64 × places) protobuf objects in Python, most
    of writing an estimate file. Entities keep their ids from scene to scene, so a viewer replaces
    each with the latest one.
    """

    def __init__(self, scene: MetricScene) -> None:
        from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

        self._scene = scene
        self._poses = np.asarray(scene.poses, float)
        self._assignment = np.asarray(scene.assignment, np.int64).tolist()
        self._update = SceneUpdate()
        self._places = self._entity("places")
        self._place_count = self._places.metadata.add()
        self._place_count.key = "places"
        self._links = self._entity("links")
        self._loops = self._entity("loop_closures")
        self._outvoted = self._entity("outvoted_closures")
        self._upto = 0
        self._drawn_places = 0
        self._seen: set[tuple[int, int]] = set()

    def _entity(self, name: str) -> Any:
        entity = self._update.entities.add()
        entity.frame_id = MAP_FRAME
        entity.id = name
        entity.frame_locked = False
        return entity

    def extend(self, upto: int) -> None:
        """Draw keyframes ``[0, upto)``: their new places, and the links between consecutive ones."""
        assignment, poses = self._assignment, self._poses
        for k in range(self._upto, upto):
            if assignment[k] == k:
                sphere = self._places.spheres.add()
                sphere.pose.CopyFrom(_pose(*poses[k]))
                sphere.size.x = sphere.size.y = sphere.size.z = PLACE_DIAMETER_M
                _color(sphere.color, PLACE_RGBA)
                self._drawn_places += 1
        for k in range(max(self._upto - 1, 0), upto - 1):
            a, b = assignment[k], assignment[k + 1]
            if a == b or (a, b) in self._seen or (b, a) in self._seen:
                continue
            self._seen.add((a, b))
            if is_loop_closure_link(a, b):
                _segment(self._loops, poses[a], poses[b], LOOP_RGBA)
            else:
                _segment(self._links, poses[a], poses[b], LINK_RGBA)
        self._upto = max(self._upto, upto)

    def message(self, stamp_ns: int, *, complete: bool = False) -> Any:
        """The scene as drawn so far, stamped ``stamp_ns``; ``complete`` adds the outvoted closures
        (drawn in the complete map only). Valid until the next ``extend``."""
        stamp = _time(stamp_ns)
        for entity in self._update.entities:
            entity.timestamp.CopyFrom(stamp)
        self._place_count.value = str(self._drawn_places)
        if complete and self._scene.outvoted is not None:
            for k in np.flatnonzero(np.asarray(self._scene.outvoted, bool)).tolist():
                _segment(self._outvoted, self._poses[k], self._poses[self._assignment[k]], OUTVOTED_RGBA)
        return self._update


def _segment(entity: Any, a: np.ndarray, b: np.ndarray, rgba: tuple[float, float, float, float]) -> None:
    """One more segment in the entity's one line list (made with its first segment)."""
    if not entity.lines:
        from foxglove_schemas_protobuf.LinePrimitive_pb2 import LinePrimitive

        line = entity.lines.add()
        line.type = LinePrimitive.LINE_LIST
        line.pose.CopyFrom(_pose(0.0, 0.0, 0.0))
        line.thickness = LINE_THICKNESS_M
        line.scale_invariant = False
        _color(line.color, rgba)
    points = entity.lines[0].points
    for p in (a, b):
        point = points.add()
        point.x, point.y, point.z = float(p[0]), float(p[1]), 0.0


def poses_in_frame(poses: np.ndarray, stamp_ns: int) -> Any:
    from foxglove_schemas_protobuf.PosesInFrame_pb2 import PosesInFrame

    message = PosesInFrame()
    message.timestamp.CopyFrom(_time(stamp_ns))
    message.frame_id = MAP_FRAME
    for pose in np.asarray(poses, float).tolist():
        message.poses.append(_pose(*pose))
    return message


def frame_transform(pose: np.ndarray, stamp_ns: int) -> Any:
    from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform

    x, y, yaw = (float(v) for v in pose)
    message = FrameTransform()
    message.timestamp.CopyFrom(_time(stamp_ns))
    message.parent_frame_id = MAP_FRAME
    message.child_frame_id = BASE_FRAME
    message.translation.x, message.translation.y, message.translation.z = x, y, 0.0
    rotation = message.rotation
    rotation.w, rotation.x, rotation.y, rotation.z = se2.yaw_quaternion(yaw)
    return message


GROWTH_STEPS = 64
"""A growth scene is written once the map (places and links) has grown by 1/64 of its size since
the last one (so at every new place or link below 64 of them), or its loop closures by 1/64 of
their number (so a loop closing is drawn when it closes, however large the map). Each scene holds
the whole map so far — a viewer that seeks shows the map of that moment — so one per growth summed
to O(places²) entities (2.0 M place spheres for 2,000 places); spaced this way they sum to
O(64 × places) (121,334 for 2,000) for the map's growth, plus a scene per closure for the first 64
closures and geometrically fewer after."""


def _grown(count: int, at_last_scene: int) -> bool:
    return count > at_last_scene and (count - at_last_scene) * GROWTH_STEPS >= count


def preload_schemas() -> None:
    """Import Foxglove's protobuf schemas (0.03 s, protobuf's runtime included) before they are needed."""
    import foxglove_schemas_protobuf.FrameTransform_pb2
    import foxglove_schemas_protobuf.LinePrimitive_pb2
    import foxglove_schemas_protobuf.PosesInFrame_pb2
    import foxglove_schemas_protobuf.SceneUpdate_pb2  # noqa: F401
    import mcap_protobuf.schema  # noqa: F401


class SceneChannels:
    """The metric view's schemas and channels, registered on an ``mcap.writer.Writer`` already started.

    The writer may carry other channels (an estimate file's JSON topics): this only adds its own,
    so the lead's ``EstimateWriter`` can hand over its writer before ``finish``.
    """

    def __init__(self, writer: Any) -> None:
        from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
        from foxglove_schemas_protobuf.PosesInFrame_pb2 import PosesInFrame
        from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
        from mcap_protobuf.schema import register_schema

        self._writer = writer
        scene = register_schema(writer, SceneUpdate)
        poses = register_schema(writer, PosesInFrame)
        transform = register_schema(writer, FrameTransform)
        self._channels = {
            SCENE_TOPIC: writer.register_channel(SCENE_TOPIC, "protobuf", scene),
            TRAJECTORY_TOPIC: writer.register_channel(TRAJECTORY_TOPIC, "protobuf", poses),
            ODOMETRY_TOPIC: writer.register_channel(ODOMETRY_TOPIC, "protobuf", poses),
            TF_TOPIC: writer.register_channel(TF_TOPIC, "protobuf", transform),
        }
        self._sequence = dict.fromkeys(self._channels, 0)

    def _add(self, topic: str, stamp_ns: int, message: Any) -> None:
        self._writer.add_message(
            self._channels[topic],
            log_time=int(stamp_ns),
            publish_time=int(stamp_ns),
            data=message.SerializeToString(deterministic=True),
            sequence=self._sequence[topic],
        )
        self._sequence[topic] += 1

    def write_keyframes(self, scene: MetricScene, *, growth: bool = True) -> None:
        """Per keyframe, in time order: ``map`` → ``base_link`` (the robot moving through the
        embedded map) and, with ``growth``, the map as of that keyframe when it has grown (drawn at
        the final embedded poses): at every new place or link while the map is small, then each
        time it has grown by ``1 / GROWTH_STEPS`` of its size since the last scene. Keyframes that
        only revisit known places and links add no scene. The last keyframe's scene is left to
        :meth:`write_map`."""
        seen: set[tuple[int, int]] = set()
        assignment = np.asarray(scene.assignment, np.int64).tolist()
        stamps = scene.stamps_ns.tolist()
        growing = _GrowingScene(scene)
        # places and links in the map so far, and at the last scene; loop closures counted apart too
        drawn = drawn_at_last_scene = closures = closures_at_last_scene = 0
        for k, (stamp_ns, pose) in enumerate(zip(stamps, scene.poses, strict=True)):
            self._add(TF_TOPIC, stamp_ns, frame_transform(pose, stamp_ns))
            if not growth or k == len(assignment) - 1:
                continue
            drawn += assignment[k] == k
            if k:
                link = (min(assignment[k - 1], assignment[k]), max(assignment[k - 1], assignment[k]))
                if link[0] != link[1] and link not in seen:
                    seen.add(link)
                    drawn += 1
                    closures += is_loop_closure_link(*link)
            if _grown(drawn, drawn_at_last_scene) or _grown(closures, closures_at_last_scene):
                drawn_at_last_scene, closures_at_last_scene = drawn, closures
                growing.extend(k + 1)
                self._add(SCENE_TOPIC, stamp_ns, growing.message(stamp_ns))

    def write_map(self, scene: MetricScene, stamp_ns: int) -> None:
        """The whole scene and the trajectories as they stand at ``stamp_ns``."""
        complete = _GrowingScene(scene)
        complete.extend(len(scene.assignment))
        self._add(SCENE_TOPIC, stamp_ns, complete.message(stamp_ns, complete=True))
        self._add(TRAJECTORY_TOPIC, stamp_ns, poses_in_frame(scene.poses, stamp_ns))
        if scene.odometry is not None:
            self._add(ODOMETRY_TOPIC, stamp_ns, poses_in_frame(scene.odometry, stamp_ns))


def write_scene(
    target: Any, scene: MetricScene, *, growth: bool = True, force: bool = False, tool_version: str = ""
) -> None:
    """Write the metric view: into ``target``, an ``mcap.writer.Writer`` already started (its owner
    finishes it), or into a new MCAP file at ``target`` (a path; written atomically).

    Transforms at every keyframe; with ``growth`` the map at each keyframe that extended it; then
    the complete map and the trajectories at the last keyframe's stamp.
    """
    if isinstance(target, str | Path):
        _write_file(Path(target), scene, growth=growth, force=force, tool_version=tool_version)
        return
    channels = SceneChannels(target)
    channels.write_keyframes(scene, growth=growth)
    if len(scene.stamps_ns):
        channels.write_map(scene, int(scene.stamps_ns[-1]))


def _write_file(path: Path, scene: MetricScene, *, growth: bool, force: bool, tool_version: str) -> None:
    from mcap.writer import CompressionType, Writer

    output = files.AtomicFile(path, force=force, error=SceneError)
    try:
        writer = Writer(output.file, chunk_size=CHUNK_SIZE_BYTES, compression=CompressionType.ZSTD)
        writer.start(profile="", library=f"aslam {tool_version}".strip())
        write_scene(writer, scene, growth=growth)
    except BaseException:
        output.abort()
        raise
    output.commit(finish=writer.finish)
