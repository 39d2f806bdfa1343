"""One entry point for every input ``estimate``, ``info`` and ``report`` accept: our recordings and
ROS bags of every kind (see ``rosbag_source.classify``), as the same ``Sample`` stream.

``open_input(path, topics)`` looks at the path once (for our MCAP recordings: the one ``McapFile``,
its summary read once) and returns an object that serves the samples (with the image count), the
ground truth and the description, whatever the kind.

Topic names are optional everywhere: a recording falls back to its standard topics, a bag finds
its own (``rosbag_source.resolve_topics``). An image folder is refused with the command that
turns it into a recording, so that stamps, poses and the odometry flag are fixed once, in a file.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Generator, Iterator
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

from aslam.data_formats.camera import CameraIntrinsics
from aslam.data_formats.errors import RecordingError
from aslam.data_formats.files import source_sha256, source_size_bytes
from aslam.data_formats.pose_sync import Sample
from aslam.data_formats.recording import Recording, RecordingTopics
from aslam.data_formats.recording_info import RecordingInfo, describe_recording
from aslam.data_formats.rosbag_source import (
    BAG_KINDS,
    BagError,
    BagTopics,
    SourceKind,
    bag_camera,
    classify,
    describe_bag,
    iter_bag_ground_truth,
    iter_bag_samples,
    summarize_bag,
)


@dataclass(frozen=True)
class TopicChoice:
    """The ``--image-topic``/``--odometry-topic``/``--ground-truth-topic`` options, and for a bag's
    odometry from /tf ``--odom-frame``/``--base-frame``; None: default/found."""

    image: str | None = None
    odometry: str | None = None
    ground_truth: str | None = None
    odom_frame: str | None = None
    base_frame: str | None = None

    @classmethod
    def from_record(cls, topics: dict[str, str | None]) -> TopicChoice:
        """The choice stored in an estimate file's metadata (extra keys, e.g. camera_info, ignored)."""
        return cls(topics.get("image"), topics.get("odometry"), topics.get("ground_truth"))

    def recording_topics(self) -> RecordingTopics:
        defaults = RecordingTopics()
        return RecordingTopics(
            image=self.image or defaults.image,
            odometry=self.odometry or defaults.odometry,
            ground_truth=self.ground_truth or defaults.ground_truth,
        )

    def bag_topics(self) -> BagTopics:
        return BagTopics(
            image=self.image,
            odometry=self.odometry,
            ground_truth=self.ground_truth,
            odom_frame=self.odom_frame or BagTopics.odom_frame,
            base_frame=self.base_frame,
        )


class _Warnings:
    """Every warning of one input, collected (for ``info --json``) and passed on as it comes."""

    def __init__(self, on_warning: Callable[[str], None] | None) -> None:
        self.lines: list[str] = []
        self._on_warning = on_warning

    def __call__(self, line: str) -> None:
        self.lines.append(line)
        if self._on_warning is not None:
            self._on_warning(line)


class RecordingInput:
    """One of our MCAP recordings, with the topics to read."""

    kind = SourceKind.RECORDING

    def __init__(self, recording: Recording, topics: RecordingTopics, warnings: _Warnings) -> None:
        self.path = recording.path
        self.recording = recording
        self.topics = topics
        self._warnings = warnings

    def stored_topics(self) -> dict[str, str | None]:
        """The topics as the estimate file records them."""
        return asdict(self.topics)

    def samples(self, on_image_count: Callable[[int | None], None] | None = None) -> Iterator[Sample]:
        """The samples, without ground truth (an estimate has no use for it, and it was a third of
        the poses decoded; ``report`` reads it with :meth:`ground_truth`); ``on_image_count(n)`` at
        once, from the summary already read."""
        if on_image_count is not None:
            on_image_count(self.recording.image_count(self.topics))
        return self.recording.samples(self.topics, ground_truth=False)

    def ground_truth(self) -> Generator[tuple[int, np.ndarray], None, None]:
        return self.recording.ground_truth(self.topics)

    def camera(self) -> CameraIntrinsics | None:
        """The intrinsics its camera-info topic gives, or None."""
        return self.recording.camera(self.topics)

    def has_topic(self, topic: str) -> bool:
        """Whether the file has ``topic`` (True where its summary is lost: known only by reading)."""
        file = self.recording.file
        return topic in file.channels or not file.complete_channels

    @property
    def odometry_known(self) -> bool:
        """False for an image folder imported without odometry (equal steps assumed, ``aslam import``)."""
        return self.recording.metadata().get("odometry_known") != "false"

    def sha256(self, stop: threading.Event | None = None) -> str:
        """SHA-256 of the recording read: the file opened, whatever is at its name now (``record
        --force`` replacing it mid-run gave an estimate the identity of a file it never read)."""
        return self.recording.file.sha256(stop)

    def size_bytes(self) -> int:
        return self.recording.size_bytes

    def describe(
        self,
        on_sample: Callable[[int], None] | None = None,
        on_image_count: Callable[[int | None], None] | None = None,
    ) -> RecordingInfo:
        """Read it all (``aslam info``); ``on_image_count`` and ``on_sample(n)`` as :meth:`samples`
        and after each sample."""
        if on_image_count is not None:
            on_image_count(self.recording.image_count(self.topics))
        info = describe_recording(self.recording, self.topics, warn=self._warnings, on_sample=on_sample)
        return replace(info, warnings=tuple(self._warnings.lines))


class BagInput:
    """A ROS bag (rosbag2 folder or file, ROS 1 bag), its topics found unless chosen."""

    def __init__(self, path: Path, kind: SourceKind, topics: TopicChoice, warnings: _Warnings) -> None:
        self.path = path
        self.kind = kind
        self.choice = topics
        self.topics = topics.bag_topics()
        self._warnings = warnings

    def stored_topics(self) -> dict[str, str | None]:
        """The topics (the /tf frames are no topic: the file's format keeps its topic names only)."""
        choice = self.choice
        return {"image": choice.image, "odometry": choice.odometry, "ground_truth": choice.ground_truth}

    def samples(self, on_image_count: Callable[[int | None], None] | None = None) -> Iterator[Sample]:
        """The samples, without ground truth (as a recording's); ``on_image_count(n)`` once the
        iteration has opened the bag (its index says), wherever it runs: in a reader process, the
        bag is opened there alone."""
        return iter_bag_samples(
            self.path,
            self.topics,
            on_warning=self._warnings,
            on_image_count=on_image_count,
            ground_truth=False,
        )

    def ground_truth(self) -> Generator[tuple[int, np.ndarray], None, None]:
        if self.choice.ground_truth is None:
            raise BagError(
                "no ground-truth topic named for this bag (--ground-truth-topic of estimate or report)",
                path=self.path,
            )
        return iter_bag_ground_truth(self.path, self.choice.ground_truth, on_warning=self._warnings)

    def camera(self) -> CameraIntrinsics | None:
        """The intrinsics of the bag's only CameraInfo topic, or None (the bag opened to read them)."""
        return bag_camera(self.path, on_warning=self._warnings)

    def has_topic(self, topic: str) -> bool:
        """Whether the bag has ``topic`` (its index says; no message read)."""
        return any(info.topic == topic for info in summarize_bag(self.path).topics)

    odometry_known = True
    """A bag's odometry is measured (an ``Odometry`` topic or ``/tf``)."""

    def sha256(self, stop: threading.Event | None = None) -> str:
        """SHA-256 of the bag's files in name order, read by name (as the bag readers open them)."""
        return source_sha256(self.path, stop)

    def size_bytes(self) -> int:
        return source_size_bytes(self.path)

    def describe(
        self,
        on_sample: Callable[[int], None] | None = None,
        on_image_count: Callable[[int | None], None] | None = None,
    ) -> RecordingInfo:
        """Read it all (``aslam info``); ``on_image_count`` and ``on_sample(n)`` as :meth:`samples`
        and after each sample."""
        info = describe_bag(
            self.path,
            self.topics,
            on_warning=self._warnings,
            on_sample=on_sample,
            on_image_count=on_image_count,
        )
        return replace(info, warnings=tuple(self._warnings.lines))


Input = RecordingInput | BagInput


def open_input(
    path: Path, topics: TopicChoice = TopicChoice(), *, on_warning: Callable[[str], None] | None = None
) -> Input:
    """The recording or bag at ``path`` (checked at once: BagError/RecordingError naming it)."""
    path = Path(path)
    warnings = _Warnings(on_warning)
    kind, mcap = classify(path, on_warning=warnings)
    if kind is SourceKind.RECORDING:
        if topics.odom_frame is not None or topics.base_frame is not None:
            option = "--odom-frame" if topics.odom_frame is not None else "--base-frame"
            raise RecordingError(
                f"{option} chooses a bag's odometry on /tf; this recording's odometry is its own topic",
                path=path,
            )
        recording = Recording(path, on_warning=warnings, file=mcap)
        return RecordingInput(recording, topics.recording_topics(), warnings)
    if kind in BAG_KINDS:
        return BagInput(path, kind, topics, warnings)
    raise not_an_input(path)


def not_an_input(path: Path) -> BagError:
    """Why ``path``, an image folder, is no input to ``estimate``, ``info`` or a sweep."""
    return BagError(
        f"is an image folder; make it a recording first: aslam import {path} -o REC.mcap", path=path
    )
