"""The names of the pose and trajectory file formats, for the command line.

Apart from the readers and writers (which need numpy) so that declaring the CLI's options, and with
them ``aslam --help``, imports no numpy.
"""

from __future__ import annotations

from enum import StrEnum


class PoseFormat(StrEnum):
    """Pose files ``aslam import`` reads (see :mod:`aslam.data_formats.pose_files`)."""

    TUM = "tum"
    KITTI = "kitti"
    CSV = "csv"


class StampUnit(StrEnum):
    """The unit of the stamps in pose files and file names, when ``aslam import`` is told it
    (see :func:`aslam.data_formats.pose_files.stamp_text_ns`)."""

    S = "s"
    MS = "ms"
    US = "us"
    NS = "ns"


class TrajectoryFormat(StrEnum):
    """Trajectory files ``aslam report`` writes (see :mod:`aslam.data_formats.trajectory`)."""

    TUM = "tum"
    KITTI = "kitti"
