"""Reading recordings: MCAP files of ROS 2 messages (camera images, odometry, ground truth).

``Recording(path)`` opens one file (its summary read once) and serves ``samples()``: one ``Sample``
per camera image with the odometry (and ground-truth) pose interpolated to the image's stamp,
streamed; ``ground_truth()``, ``metadata()``, ``camera()`` and ``image_count()``. Written by
``recording_writer.RecordingWriter``. The format, units and frames are in ``docs/formats.md``.

This module imports neither cv2 nor mcap_ros2 at import time (both are imported where used), so a
command can name these types in its signature without slowing ``aslam --help``.
"""

from __future__ import annotations

import contextlib
import io
import json
import math
from collections.abc import Callable, Generator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from aslam.data_formats import ros_msgs
from aslam.data_formats.camera import CameraIntrinsics
from aslam.data_formats.errors import RecordingError
from aslam.data_formats.image_encodings import RAW_ENCODINGS, is_raw_encoding
from aslam.data_formats.images import LazyImage, sniffed_format
from aslam.data_formats.mcap_file import McapFile
from aslam.data_formats.pose_limits import implausible
from aslam.data_formats.pose_sync import Sample, SampleAssembler, StampOrder
from aslam.data_formats.schema_check import definition_problem

METADATA_NAME = "aslam.recording"
ODOMETRY_FRAME = "odom"
BASE_FRAME = "base_link"
WORLD_FRAME = "world"
CAMERA_FRAME = "camera"


@dataclass(frozen=True)
class RecordingTopics:
    image: str = "/camera/image/compressed"
    odometry: str = "/odom"
    ground_truth: str = "/ground_truth/pose"
    camera_info: str = "/camera/camera_info"


class _MessageDecoder:
    """CDR → message objects, one decoder per channel, every failure a RecordingError."""

    def __init__(self, path: Path) -> None:
        from mcap_ros2.decoder import DecoderFactory

        self._path = path
        self._factory = DecoderFactory()
        self._decoders: dict[int, Callable[[bytes], Any]] = {}

    def __call__(self, schema: Any, channel: Any, message: Any) -> Any:
        decode = self._decoders.get(channel.id)
        if decode is None:
            if channel.message_encoding != "cdr" or schema is None or schema.encoding != "ros2msg":
                raise RecordingError(
                    f"topic '{channel.topic}' is not CDR with a ros2msg schema "
                    f"(message encoding '{channel.message_encoding}', "
                    f"schema encoding '{getattr(schema, 'encoding', None)}')",
                    path=self._path,
                )
            problem = definition_problem(schema.name, schema.data.decode("utf-8", "replace"))
            if problem is not None:
                raise RecordingError(
                    f"topic '{channel.topic}': schema '{schema.name}': {problem}", path=self._path
                )
            try:
                with contextlib.redirect_stderr(io.StringIO()):  # the ROS parser prints before raising
                    decode = self._factory.decoder_for(channel.message_encoding, schema)
            except Exception as err:
                raise RecordingError(
                    f"topic '{channel.topic}': unreadable message definition for '{schema.name}' ({err})",
                    path=self._path,
                ) from err
            if decode is None:
                raise RecordingError(
                    f"topic '{channel.topic}': no decoder for '{schema.name}'", path=self._path
                )
            self._decoders[channel.id] = decode
        try:
            return decode(message.data)
        except Exception as err:
            raise RecordingError(
                f"undecodable CDR message on '{channel.topic}' at log time {message.log_time} ns "
                f"({type(err).__name__}: {err})",
                path=self._path,
            ) from err


def _header_stamp_ns(msg: Any, log_time: int) -> int:
    """The header stamp; the log time when a driver left the stamp unset (zero)."""
    stamp = _set_header_stamp_ns(msg)
    return log_time if stamp is None else stamp


def _set_header_stamp_ns(msg: Any) -> int | None:
    """The header stamp, or None where a driver left it unset (zero) or there is no header."""
    try:
        stamp = ros_msgs.stamp_ns_of(msg.header.stamp)
    except AttributeError:
        return None
    return stamp if stamp != 0 else None


def negative_stamp(what: str, topic: str, stamp_ns: int) -> str:
    """The problem of a stamp before 1970, which no MCAP file (unsigned times) can hold."""
    return f"{what} stamp on '{topic}' is {stamp_ns} ns, before 1970: not a time a recording can hold"


def topic_list(channels: Mapping[str, str]) -> str:
    """``topic (type), …`` in name order, for an error naming the choices (a recording's or a bag's)."""
    return ", ".join(f"{topic} ({kind})" for topic, kind in sorted(channels.items())) or "none"


def _missing_topic(
    path: Path, what: str, topic: str, channels: Mapping[str, str], source: Any
) -> RecordingError:
    note = ""
    if source.truncation is not None:
        cut = source.truncation
        note = f"; the file is truncated at byte {cut.at_byte} of {cut.size}"
    return RecordingError(
        f"no {what} topic '{topic}' (topics in the file: {topic_list(channels)}{note})", path=path
    )


def _check_type(path: Path, what: str, topic: str, datatype: str, accepted: tuple[str, ...]) -> None:
    if datatype not in accepted:
        raise RecordingError(
            f"{what} topic '{topic}' has type '{datatype or 'no schema'}'; expected {' or '.join(accepted)}",
            path=path,
        )


def _lazy_image(path: Path, topic: str, datatype: str, msg: Any, stamp_ns: int) -> LazyImage:
    where = f"image on '{topic}' at stamp {stamp_ns} ns"
    if datatype == ros_msgs.COMPRESSED_IMAGE:
        fmt = str(msg.format)
        lowered = fmt.lower()
        # image_transport writes e.g. "bgr8; jpeg compressed bgr8"; a driver that leaves the field
        # empty is read by the bytes.
        why = ""
        if not lowered.strip():
            sniffed = sniffed_format(bytes(msg.data[:8]))
            kind = None if sniffed is None else sniffed.value
            why = " and its bytes are neither PNG nor JPEG"
        elif "compresseddepth" in lowered:  # "16UC1; compressedDepth png": says png, holds depths
            kind = None
            why = " (a depth map, compressed_depth_image_transport's, not a camera image)"
        elif "png" in lowered:
            kind = "png"
        elif "jpeg" in lowered or "jpg" in lowered:
            kind = "jpeg"
        else:
            kind = None
        if kind is None:
            raise RecordingError(
                f"unknown image encoding '{fmt}'{why} on '{topic}' at stamp {stamp_ns} ns "
                "(accepted: png, jpeg)",
                path=path,
            )
        return LazyImage(bytes(msg.data), kind, path=path, where=where)
    encoding = str(msg.encoding)
    if not is_raw_encoding(encoding):
        raise RecordingError(
            f"unknown image encoding '{encoding}' on '{topic}' at stamp {stamp_ns} ns "
            f"(accepted: png, jpeg, {', '.join(sorted(RAW_ENCODINGS))})",
            path=path,
        )
    return LazyImage(
        bytes(msg.data),
        encoding.lower(),
        path=path,
        where=where,
        width=int(msg.width),
        height=int(msg.height),
        step=int(msg.step),
        is_bigendian=bool(getattr(msg, "is_bigendian", False)),
    )


class _Stream:
    """One kind of message in a recording: its accepted types, its stamps and poses checked (which
    messages are kept, in stamp order, is a ``pose_sync.StampOrder``'s to say)."""

    def __init__(self, path: Path, what: str, accepted: tuple[str, ...], decode: _MessageDecoder) -> None:
        self.path = path
        self.what = what
        self.accepted = accepted
        self.decode = decode
        self.last_pose: np.ndarray | None = None

    def read(self, schema: Any, channel: Any, message: Any) -> tuple[int, Any, str]:
        """``(stamp_ns, decoded message, datatype)``, checked."""
        datatype = schema.name if schema is not None else ""
        _check_type(self.path, self.what, channel.topic, datatype, self.accepted)
        msg = self.decode(schema, channel, message)
        try:
            stamp_ns = _header_stamp_ns(msg, message.log_time)
        except ros_msgs.StampError as err:
            raise RecordingError(f"{self.what} message on '{channel.topic}': {err}", path=self.path) from None
        if stamp_ns < 0:
            raise RecordingError(negative_stamp(self.what, channel.topic, stamp_ns), path=self.path)
        return stamp_ns, msg, datatype

    def pose(self, topic: str, datatype: str, msg: Any, stamp_ns: int) -> np.ndarray:
        """The planar pose of a pose message (Odometry, PoseStamped, ...), finite and plausible after
        the pose before it (of the messages kept)."""
        self.last_pose = checked_pose(self.path, self.what, topic, datatype, msg, stamp_ns, self.last_pose)
        return self.last_pose


def checked_pose(
    path: Path,
    what: str,
    topic: str,
    datatype: str,
    msg: Any,
    stamp_ns: int,
    previous: np.ndarray | None,
    error: type[RecordingError] = RecordingError,
) -> np.ndarray:
    """The planar pose of a pose message, finite and plausible after ``previous``: the one check of
    a recording's and a bag's poses (``error`` says which)."""
    try:
        pose = ros_msgs.pose_of_message(datatype, msg)
    except (AttributeError, TypeError, ValueError) as err:
        raise error(f"{what} message on '{topic}' at stamp {stamp_ns} ns has no pose", path=path) from err
    if not np.all(np.isfinite(pose)):
        raise error(
            f"{what} pose on '{topic}' at stamp {stamp_ns} ns is not finite (NaN or infinite)", path=path
        )
    problem = implausible(pose, previous)
    if problem is not None:
        raise error(f"{what} pose on '{topic}' at stamp {stamp_ns} ns {problem}", path=path)
    return pose


#: Fields of a generated world's description that are its textures, not its rooms (``--aliasing``).
_TEXTURE_FIELDS = ("aliasing", "aliased_panels", "doors", "shared_textures")


def world_identity(metadata: Mapping[str, str]) -> str | None:
    """Which world a recording's ground truth is in, from its ``aslam.recording`` metadata: sessions
    of different worlds share no place, and their true poses no frame. The recorder's ``world``: a
    generated world's rooms with its ``seed`` (its textures left out: the same rooms with other
    wallpaper, ``--aliasing``, are the same places), a scene file's description. None where the
    recording does not say (an imported image folder, a bag): one world is assumed.
    """
    world = metadata.get("world")
    if world is None:
        return None
    try:
        description = json.loads(world)
    except ValueError:
        return world
    if not isinstance(description, dict):
        return world
    if description.get("kind") == "generated":
        description = {key: v for key, v in description.items() if key not in _TEXTURE_FIELDS}
        description["seed"] = metadata.get("seed")
    return json.dumps(description, sort_keys=True, separators=(",", ":"))


class Recording:
    """One recording file: the path checked and the MCAP summary read once, here.

    Every reading method streams and may be called more than once; no file handle is kept between
    calls, so a ``Recording`` may be handed to a forked reader process. Problems in the file surface
    while iterating (RecordingError); warnings (dropped images, a truncated file) go to
    ``on_warning``, one line each.
    """

    def __init__(
        self, path: Path, *, on_warning: Callable[[str], None] | None = None, file: McapFile | None = None
    ) -> None:
        """``file``: the ``McapFile`` of ``path`` when the caller has opened it already."""
        self.path = Path(path)
        self._warn = on_warning or (lambda _message: None)
        self.file = file if file is not None else McapFile(self.path, on_warning=self._warn)

    @property
    def size_bytes(self) -> int:
        return self.file.size

    def image_count(self, topics: RecordingTopics = RecordingTopics()) -> int | None:
        """Images on the image topic, from the summary's statistics; None when unknown."""
        return self.file.message_count(topics.image) or None

    def metadata(self) -> dict[str, str]:
        """The ``aslam.recording`` metadata record (``{}`` if the file has none)."""
        return self.file.metadata(METADATA_NAME) or {}

    def samples(
        self, topics: RecordingTopics = RecordingTopics(), *, ground_truth: bool = True
    ) -> Generator[Sample, None, None]:
        """One ``Sample`` per camera image, in time order, with poses interpolated to its stamp;
        with ``ground_truth=False`` the truth topic is not read and every sample's truth is None.

        Memory is bounded by a chunk of the file plus the images waiting for the next odometry
        message, whatever the recording's length.
        """
        path, source, warn = self.path, self.file, self._warn
        channels = source.channels
        if source.complete_channels:
            if topics.image not in channels:
                raise _missing_topic(path, "image", topics.image, channels, source)
            if topics.odometry not in channels:
                raise _missing_topic(path, "odometry", topics.odometry, channels, source)
            _check_type(path, "image", topics.image, channels[topics.image], ros_msgs.IMAGE_TYPES)
            _check_type(path, "odometry", topics.odometry, channels[topics.odometry], ros_msgs.POSE_TYPES)
            if topics.ground_truth in channels:
                _check_type(
                    path,
                    "ground-truth",
                    topics.ground_truth,
                    channels[topics.ground_truth],
                    ros_msgs.POSE_TYPES,
                )
        decode = _MessageDecoder(path)
        assembler = SampleAssembler(
            path, odometry_topic=f"'{topics.odometry}'", ground_truth_topic=f"'{topics.ground_truth}'"
        )
        images = _Stream(path, "image", ros_msgs.IMAGE_TYPES, decode)
        odometry = _Stream(path, "odometry", ros_msgs.POSE_TYPES, decode)
        truth = _Stream(path, "ground-truth", ros_msgs.POSE_TYPES, decode)
        wanted = (topics.image, topics.odometry, *([topics.ground_truth] if ground_truth else []))
        truth_messages = source.message_count(topics.ground_truth) if ground_truth else 0
        for schema, channel, message in source.messages(wanted):
            topic = channel.topic
            if not assembler.expect_ground_truth and topics.ground_truth in channels and truth_messages != 0:
                assembler.expect_ground_truth = True
            if topic == topics.image:
                stamp_ns, msg, datatype = images.read(schema, channel, message)
                assembler.log_time_images += _set_header_stamp_ns(msg) is None
                yield from assembler.add_image(stamp_ns, _lazy_image(path, topic, datatype, msg, stamp_ns))
                continue
            if topic == topics.odometry:
                stamp_ns, msg, datatype = odometry.read(schema, channel, message)
                if assembler.odometry_stamps.admits(stamp_ns):
                    yield from assembler.add_odometry(stamp_ns, odometry.pose(topic, datatype, msg, stamp_ns))
            if ground_truth and topic == topics.ground_truth:  # the odometry's own too, if named so
                stamp_ns, msg, datatype = truth.read(schema, channel, message)
                if assembler.ground_truth_stamps.admits(stamp_ns):
                    yield from assembler.add_ground_truth(
                        stamp_ns, truth.pose(topic, datatype, msg, stamp_ns)
                    )
        if not source.complete_channels:
            if topics.image not in channels:
                raise _missing_topic(path, "image", topics.image, channels, source)
            if topics.odometry not in channels:
                raise _missing_topic(path, "odometry", topics.odometry, channels, source)
        yield from assembler.finish()
        cut = source.truncation
        problem = assembler.unpaired(f"'{topics.image}'", f"'{topics.odometry}'")
        if problem is not None:  # a file cut short says so: its odometry may be in the part lost
            note = "" if cut is None else f"; the file is truncated at byte {cut.at_byte} of {cut.size}"
            raise RecordingError(problem + note, path=path)
        if cut is not None:
            read, paired = assembler.images, assembler.yielded
            pairs = "" if paired == read else f" ({paired} paired with odometry)"
            warn(
                f"{path}: truncated at byte {cut.at_byte} of {cut.size}; read {read} images{pairs}, "
                "the rest is lost"
            )
        for line in assembler.warnings():
            warn(line)

    def ground_truth(
        self, topics: RecordingTopics = RecordingTopics()
    ) -> Generator[tuple[int, np.ndarray], None, None]:
        """``(stamp_ns, (x_m, y_m, yaw_rad))`` of every ground-truth message kept (as ``samples``
        keeps them), in time order.

        RecordingError if the recording has no ground-truth topic.
        """
        path, source = self.path, self.file
        topic = topics.ground_truth
        if source.complete_channels and topic not in source.channels:
            raise _missing_topic(path, "ground-truth", topic, source.channels, source)
        stream = _Stream(path, "ground-truth", ros_msgs.POSE_TYPES, _MessageDecoder(path))
        order = StampOrder(path, "ground-truth", f"'{topic}'")
        count = 0
        try:
            for schema, channel, message in source.messages([topic]):
                stamp_ns, msg, datatype = stream.read(schema, channel, message)
                if not order.admits(stamp_ns):
                    continue
                count += 1
                yield stamp_ns, stream.pose(topic, datatype, msg, stamp_ns)
        except GeneratorExit:  # closed once read far enough (report: at its last keyframe's stamp)
            for line in order.dropped():
                self._warn(line)
            raise
        if not source.complete_channels and topic not in source.channels:
            raise _missing_topic(path, "ground-truth", topic, source.channels, source)
        if source.truncation is not None:
            cut = source.truncation
            self._warn(
                f"{path}: truncated at byte {cut.at_byte} of {cut.size}; read {count} poses, the rest is lost"
            )
        for line in order.dropped():
            self._warn(line)

    def camera(self, topics: RecordingTopics = RecordingTopics()) -> CameraIntrinsics | None:
        """The intrinsics of the first camera-info message (horizontal FOV from ``fx``), or None."""
        path, source = self.path, self.file
        if source.complete_channels and topics.camera_info not in source.channels:
            return None
        decode = _MessageDecoder(path)
        messages = source.messages([topics.camera_info])
        try:
            for schema, channel, message in messages:
                if schema is None or schema.name != ros_msgs.CAMERA_INFO:
                    return None
                msg = decode(schema, channel, message)
                fx = float(msg.k[0])
                try:  # ValueError also for a focal length so short the field of view rounds to 180°
                    if not (msg.width > 0 and msg.height > 0 and math.isfinite(fx) and fx > 0):
                        raise ValueError("not a camera")
                    return CameraIntrinsics.from_camera_info(int(msg.width), int(msg.height), fx)
                except ValueError as err:
                    raise RecordingError(
                        f"camera info on '{topics.camera_info}' has no usable intrinsics "
                        f"({msg.width}x{msg.height}, fx={fx})",
                        path=path,
                    ) from err
        finally:
            messages.close()  # type: ignore[attr-defined]
        return None
