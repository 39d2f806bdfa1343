"""One entry point for every input ``estimate``, ``info`` and ``report`` accept: our recordings and
ROS bags of every kind (see ``rosbag_source.open_source``), as the same ``Sample`` stream.

Topic names are optional everywhere: a recording falls back to its standard topics, a bag finds
its own (``rosbag_source.resolve_topics``). An image folder is refused with the command that
turns it into a recording, so that stamps, poses and the odometry flag are fixed once, in a file.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

from aslam.data_formats.pose_sync import Sample
from aslam.data_formats.recording import Recording, RecordingTopics
from aslam.data_formats.rosbag_source import (
    BAG_KINDS,
    BagError,
    BagTopics,
    SourceKind,
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

    def recording_topics(self) -> RecordingTopics:
        defaults = RecordingTopics()
        return RecordingTopics(
            image=self.image or defaults.image,
            odometry=self.odometry or defaults.odometry,
            ground_truth=self.ground_truth or defaults.ground_truth,
        )

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
