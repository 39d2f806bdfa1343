"""``aslam info``: read a whole recording or bag, decoding every image, and describe it.

Reading all of it is the point: a truncated file, a corrupt image or a topic of the wrong type is
found here rather than half-way through an estimate.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from aslam.data_formats.recording_info import RecordingInfo
from aslam.data_formats.sources import TopicChoice, open_input

Progress = Callable[[int, int | None], None]
"""(images read, images in all — None when the input cannot say without reading it)."""


def describe(
    recording: Path | str,
    topics: TopicChoice = TopicChoice(),
    *,
    on_progress: Progress | None = None,
    on_warning: Callable[[str], None] | None = None,
) -> RecordingInfo:
    """Topics, counts, duration, image sizes, camera and metadata of ``recording`` (one of our MCAP
    recordings or a ROS bag); RecordingError/BagError naming the file when it does not read."""
    source = open_input(Path(recording), topics, on_warning=on_warning)
    if on_progress is None:
        return source.describe()
    total: int | None = None

    def counted(images: int | None) -> None:
        """The total, shown before the first image is read: from the reading's own opening of the
        source (a bag opened for the count, then to be read, was opened twice)."""
        nonlocal total
        total = images
        on_progress(0, total)

    return source.describe(on_sample=lambda done: on_progress(done, total), on_image_count=counted)
