"""The names of the pose and trajectory file formats, for the command line.

Apart from the readers and writers (which need numpy) so that declaring the CLI's options, and with
them ``aslam --help``, imports no numpy.
"""

from __future__ import annotations

from enum import StrEnum
from typing import Any

from aslam.core.errors import ConfigError


class _Name(StrEnum):
    """A name one of these formats takes. A library caller's other string (``"TUM"``, ``"sec"``) is
    a ConfigError naming the choices, as the command line's is, never Enum's bare ValueError."""

    @classmethod
    def _missing_(cls, value: Any) -> Any:
        choices = ", ".join(member.value for member in cls)
        raise ConfigError(f"{value!r} is not a {cls.__name__} (one of: {choices})")


class PoseFormat(_Name):
    """Pose files ``aslam import`` reads (see :mod:`aslam.data_formats.pose_files`)."""

    TUM = "tum"
    KITTI = "kitti"
    CSV = "csv"


class StampUnit(_Name):
    """The unit of the stamps in pose files and file names, when ``aslam import`` is told it
    (see :func:`aslam.data_formats.pose_files.stamp_text_ns`)."""

    S = "s"
    MS = "ms"
    US = "us"
    NS = "ns"


class TrajectoryFormat(_Name):
    """Trajectory files ``aslam report`` writes (see :mod:`aslam.data_formats.trajectory`)."""

    TUM = "tum"
    KITTI = "kitti"
