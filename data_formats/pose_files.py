"""Pose files as datasets ship them, read line by line into planar poses ``(x_m, y_m, yaw_rad)``.

- TUM: ``t x y z qx qy qz qw`` (seconds, metres, unit quaternion) in a z-up frame: the planar
  pose is x, y and the yaw about z (REP 103).
- KITTI: 12 numbers, a row-major 3×4 ``[R | t]`` per line, one line per image, no stamp.
- CSV: ``t,x,y,yaw`` (seconds, metres, radians), planar already; an optional header line.

KITTI poses are camera poses (x right, y down, z forward) in the first camera's frame; the planar
pose is the one on the ground plane a robot would use: forward ``z`` → ``x_m``, left ``−x`` →
``y_m``, and the heading of the optical axis as ``yaw_rad``.

Lines starting with ``#`` and blank lines are skipped. Stamps are parsed as decimals, so
``1305031102.175304`` becomes exactly ``1305031102175304000`` ns; their unit is seconds (or
nanoseconds for whole numbers of 18+ digits) unless a ``StampUnit`` is given. The format is detected
from the first pose line when not given. Hand-written rather than through evo because every malformed line
must be reported with its file and line number, and the rows are streamed.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from decimal import Decimal, InvalidOperation
from pathlib import Path
from typing import NamedTuple

import numpy as np

from aslam.core.decimal_text import is_decimal
from aslam.core.errors import InputError
from aslam.data_formats import ros_msgs
from aslam.data_formats.files import check_input_file
from aslam.data_formats.format_names import PoseFormat, StampUnit
from aslam.data_formats.pose_limits import MAX_YAW_RAD, implausible


class PoseFileError(InputError):
    """A pose file that cannot be read; the message is ``PATH: line N: problem`` (exit 2)."""


class PoseRow(NamedTuple):
    line: int  # 1-based line number in the file
    stamp_ns: int | None  # None for KITTI (one row per image, no stamps)
    pose: np.ndarray  # (x_m, y_m, yaw_rad)
    off_plane_m: float = 0.0
    """The coordinate the planar pose leaves out: TUM's z, KITTI's t_y (the camera's down axis); 0 for CSV."""


MAX_LINE_CHARS = 65_536
"""A pose line is a few numbers; a longer one is no pose file (a binary file with no newline was read
whole into one line)."""


def text_lines(
    path: Path, failure: Callable[[str], Exception], *, comments: bool
) -> Iterator[tuple[int, str]]:
    """``(line number, stripped text)`` of every line that is not blank (nor, with ``comments``, a
    ``#`` comment), a line at a time, each bounded; a problem is raised as ``failure(problem)``."""
    try:
        with path.open(encoding="utf-8-sig") as f:  # a byte-order mark (Windows editors) is no text
            for number, raw in enumerate(iter(lambda: f.readline(MAX_LINE_CHARS + 1), ""), start=1):
                if len(raw) > MAX_LINE_CHARS:
                    raise failure(f"line {number}: longer than {MAX_LINE_CHARS:,} characters")
                text = raw.strip()
                if text and not (comments and text.startswith("#")):
                    yield number, text
    except UnicodeDecodeError as err:
        raise failure(f"not a text file (byte {err.start} is not UTF-8)") from err
    except OSError as err:
        raise failure(f"cannot read: {err.strerror or err}") from err


def _lines(path: Path) -> Iterator[tuple[int, str]]:
    """A pose file's lines (:func:`text_lines`, ``#`` comments skipped). Only a regular file is read
    (a FIFO was waited on for ever, ``/dev/zero`` read until memory ran out)."""
    check_input_file(path, error=PoseFileError, what="a pose file")
    return text_lines(path, lambda problem: PoseFileError(problem, path=path), comments=True)


def _split(text: str) -> list[str]:
    return [part.strip() for part in text.split(",")] if "," in text else text.split()


def _is_header(fields: list[str]) -> bool:
    """A CSV file's first line may name its columns (``t,x,y,yaw``): no field of it is a number. A
    line with numbers and something else (``1,a,b,c``, a trailing comma) is a bad pose line."""
    return not any(is_decimal(f) for f in fields)


def detect_format(path: Path) -> PoseFormat:
    """The format of ``path`` from its first pose line (a first line of comma-separated names, a
    header, is skipped)."""
    path = Path(path)
    first = True
    for number, text in _lines(path):
        fields = _split(text)
        if first and "," in text and _is_header(fields):
            first = False
            continue  # a CSV header such as "t,x,y,yaw"
        for fmt, layout in LAYOUTS.items():
            if layout.comma_separated == ("," in text) and layout.fields == len(fields):
                return fmt
        shapes = [layout.shape for layout in LAYOUTS.values()]
        raise PoseFileError(
            f"line {number}: cannot tell the format from {len(fields)} fields; expected "
            f"{', '.join(shapes[:-1])} or {shapes[-1]}",
            path=path,
        )
    raise PoseFileError("has no pose lines", path=path)


NANOSECOND_STAMP_MIN = 10**17
"""A whole-number stamp this large is nanoseconds (EuRoC's file names and the files made from them):
as seconds it would be three billion years on."""


NS_PER_UNIT = {StampUnit.S: 10**9, StampUnit.MS: 10**6, StampUnit.US: 10**3, StampUnit.NS: 1}


def stamp_text_ns(text: str, unit: StampUnit | str | None = None) -> int:
    """Nanoseconds of a stamp as datasets write it: a number of ``unit``, or without one decimal
    seconds or whole nanoseconds of 18 or more digits. Raises ``ValueError`` saying why a stamp is
    none (milliseconds since 1970, say, read as seconds are past the last time a ROS message holds;
    relative ones are not, see :func:`spacing_doubt`)."""
    if not is_decimal(text):  # Decimal too takes 1_0 and digits of other scripts
        raise ValueError(f"stamp '{text}' is not a number")
    try:
        value = Decimal(text)
    except InvalidOperation as err:
        raise ValueError(f"stamp '{text}' is not a number") from err
    if not value.is_finite() or value < 0:
        raise ValueError(f"stamp '{text}' is not a finite, non-negative time")
    if unit is not None:
        # Past the last nanosecond is past it in any unit: not multiplied, as 1e999999 (a file name)
        # would overflow the product, decimal.Overflow, an internal error.
        past_last = ros_msgs.LAST_STAMP_NS + 1
        per_unit = NS_PER_UNIT[StampUnit(unit)]
        stamp_ns = int(value * per_unit) if value <= past_last else past_last * per_unit
    elif value >= NANOSECOND_STAMP_MIN and value == value.to_integral_value():
        stamp_ns = int(value)
    else:
        stamp_ns = int(value * ros_msgs.NS_PER_S)
    if stamp_ns > ros_msgs.LAST_STAMP_NS:
        if unit is not None:
            raise ValueError(f"stamp '{text}' {unit} is after 2038, the last year a ROS time holds")
        raise ValueError(
            f"stamp '{text}' is after 2038 read as seconds, the last year a ROS time holds: stamps are "
            "seconds, or whole nanoseconds of 18 or more digits; for other units give --stamp-unit ms, us"
            " or ns"
        )
    return stamp_ns


SECONDS_STEP_DOUBTED_S = 5.0
"""Stamps read as seconds (no unit given) a median step of this or more apart get a warning: a camera
or odometry up to 200 Hz stamped in milliseconds looks like this, seconds rarely do."""
SECONDS_STEP_REFUSED_S = 3600.0
"""... and beyond this (an hour) are refused: nanoseconds or microseconds counted from a start
(0, 33333333, …) are below 2³¹ and pass for seconds, and would put the frames days or years apart."""
SPACING_SAMPLE = 10_001
"""Stamps judged: a file's first ten thousand steps tell its unit, and a pose file of millions of
rows is not held (the import streams)."""


@dataclass(frozen=True)
class SpacingDoubt:
    """Stamps spaced as no poses in seconds are: ``refused`` above an hour, else a warning."""

    refused: bool
    message: str


def spacing_doubt(stamps_ns: Sequence[int]) -> SpacingDoubt | None:
    """Whether the spacing of stamps read without a unit says they are not seconds (None: plausible).

    The median step, so that a pause or a gap between two sessions in the file does not count.
    Only for stamps read by ``stamp_text_ns``'s default rule: a unit given is the user's word.
    """
    if len(stamps_ns) < 2:
        return None
    step_s = float(np.median(np.diff(np.asarray(stamps_ns, dtype=np.int64)))) / ros_msgs.NS_PER_S
    if step_s < SECONDS_STEP_DOUBTED_S:
        return None
    refused = step_s > SECONDS_STEP_REFUSED_S
    judged = ", implausible for poses" if refused else ""
    return SpacingDoubt(
        refused,
        f"stamps a median {_duration(step_s)} apart read as seconds{judged}: if they are milliseconds,"
        " microseconds or nanoseconds, give --stamp-unit ms, us or ns (--stamp-unit s if they are seconds)",
    )


def _duration(seconds: float) -> str:
    if seconds < 120:
        return f"{seconds:.3g} s"
    if seconds < 48 * 3600:
        return f"{seconds / 3600:.3g} h" if seconds >= 3600 else f"{seconds / 60:.3g} min"
    return f"{seconds / 86400:.3g} days"


def _stamp_ns(text: str, path: Path, number: int, unit: StampUnit | None) -> int:
    try:
        return stamp_text_ns(text, unit)
    except ValueError as err:
        raise PoseFileError(f"line {number}: {err}", path=path) from err


def _csv_pose(values: list[float]) -> np.ndarray:
    _t, x, y, yaw = values
    if not abs(yaw) <= MAX_YAW_RAD:
        raise ValueError(f"yaw {yaw:g} rad is beyond the ±{MAX_YAW_RAD:g} rad that names a heading")
    return np.array([x, y, math.remainder(yaw, 2 * math.pi)])


def _tum_pose(values: list[float]) -> np.ndarray:
    _t, x, y, _z, qx, qy, qz, qw = values
    if math.isclose(qx * qx + qy * qy + qz * qz + qw * qw, 0.0):
        raise ValueError("the quaternion is zero")
    return np.array([x, y, ros_msgs.yaw_of_quaternion(qx, qy, qz, qw)])


def _kitti_pose(values: list[float]) -> np.ndarray:
    m = np.array(values).reshape(3, 4)
    if not math.hypot(m[0, 2], m[2, 2]) > 1e-6:  # a zero matrix was read as a yaw of 0
        raise ValueError("the rotation gives no heading (its forward axis is zero or vertical)")
    # Camera axes (x right, y down, z forward) → ground plane (x forward, y left).
    return np.array([m[2, 3], -m[0, 3], math.atan2(-m[0, 2], m[2, 2])])


@dataclass(frozen=True)
class PoseLayout:
    """How a pose-file format writes one pose per line."""

    fields: int
    comma_separated: bool
    """Fields split at commas, a first line of names allowed (a header); else at whitespace."""
    stamped: bool
    """The first field is the stamp; an unstamped file has one line per image."""
    planar: Callable[[list[float]], np.ndarray]
    """The line's numbers → ``(x_m, y_m, yaw_rad)``; ValueError says why a line holds no pose."""
    shape: str
    """The line as the error of a file whose format cannot be told names it."""
    off_plane: Callable[[list[float]], float]
    """The line's numbers → the coordinate ``planar`` leaves out (``PoseRow.off_plane_m``)."""


LAYOUTS: dict[PoseFormat, PoseLayout] = {
    PoseFormat.TUM: PoseLayout(
        8, False, True, _tum_pose, "8 numbers (TUM 't x y z qx qy qz qw')", lambda values: values[3]
    ),
    PoseFormat.KITTI: PoseLayout(
        12, False, False, _kitti_pose, "12 (KITTI 3×4 rows)", lambda values: values[7]
    ),
    PoseFormat.CSV: PoseLayout(
        4, True, True, _csv_pose, "4 comma-separated (CSV 't,x,y,yaw')", lambda _values: 0.0
    ),
}
"""Every pose-file format, the one place it is described (detection, splitting, stamps, the pose);
its name is a ``PoseFormat`` (``aslam import --format``)."""


def iter_poses(
    path: Path, fmt: PoseFormat | str | None = None, unit: StampUnit | str | None = None
) -> Iterator[PoseRow]:
    """Every pose of ``path``, in file order; a malformed line is a PoseFileError naming it.

    Stamps must not go backwards (TUM and CSV), where a bag's odometry drops a message that does
    (``pose_sync.StampOrder``): a text file is sorted in a moment, and one of a row per image is
    paired row by row, which a dropped row would shift. ``unit`` as ``stamp_text_ns`` takes it. The
    format is detected when ``fmt`` is None.
    """
    path = Path(path)
    fmt = detect_format(path) if fmt is None else PoseFormat(fmt)
    return _iter_poses(path, fmt, None if unit is None else StampUnit(unit))


def _iter_poses(path: Path, fmt: PoseFormat, unit: StampUnit | None) -> Iterator[PoseRow]:
    layout = LAYOUTS[fmt]
    previous: int | None = None
    previous_pose: np.ndarray | None = None
    first = True
    for number, text in _lines(path):
        fields = _split(text) if layout.comma_separated else text.split()
        if first and layout.comma_separated and _is_header(fields):
            first = False
            continue  # the header line
        first = False
        if len(fields) != layout.fields:
            raise PoseFileError(
                f"line {number}: {len(fields)} fields, a {fmt.value.upper()} line has {layout.fields}",
                path=path,
            )
        bad = next((f for f in fields if not is_decimal(f)), None)
        if bad is not None:
            raise PoseFileError(f"line {number}: '{bad}' is not a number", path=path)
        values = [float(f) for f in fields]
        if not all(math.isfinite(v) for v in values):
            raise PoseFileError(f"line {number}: not finite (NaN or infinite)", path=path)
        stamp = None
        if layout.stamped:
            stamp = _stamp_ns(fields[0], path, number, unit)
            if previous is not None and stamp < previous:
                raise PoseFileError(
                    f"line {number}: stamp {fields[0]} {unit or 's'} is before the previous line's", path=path
                )
            previous = stamp
        try:
            pose = layout.planar(values)
        except ValueError as err:
            raise PoseFileError(f"line {number}: {err}", path=path) from err
        problem = implausible(pose, previous_pose)  # as a recording's reader would refuse it
        if problem is not None:
            raise PoseFileError(f"line {number}: the pose {problem}", path=path)
        previous_pose = pose
        yield PoseRow(number, stamp, pose, layout.off_plane(values))
