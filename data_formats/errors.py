"""The file-format errors, under the tool's one root (``aslam.core.errors.AslamError``).

Kept apart from the readers and writers so that every module of ``data_formats`` can raise them
without importing another's machinery (no import cycles, no imports hidden inside functions).
"""

from __future__ import annotations

from aslam.core.errors import InputError


class RecordingError(InputError):
    """A recording that cannot be read or written; the message is ``PATH: problem`` (exit 2)."""


class EstimateError(InputError):
    """An estimate file that cannot be read or written; the message is ``PATH: problem`` (exit 2)."""


class CutWhileReadError(InputError):
    """A file another process truncated while it was read (exit 2). Never a recording's damage,
    which readers read around (``report`` then goes on without the truth it held): a file that
    shrinks mid-read says nothing of what it holds, so every command stops and says to read it
    again once it is whole."""


class BagError(RecordingError):
    """A ROS bag (rosbag2 folder or file, ROS 1 bag) that cannot be read (exit 2)."""


class UnopenableBag(BagError):
    """A bag that cannot even be opened (its index or header damaged, not a bag at all): no topic of
    it can be read, so ``report`` does not go on without its ground truth as for a missing topic."""


class SceneError(InputError):
    """A Foxglove scene file that cannot be written; the message is ``PATH: problem`` (exit 2)."""


class TrajectoryError(InputError):
    """A trajectory file that cannot be read or written; the message is ``PATH: problem`` (exit 2)."""
