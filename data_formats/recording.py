"""Recordings: MCAP files of ROS 2 messages (camera images, odometry, ground truth).

Written by ``RecordingWriter``; read by ``iter_samples``, which streams one ``Sample`` per camera
image with the odometry (and ground-truth) pose interpolated to the image's stamp. The format,
units and frames are described in ``docs/formats.md``.

This module imports neither cv2 nor mcap at import time (both are imported where used), so a
command can name these types in its signature without slowing ``aslam --help``.
"""

from __future__ import annotations

import math
import threading
from bisect import bisect_right
from collections import deque
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from types import TracebackType
from typing import Any, NamedTuple

import numpy as np

from aslam.core.errors import InputError
from aslam.core.se2 import wrap_angle
from aslam.data_formats import ros_msgs

METADATA_NAME = "aslam.recording"
ODOMETRY_FRAME = "odom"
BASE_FRAME = "base_link"
WORLD_FRAME = "world"
CAMERA_FRAME = "camera"
CHUNK_SIZE_BYTES = 1024 * 1024
# Images held while waiting for the odometry message after them. Past this the oldest is dropped
# (counted and reported): memory stays bounded even when odometry stops mid-recording.
MAX_PENDING_IMAGES = 512
# Odometry (and ground-truth) messages kept to interpolate images that arrive late, i.e. whose
# stamp is older than the newest pose already read (sensor latency differs between topics).
POSE_HISTORY = 256


class RecordingError(InputError):
    """A recording that cannot be read or written; the message is ``PATH: problem`` (exit 2)."""


# --- camera and images ---------------------------------------------------------------------------


@dataclass(frozen=True)
class CameraIntrinsics:
    """A pinhole camera with square pixels, centred principal point and no distortion.

    ``fov_deg`` is the horizontal field of view. Pixel centres are at integer coordinates
    (OpenCV and ROS convention), so the principal point is ``((width - 1) / 2, (height - 1) / 2)``.
    """

    width_px: int
    height_px: int
    fov_deg: float

    def __post_init__(self) -> None:
        if self.width_px <= 0 or self.height_px <= 0:
            raise ValueError(f"camera size must be positive, got {self.width_px}x{self.height_px}")
        if not 0.0 < self.fov_deg < 180.0:
            raise ValueError(f"horizontal field of view must be in (0, 180) degrees, got {self.fov_deg}")

    @property
    def fx(self) -> float:
        return (self.width_px / 2.0) / math.tan(math.radians(self.fov_deg) / 2.0)

    @property
    def fy(self) -> float:
        return self.fx

    @property
    def cx(self) -> float:
        return (self.width_px - 1) / 2.0

    @property
    def cy(self) -> float:
        return (self.height_px - 1) / 2.0

    @property
    def K(self) -> tuple[float, ...]:
        """Row-major 3×3 camera matrix, as in ``sensor_msgs/CameraInfo.k``."""
        return (self.fx, 0.0, self.cx, 0.0, self.fy, self.cy, 0.0, 0.0, 1.0)

    @classmethod
    def from_camera_info(cls, width_px: int, height_px: int, fx: float) -> CameraIntrinsics:
        """The intrinsics whose horizontal field of view gives focal length ``fx``."""
        return cls(width_px, height_px, math.degrees(2.0 * math.atan((width_px / 2.0) / fx)))


class ImageFormat(StrEnum):
    PNG = "png"
    JPEG = "jpeg"


class EncodedImage(NamedTuple):
    format: ImageFormat
    data: bytes


def encode_image(rgb: np.ndarray, fmt: ImageFormat = ImageFormat.PNG, jpeg_quality: int = 90) -> EncodedImage:
    """PNG or JPEG bytes of an RGB ``(H, W, 3)`` (or grey ``(H, W)``) uint8 image.

    The same input gives the same bytes (same OpenCV build): no timestamps or random state.
    """
    import cv2

    rgb = np.asarray(rgb)
    if rgb.dtype != np.uint8 or not (rgb.ndim == 2 or (rgb.ndim == 3 and rgb.shape[2] == 3)):
        raise ValueError(f"expected a uint8 (H, W, 3) or (H, W) image, got {rgb.dtype} {rgb.shape}")
    pixels = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR) if rgb.ndim == 3 else rgb
    fmt = ImageFormat(fmt)
    if fmt is ImageFormat.PNG:
        ok, buf = cv2.imencode(".png", pixels, [cv2.IMWRITE_PNG_COMPRESSION, 3])
    else:
        if not 0 <= jpeg_quality <= 100:
            raise ValueError(f"jpeg_quality must be in [0, 100], got {jpeg_quality}")
        ok, buf = cv2.imencode(".jpg", pixels, [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)])
    if not ok:
        raise ValueError(f"OpenCV could not encode a {rgb.shape} image as {fmt.value}")
    return EncodedImage(fmt, buf.tobytes())


_RAW_CHANNELS = {"mono8": 1, "rgb8": 3, "bgr8": 3}


class _QuietOpenCV:
    """Silence OpenCV's log while any thread decodes, so a corrupt image's warning (``[ WARN:0@…]
    PNG input buffer is incomplete``) does not reach stderr; the error says it instead. Reference
    counted, so decoding threads can overlap and the user's level comes back after the last one."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._users = 0
        self._saved_level = 0

    @contextmanager
    def __call__(self) -> Iterator[None]:
        import cv2

        logging = cv2.utils.logging
        with self._lock:
            if self._users == 0:
                self._saved_level = logging.getLogLevel()
                logging.setLogLevel(logging.LOG_LEVEL_SILENT)
            self._users += 1
        try:
            yield
        finally:
            with self._lock:
                self._users -= 1
                if self._users == 0:
                    logging.setLogLevel(self._saved_level)


_quiet_opencv = _QuietOpenCV()
_ZERO3 = {"x": 0.0, "y": 0.0, "z": 0.0}


class LazyImage:
    """One camera image as stored: encoded bytes (PNG/JPEG) or raw pixels, decoded only on request.

    ``encoding`` is ``"png"``, ``"jpeg"``, ``"mono8"``, ``"rgb8"`` or ``"bgr8"``; ``width``,
    ``height`` and ``step`` are known up front only for raw images (0 otherwise).
    """

    __slots__ = ("data", "encoding", "height", "path", "stamp_ns", "step", "width")

    def __init__(
        self,
        data: bytes,
        encoding: str,
        *,
        path: Path | str,
        stamp_ns: int,
        width: int = 0,
        height: int = 0,
        step: int = 0,
    ) -> None:
        self.data = data
        self.encoding = encoding
        self.path = Path(path)
        self.stamp_ns = stamp_ns
        self.width = width
        self.height = height
        self.step = step

    def __repr__(self) -> str:
        return f"LazyImage({self.encoding}, {len(self.data)} bytes, stamp_ns={self.stamp_ns})"

    def _error(self, problem: str) -> RecordingError:
        return RecordingError(f"image at stamp {self.stamp_ns} ns: {problem}", path=self.path)

    def _imdecode(self, flags: int) -> np.ndarray:
        import cv2

        buf = np.frombuffer(self.data, dtype=np.uint8)
        try:
            with _quiet_opencv():
                pixels = cv2.imdecode(buf, flags) if buf.size else None
        except cv2.error as err:
            raise self._error(f"corrupt {self.encoding.upper()} data ({err})") from err
        if pixels is None:
            raise self._error(f"corrupt {self.encoding.upper()} data ({len(self.data)} bytes)")
        return pixels

    def _raw(self) -> np.ndarray:
        channels = _RAW_CHANNELS[self.encoding]
        row = self.width * channels
        if self.width <= 0 or self.height <= 0 or self.step < row or len(self.data) < self.step * self.height:
            raise self._error(
                f"{len(self.data)} bytes do not hold a {self.width}x{self.height} {self.encoding} "
                f"image with step {self.step}"
            )
        rows = np.frombuffer(self.data, dtype=np.uint8, count=self.step * self.height)
        pixels = rows.reshape(self.height, self.step)[:, :row]
        return pixels.reshape(self.height, self.width, channels) if channels == 3 else pixels

    def decode_gray(self) -> np.ndarray:
        """uint8 ``(H, W)``."""
        import cv2

        if self.encoding in _RAW_CHANNELS:
            pixels = self._raw()
            if self.encoding == "mono8":
                return np.ascontiguousarray(pixels)
            code = cv2.COLOR_RGB2GRAY if self.encoding == "rgb8" else cv2.COLOR_BGR2GRAY
            return cv2.cvtColor(pixels, code)
        pixels = self._imdecode(cv2.IMREAD_GRAYSCALE)
        return pixels

    def decode_bgr(self) -> np.ndarray:
        """uint8 ``(H, W, 3)``, OpenCV's channel order."""
        import cv2

        if self.encoding in _RAW_CHANNELS:
            pixels = self._raw()
            if self.encoding == "mono8":
                return cv2.cvtColor(pixels, cv2.COLOR_GRAY2BGR)
            if self.encoding == "rgb8":
                return cv2.cvtColor(pixels, cv2.COLOR_RGB2BGR)
            return np.ascontiguousarray(pixels)
        return self._imdecode(cv2.IMREAD_COLOR)


# --- writing ------------------------------------------------------------------------------------


def _as_pose(value: np.ndarray, what: str, stamp_ns: int, path: Path) -> np.ndarray:
    pose = np.asarray(value, dtype=float)
    if pose.shape != (3,):
        raise ValueError(f"{what} pose must be (x_m, y_m, yaw_rad), got shape {pose.shape}")
    if not np.all(np.isfinite(pose)):
        raise RecordingError(f"{what} pose at stamp {stamp_ns} ns is not finite: {pose.tolist()}", path=path)
    return pose


class RecordingWriter:
    """Writes a recording; use as a context manager.

    The file is written under a hidden temporary name in the target folder and renamed to ``path``
    when the ``with`` block ends cleanly. If it ends with an exception (KeyboardInterrupt too) the
    temporary file is removed and nothing appears under ``path``. Messages are zstd-compressed in
    chunks of about ``chunk_size_bytes``: a file cut short loses at most its last chunk.
    """

    def __init__(
        self,
        path: Path,
        *,
        camera: CameraIntrinsics,
        metadata: Mapping[str, str],
        force: bool = False,
        chunk_size_bytes: int = CHUNK_SIZE_BYTES,
    ) -> None:
        from mcap_ros2.writer import Writer

        from aslam.data_formats.files import AtomicFile

        self.path = Path(path)
        self.camera = camera
        for key, value in metadata.items():
            if not isinstance(key, str) or not isinstance(value, str):
                raise TypeError(f"metadata must map str to str, got {key!r}: {value!r}")
        self._output = AtomicFile(self.path, force=force, error=RecordingError)
        self.partial_path = self._output.partial_path
        self._file = self._output.file
        self._last_stamp_ns: int | None = None
        self.frames_written = 0
        try:
            self._writer = Writer(self._file, chunk_size=chunk_size_bytes)
            self._schemas = {
                name: self._writer.register_msgdef(name, ros_msgs.message_definition(name))
                for name in (
                    ros_msgs.CAMERA_INFO,
                    ros_msgs.COMPRESSED_IMAGE,
                    ros_msgs.ODOMETRY,
                    ros_msgs.POSE_STAMPED,
                )
            }
            # Metadata first: it survives if the recording is cut short.
            self._writer.add_metadata(METADATA_NAME, dict(metadata))
        except BaseException:
            self.abort()
            raise
        self.topics = RecordingTopics()

    def __enter__(self) -> RecordingWriter:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()

    def write(
        self,
        stamp_ns: int,
        image: EncodedImage,
        odometry_pose: np.ndarray,
        ground_truth_pose: np.ndarray | None,
    ) -> None:
        """One camera frame with the odometry pose (and true pose) at the same stamp."""
        if self._output.closed:
            raise RuntimeError(f"{self.path}: write() after the writer was closed")
        stamp_ns = int(stamp_ns)
        if stamp_ns < 0:
            raise RecordingError(f"negative stamp {stamp_ns} ns", path=self.path)
        if self._last_stamp_ns is not None and stamp_ns <= self._last_stamp_ns:
            raise RecordingError(
                f"stamp {stamp_ns} ns is not after the previous one ({self._last_stamp_ns} ns)",
                path=self.path,
            )
        fmt = ImageFormat(image.format)
        odometry = _as_pose(odometry_pose, "odometry", stamp_ns, self.path)
        truth = None
        if ground_truth_pose is not None:
            truth = _as_pose(ground_truth_pose, "ground-truth", stamp_ns, self.path)
        topics = self.topics
        if self._last_stamp_ns is None:
            self._put(topics.camera_info, ros_msgs.CAMERA_INFO, stamp_ns, self._camera_info(stamp_ns))
        self._last_stamp_ns = stamp_ns
        self._put(
            topics.image,
            ros_msgs.COMPRESSED_IMAGE,
            stamp_ns,
            {
                "header": ros_msgs.header_msg(stamp_ns, CAMERA_FRAME),
                "format": fmt.value,
                "data": bytes(image.data),
            },
        )
        self._put(
            topics.odometry,
            ros_msgs.ODOMETRY,
            stamp_ns,
            {
                "header": ros_msgs.header_msg(stamp_ns, ODOMETRY_FRAME),
                "child_frame_id": BASE_FRAME,
                "pose": {"pose": ros_msgs.planar_pose_msg(odometry), "covariance": [0.0] * 36},
                "twist": {"twist": {"linear": _ZERO3, "angular": _ZERO3}, "covariance": [0.0] * 36},
            },
        )
        if truth is not None:
            self._put(
                topics.ground_truth,
                ros_msgs.POSE_STAMPED,
                stamp_ns,
                {
                    "header": ros_msgs.header_msg(stamp_ns, WORLD_FRAME),
                    "pose": ros_msgs.planar_pose_msg(truth),
                },
            )
        self.frames_written += 1

    def _camera_info(self, stamp_ns: int) -> dict[str, Any]:
        cam = self.camera
        return {
            "header": ros_msgs.header_msg(stamp_ns, CAMERA_FRAME),
            "height": cam.height_px,
            "width": cam.width_px,
            "distortion_model": "plumb_bob",
            "d": [0.0] * 5,
            "k": list(cam.K),
            "r": [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
            "p": [cam.fx, 0.0, cam.cx, 0.0, 0.0, cam.fy, cam.cy, 0.0, 0.0, 0.0, 1.0, 0.0],
            "binning_x": 0,
            "binning_y": 0,
            "roi": {"x_offset": 0, "y_offset": 0, "height": 0, "width": 0, "do_rectify": False},
        }

    def _put(self, topic: str, datatype: str, stamp_ns: int, message: dict[str, Any]) -> None:
        try:
            self._writer.write_message(
                topic, self._schemas[datatype], message, log_time=stamp_ns, publish_time=stamp_ns
            )
        except OSError as err:
            self.abort()
            raise RecordingError(f"cannot write: {err.strerror or err}", path=self.path) from err

    def close(self) -> None:
        """Finish the file and move it to its final name."""
        if not self._output.closed:
            self._output.commit(finish=self._writer.finish)

    def abort(self) -> None:
        """Drop the partial file; nothing is left under the final name."""
        self._output.abort()


# --- reading ------------------------------------------------------------------------------------


@dataclass(frozen=True)
class RecordingTopics:
    image: str = "/camera/image/compressed"
    odometry: str = "/odom"
    ground_truth: str = "/ground_truth/pose"
    camera_info: str = "/camera/camera_info"


class Sample(NamedTuple):
    stamp_ns: int
    image: LazyImage
    odometry_pose: np.ndarray  # (x_m, y_m, yaw_rad) in the odom frame, at stamp_ns
    ground_truth_pose: np.ndarray | None  # (x_m, y_m, yaw_rad) in the world frame, or None


_WAIT, _BEFORE, _LATE = "wait", "before", "late"


class _PoseTrack:
    """Recent poses of one topic, for interpolation to image stamps."""

    def __init__(self, history: int = POSE_HISTORY) -> None:
        self._stamps: deque[int] = deque(maxlen=history)
        self._poses: deque[np.ndarray] = deque(maxlen=history)
        self.first_ns: int | None = None
        self.last_ns: int | None = None
        self.count = 0

    def add(self, stamp_ns: int, pose: np.ndarray) -> None:
        self._stamps.append(stamp_ns)
        self._poses.append(pose)
        if self.first_ns is None:
            self.first_ns = stamp_ns
        self.last_ns = stamp_ns
        self.count += 1

    def lookup(self, stamp_ns: int) -> np.ndarray | str:
        """The pose at ``stamp_ns``, or why not: _WAIT (no pose after it yet), _BEFORE, _LATE."""
        if self.last_ns is None or stamp_ns > self.last_ns:
            return _WAIT
        stamps = self._stamps
        if stamp_ns < stamps[0]:
            return _BEFORE if stamps[0] == self.first_ns else _LATE
        j = bisect_right(stamps, stamp_ns) - 1  # the last pose at or before stamp_ns
        if stamps[j] == stamp_ns:
            return self._poses[j].copy()
        t0, t1 = stamps[j], stamps[j + 1]
        p0, p1 = self._poses[j], self._poses[j + 1]
        fraction = (stamp_ns - t0) / (t1 - t0)
        xy = p0[:2] + fraction * (p1[:2] - p0[:2])
        yaw = wrap_angle(p0[2] + fraction * wrap_angle(p1[2] - p0[2]))  # shortest arc
        return np.array([xy[0], xy[1], float(yaw)])


@dataclass(eq=False)
class _Pending:
    stamp_ns: int
    image: LazyImage
    ground_truth_done: bool = False
    odometry: np.ndarray | None = None
    ground_truth: np.ndarray | None = None
    dropped: bool = False


@dataclass
class _Counts:
    before_first: int = 0
    late: int = 0
    gap: int = 0
    after_last: int = 0
    no_ground_truth: int = 0


@dataclass
class _Assembler:
    """Pairs images with poses interpolated to their stamps, holding only images still waiting."""

    path: Path
    max_pending: int = MAX_PENDING_IMAGES
    # Whether images wait for a ground-truth pose; set once the ground-truth channel is known
    # (on a linear read it may be met after the first images).
    expect_ground_truth: bool = False
    odometry: _PoseTrack = field(default_factory=_PoseTrack)
    ground_truth: _PoseTrack = field(default_factory=_PoseTrack)
    counts: _Counts = field(default_factory=_Counts)
    images: int = 0
    yielded: int = 0
    last_image_ns: int | None = None
    _pending: deque[_Pending] = field(default_factory=deque)

    def add_image(self, stamp_ns: int, image: LazyImage) -> Iterator[Sample]:
        self.images += 1
        self.last_image_ns = stamp_ns
        item = _Pending(stamp_ns, image)
        self._resolve(item)
        if not item.dropped:
            self._pending.append(item)
        yield from self._drain()

    def add_odometry(self, stamp_ns: int, pose: np.ndarray) -> Iterator[Sample]:
        self.odometry.add(stamp_ns, pose)
        for item in self._pending:
            if item.odometry is None and not item.dropped:
                self._resolve(item)
        yield from self._drain()

    def add_ground_truth(self, stamp_ns: int, pose: np.ndarray) -> Iterator[Sample]:
        self.ground_truth.add(stamp_ns, pose)
        for item in self._pending:
            if not item.ground_truth_done and not item.dropped:
                self._resolve(item)
        yield from self._drain()

    def _resolve(self, item: _Pending) -> None:
        if item.odometry is None:
            found = self.odometry.lookup(item.stamp_ns)
            if found is _BEFORE or found is _LATE:
                item.dropped = True
                if found is _BEFORE:
                    self.counts.before_first += 1
                else:
                    self.counts.late += 1
                return
            if not isinstance(found, str):
                item.odometry = found
        if self.expect_ground_truth and not item.ground_truth_done:
            found = self.ground_truth.lookup(item.stamp_ns)
            if found is _BEFORE or found is _LATE:
                item.ground_truth_done = True
                self.counts.no_ground_truth += 1
            elif not isinstance(found, str):
                item.ground_truth = found
                item.ground_truth_done = True

    def _drain(self) -> Iterator[Sample]:
        pending = self._pending
        while pending:
            head = pending[0]
            if head.dropped:
                pending.popleft()
                continue
            ready = head.odometry is not None and (head.ground_truth_done or not self.expect_ground_truth)
            if not ready and len(pending) > self.max_pending:
                if head.odometry is None:  # odometry stopped or far too slow: let the oldest go
                    if self.odometry.last_ns is None:
                        self.counts.before_first += 1
                    else:
                        self.counts.gap += 1
                    pending.popleft()
                    continue
                head.ground_truth_done = True
                self.counts.no_ground_truth += 1
                ready = True
            if not ready:
                return
            pending.popleft()
            yield self._sample(head)

    def _sample(self, item: _Pending) -> Sample:
        self.yielded += 1
        assert item.odometry is not None
        return Sample(item.stamp_ns, item.image, item.odometry, item.ground_truth)

    def finish(self) -> Iterator[Sample]:
        while self._pending:
            item = self._pending.popleft()
            if item.dropped:
                continue
            if item.odometry is None:
                self.counts.after_last += 1
                continue
            if self.expect_ground_truth and not item.ground_truth_done:
                self.counts.no_ground_truth += 1
            yield self._sample(item)

    def warnings(self) -> list[str]:
        c, path, out = self.counts, self.path, []
        if c.before_first:
            out.append(
                f"{path}: dropped {c.before_first} image(s) stamped before the first odometry message"
                + (f" (at {self.odometry.first_ns} ns)" if self.odometry.first_ns is not None else "")
            )
        if c.late:
            out.append(
                f"{path}: dropped {c.late} image(s) that arrived more than {POSE_HISTORY} "
                "odometry messages late"
            )
        if c.gap:
            out.append(
                f"{path}: dropped {c.gap} image(s) in odometry gaps longer than {self.max_pending} images"
            )
        if c.after_last:
            out.append(
                f"{path}: dropped {c.after_last} image(s) stamped after the last odometry message"
                + (f" (at {self.odometry.last_ns} ns)" if self.odometry.last_ns is not None else "")
            )
        if c.no_ground_truth:
            out.append(
                f"{path}: {c.no_ground_truth} image(s) have no ground truth (stamped outside the "
                "ground-truth messages)"
            )
        return out


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
            try:
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
    try:
        stamp = ros_msgs.stamp_ns_of(msg.header.stamp)
    except AttributeError:
        return log_time
    return stamp if stamp != 0 else log_time


def _topic_list(channels: Mapping[str, str]) -> str:
    return ", ".join(f"{topic} ({kind})" for topic, kind in sorted(channels.items())) or "none"


def _missing_topic(
    path: Path, what: str, topic: str, channels: Mapping[str, str], source: Any
) -> RecordingError:
    note = ""
    if source.truncation is not None:
        cut = source.truncation
        note = f"; the file is truncated at byte {cut.at_byte} of {cut.size}"
    return RecordingError(
        f"no {what} topic '{topic}' (topics in the file: {_topic_list(channels)}{note})", path=path
    )


def _check_type(path: Path, what: str, topic: str, datatype: str, accepted: tuple[str, ...]) -> None:
    if datatype not in accepted:
        raise RecordingError(
            f"{what} topic '{topic}' has type '{datatype or 'no schema'}'; expected {' or '.join(accepted)}",
            path=path,
        )


def _lazy_image(path: Path, topic: str, datatype: str, msg: Any, stamp_ns: int) -> LazyImage:
    if datatype == ros_msgs.COMPRESSED_IMAGE:
        fmt = str(msg.format)
        lowered = fmt.lower()
        # image_transport writes e.g. "bgr8; jpeg compressed bgr8"; depth formats are not images here.
        if "compresseddepth" in lowered:
            kind = None
        elif "png" in lowered:
            kind = "png"
        elif "jpeg" in lowered or "jpg" in lowered:
            kind = "jpeg"
        else:
            kind = None
        if kind is None:
            raise RecordingError(
                f"unknown image encoding '{fmt}' on '{topic}' at stamp {stamp_ns} ns (accepted: png, jpeg)",
                path=path,
            )
        return LazyImage(bytes(msg.data), kind, path=path, stamp_ns=stamp_ns)
    encoding = str(msg.encoding)
    if encoding.lower() not in _RAW_CHANNELS:
        raise RecordingError(
            f"unknown image encoding '{encoding}' on '{topic}' at stamp {stamp_ns} ns "
            f"(accepted: {', '.join(_RAW_CHANNELS)})",
            path=path,
        )
    return LazyImage(
        bytes(msg.data),
        encoding.lower(),
        path=path,
        stamp_ns=stamp_ns,
        width=int(msg.width),
        height=int(msg.height),
        step=int(msg.step),
    )


def _pose(path: Path, what: str, topic: str, datatype: str, msg: Any, stamp_ns: int) -> np.ndarray:
    try:
        pose = ros_msgs.pose_of_message(datatype, msg)
    except (AttributeError, TypeError, ValueError) as err:
        raise RecordingError(
            f"{what} message on '{topic}' at stamp {stamp_ns} ns has no pose", path=path
        ) from err
    if not np.all(np.isfinite(pose)):
        raise RecordingError(
            f"{what} pose on '{topic}' at stamp {stamp_ns} ns is not finite (NaN or infinite)", path=path
        )
    return pose


def _backwards(path: Path, what: str, topic: str, stamp_ns: int, previous_ns: int) -> RecordingError:
    return RecordingError(
        f"{what} stamps go backwards on '{topic}': {stamp_ns} ns after {previous_ns} ns", path=path
    )


def iter_samples(
    path: Path,
    topics: RecordingTopics = RecordingTopics(),
    *,
    on_warning: Callable[[str], None] | None = None,
) -> Iterator[Sample]:
    """One ``Sample`` per camera image, in time order, with poses interpolated to its stamp.

    Streams: memory is bounded by a chunk of the file plus the images waiting for the next odometry
    message, whatever the recording's length. The path is checked at once (RecordingError); the
    rest of the problems surface while iterating. Warnings (dropped images, a truncated file) go to
    ``on_warning``, one line each, at the end of the stream.
    """
    from aslam.data_formats.mcap_io import check_recording_path

    path = Path(path)
    check_recording_path(path)
    return _iter_samples(path, topics, on_warning or (lambda _message: None))


def _iter_samples(path: Path, topics: RecordingTopics, warn: Callable[[str], None]) -> Iterator[Sample]:
    from aslam.data_formats.mcap_io import McapSource

    source = McapSource(path, on_warning=warn)
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
                path, "ground-truth", topics.ground_truth, channels[topics.ground_truth], ros_msgs.POSE_TYPES
            )
    decode = _MessageDecoder(path)
    assembler = _Assembler(path)
    last_odometry_ns: int | None = None
    last_truth_ns: int | None = None
    wanted = (topics.image, topics.odometry, topics.ground_truth)
    truth_messages = None if source.message_counts is None else source.message_counts.get(topics.ground_truth)
    for schema, channel, message in source.messages(wanted):
        datatype = schema.name if schema is not None else ""
        topic = channel.topic
        if not assembler.expect_ground_truth and topics.ground_truth in channels and truth_messages != 0:
            assembler.expect_ground_truth = True
        if topic == topics.image:
            _check_type(path, "image", topic, datatype, ros_msgs.IMAGE_TYPES)
            msg = decode(schema, channel, message)
            stamp_ns = _header_stamp_ns(msg, message.log_time)
            if assembler.last_image_ns is not None and stamp_ns < assembler.last_image_ns:
                raise _backwards(path, "image", topic, stamp_ns, assembler.last_image_ns)
            image = _lazy_image(path, topic, datatype, msg, stamp_ns)
            yield from assembler.add_image(stamp_ns, image)
        elif topic == topics.odometry:
            _check_type(path, "odometry", topic, datatype, ros_msgs.POSE_TYPES)
            msg = decode(schema, channel, message)
            stamp_ns = _header_stamp_ns(msg, message.log_time)
            if last_odometry_ns is not None and stamp_ns < last_odometry_ns:
                raise _backwards(path, "odometry", topic, stamp_ns, last_odometry_ns)
            last_odometry_ns = stamp_ns
            pose = _pose(path, "odometry", topic, datatype, msg, stamp_ns)
            yield from assembler.add_odometry(stamp_ns, pose)
        else:
            _check_type(path, "ground-truth", topic, datatype, ros_msgs.POSE_TYPES)
            msg = decode(schema, channel, message)
            stamp_ns = _header_stamp_ns(msg, message.log_time)
            if last_truth_ns is not None and stamp_ns < last_truth_ns:
                raise _backwards(path, "ground-truth", topic, stamp_ns, last_truth_ns)
            last_truth_ns = stamp_ns
            pose = _pose(path, "ground-truth", topic, datatype, msg, stamp_ns)
            yield from assembler.add_ground_truth(stamp_ns, pose)
    if not source.complete_channels:
        if topics.image not in channels:
            raise _missing_topic(path, "image", topics.image, channels, source)
        if topics.odometry not in channels:
            raise _missing_topic(path, "odometry", topics.odometry, channels, source)
    yield from assembler.finish()
    if source.truncation is not None:
        cut = source.truncation
        warn(
            f"{path}: truncated at byte {cut.at_byte} of {cut.size}; read {assembler.yielded} images, "
            "the rest is lost"
        )
    for line in assembler.warnings():
        warn(line)


def iter_ground_truth(
    path: Path,
    topics: RecordingTopics = RecordingTopics(),
    *,
    on_warning: Callable[[str], None] | None = None,
) -> Iterator[tuple[int, np.ndarray]]:
    """``(stamp_ns, (x_m, y_m, yaw_rad))`` of every ground-truth message, in time order.

    RecordingError if the recording has no ground-truth topic.
    """
    from aslam.data_formats.mcap_io import check_recording_path

    path = Path(path)
    check_recording_path(path)
    return _iter_ground_truth(path, topics, on_warning or (lambda _message: None))


def _iter_ground_truth(
    path: Path, topics: RecordingTopics, warn: Callable[[str], None]
) -> Iterator[tuple[int, np.ndarray]]:
    from aslam.data_formats.mcap_io import McapSource

    source = McapSource(path, on_warning=warn)
    topic = topics.ground_truth
    if source.complete_channels and topic not in source.channels:
        raise _missing_topic(path, "ground-truth", topic, source.channels, source)
    decode = _MessageDecoder(path)
    last_ns: int | None = None
    count = 0
    for schema, channel, message in source.messages([topic]):
        datatype = schema.name if schema is not None else ""
        _check_type(path, "ground-truth", topic, datatype, ros_msgs.POSE_TYPES)
        msg = decode(schema, channel, message)
        stamp_ns = _header_stamp_ns(msg, message.log_time)
        if last_ns is not None and stamp_ns < last_ns:
            raise _backwards(path, "ground-truth", topic, stamp_ns, last_ns)
        last_ns = stamp_ns
        count += 1
        yield stamp_ns, _pose(path, "ground-truth", topic, datatype, msg, stamp_ns)
    if not source.complete_channels and topic not in source.channels:
        raise _missing_topic(path, "ground-truth", topic, source.channels, source)
    if source.truncation is not None:
        cut = source.truncation
        warn(f"{path}: truncated at byte {cut.at_byte} of {cut.size}; read {count} poses, the rest is lost")


def read_metadata(path: Path) -> dict[str, str]:
    """The ``aslam.recording`` metadata record (``{}`` if the file has none)."""
    from aslam.data_formats.mcap_io import McapSource

    return McapSource(Path(path)).metadata(METADATA_NAME) or {}


def read_camera_intrinsics(
    path: Path, topics: RecordingTopics = RecordingTopics()
) -> CameraIntrinsics | None:
    """The intrinsics of the first camera-info message (horizontal FOV from ``fx``), or None."""
    from aslam.data_formats.mcap_io import McapSource

    path = Path(path)
    source = McapSource(path)
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
            if not (msg.width > 0 and msg.height > 0 and math.isfinite(fx) and fx > 0):
                raise RecordingError(
                    f"camera info on '{topics.camera_info}' has no usable intrinsics "
                    f"({msg.width}x{msg.height}, fx={fx})",
                    path=path,
                )
            return CameraIntrinsics.from_camera_info(int(msg.width), int(msg.height), fx)
    finally:
        messages.close()  # type: ignore[attr-defined]
    return None
