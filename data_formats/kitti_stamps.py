"""KITTI's stamp files, which lie beside its image folders rather than in their file names:

- odometry: ``sequences/00/times.txt`` beside ``image_0/`` … ``image_3/``, one line per frame,
  seconds from the sequence's start (``1.036000e-01``);
- raw: ``image_02/timestamps.txt`` beside ``image_02/data/``, one line per frame, date and time
  to the nanosecond (``2011-09-26 13:02:25.964389445``), read as UTC (the file names no zone; UTC
  gives the same stamps on every machine).

Frames are ~0.1 s apart, not exactly (``1.036000e-01``): without these an import had to guess a
``--rate``. A file is only used when it is the only one and has one stamp per image, strictly
increasing; otherwise :class:`KittiStampsUnusable` says why, as one line, and the caller goes on
without it (the file was found, not named by the user).
"""

from __future__ import annotations

import calendar
import re
from array import array
from collections.abc import Iterator
from datetime import UTC, datetime
from pathlib import Path

from aslam.data_formats import ros_msgs
from aslam.data_formats.files import full_path, real_path
from aslam.data_formats.format_names import StampUnit
from aslam.data_formats.pose_files import stamp_text_ns, text_lines

#: Name → what its lines are; looked for in the image folder's parent folder.
SECONDS_FILE = "times.txt"
DATE_TIME_FILE = "timestamps.txt"

_DATE_TIME = re.compile(r"(\d{4})-(\d{2})-(\d{2})[ T](\d{2}):(\d{2}):(\d{2})(?:\.(\d{1,9}))?")


class KittiStampsUnusable(Exception):
    """A KITTI stamp file found beside the images that cannot stamp them; the message says why."""


def kitti_stamp_file(folder: Path) -> Path | None:
    """The KITTI stamp file beside ``folder`` (in its parent), if there is one; two (both names)
    are ambiguous: :class:`KittiStampsUnusable`. The parent of the folder as a path names it
    (``image_0`` typed in ``00/``, ``.`` typed in ``image_0/``), so the path is made absolute first;
    a folder that is a symlink (``cam0 -> /data/kitti/sequences/00/image_0``) has it beside the
    folder it points to, looked in when there is none beside the link."""
    for parent in dict.fromkeys([full_path(folder).parent, real_path(folder).parent]):
        found = [parent / name for name in (SECONDS_FILE, DATE_TIME_FILE) if (parent / name).is_file()]
        if len(found) > 1:
            raise KittiStampsUnusable(f"{found[0]} and {found[1]} are not used: which one stamps {folder}?")
        if found:
            return found[0]
    return None


def read_kitti_stamps(path: Path, folder: Path, images: int) -> tuple[int, ...]:
    """One stamp (ns) from ``path`` per image of ``folder`` (``images`` of them), or
    :class:`KittiStampsUnusable` naming the file and the problem: a line that is no time, stamps not
    strictly increasing, another count."""
    stamps = array("q")
    count = 0
    for number, text in _lines(path):
        try:
            stamp_ns = (
                _date_time_ns(text) if path.name == DATE_TIME_FILE else stamp_text_ns(text, StampUnit.S)
            )
        except ValueError as err:
            raise KittiStampsUnusable(f"{path}: not used: line {number}: {err}") from err
        if stamps and stamp_ns <= stamps[-1]:
            raise KittiStampsUnusable(f"{path}: not used: line {number}: not after the line before")
        count += 1
        if count <= images:
            stamps.append(stamp_ns)
    if count != images:
        raise KittiStampsUnusable(f"{path}: not used: {count} stamps for {images} images in {folder}")
    return tuple(stamps)


def _lines(path: Path) -> Iterator[tuple[int, str]]:
    def unusable(problem: str) -> KittiStampsUnusable:
        return KittiStampsUnusable(f"{path}: not used: {problem}")

    return text_lines(path, unusable, comments=False)


def _date_time_ns(text: str) -> int:
    match = _DATE_TIME.fullmatch(text)
    if match is None:
        raise ValueError(f"'{text}' is not a date and time (2011-09-26 13:02:25.964389445)")
    *fields, fraction = match.groups()
    year, month, day, hour, minute, second = (int(field) for field in fields)
    try:
        moment = datetime(year, month, day, hour, minute, second, tzinfo=UTC)
    except ValueError as err:
        raise ValueError(f"'{text}' is not a date and time ({err})") from err
    stamp_ns = calendar.timegm(moment.timetuple()) * ros_msgs.NS_PER_S + int((fraction or "0").ljust(9, "0"))
    if not 0 <= stamp_ns <= ros_msgs.LAST_STAMP_NS:
        raise ValueError(f"'{text}' is outside 1970–2038, the years a ROS time holds")
    return stamp_ns
