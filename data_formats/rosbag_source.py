"""ROS bags as robots write them: rosbag2 folders (mcap or sqlite3 storage, split or zstd-compressed
files), single rosbag2 storage files and ROS 1 ``.bag`` files, read through ``rosbags``.

:func:`iter_bag_samples` yields the same ``Sample`` stream as ``Recording.samples`` (one per
camera image, poses interpolated to its stamp by the same ``SampleAssembler``), so everything downstream
is unchanged. Topics are found rather than configured: the only image topic, the only
``nav_msgs/Odometry`` topic or else the ``odom → base`` transforms on ``/tf``. Message types come
from the bag's own definitions (rosbags' ``AnyReader``); a rosbag2 bag written before ROS 2 Iron
carries none, and is read with rosbags' latest ROS 2 type store.

:func:`open_source` tells the kinds of input apart, :func:`summarize_bag` lists a bag's topics
without reading its messages, :func:`describe_bag` reads it all for ``aslam info``.
"""

from __future__ import annotations

import errno
import math
import re
import tempfile
from collections.abc import Callable, Generator, Iterator
from contextlib import contextmanager, suppress
from dataclasses import dataclass, replace
from enum import StrEnum
from pathlib import Path
from typing import Any

import numpy as np

from aslam.core.errors import InputError
from aslam.data_formats import ros_msgs
from aslam.data_formats.camera import CameraIntrinsics
from aslam.data_formats.errors import BagError, UnopenableBag
from aslam.data_formats.files import (
    ROSBAG2_METADATA_MAX_BYTES,
    check_input_file,
    rosbag2_information,
    source_files,
    source_size_bytes,
)
from aslam.data_formats.mcap_file import McapFile
from aslam.data_formats.pose_limits import implausible
from aslam.data_formats.pose_sync import Sample, SampleAssembler, StampOrder
from aslam.data_formats.recording import (
    _header_stamp_ns,
    _lazy_image,
    _set_header_stamp_ns,
    checked_pose,
    negative_stamp,
    topic_list,
)
from aslam.data_formats.recording_info import TopicInfo

TF_TYPES = ("tf2_msgs/msg/TFMessage", "tf/msg/tfMessage")
_BAG1_MAGIC = b"#ROSBAG V2.0"
_SQLITE_MAGIC = b"SQLite format 3\x00"
ESTIMATE_METADATA_NAME = "aslam.estimate"
"""``aslam.data_formats.estimate.ESTIMATE_METADATA``, named here so telling inputs apart imports no numpy."""
_ZSTD_MAGIC = b"\x28\xb5\x2f\xfd"


class SourceKind(StrEnum):
    """What a path given to ``estimate``/``info``/``report`` holds."""

    RECORDING = "recording"  # our MCAP recording (carries the ``aslam.recording`` metadata)
    ROSBAG2 = "rosbag2"  # a rosbag2 folder (metadata.yaml + storage files)
    ROSBAG2_FILE = "rosbag2-file"  # one rosbag2 storage file (.mcap or .db3) on its own
    ROSBAG1 = "rosbag1"  # a ROS 1 .bag file
    IMAGE_FOLDER = "image-folder"  # a folder of png/jpg images (``aslam import``)


BAG_KINDS = (SourceKind.ROSBAG2, SourceKind.ROSBAG2_FILE, SourceKind.ROSBAG1)


def open_source(path: Path) -> SourceKind:
    """Tell by content (not only the name) what ``path`` is; BagError for anything unreadable."""
    return classify(path)[0]


def classify(
    path: Path, *, on_warning: Callable[[str], None] | None = None
) -> tuple[SourceKind, McapFile | None]:
    """:func:`open_source`, with the ``McapFile`` opened on the way (summary read) for an MCAP file."""
    path = Path(path)
    if not path.exists():
        raise BagError("no such file or folder", path=path)
    if path.is_dir():
        metadata = path / "metadata.yaml"
        if metadata.is_file():
            if (size := metadata.stat().st_size) > ROSBAG2_METADATA_MAX_BYTES:
                raise BagError(
                    f"its metadata.yaml is {size:,} bytes; a rosbag2 index is a few kilobytes (at most"
                    f" {ROSBAG2_METADATA_MAX_BYTES:,} are read)",
                    path=path,
                )
            for file in source_files(path):  # a FIFO among them blocked every command in open()
                if file.exists() and not file.is_file():
                    raise BagError(
                        f"{file.name} in it is not a regular file (a FIFO, socket, device or folder)",
                        path=path,
                    )
            return SourceKind.ROSBAG2, None
        # Imported here: the image folder's reader (pose files, KITTI stamps, decimal) is no part of
        # an estimate's start-up from a recording (about 5 ms before the reader process starts).
        from aslam.data_formats.image_folder import holds_frames

        if holds_frames(path):
            return SourceKind.IMAGE_FOLDER, None
        raise BagError("is a folder with neither a rosbag2 metadata.yaml nor png/jpg images", path=path)
    check_input_file(path, error=BagError, what="an MCAP recording")  # a FIFO is refused, never opened
    try:
        with path.open("rb") as f:
            head = f.read(len(_SQLITE_MAGIC))
    except OSError as err:
        raise BagError(f"cannot read: {err.strerror or err}", path=path) from err
    if not head:
        raise BagError("empty file (0 bytes)", path=path)
    from aslam.data_formats.files import MCAP_MAGIC

    if head.startswith(MCAP_MAGIC):
        from aslam.data_formats.recording import METADATA_NAME, RecordingTopics

        if len(head) <= len(MCAP_MAGIC):  # rosbags then fails inside its parser (a TypeError)
            raise BagError(
                f"an MCAP file of {len(head)} bytes, its magic alone: cut short, nothing to read", path=path
            )

        mcap = McapFile(path, on_warning=on_warning)
        ours = RecordingTopics()
        # Our own recordings, and MCAP files laid out as ours (the same image and odometry topics),
        # are read by aslam's own reader; any other MCAP file as a rosbag2 storage file.
        if mcap.metadata(METADATA_NAME) is not None or {ours.image, ours.odometry} <= set(mcap.channels):
            return SourceKind.RECORDING, mcap
        if mcap.metadata(ESTIMATE_METADATA_NAME) is not None:
            raise BagError("an aslam estimate file, not a recording (`aslam report` reads it)", path=path)
        _need_suffix(path, ".mcap", "an MCAP file")
        return SourceKind.ROSBAG2_FILE, mcap
    if head.startswith(_BAG1_MAGIC):
        _need_suffix(path, ".bag", "a ROS 1 bag")
        return SourceKind.ROSBAG1, None
    if head == _SQLITE_MAGIC:
        _need_suffix(path, ".db3", "a rosbag2 sqlite3 file")
        return SourceKind.ROSBAG2_FILE, None
    if head.startswith(_ZSTD_MAGIC):
        raise BagError(
            "is a zstd-compressed file; pass the rosbag2 folder that holds it and its metadata.yaml",
            path=path,
        )
    raise BagError("not a recording or a bag (neither MCAP, rosbag2 sqlite3 nor ROS 1 bag)", path=path)


def _need_suffix(path: Path, suffix: str, what: str) -> None:
    # rosbags picks its reader by file name; a renamed file would be read as something else.
    if path.suffix.lower() != suffix:
        raise BagError(f"is {what} but its name does not end in '{suffix}'; rename it", path=path)


# --- topics -------------------------------------------------------------------------------------


@dataclass(frozen=True)
class BagTopics:
    """Which topics to read; None means "find it" (see :func:`resolve_topics`)."""

    image: str | None = None
    odometry: str | None = None  # an Odometry/PoseStamped topic; None: the only Odometry, else /tf
    ground_truth: str | None = None  # read only when named
    tf: str = "/tf"
    odom_frame: str = "odom"
    base_frame: str | None = None  # None: found among odom_frame's children on /tf (_TfOdometry)


@dataclass(frozen=True)
class ResolvedTopics:
    image: str
    odometry: str | None  # None: poses from the odom → base transforms on ``tf``
    ground_truth: str | None
    tf: str | None

    def describe_odometry(self, base_frame: str | None, odom_frame: str) -> str:
        if self.odometry is not None:
            return self.odometry
        return f"{self.tf} ({odom_frame} → {base_frame or 'first child frame'})"


def resolve_topics(path: Path, types: dict[str, str], topics: BagTopics) -> ResolvedTopics:
    """The topics to read, given the bag's ``topic → type``; BagError naming the choices if ambiguous."""

    def named(what: str, topic: str, accepted: tuple[str, ...]) -> str:
        if topic not in types:
            raise BagError(f"no {what} topic '{topic}' (topics in the bag: {topic_list(types)})", path=path)
        if types[topic] not in accepted:
            raise BagError(
                f"{what} topic '{topic}' has type '{types[topic]}'; expected {' or '.join(accepted)}",
                path=path,
            )
        return topic

    def only(what: str, accepted: tuple[str, ...], option: str) -> str | None:
        found = sorted(t for t, datatype in types.items() if datatype in accepted)
        if len(found) > 1:
            listed = ", ".join(f"{t} ({types[t]})" for t in found)
            raise BagError(f"{len(found)} {what} topics: {listed}; choose one with {option}", path=path)
        return found[0] if found else None

    if topics.image is not None:
        image = named("image", topics.image, ros_msgs.IMAGE_TYPES)
    else:
        found = only("image", ros_msgs.IMAGE_TYPES, "--image-topic")
        if found is None:
            raise BagError(
                f"no sensor_msgs/msg/Image or CompressedImage topic (topics in the bag: {topic_list(types)})",
                path=path,
            )
        image = found
    tf = None
    if topics.odometry is not None:
        odometry: str | None = named("odometry", topics.odometry, ros_msgs.POSE_TYPES)
    else:
        odometry = only("odometry", (ros_msgs.ODOMETRY,), "--odometry-topic")
        if odometry is None:
            if types.get(topics.tf) not in TF_TYPES:
                poses = [
                    t for t, kind in types.items() if kind in ros_msgs.POSE_TYPES and t != topics.ground_truth
                ]
                hint = _odometry_hint(poses)
                raise BagError(
                    f"no odometry: neither a nav_msgs/msg/Odometry topic nor transforms on '{topics.tf}' "
                    f"(topics in the bag: {topic_list(types)}){hint}",
                    path=path,
                )
            tf = topics.tf
    truth = None
    if topics.ground_truth is not None:
        truth = named("ground-truth", topics.ground_truth, ros_msgs.POSE_TYPES)
    return ResolvedTopics(image, odometry, truth, tf)


# --- reading ------------------------------------------------------------------------------------


def _pose(
    path: Path, what: str, topic: str, datatype: str, msg: Any, stamp_ns: int, previous: np.ndarray | None
) -> np.ndarray:
    """The planar pose of a pose message, finite and plausible after ``previous`` (as a recording's)."""
    return checked_pose(path, what, topic, datatype, msg, stamp_ns, previous, error=BagError)


def _stamp(path: Path, what: str, topic: str, msg: Any, log_time: int) -> int:
    """The message's header stamp (its log time if unset), refused before 1970."""
    try:
        stamp_ns = _header_stamp_ns(msg, log_time)
    except ros_msgs.StampError as err:
        raise BagError(f"{what} message on '{topic}' at log time {log_time} ns: {err}", path=path) from None
    if stamp_ns < 0:
        raise BagError(negative_stamp(what, topic, stamp_ns), path=path)
    return stamp_ns


@contextmanager
def _rosbags_errors(path: Path, doing: str) -> Iterator[None]:
    """Every exception from rosbags (and the sqlite/zstd/yaml code under it) → one BagError line."""
    try:
        yield
    except InputError:
        raise
    except Exception as err:
        raise BagError(f"{doing}: {type(err).__name__}: {err}", path=path) from err


@contextmanager
def _metadata_errors(path: Path, doing: str) -> Iterator[None]:
    """:func:`_rosbags_errors`; in a rosbag2 folder, whose index is its metadata.yaml as written
    (rosbags checks the fields' names, not their types), a value of the wrong type there is named
    as that file's fault rather than as a TypeError of rosbags' own arithmetic."""
    try:
        with _rosbags_errors(path, doing):
            yield
    except BagError as err:
        cause = err.__cause__
        if not path.is_dir() or not isinstance(cause, (TypeError, ValueError, AttributeError, KeyError)):
            raise
        raise BagError(
            f"its metadata.yaml has a field of the wrong type ({type(cause).__name__}: {cause})", path=path
        ) from cause


#: What rosbags says of a bag whose recorder stopped before writing its index (killed, power lost).
_NO_INDEX_SIGNS = ("File end magic is invalid", "index looks damaged", "Header could not be read")
#: A file that cannot grow: the disk full, over quota, or over the process's file size limit.
_NO_ROOM = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG)
_REINDEX_HINT = (
    "a bag whose recorder was stopped before closing it has no index: rebuild it on a copy with "
    "'ros2 bag reindex' (ROS 2) or 'rosbag reindex' (ROS 1)"
)


@contextmanager
def _open_reader(path: Path) -> Iterator[Any]:
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    try:
        with _metadata_errors(path, "cannot open the bag"):
            reader = AnyReader([path], default_typestore=get_typestore(Stores.LATEST))
            reader.open()
    except BagError as err:
        problem = err.problem
        if any(sign in str(err) for sign in _NO_INDEX_SIGNS):
            hint = _REINDEX_HINT
            if path.is_file() and path.suffix.lower() == ".mcap":  # ours and a rosbag2 file look alike cut
                hint += "; an aslam recording cut short that early holds nothing to read: record it again"
            problem = f"{problem}; {hint}"
        elif isinstance(err.__cause__, OSError) and err.__cause__.errno in _NO_ROOM:
            problem = (
                f"{problem}; rosbags decompresses a bag compressed by file whole into the temporary folder"
                f" ({tempfile.gettempdir()}): point TMPDIR at a disk with room for the uncompressed bag"
            )
        raise UnopenableBag(problem, path=path) from err
    try:
        try:
            with _metadata_errors(path, "cannot read the bag's index"):
                # rosbags derives these from a rosbag2 folder's metadata.yaml only when first asked,
                # and keeps its names as written: a field of the wrong type (a count that is a word, a
                # type that is a number) surfaced as a bare TypeError in the middle of a run. Asked
                # here, it is one line at the open, naming the file.
                _ = (reader.topics, reader.message_count, reader.start_time, reader.end_time)
                _check_names(reader, path)
        except BagError as err:  # its index damaged: no topic of it can be read either
            raise UnopenableBag(err.problem, path=path) from err
        yield reader
    finally:
        with _rosbags_errors(path, "cannot close the bag"):
            reader.close()


def _check_names(reader: Any, path: Path) -> None:
    """TypeError where a topic's name or type, or a rosbag2 folder's ROS distribution, is no text."""
    for connection in reader.connections:
        for what, value in (("name", connection.topic), ("type", connection.msgtype)):
            if not isinstance(value, str):
                raise TypeError(f"a topic's {what} is {value!r}, not text")
    if path.is_dir():
        distro = reader.readers[0].storage.metadata.ros_distro  # as _storage reads it
        if distro is not None and not isinstance(distro, str):
            raise TypeError(f"ros_distro is {distro!r}, not text")


def _topic_types(reader: Any) -> dict[str, str]:
    """Each topic's message type; rosbags gives none for a topic that carries several, which the
    errors then showed as type '' (now: the types, joined with " and ")."""
    types = {topic: info.msgtype or "" for topic, info in reader.topics.items()}
    for topic in [topic for topic, msgtype in types.items() if not msgtype]:
        types[topic] = " and ".join(sorted({c.msgtype for c in reader.connections if c.topic == topic}))
    return types


def _messages(path: Path, reader: Any, topics: set[str]) -> Iterator[tuple[str, str, int, Any]]:
    """``(topic, type, log_time_ns, message)`` in log-time order; rosbags errors become BagErrors."""
    connections = [c for c in reader.connections if c.topic in topics]
    if not connections:
        return
    with _rosbags_errors(path, "cannot read the bag"):
        stream = reader.messages(connections=connections)
    while True:
        with _rosbags_errors(path, "corrupt bag data"):
            try:
                connection, log_time, raw = next(stream)
            except StopIteration:
                return
        with _rosbags_errors(path, f"undecodable message on '{connection.topic}' at log time {log_time} ns"):
            msg = reader.deserialize(raw, connection.msgtype)
        yield connection.topic, connection.msgtype, log_time, msg


def _frame(name: str) -> str:
    return str(name).lstrip("/")  # ROS 1 frames may carry a leading slash


#: The body frames REP 105 names, preferred among ``odom``'s children on /tf when none is named.
BASE_FRAMES = ("base_footprint", "base_link")


TRUTH_NAMES = ("gt", "mocap", "vicon", "optitrack")
"""Words in a topic's name that say it holds the true path, not odometry (besides "truth" anywhere)."""


def _odometry_hint(poses: list[str]) -> str:
    """The error's suggestion of a pose topic for ``--odometry-topic``: one whose name says odometry
    first; a ground-truth topic last and said to be one (estimated on it, a run is scored against
    its own odometry, and the figures look perfect and mean nothing)."""
    if not poses:
        return ""

    def looks_like_truth(topic: str) -> bool:
        name = topic.lower()
        return "truth" in name or any(word in TRUTH_NAMES for word in re.split(r"[-_/]", name))

    topic = min(poses, key=lambda t: ("odom" not in t.lower(), looks_like_truth(t), t))
    caveat = (
        " (its name says ground truth: estimated on it, the scores would compare it with itself)"
        if looks_like_truth(topic)
        else ""
    )
    return f"; name a pose topic with --odometry-topic, e.g. {topic}{caveat}"


class _TfOdometry:
    """Planar poses of ``base`` in ``odom`` from TFMessages. Unnamed, ``base`` is the first message's
    child of ``odom`` that REP 105 names a body frame, else its first child: a marker or sensor frame
    published beside ``base_link`` in one message was taken for the robot (a constant pose: one
    keyframe from a whole drive)."""

    def __init__(self, odom_frame: str, base_frame: str | None, warn: Callable[[str], None], path: Path):
        self.odom_frame = _frame(odom_frame)
        self.base_frame = None if base_frame is None else _frame(base_frame)
        self._warn = warn
        self._path = path
        self.pairs_seen: set[tuple[str, str]] = set()

    def _choose_base(self, msg: Any) -> None:
        children = [
            _frame(t.child_frame_id) for t in msg.transforms if _frame(t.header.frame_id) == self.odom_frame
        ]
        if not children:
            return
        named = [child for child in BASE_FRAMES if child in children]
        self.base_frame = named[0] if named else children[0]
        others = sorted(set(children) - {self.base_frame})
        if named and not others:  # REP 105's body frame, the only child: nothing was guessed
            return
        also = f" (its other children: {', '.join(others)}; --base-frame chooses)" if others else ""
        self._warn(f"{self._path}: odometry from /tf: {self.odom_frame} → {self.base_frame}{also}")

    def poses(self, msg: Any, log_time: int) -> Iterator[tuple[int, np.ndarray]]:
        if self.base_frame is None:
            self._choose_base(msg)
        for transform in msg.transforms:
            parent, child = _frame(transform.header.frame_id), _frame(transform.child_frame_id)
            if len(self.pairs_seen) < 64:
                self.pairs_seen.add((parent, child))
            if parent != self.odom_frame:
                continue
            if child != self.base_frame:
                continue
            try:
                stamp_ns = _header_stamp_ns(transform, log_time)
            except ros_msgs.StampError as err:
                raise BagError(
                    f"odometry transform {parent} → {child} at log time {log_time} ns: {err}", path=self._path
                ) from None
            t, q = transform.transform.translation, transform.transform.rotation
            values = (float(t.x), float(t.y), float(q.x), float(q.y), float(q.z), float(q.w))
            if not all(math.isfinite(v) for v in values):
                raise BagError(
                    f"odometry transform {parent} → {child} at stamp {stamp_ns} ns is not finite",
                    path=self._path,
                )
            try:
                yaw = ros_msgs.yaw_of_quaternion(*values[2:])
            except ValueError as err:  # a zero quaternion: exit 70 from the reader, before
                raise BagError(
                    f"odometry transform {parent} → {child} at stamp {stamp_ns} ns: {err}", path=self._path
                ) from None
            yield stamp_ns, np.array([values[0], values[1], yaw])


def check_bag_path(path: Path) -> SourceKind:
    kind = open_source(path)
    if kind not in BAG_KINDS:
        raise BagError(f"is a {kind.value}, not a ROS bag", path=path)
    return kind


def iter_bag_samples(
    path: Path,
    topics: BagTopics = BagTopics(),
    *,
    on_warning: Callable[[str], None] | None = None,
    on_image_count: Callable[[int], None] | None = None,
    ground_truth: bool = True,
) -> Iterator[Sample]:
    """One ``Sample`` per camera image of a bag, in time order, with poses interpolated to its stamp;
    with ``ground_truth=False`` the truth topic (still resolved and checked) is not read.

    Streams (rosbags reads chunk by chunk; only images waiting for the next odometry message are
    held). The path is checked at once; topic problems surface on the first ``next``. Warnings
    (dropped images, odometry taken from /tf) go to ``on_warning``, one line each;
    ``on_image_count(n)``, once the bag is open, gets the image topic's message count from its index.
    """
    path = Path(path)
    check_bag_path(path)
    warn = on_warning or (lambda _message: None)
    return _iter_bag_samples(path, topics, warn, on_image_count, ground_truth=ground_truth)


def _iter_bag_samples(
    path: Path,
    topics: BagTopics,
    warn: Callable[[str], None],
    on_image_count: Callable[[int], None] | None,
    *,
    ground_truth: bool,
) -> Iterator[Sample]:
    with _open_reader(path) as reader:
        yield from _bag_samples(path, reader, topics, warn, on_image_count, ground_truth=ground_truth)


def _bag_samples(
    path: Path,
    reader: Any,
    topics: BagTopics,
    warn: Callable[[str], None],
    on_image_count: Callable[[int], None] | None,
    read_counts: dict[str, int] | None = None,
    *,
    ground_truth: bool = True,
) -> Iterator[Sample]:
    """The samples of the bag ``reader`` has open, then the pairing's warnings; ``on_image_count``
    and ``ground_truth`` as :func:`iter_bag_samples`'s. ``read_counts``, if given, gets the messages
    read per topic.

    A topic read holding fewer (or more) messages than the bag's index says is warned about: rosbags
    skips an MCAP chunk it cannot read and a sqlite row deleted, with no error, so a damaged bag
    would otherwise read as a shorter one with no word (and be scored as complete)."""
    if read_counts is None:
        read_counts = {}
    types = _topic_types(reader)
    resolved = resolve_topics(path, types, topics)
    if not ground_truth:  # resolved, so a named topic the bag lacks is still an error
        resolved = replace(resolved, ground_truth=None)
    counts = {topic: info.msgcount for topic, info in reader.topics.items()}
    if on_image_count is not None:
        on_image_count(int(counts[resolved.image]))
    tf = _TfOdometry(topics.odom_frame, topics.base_frame, warn, path) if resolved.tf else None
    odometry_topic = (
        f"'{resolved.odometry}'" if tf is None else f"'{resolved.tf}' (from frame '{tf.odom_frame}')"
    )
    assembler = SampleAssembler(
        path, odometry_topic=odometry_topic, ground_truth_topic=f"'{resolved.ground_truth}'"
    )
    assembler.expect_ground_truth = resolved.ground_truth is not None and counts[resolved.ground_truth] != 0
    last_odometry: np.ndarray | None = None
    last_truth: np.ndarray | None = None
    wanted = {t for t in (resolved.image, resolved.odometry, resolved.ground_truth, resolved.tf) if t}
    for topic, datatype, log_time, msg in _messages(path, reader, wanted):
        read_counts[topic] = read_counts.get(topic, 0) + 1
        if topic == resolved.image:
            stamp_ns = _stamp(path, "image", topic, msg, log_time)
            assembler.log_time_images += _set_header_stamp_ns(msg) is None
            yield from assembler.add_image(stamp_ns, _lazy_image(path, topic, datatype, msg, stamp_ns))
        elif topic == resolved.odometry:
            stamp_ns = _stamp(path, "odometry", topic, msg, log_time)
            if assembler.odometry_stamps.admits(stamp_ns):
                last_odometry = _pose(path, "odometry", topic, datatype, msg, stamp_ns, last_odometry)
                yield from assembler.add_odometry(stamp_ns, last_odometry)
        elif topic == resolved.tf and tf is not None:
            for stamp_ns, pose in tf.poses(msg, log_time):
                if stamp_ns < 0:
                    raise BagError(negative_stamp("odometry", topic, stamp_ns), path=path)
                if not assembler.odometry_stamps.admits(stamp_ns):
                    continue
                problem = implausible(pose, last_odometry)
                if problem is not None:
                    raise BagError(f"odometry pose on '{topic}' at stamp {stamp_ns} ns {problem}", path=path)
                last_odometry = pose
                yield from assembler.add_odometry(stamp_ns, pose)
        if topic == resolved.ground_truth:  # the odometry's own topic too, if named so (exact odometry)
            stamp_ns = _stamp(path, "ground-truth", topic, msg, log_time)
            if assembler.ground_truth_stamps.admits(stamp_ns):
                last_truth = _pose(path, "ground-truth", topic, datatype, msg, stamp_ns, last_truth)
                yield from assembler.add_ground_truth(stamp_ns, last_truth)
    if tf is not None and last_odometry is None:
        pairs = ", ".join(f"{p} → {c}" for p, c in sorted(tf.pairs_seen)) or "none"
        raise BagError(
            f"no transform from frame '{tf.odom_frame}'"
            + (f" to '{tf.base_frame}'" if tf.base_frame else "")
            + f" on '{resolved.tf}' (transforms seen: {pairs}); name the frames (--odom-frame,"
            " --base-frame) or an odometry topic (--odometry-topic)",
            path=path,
        )
    yield from assembler.finish()
    odometry = (
        f"'{resolved.odometry}'" if tf is None else f"'{resolved.tf}' ({tf.odom_frame} → {tf.base_frame})"
    )
    problem = assembler.unpaired(f"'{resolved.image}'", odometry)
    if problem is not None:
        raise BagError(problem, path=path)
    for line in assembler.warnings():
        warn(line)
    for topic in sorted(wanted):
        if (held := read_counts.get(topic, 0)) != counts[topic]:
            warn(f"{path}: the bag's index says {counts[topic]} messages on '{topic}'; it holds {held}")


def iter_bag_ground_truth(
    path: Path, topic: str, *, on_warning: Callable[[str], None] | None = None
) -> Generator[tuple[int, np.ndarray], None, None]:
    """``(stamp_ns, (x_m, y_m, yaw_rad))`` of every message kept on the ground-truth ``topic`` (as
    ``iter_bag_samples`` keeps them), in order: what ``report`` scores against, like
    ``Recording.ground_truth``. The messages dropped are said to ``on_warning`` at the end."""
    path = Path(path)
    check_bag_path(path)
    return _iter_bag_ground_truth(path, topic, on_warning or (lambda _message: None))


def _iter_bag_ground_truth(
    path: Path, topic: str, warn: Callable[[str], None]
) -> Generator[tuple[int, np.ndarray], None, None]:
    with _open_reader(path) as reader:
        types = _topic_types(reader)
        if topic not in types:
            raise BagError(
                f"no ground-truth topic '{topic}' (topics in the bag: {topic_list(types)})", path=path
            )
        if types[topic] not in ros_msgs.POSE_TYPES:
            raise BagError(
                f"ground-truth topic '{topic}' has type '{types[topic]}'; "
                f"expected {' or '.join(ros_msgs.POSE_TYPES)}",
                path=path,
            )
        order = StampOrder(path, "ground-truth", f"'{topic}'")
        pose: np.ndarray | None = None
        try:
            for _topic, datatype, log_time, msg in _messages(path, reader, {topic}):
                stamp_ns = _stamp(path, "ground-truth", topic, msg, log_time)
                if order.admits(stamp_ns):
                    pose = _pose(path, "ground-truth", topic, datatype, msg, stamp_ns, pose)
                    yield stamp_ns, pose
        except GeneratorExit:  # closed once read far enough (report: at its last keyframe's stamp)
            for line in order.dropped():
                warn(line)
            raise
        for line in order.dropped():
            warn(line)


# --- describing ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class BagSummary:
    """What a bag's index says (no message read): ``summarize_bag``."""

    path: str
    kind: SourceKind
    storage: str  # "mcap", "sqlite3" or "rosbag1"
    files: tuple[str, ...]  # the storage files, in order (several when the bag was split)
    compression: str | None  # e.g. "zstd (file)"; None when uncompressed
    ros_distro: str | None
    messages: int
    start_ns: int | None
    end_ns: int | None
    topics: tuple[TopicInfo, ...]
    resolved: ResolvedTopics | None  # the topics iter_bag_samples would read
    problem: str | None  # why it could not resolve them (e.g. two image topics)

    def as_dict(self) -> dict[str, Any]:
        return {
            "path": self.path,
            "kind": self.kind.value,
            "storage": self.storage,
            "files": list(self.files),
            "compression": self.compression,
            "ros_distro": self.ros_distro,
            "messages": self.messages,
            "start_ns": self.start_ns,
            "end_ns": self.end_ns,
            "topics": [{"topic": t.topic, "type": t.datatype, "messages": t.messages} for t in self.topics],
            "image_topic": None if self.resolved is None else self.resolved.image,
            "odometry_topic": None if self.resolved is None else (self.resolved.odometry or self.resolved.tf),
            "ground_truth_topic": None if self.resolved is None else self.resolved.ground_truth,
            "problem": self.problem,
        }


def summarize_bag(path: Path, topics: BagTopics = BagTopics()) -> BagSummary:
    """Topics, types and message counts from the bag's index or metadata; reads no message."""
    path = Path(path)
    kind = check_bag_path(path)
    with _open_reader(path) as reader:
        return _summary(path, kind, reader, topics)


def _summary(path: Path, kind: SourceKind, reader: Any, topics: BagTopics) -> BagSummary:
    """:func:`summarize_bag` of the bag ``reader`` has open."""
    with _rosbags_errors(path, "cannot read the bag's index"):
        types = _topic_types(reader)
        infos = reader.topics
        bag_topics = tuple(TopicInfo(t, types[t], int(infos[t].msgcount)) for t in sorted(types))
        storage, files, compression, distro = _storage(reader, kind, path)
        messages = int(reader.message_count)
        start = int(reader.start_time) if messages else None
        end = int(reader.end_time) - 1 if messages else None
    try:
        resolved, problem = resolve_topics(path, types, topics), None
    except BagError as err:
        resolved, problem = None, err.problem
    return BagSummary(
        str(path),
        kind,
        storage,
        files,
        compression,
        distro,
        messages,
        start,
        end,
        bag_topics,
        resolved,
        problem,
    )


def _storage(
    reader: Any, kind: SourceKind, path: Path
) -> tuple[str, tuple[str, ...], str | None, str | None]:
    """(storage, files, compression, ros_distro) of an open AnyReader."""
    if kind is SourceKind.ROSBAG1:
        return "rosbag1", (path.name,), None, None
    inner = reader.readers[0]
    if kind is SourceKind.ROSBAG2_FILE:
        return ("mcap" if path.suffix.lower() == ".mcap" else "sqlite3"), (path.name,), None, None
    directory = inner.storage  # rosbags' DirectoryReader
    metadata = directory.metadata
    info = rosbag2_information(path) or {}  # read by rosbags at the open: it is there
    files = tuple(Path(p).name for p in info.get("relative_file_paths", []))
    compression = None
    if metadata.compression_mode:
        compression = f"{metadata.compression_format} ({metadata.compression_mode})"
    return str(info.get("storage_identifier", "")), files, compression, metadata.ros_distro


def describe_bag(
    path: Path,
    topics: BagTopics = BagTopics(),
    *,
    on_warning: Callable[[str], None] | None = None,
    on_sample: Callable[[int], None] | None = None,
    on_image_count: Callable[[int], None] | None = None,
) -> Any:
    """Read the whole bag, decoding every image, and say what it holds, as ``describe_recording``
    does for a recording (same ``RecordingInfo`` type, so ``aslam info`` prints both alike).
    ``on_image_count`` and ``on_sample`` as :func:`iter_bag_samples`'s and after each sample.

    The bag's own facts (kind, storage, files, compression, the topics read) go in ``metadata``.
    The topics read are counted as read: a rosbag2 index (its ``metadata.yaml``) may be stale, and
    a count that differs from it is warned about. Other topics keep the index's counts (reading
    them, a lidar's point clouds say, is not what ``info`` is for).
    """
    from aslam.data_formats.recording_info import RecordingInfo, SampleStats

    path = Path(path)
    kind = check_bag_path(path)
    warnings: list[str] = []

    def warn(message: str) -> None:
        warnings.append(message)
        if on_warning is not None:
            on_warning(message)

    stats = SampleStats()
    read_counts: dict[str, int] = {}
    # Opened once: a rosbag2 bag compressed by file is decompressed whole, into a temporary folder,
    # at every open (rosbags), and a ROS 1 bag's index read in full.
    with _open_reader(path) as reader:
        summary = _summary(path, kind, reader, topics)
        if summary.problem is not None:
            raise BagError(summary.problem, path=path)
        for sample in _bag_samples(path, reader, topics, warn, on_image_count, read_counts):
            stats.add(sample)
            if on_sample is not None:
                on_sample(stats.samples)
        camera = _camera_intrinsics(path, reader, warn)
    if (line := stats.jpeg_damage.warning(path, stats.samples)) is not None:
        warn(line)
    resolved = summary.resolved
    assert resolved is not None
    read = {t for t in (resolved.image, resolved.odometry, resolved.ground_truth, resolved.tf) if t}
    topic_infos = []
    for t in summary.topics:  # (a count the reading found short of the index's was warned about)
        messages = read_counts.get(t.topic, 0) if t.topic in read else t.messages
        topic_infos.append(TopicInfo(t.topic, t.datatype, messages))
    metadata = {
        "kind": summary.kind.value,
        "storage": summary.storage,
        "files": ", ".join(summary.files),
        "compression": summary.compression or "none",
        "ros_distro": summary.ros_distro or "unknown",
        "image_topic": resolved.image,
        "odometry": resolved.describe_odometry(topics.base_frame, topics.odom_frame),
        "ground_truth_topic": resolved.ground_truth or "none",
    }
    return RecordingInfo(
        path=str(path),
        size_bytes=source_size_bytes(path),
        topics=tuple(topic_infos),
        **stats.fields(),
        camera=camera,
        metadata=metadata,
        truncated=False,
        warnings=tuple(warnings),
    )


def bag_camera(path: Path, *, on_warning: Callable[[str], None] | None = None) -> CameraIntrinsics | None:
    """The intrinsics of the bag's only CameraInfo topic, or None."""
    with _open_reader(Path(path)) as reader:
        return _camera_intrinsics(Path(path), reader, on_warning or (lambda _line: None))


def _camera_intrinsics(path: Path, reader: Any, warn: Callable[[str], None]) -> CameraIntrinsics | None:
    """The intrinsics of the first message of the bag's only CameraInfo topic, or None; what of its
    K and distortion that model leaves out is said in a warning."""
    infos = [t for t, datatype in _topic_types(reader).items() if datatype == ros_msgs.CAMERA_INFO]
    if len(infos) != 1:
        return None
    for topic, _datatype, _log_time, msg in _messages(path, reader, {infos[0]}):
        k = msg.k if hasattr(msg, "k") else msg.K  # ROS 1 spells it K
        fx = float(k[0])
        if msg.width > 0 and msg.height > 0 and math.isfinite(fx) and fx > 0:
            with suppress(ValueError):  # a field of view that rounds to 180°: none
                camera = CameraIntrinsics.from_camera_info(int(msg.width), int(msg.height), fx)
                left_out = _left_out(camera, [float(v) for v in k], msg.d if hasattr(msg, "d") else msg.D)
                if left_out:
                    warn(
                        f"{path}: camera info on '{topic}': aslam's camera is a centred pinhole with square"
                        f" pixels and no distortion, from fx alone; {'; '.join(left_out)}: not used"
                    )
                return camera
        return None
    return None


def _left_out(camera: CameraIntrinsics, k: list[float], distortion: Any) -> list[str]:
    """What of a CameraInfo's K (row-major 3 × 3) and distortion ``camera`` does not model."""
    fx, cx, fy, cy = k[0], k[2], k[4], k[5]
    left_out = []
    if not abs(fy - fx) <= 0.01 * fx:
        left_out.append(f"fy {fy:g} (fx {fx:g})")
    if not (abs(cx - camera.cx) <= 0.02 * camera.width_px and abs(cy - camera.cy) <= 0.02 * camera.height_px):
        left_out.append(f"principal point ({cx:g}, {cy:g}), the centre being ({camera.cx:g}, {camera.cy:g})")
    coefficients = [float(v) for v in distortion]
    if any(not abs(v) <= 1e-9 for v in coefficients):
        left_out.append(f"distortion ({', '.join(f'{v:g}' for v in coefficients)})")
    return left_out
