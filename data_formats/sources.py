"""One entry point for every input ``estimate``, ``info`` and ``report`` accept: our recordings and
ROS bags of every kind (see ``rosbag_source.open_source``), as the same ``Sample`` stream.

Topic names are optional everywhere: a recording falls back to its standard topics, a bag finds
its own (``rosbag_source.resolve_topics``). An image folder is refused with the command that
turns it into a recording, so that stamps, poses and the odometry flag are fixed once, in a file.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from aslam.data_formats.pose_sync import Sample
from aslam.data_formats.recording import Recording, RecordingTopics
from aslam.data_formats.recording_info import RecordingInfo
from aslam.data_formats.rosbag_source import (
    BAG_KINDS,
    BagError,
    BagTopics,
    SourceKind,
    iter_bag_ground_truth,
    iter_bag_samples,
    open_source,
    summarize_bag,
)


@dataclass(frozen=True)
class TopicChoice:
    """The ``--image-topic``/``--odometry-topic``/``--ground-truth-topic`` options; None: default/found."""

    image: str | None = None
    odometry: str | None = None
    ground_truth: str | None = None

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

    def stored(self, kind: SourceKind) -> dict[str, str | None]:
        """What the estimate file records: a recording's topics in full, a bag's as chosen."""
        if kind is SourceKind.RECORDING:
            return asdict(self.recording_topics())
        return asdict(self)

    def bag_topics(self) -> BagTopics:
        return BagTopics(image=self.image, odometry=self.odometry, ground_truth=self.ground_truth)


def _not_a_stream(path: Path) -> BagError:
    return BagError(
        f"is an image folder; make it a recording first: aslam import {path} -o REC.mcap", path=path
    )


def iter_source_samples(
    path: Path,
    topics: TopicChoice = TopicChoice(),
    *,
    on_warning: Callable[[str], None] | None = None,
) -> Iterator[Sample]:
    """The samples of a recording or a bag, whichever ``path`` is (checked at once)."""
    path = Path(path)
    kind = open_source(path)
    if kind is SourceKind.RECORDING:
        return Recording(path, on_warning=on_warning).samples(topics.recording_topics())
    if kind in BAG_KINDS:
        return iter_bag_samples(path, topics.bag_topics(), on_warning=on_warning)
    raise _not_a_stream(path)


def source_image_count(path: Path, topics: TopicChoice = TopicChoice()) -> int | None:
    """How many images the stream will read (for a progress bar), from the index; None if unknown."""
    path = Path(path)
    kind = open_source(path)
    if kind in BAG_KINDS:
        summary = summarize_bag(path, topics.bag_topics())
        if summary.resolved is None:
            return None
        return next((t.messages for t in summary.topics if t.topic == summary.resolved.image), None)
    if kind is SourceKind.RECORDING:
        return Recording(path).image_count(topics.recording_topics())
    raise _not_a_stream(path)


def iter_source_ground_truth(
    path: Path, topics: TopicChoice = TopicChoice(), *, on_warning: Callable[[str], None] | None = None
) -> Iterator[tuple[int, np.ndarray]]:
    """``(stamp_ns, pose)`` of the ground truth of a recording, or of a bag's named topic.

    RecordingError when there is none (a bag has ground truth only on a topic named for it).
    """
    path = Path(path)
    kind = open_source(path)
    if kind is SourceKind.RECORDING:
        return Recording(path, on_warning=on_warning).ground_truth(topics.recording_topics())
    if kind in BAG_KINDS:
        if topics.ground_truth is None:
            raise BagError("no ground-truth topic named for this bag (--ground-truth-topic)", path=path)
        return iter_bag_ground_truth(path, topics.ground_truth)
    raise _not_a_stream(path)


def describe_source(
    path: Path, topics: TopicChoice = TopicChoice(), *, on_warning: Callable[[str], None] | None = None
) -> RecordingInfo:
    """What a recording or a bag holds, read whole (``aslam info``)."""
    from aslam.data_formats.recording_info import describe_recording
    from aslam.data_formats.rosbag_source import describe_bag

    path = Path(path)
    kind = open_source(path)
    if kind is SourceKind.RECORDING:
        return describe_recording(path, topics.recording_topics(), on_warning=on_warning)
    if kind in BAG_KINDS:
        return describe_bag(path, topics.bag_topics(), on_warning=on_warning)
    raise _not_a_stream(path)
