"""What a recording holds, found by reading all of it (every image decoded): ``aslam info``'s data."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from aslam.data_formats.camera import CameraIntrinsics
from aslam.data_formats.files import full_path
from aslam.data_formats.images import JpegDamage
from aslam.data_formats.pose_sync import Sample
from aslam.data_formats.recording import METADATA_NAME, Recording, RecordingTopics


@dataclass(frozen=True)
class TopicInfo:
    topic: str
    datatype: str
    messages: int


@dataclass(frozen=True)
class RecordingInfo:
    """A recording's contents; ``warnings`` holds every warning met while reading it."""

    path: str
    size_bytes: int
    topics: tuple[TopicInfo, ...]
    samples: int
    first_stamp_ns: int | None
    last_stamp_ns: int | None
    image_encodings: dict[str, int]
    image_sizes: dict[str, int]  # "WxH" → images of that size
    samples_with_ground_truth: int
    odometry_distance_m: float
    camera: CameraIntrinsics | None
    metadata: dict[str, str]
    truncated: bool
    warnings: tuple[str, ...] = field(default=())

    @property
    def duration_s(self) -> float:
        if self.first_stamp_ns is None or self.last_stamp_ns is None:
            return 0.0
        return (self.last_stamp_ns - self.first_stamp_ns) / 1e9

    def as_dict(self) -> dict[str, Any]:
        camera = None
        if self.camera is not None:
            c = self.camera
            camera = {
                "width_px": c.width_px,
                "height_px": c.height_px,
                # derived from the camera info's fx by an arctangent: 60° came back as 59.99999999999999
                "fov_deg": round(c.fov_deg, 9),
                "fx": c.fx,
                "fy": c.fy,
                "cx": c.cx,
                "cy": c.cy,
            }
        return {
            # as every other JSON output names files: the same file from another folder, same bytes
            "path": str(full_path(self.path)),
            "size_bytes": self.size_bytes,
            "topics": [{"topic": t.topic, "type": t.datatype, "messages": t.messages} for t in self.topics],
            "samples": self.samples,
            "samples_with_ground_truth": self.samples_with_ground_truth,
            "first_stamp_ns": self.first_stamp_ns,
            "last_stamp_ns": self.last_stamp_ns,
            "duration_s": self.duration_s,
            "image_encodings": dict(self.image_encodings),
            "image_sizes": dict(self.image_sizes),
            "odometry_distance_m": self.odometry_distance_m,
            "camera": camera,
            "metadata": {"name": METADATA_NAME, "entries": dict(self.metadata)},
            "truncated": self.truncated,
            "warnings": list(self.warnings),
        }


@dataclass
class SampleStats:
    """What ``aslam info`` counts over a stream of samples, whatever the source (every image decoded)."""

    samples: int = 0
    with_truth: int = 0
    first: int | None = None
    last: int | None = None
    encodings: dict[str, int] = field(default_factory=dict)
    sizes: dict[str, int] = field(default_factory=dict)
    distance_m: float = 0.0
    jpeg_damage: JpegDamage = field(default_factory=JpegDamage)
    _previous_xy: Any = None

    def add(self, sample: Sample) -> None:
        gray = self.jpeg_damage.decode_gray(sample.image)
        size = f"{gray.shape[1]}x{gray.shape[0]}"
        self.sizes[size] = self.sizes.get(size, 0) + 1
        self.encodings[sample.image.encoding] = self.encodings.get(sample.image.encoding, 0) + 1
        self.first = sample.stamp_ns if self.first is None else self.first
        self.last = sample.stamp_ns
        self.with_truth += sample.ground_truth_pose is not None
        xy = sample.odometry_pose[:2]
        if self._previous_xy is not None:
            self.distance_m += math.hypot(
                float(xy[0] - self._previous_xy[0]), float(xy[1] - self._previous_xy[1])
            )
        self._previous_xy = xy
        self.samples += 1

    def fields(self) -> dict[str, Any]:
        """The ``RecordingInfo`` fields these counts fill."""
        return {
            "samples": self.samples,
            "first_stamp_ns": self.first,
            "last_stamp_ns": self.last,
            "image_encodings": self.encodings,
            "image_sizes": self.sizes,
            "samples_with_ground_truth": self.with_truth,
            "odometry_distance_m": self.distance_m,
        }


def describe_recording(
    recording: Recording,
    topics: RecordingTopics = RecordingTopics(),
    *,
    warn: Callable[[str], None],
    on_sample: Callable[[int], None] | None = None,
) -> RecordingInfo:
    """Read the whole recording, decoding every image, and say what it holds; ``on_sample(n)``
    after each of the n samples read (a progress display).

    Any problem ``Recording.samples`` would meet raises here too (RecordingError). ``warnings`` in
    the result is empty: the caller, who made ``recording`` with its warning callback, fills it.
    """
    path = recording.path
    source = recording.file
    counts = source.count_messages()
    metadata = recording.metadata()
    camera = recording.camera(topics)

    stats = SampleStats()
    for sample in recording.samples(topics):
        stats.add(sample)
        if on_sample is not None:
            on_sample(stats.samples)
    sizes = stats.sizes
    if (line := stats.jpeg_damage.warning(path, stats.samples)) is not None:
        warn(line)

    if camera is not None and sizes:
        expected = f"{camera.width_px}x{camera.height_px}"
        if set(sizes) != {expected}:
            warn(f"{path}: camera info says {expected} but the images are {', '.join(sorted(sizes))}")

    # The channels a linear read met (every channel of an indexed file) with their counts.
    topic_infos = tuple(
        TopicInfo(topic, datatype, counts.get(topic, 0))
        for topic, datatype in sorted(source.channels.items())
    )
    return RecordingInfo(
        path=str(path),
        size_bytes=source.size,
        topics=topic_infos,
        **stats.fields(),
        camera=camera,
        metadata=metadata,
        truncated=source.truncation is not None,
    )
