"""Writing recordings: MCAP files of ROS 2 messages, one camera frame at a time (``docs/formats.md``)."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np

from aslam.data_formats import ros_msgs
from aslam.data_formats.camera import CameraIntrinsics
from aslam.data_formats.errors import RecordingError
from aslam.data_formats.files import AtomicFile, utf8_metadata
from aslam.data_formats.images import EncodedImage, ImageFormat
from aslam.data_formats.recording import (
    BASE_FRAME,
    CAMERA_FRAME,
    METADATA_NAME,
    ODOMETRY_FRAME,
    WORLD_FRAME,
    RecordingTopics,
)

CHUNK_SIZE_BYTES = 1024 * 1024
_ZERO3 = {"x": 0.0, "y": 0.0, "z": 0.0}


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

        self.path = Path(path)
        self.camera = camera
        for key, value in metadata.items():
            if not isinstance(key, str) or not isinstance(value, str):
                raise TypeError(f"metadata must map str to str, got {key!r}: {value!r}")
        self._output = AtomicFile(self.path, force=force, error=RecordingError)
        self.partial_path = self._output.partial_path
        self._file = self._output.file
        self._last_stamp_ns: int | None = None
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
            self._writer.add_metadata(METADATA_NAME, utf8_metadata(metadata))
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
