"""Helpers shared by the test modules: recordings written our way and the foreign way, error checks.

Test modules import them by name (``from conftest import ForeignRecording``); pytest puts this
folder on ``sys.path``.
"""

from __future__ import annotations

import math
import signal
import sys
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from mcap_ros2.writer import Writer as Ros2Writer

from aslam.cli.app import main
from aslam.core import se2
from aslam.data_formats import ros_msgs
from aslam.data_formats.camera import CameraIntrinsics
from aslam.data_formats.images import EncodedImage, ImageFormat, encode_image
from aslam.data_formats.recording_writer import RecordingWriter


@pytest.fixture(autouse=True, scope="session")
def _interruptible():
    """Ctrl-C reaches the tests as it reaches a user. Started as a background job (``make test &``,
    ``nohup``) the test process ignores SIGINT, which aslam rightly keeps ignoring
    (:mod:`aslam.cli.entry`) and every ``aslam`` it starts inherits: the tests that interrupt an
    estimate would then watch it finish."""
    previous = signal.getsignal(signal.SIGINT)
    if previous is signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)


def one_error_line(err: str) -> str:
    """Assert ``err`` (captured stderr) is exactly one ``aslam: error:`` line; return it."""
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("aslam: error:"), err
    assert "Traceback" not in err
    return lines[0]


CAMERA = CameraIntrinsics(width_px=32, height_px=24, fov_deg=70.0)
ASLAM = Path(sys.executable).with_name("aslam")
"""The console script, for tests that need a real process."""
T0_NS = 1_700_000_000_000_000_000
FRAME_NS = 100_000_000


def random_frames(n: int, seed: int = 0) -> list[tuple[int, np.ndarray, np.ndarray, np.ndarray]]:
    """``(stamp_ns, rgb, odometry_pose, ground_truth_pose)`` rows with random images and poses."""
    rng = np.random.default_rng(seed)
    frames = []
    for i in range(n):
        rgb = rng.integers(0, 256, size=(CAMERA.height_px, CAMERA.width_px, 3), dtype=np.uint8)
        odometry = np.array([rng.uniform(-50, 50), rng.uniform(-50, 50), rng.uniform(-math.pi, math.pi)])
        truth = np.array([rng.uniform(-50, 50), rng.uniform(-50, 50), rng.uniform(-math.pi, math.pi)])
        frames.append((T0_NS + i * FRAME_NS, rgb, odometry, truth))
    return frames


def write_recording(
    path: Path,
    frames: list[tuple[int, np.ndarray, np.ndarray, np.ndarray]],
    *,
    fmt: ImageFormat = ImageFormat.PNG,
    metadata: dict[str, str] | None = None,
    with_ground_truth: bool = True,
    chunk_size_bytes: int = 1024 * 1024,
    camera: CameraIntrinsics = CAMERA,
) -> Path:
    with RecordingWriter(
        path,
        camera=camera,
        metadata=metadata if metadata is not None else {"seed": "7"},
        chunk_size_bytes=chunk_size_bytes,
    ) as writer:
        for stamp_ns, rgb, odometry, truth in frames:
            writer.write(stamp_ns, encode_image(rgb, fmt), odometry, truth if with_ground_truth else None)
    return path


def write_with_corrupt_image(path: Path, fmt: ImageFormat) -> Path:
    frames = random_frames(3)
    with RecordingWriter(path, camera=CAMERA, metadata={}) as writer:
        for i, (stamp_ns, rgb, odometry, truth) in enumerate(frames):
            image = encode_image(rgb, fmt)
            if i == 1:  # keep the signature, break the body
                image = EncodedImage(fmt, image.data[:20] + bytes(len(image.data) - 20))
            writer.write(stamp_ns, image, odometry, truth)
    return path


# A raw-image definition written the way ROS 2 ships it (comments and all), not ours.
IMAGE_MSGDEF = """# This message contains an uncompressed image
# (0, 0) is at top-left corner of image

std_msgs/Header header # Header timestamp should be acquisition time of image

uint32 height                # image height, that is, number of rows
uint32 width                 # image width, that is, number of columns

string encoding       # Encoding of pixels -- channel meaning, ordering, size

uint8 is_bigendian    # is this data bigendian?
uint32 step           # Full row length in bytes
uint8[] data          # actual matrix data, size is (step * rows)

================================================================================
MSG: std_msgs/Header
# Standard metadata for higher-level stamped data types.
builtin_interfaces/Time stamp
string frame_id

================================================================================
MSG: builtin_interfaces/Time
int32 sec
uint32 nanosec
"""


class ForeignRecording:
    """A recording written message by message with mcap_ros2, for inputs our writer never makes."""

    def __init__(self, path: Path) -> None:
        self._file = path.open("wb")
        self.writer = Ros2Writer(self._file)
        self.schemas: dict[str, Any] = {}

    def schema(self, datatype: str, msgdef: str | None = None) -> Any:
        if datatype not in self.schemas:
            text = msgdef if msgdef is not None else ros_msgs.message_definition(datatype)
            self.schemas[datatype] = self.writer.register_msgdef(datatype, text)
        return self.schemas[datatype]

    def raw_image(
        self, topic: str, stamp_ns: int, pixels: np.ndarray, encoding: str, log_time: int | None = None
    ) -> None:
        height, width = pixels.shape[:2]
        channels = 1 if pixels.ndim == 2 else pixels.shape[2]
        message = {
            "header": ros_msgs.header_msg(stamp_ns, "camera"),
            "height": height,
            "width": width,
            "encoding": encoding,
            "is_bigendian": 0,
            "step": width * channels,
            "data": np.ascontiguousarray(pixels).tobytes(),
        }
        self.writer.write_message(
            topic, self.schema(ros_msgs.RAW_IMAGE, IMAGE_MSGDEF), message, log_time=log_time or stamp_ns
        )

    def compressed_image(
        self, topic: str, stamp_ns: int, data: bytes, fmt: str, log_time: int | None = None
    ) -> None:
        message = {"header": ros_msgs.header_msg(stamp_ns, "camera"), "format": fmt, "data": data}
        self.writer.write_message(
            topic, self.schema(ros_msgs.COMPRESSED_IMAGE), message, log_time=log_time or stamp_ns
        )

    def odometry(
        self, topic: str, stamp_ns: int, x: float, y: float, yaw: float, log_time: int | None = None
    ) -> None:
        if math.isfinite(yaw):
            quaternion = {"x": 0.0, "y": 0.0, "z": math.sin(yaw / 2), "w": math.cos(yaw / 2)}
        else:  # a broken quaternion, the way a bad driver would write it
            quaternion = {"x": 0.0, "y": 0.0, "z": yaw, "w": 1.0}
        message = {
            "header": ros_msgs.header_msg(stamp_ns, "odom"),
            "child_frame_id": "base_link",
            "pose": {"pose": {"position": {"x": x, "y": y, "z": 0.0}, "orientation": quaternion}},
        }
        self.writer.write_message(
            topic, self.schema(ros_msgs.ODOMETRY), message, log_time=log_time or stamp_ns
        )

    def pose(self, topic: str, stamp_ns: int, pose: np.ndarray, log_time: int | None = None) -> None:
        """A ``PoseStamped`` (a bag's ground truth: motion capture, GPS)."""
        x, y, yaw = (float(v) for v in pose)
        message = {
            "header": ros_msgs.header_msg(stamp_ns, "map"),
            "pose": {
                "position": {"x": x, "y": y, "z": 0.0},
                "orientation": {"x": 0.0, "y": 0.0, "z": math.sin(yaw / 2), "w": math.cos(yaw / 2)},
            },
        }
        self.writer.write_message(
            topic, self.schema(ros_msgs.POSE_STAMPED), message, log_time=log_time or stamp_ns
        )

    def close(self) -> None:
        self.writer.finish()
        self._file.close()

    def __enter__(self) -> ForeignRecording:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


# --- the square route: a recording and its estimate, shared by several test modules ----------

SIDE_STEPS = 3
LAPS = 2


def long_recording(path: Path, frames: int = 600) -> None:
    """Enough images that an estimate runs for a while (a straight corridor, back and forth)."""
    rng = np.random.default_rng(0)
    with RecordingWriter(path, camera=CameraIntrinsics(64, 48, 60.0), metadata={}) as writer:
        for i in range(frames):
            x = float(i % 40)
            image = encode_image(rng.integers(0, 255, (48, 64, 3), dtype=np.uint8))
            writer.write(1_000_000_000 * (i + 1), image, np.array([x, 0.0, 0.0]), None)


def square_route() -> list[np.ndarray]:
    """True poses: per side 3 one-metre steps then a 90° turn in place; twice round."""
    poses = [np.zeros(3)]
    for _ in range(LAPS):
        for _side in range(4):
            for _ in range(SIDE_STEPS):
                x, y, yaw = poses[-1]
                poses.append(np.array([x + math.cos(yaw), y + math.sin(yaw), yaw]))
            x, y, yaw = poses[-1]
            poses.append(
                np.array([x, y, math.atan2(math.sin(yaw + math.pi / 2), math.cos(yaw + math.pi / 2))])
            )
    return poses


def square_view(pose: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A 64×48 image that depends on the place and heading (plus a little noise per visit)."""
    key = (round(pose[0]), round(pose[1]), round(math.degrees(pose[2]) / 90) % 4)
    place = np.random.default_rng(abs(hash(key)) % (2**32))
    image = np.full((48, 64, 3), 40, np.uint8)
    for _ in range(12):
        p1 = tuple(int(v) for v in place.integers(0, 64, 2))
        p2 = tuple(int(v) for v in place.integers(0, 64, 2))
        colour = tuple(int(v) for v in place.integers(60, 255, 3))
        if place.random() < 0.5:
            cv2.line(image, p1, p2, colour, int(place.integers(1, 4)))
        else:
            cv2.rectangle(image, p1, p2, colour, -1)
    noise = rng.normal(0, 3, image.shape)
    return np.clip(image + noise, 0, 255).astype(np.uint8)


def write_square_recording(
    path: Path,
    route: list[np.ndarray] | None = None,
    seed: int = 7,
    *,
    metadata: dict[str, str] | None = None,
    view_offset: tuple[float, float] = (0.0, 0.0),
) -> None:
    """A small recording of the square route (or ``route``: true poses) with views that depend on
    the place (64×48 PNG); ``seed`` draws the image and odometry noise of this run. ``view_offset``:
    the views of the places that far away (another world laid out alike, its truth in its own
    frame); ``metadata``: the recording's (default: the test world's)."""
    rng = np.random.default_rng(seed)
    camera = CameraIntrinsics(64, 48, 60.0)
    odometry = np.zeros(3)
    previous = None
    metadata = {"world": "test", "route": "square"} if metadata is None else metadata
    with RecordingWriter(path, camera=camera, metadata=metadata) as writer:
        for i, truth in enumerate(square_route() if route is None else route):
            if previous is not None:
                step = se2.between(previous, truth)
                noisy = step * (1 + rng.normal(0, 0.01, 3))
                odometry = se2.compose(odometry, noisy)
            previous = truth
            stamp_ns = 1_000_000_000 * (i + 1)
            image = encode_image(square_view(truth + np.array([*view_offset, 0.0]), rng))
            writer.write(stamp_ns, image, odometry, truth)


def write_square_bag(path: Path, route: list[np.ndarray], seed: int, *, ground_truth_topic: str) -> None:
    """The square route as a ROS bag (one rosbag2 MCAP file), as ``write_square_recording`` draws
    it, its truth on ``ground_truth_topic`` (a ``PoseStamped``), its camera on a topic of its own."""
    rng = np.random.default_rng(seed)
    odometry = np.zeros(3)
    previous = None
    with ForeignRecording(path) as bag:
        for i, truth in enumerate(route):
            if previous is not None:
                step = se2.between(previous, truth)
                odometry = se2.compose(odometry, step * (1 + rng.normal(0, 0.01, 3)))
            previous = truth
            stamp_ns = 1_000_000_000 * (i + 1)
            png = encode_image(square_view(truth, rng)).data
            bag.compressed_image("/front_camera/compressed", stamp_ns, png, "png")
            bag.odometry("/odom", stamp_ns, *odometry)
            bag.pose(ground_truth_topic, stamp_ns, truth)


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("rec") / "square.mcap"
    write_square_recording(path)
    return path


@pytest.fixture(scope="module")
def estimate_file(recording: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("est") / "estimate.mcap"
    assert main(["estimate", str(recording), "-o", str(out)]) == 0
    return out
