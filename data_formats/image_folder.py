"""A folder of PNG/JPEG images with optional pose files (how Nordland, KITTI, TUM RGB-D ship), read
as the same ``Sample`` stream a recording gives.

Images are taken in file-name order, numbers compared as numbers (``2.png`` before ``10.png``;
zero-padded names sort as usual). Each is read from disk only when its sample is yielded and
decoded only on request, so memory does not grow with the folder.

**Stamps**, the first that applies:

1. a stamped pose file (TUM, CSV) with exactly one row per image gives the images its stamps
   (the odometry file first, then the ground-truth file);
2. ``rate_hz``: image ``i`` at ``START_STAMP_NS + i / rate_hz`` (from the first stamp of a pose
   file to be interpolated);
3. file names that are all times (TUM RGB-D's seconds ``1305031102.175304.png``, EuRoC's
   nanoseconds), not frame numbers (``FRAME_NUMBER_MAX``);
4. KITTI's stamp file beside the folder (``data_formats.kitti_stamps``), where it has one stamp per
   image;
5. otherwise 1 Hz, and the folder says so (``stamps`` = ``"default 1 Hz"``); with a stamped pose
   file of another length that is an error: the images have no stamps on its clock.

**Poses**: a pose file with one row per image (always so for KITTI) pairs row ``i`` with image
``i``; a stamped file with another count is interpolated to the image stamps (the recording
reader's ``SampleAssembler``; images outside its span are dropped, with a warning). Without an odometry
file the odometry is synthetic, one unit (``SYNTHETIC_STEP_M``) straight ahead per image, and
``odometry_known`` is False: the frames are assumed equally spaced along the route, SeqSLAM's
assumption, and the estimator should use its motion prior for that case rather than trust it.
"""

from __future__ import annotations

import heapq
import math
import re
from array import array
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from decimal import Decimal, InvalidOperation
from itertools import pairwise
from pathlib import Path

import numpy as np

from aslam.core.decimal_text import is_decimal
from aslam.core.errors import InputError
from aslam.data_formats.format_names import StampUnit
from aslam.data_formats.images import ImageFormat, LazyImage, sniffed_format
from aslam.data_formats.kitti_stamps import KittiStampsUnusable, kitti_stamp_file, read_kitti_stamps
from aslam.data_formats.pose_files import (
    LAYOUTS,
    SPACING_SAMPLE,
    PoseFileError,
    PoseFormat,
    PoseRow,
    detect_format,
    iter_poses,
    spacing_doubt,
    stamp_text_ns,
)
from aslam.data_formats.pose_sync import Sample, SampleAssembler
from aslam.data_formats.ros_msgs import LAST_STAMP_NS

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".jfif")
#: Same fixed epoch as the recorder (2020-09-13T12:26:40Z): not 0, which ROS tools treat as unset.
START_STAMP_NS = 1_600_000_000_000_000_000
DEFAULT_RATE_HZ = 1.0
SYNTHETIC_STEP_M = 1.0
FRAME_NUMBER_MAX = 10**9
"""File names that are all whole numbers below this are frame numbers (KITTI's ``000000.png``, KITTI
raw's ``0000000000.png``), not stamps, unless a stamp unit is given: as seconds they would be before
2001, no dataset's clock, and frame ``i`` would be ``i`` seconds after 1970, paired with the poses of
that second."""


class ImageFolderError(InputError):
    """An image folder (or one of its files) that cannot be used; exit 2."""


def _natural_key(path: Path) -> tuple[list[object], str]:
    """Numbers compared as numbers, text as text (the odd parts of the split are the digit runs:
    ``str.isdigit`` would also take a superscript ``²``, which ``int`` refuses); the name breaks
    ties (``1.png``, ``01.png``), so the order never depends on the folder's listing."""
    parts = re.split(r"(\d+)", path.name)
    return [int(part) if i % 2 else part for i, part in enumerate(parts)], path.name


#: Image files import cannot store as they are (a recording holds PNG or JPEG bytes): among the
#: frames, each would shift every later frame's pairing, so one is refused rather than skipped.
OTHER_IMAGE_SUFFIXES = (
    ".bmp", ".tif", ".tiff", ".webp", ".gif", ".pgm", ".ppm", ".pnm", ".jp2", ".exr", ".heic", ".heif",
    ".avif", ".jxl", ".dng", ".raw",
)  # fmt: skip


def is_hidden(path: Path) -> bool:
    """Hidden files are never frames: macOS's ``._NAME.png`` beside each file on a FAT or exFAT
    disk holds no image, ``.DS_Store`` none either."""
    return path.name.startswith(".")


def is_frame(path: Path) -> bool:
    """Whether the folder entry ``path`` is one of the folder's frames: a PNG or JPEG name
    (``IMAGE_SUFFIXES``, in any case), not hidden (:func:`is_hidden`), and a regular file or a link
    to one (a folder named ``x.png`` is none). The one rule :func:`holds_frames` and
    :func:`list_images` apply."""
    return path.suffix.lower() in IMAGE_SUFFIXES and not is_hidden(path) and path.is_file()


def holds_frames(folder: Path) -> bool:
    """Whether ``folder`` has a file that would be one of its frames (``aslam estimate`` on it is
    then told to ``aslam import`` it)."""
    return any(is_frame(path) for path in folder.iterdir())


def _refusal(path: Path) -> str | None:
    """Why ``path``, not a frame (:func:`is_frame`), stops an import, since skipping it would pair
    every later frame wrongly: an image name that cannot be read (a broken symbolic link: a dataset
    on a disk not mounted; a pipe), or another image format's. None: it is simply no frame (hidden,
    a folder, another kind of file)."""
    suffix = path.suffix.lower()
    if is_hidden(path) or suffix not in IMAGE_SUFFIXES + OTHER_IMAGE_SUFFIXES or path.is_dir():
        return None
    if not path.exists():
        return "cannot read: a broken symbolic link"
    if suffix in OTHER_IMAGE_SUFFIXES:
        return (
            f"a {suffix} image among the frames; import stores PNG and JPEG only (convert it, "
            "or move it out of the folder)"
        )
    return "is not a regular file (a pipe, socket or device)"


def list_images(folder: Path) -> list[Path]:
    """The frames of ``folder`` (:func:`is_frame`; not its subfolders), in natural file-name order,
    or by value where every name is a number (``0.05.png`` before ``0.1.png``: stamps as Python
    writes them). An entry :func:`_refusal` names stops it (ImageFolderError naming the entry).
    """
    folder = Path(folder)
    if not folder.exists():
        raise ImageFolderError("no such folder", path=folder)
    if not folder.is_dir():
        raise ImageFolderError("is a file, not a folder of images", path=folder)
    images = []
    try:
        # In name order, so that of several frames refused the first is named, whatever the file
        # system lists first.
        for path in sorted(folder.iterdir(), key=_natural_key):
            if is_frame(path):
                images.append(path)
                continue
            problem = _refusal(path)
            if problem is not None:
                raise ImageFolderError(problem, path=path)
    except OSError as err:
        raise ImageFolderError(f"cannot list: {err.strerror or err}", path=folder) from err
    if not images:
        raise ImageFolderError("has no .png or .jpg images", path=folder)
    return frame_order(images)


def frame_order(images: list[Path]) -> list[Path]:
    """``images`` in natural file-name order, or by value where every name is a number (ties in
    natural order): the same order whatever order they are listed in."""
    images = sorted(images, key=_natural_key)
    values = [value for value in (_number(image.stem) for image in images) if value is not None]
    if len(values) == len(images):
        images = [image for _, image in sorted(zip(values, images, strict=True), key=lambda pair: pair[0])]
    return images


def _number(text: str) -> Decimal | None:
    """The name's value where it is a decimal number as :mod:`aslam.core.decimal_text` reads one
    (``Decimal`` alone also takes ``1_0`` and other scripts' digits: such a folder was refused
    as badly stamped instead of read in name order)."""
    if not is_decimal(text):
        return None
    try:
        value = Decimal(text)
    except InvalidOperation:
        return None
    return value if value.is_finite() else None


def image_format(data: bytes, path: Path) -> ImageFormat:
    """PNG or JPEG, from the file's first bytes (not its name)."""
    fmt = sniffed_format(data)
    if fmt is not None:
        return fmt
    if not data:
        raise ImageFolderError("empty image file (0 bytes)", path=path)
    raise ImageFolderError(f"not a PNG or JPEG file (starts with {data[:8].hex(' ')})", path=path)


def read_image(path: Path) -> LazyImage:
    """The file's bytes as a LazyImage (encoding "png" or "jpeg"), decoded only on request; its
    errors name the file alone (its stamp may be made up: a rate, the default 1 Hz)."""
    try:
        data = path.read_bytes()
    except OSError as err:
        raise ImageFolderError(f"cannot read: {err.strerror or err}", path=path) from err
    fmt = image_format(data, path)
    return LazyImage(data, fmt.value, path=path)


@dataclass(frozen=True)
class PoseSource:
    """One pose file, checked whole before any image is read."""

    path: Path
    format: PoseFormat
    rows: int
    stamped: bool
    last_line: int
    first_stamp_ns: int | None
    unit: StampUnit | None  # of its stamps; None: seconds, or nanoseconds of 18+ digits


def _check_pose_file(
    path: Path, fmt: PoseFormat | str | None, what: str, unit: StampUnit | None, warnings: list[str]
) -> PoseSource:
    """The file read whole: every bad line, and stamps spaced as no seconds are, refused now; a
    doubtful spacing (``spacing_doubt``) added to ``warnings``."""
    path = Path(path)
    fmt = detect_format(path) if fmt is None else PoseFormat(fmt)
    rows = 0
    last_line = 0
    previous: int | None = None
    first: int | None = None
    stamps = array("q")  # the first SPACING_SAMPLE stamps, for the median step
    plane = OffPlane()
    for row in iter_poses(path, fmt, unit):
        plane.add(row)
        first = row.stamp_ns if rows == 0 else first
        if row.stamp_ns is not None and unit is None and len(stamps) < SPACING_SAMPLE:
            stamps.append(row.stamp_ns)
        if row.stamp_ns is not None and previous is not None and row.stamp_ns == previous:
            raise PoseFileError(
                f"line {row.line}: the same stamp as the line before; {what} poses need increasing stamps",
                path=path,
            )
        previous = row.stamp_ns
        rows += 1
        last_line = row.line
    if rows == 0:
        raise PoseFileError("has no pose lines", path=path)
    _judge_spacing(stamps, path, PoseFileError, warnings, "")
    if (line := plane.warning(path, fmt)) is not None and line not in warnings:  # (one file, two roles)
        warnings.append(line)
    return PoseSource(path, fmt, rows, LAYOUTS[fmt].stamped, last_line, first, unit)


class OffPlane:
    """How far a pose file's path leaves the plane its planar poses are read in: a camera pitched
    down (KITTI's poses are in the first camera's axes, level only if that camera was), or a path on
    a slope. Read as planar, such a path is shortened and its turns bent (a camera pitched 30° on a
    level car: 27.3 m of a 30 m loop, its 90° turns read as 74° and 106°), in silence before."""

    SHARE = 0.1
    """Off-plane extent over this share of the planar extent gets a warning."""

    def __init__(self) -> None:
        self._low = [math.inf] * 3  # x, y, off-plane
        self._high = [-math.inf] * 3

    def add(self, row: PoseRow) -> None:
        for i, value in enumerate((float(row.pose[0]), float(row.pose[1]), row.off_plane_m)):
            self._low[i] = min(self._low[i], value)
            self._high[i] = max(self._high[i], value)

    def warning(self, path: Path, fmt: PoseFormat) -> str | None:
        extent = [high - low for low, high in zip(self._low, self._high, strict=True)]
        planar, off = max(extent[0], extent[1]), extent[2]
        if not (off > self.SHARE * planar and off > 0.1):
            return None
        axis = "t_y (the camera's down axis)" if fmt is PoseFormat.KITTI else "z"
        return (
            f"{path}: its {axis} spans {off:.2f} m where x and y span {planar:.2f} m: the poses are read"
            " in the plane of the file's own axes, so a camera pitched or rolled from level, or a path on"
            " a slope, reads shortened and with bent turns"
        )


def _frame_numbers(images: list[Path]) -> bool:
    """Whether every name is a whole number below ``FRAME_NUMBER_MAX`` (``0000.png``, ``17.png``)."""
    return all(re.fullmatch(r"[0-9]+", image.stem) and int(image.stem) < FRAME_NUMBER_MAX for image in images)


def _judge_spacing(
    stamps: array[int] | list[int], path: Path, error: type[InputError], warnings: list[str], what: str
) -> None:
    doubt = spacing_doubt(stamps)
    if doubt is not None and doubt.refused:
        raise error(what + doubt.message, path=path)
    if doubt is not None:
        warnings.append(f"{path}: {what}{doubt.message}")


def _named_stamps(
    folder: Path, images: list[Path], unit: StampUnit | None, warnings: list[str]
) -> list[int] | None:
    """Stamps from file names that are all times (read as ``stamp_text_ns`` reads them, their spacing
    judged as a pose file's); else None (frame numbers, say). Two names of one time are an error, as
    two rows of one stamp in a pose file are: falling back to 1 Hz dropped every stamp unsaid."""
    if unit is None and _frame_numbers(images):
        return None
    stamps = []
    for path in images:
        value = _number(path.stem)
        if value is None or value < 0:
            return None
        try:
            stamps.append(stamp_text_ns(path.stem, unit))
        except ValueError as err:
            raise ImageFolderError(f"file name: {err}", path=path) from err
    # In value order (``_ordered``): a pair out of order is a pair of one time, or names read in two
    # units (whole numbers of 10^17 or more are nanoseconds, smaller ones seconds).
    for (a, first), (b, second) in pairwise(zip(stamps, images, strict=True)):
        if b == a:
            raise ImageFolderError(
                f"file names {first.name} and {second.name} are the same time ({a} ns): rename one, or"
                " give --rate HZ to stamp the images in name order",
                path=folder,
            )
        if b < a:
            raise ImageFolderError(
                f"file names {first.name} and {second.name} read as times in two units ({a} and {b} ns):"
                " give --stamp-unit, or --rate HZ to stamp the images in name order",
                path=folder,
            )
    if unit is None:
        _judge_spacing(stamps, folder, ImageFolderError, warnings, "file names: ")
    return stamps


def _kitti_stamps(folder: Path, n: int, warnings: list[str]) -> tuple[tuple[int, ...], str] | None:
    """The images' stamps from KITTI's ``times.txt`` or ``timestamps.txt`` beside the folder, and
    where they came from; None where there is none, or (with a warning) it cannot stamp them."""
    try:
        path = kitti_stamp_file(folder)
        if path is None:
            return None
        return read_kitti_stamps(path, folder, n), f"KITTI {path.parent.name}/{path.name}"
    except KittiStampsUnusable as err:
        warnings.append(str(err))
        return None


def _warn_kitti_stamps_unused(folder: Path, why: str, warnings: list[str]) -> None:
    """A KITTI stamp file beside the folder that another source of stamps overrides, said once."""
    try:
        path = kitti_stamp_file(folder)
    except KittiStampsUnusable:
        return
    if path is not None:
        warnings.append(f"{path}: not used: {why}")


@dataclass(frozen=True)
class ImageFolder:
    """An image folder ready to stream; build it with :func:`open_image_folder`."""

    folder: Path
    images: tuple[Path, ...]
    stamps: str  # where the stamps came from: "pose file <name>", "rate 10 Hz", "file names",
    # "KITTI 00/times.txt", "default 1 Hz"
    odometry: PoseSource | None
    ground_truth: PoseSource | None
    warnings: tuple[str, ...]  # about the files, found when opening; given again by samples()
    _image_stamps: tuple[int, ...] | None  # None: from the per-image pose file (read while streaming)
    _stamp_file: PoseSource | None

    @property
    def odometry_known(self) -> bool:
        return self.odometry is not None

    def __len__(self) -> int:
        return len(self.images)

    def samples(self, *, on_warning: Callable[[str], None] | None = None) -> Iterator[Sample]:
        """One sample per image, in order (images outside a stamped pose file's span are dropped);
        ``on_warning`` hears the folder's ``warnings`` first, then what the pairing dropped.

        Each image is a ``LazyImage`` holding the file's bytes, its ``encoding`` ``"png"`` or
        ``"jpeg"`` (an ``ImageFormat`` value), so the bytes can be passed on unchanged.
        """
        return self._samples(on_warning or (lambda _message: None))

    def _stamp_stream(self) -> Iterator[int]:
        if self._image_stamps is not None:
            yield from self._image_stamps
            return
        assert self._stamp_file is not None
        for row in iter_poses(self._stamp_file.path, self._stamp_file.format, self._stamp_file.unit):
            assert row.stamp_ns is not None
            yield row.stamp_ns

    def _pose_stream(
        self, source: PoseSource | None, stamps: Iterator[int]
    ) -> Iterator[tuple[int, np.ndarray]]:
        """``(stamp_ns, pose)``: per image (re-stamped) when the counts match, else the file's own."""
        if source is None:  # synthetic odometry: equally spaced, straight ahead
            for i, stamp in enumerate(stamps):
                yield stamp, np.array([i * SYNTHETIC_STEP_M, 0.0, 0.0])
            return
        rows = iter_poses(source.path, source.format, source.unit)
        if source.rows == len(self.images):
            for stamp, row in zip(stamps, rows, strict=True):
                yield stamp, row.pose
            return
        for row in rows:
            assert row.stamp_ns is not None
            yield row.stamp_ns, row.pose

    def _samples(self, warn: Callable[[str], None]) -> Iterator[Sample]:
        for line in self.warnings:
            warn(line)

        # Time-ordered streams merged by stamp; at equal stamps the poses come before the image.
        def images() -> Iterator[tuple[int, int, object]]:
            for path, stamp in zip(self.images, self._stamp_stream(), strict=True):
                yield stamp, 2, path

        def poses(source: PoseSource | None, order: int) -> Iterator[tuple[int, int, object]]:
            for stamp, pose in self._pose_stream(source, self._stamp_stream()):
                yield stamp, order, pose

        streams = [images(), poses(self.odometry, 0)]
        assembler = SampleAssembler(self.folder)
        if self.ground_truth is not None:
            streams.append(poses(self.ground_truth, 1))
            assembler.expect_ground_truth = True
        for stamp, order, item in heapq.merge(*streams, key=lambda row: (row[0], row[1])):
            if order == 2:
                assert isinstance(item, Path)
                yield from assembler.add_image(stamp, read_image(item))
            elif order == 0:
                yield from assembler.add_odometry(stamp, item)  # type: ignore[arg-type]
            else:
                yield from assembler.add_ground_truth(stamp, item)  # type: ignore[arg-type]
        yield from assembler.finish()
        for line in assembler.warnings():
            warn(line)


def open_image_folder(
    folder: Path,
    *,
    ground_truth: Path | None = None,
    odometry: Path | None = None,
    fmt: PoseFormat | str | None = None,
    rate_hz: float | None = None,
    stamp_unit: StampUnit | str | None = None,
) -> ImageFolder:
    """List the images and check the pose files whole (every bad line is an error now, not later).

    ``fmt`` applies to both pose files; None detects each from its content. ``stamp_unit`` is the
    unit of every stamp read (pose files, file names); None: seconds, or nanoseconds of 18+ digits,
    with stamps spaced as seconds never are refused (``pose_files.spacing_doubt``).
    """
    folder = Path(folder)
    if rate_hz is not None and not (rate_hz > 0 and np.isfinite(rate_hz)):
        raise ImageFolderError(f"--rate must be a positive number of images per second, got {rate_hz}")
    unit = None if stamp_unit is None else StampUnit(stamp_unit)
    images = list_images(folder)
    n = len(images)
    warnings: list[str] = []
    odo = None if odometry is None else _check_pose_file(odometry, fmt, "odometry", unit, warnings)
    truth = (
        None if ground_truth is None else _check_pose_file(ground_truth, fmt, "ground-truth", unit, warnings)
    )
    for source in (odo, truth):
        if source is None or (source.stamped and source.rows != n) or source.rows == n:
            continue
        # An unstamped (KITTI) file must have one row per image.
        raise PoseFileError(
            f"line {source.last_line}: {source.rows} poses for {n} images in {folder} "
            "(a KITTI file has one line per image)",
            path=source.path,
        )
    stamp_file = next((s for s in (odo, truth) if s is not None and s.stamped and s.rows == n), None)
    # A stamped file with another count is interpolated: the images need stamps on its clock.
    interpolated = next((s for s in (odo, truth) if s is not None and s.stamped and s.rows != n), None)
    image_stamps: tuple[int, ...] | None = None
    named: list[int] | None = None
    in_unit = "" if unit is None else f" ({unit})"
    if stamp_file is not None:
        how = f"pose file {stamp_file.path.name}{in_unit}"
    elif rate_hz is not None:
        _warn_kitti_stamps_unused(folder, f"--rate {rate_hz:g} Hz gives the stamps", warnings)
        start = START_STAMP_NS if interpolated is None else interpolated.first_stamp_ns
        assert start is not None
        if start + (n - 1) * 1e9 / rate_hz > LAST_STAMP_NS:
            raise ImageFolderError(
                f"--rate {rate_hz:g} Hz is too slow: {n} images would run past 2038, the last year a ROS"
                " time holds"
            )
        image_stamps = tuple(start + round(i * 1e9 / rate_hz) for i in range(n))
        how = f"rate {rate_hz:g} Hz" + (
            "" if interpolated is None else f" from the first stamp of {interpolated.path.name}"
        )
    elif (named := _named_stamps(folder, images, unit, warnings)) is not None:
        image_stamps, how = tuple(named), f"file names{in_unit}"
    elif (kitti := _kitti_stamps(folder, n, warnings)) is not None:
        image_stamps, how = kitti
    elif interpolated is not None:
        names = " (their names are frame numbers)" if _frame_numbers(images) else ""
        unit_hint = ", or --stamp-unit if the names are times" if names and unit is None else ""
        raise PoseFileError(
            f"{interpolated.rows} poses for {n} images in {folder}, and the images have no stamps{names}: "
            f"give --rate HZ (the images then start at this file's first stamp) or one pose per image"
            f"{unit_hint}",
            path=interpolated.path,
        )
    else:
        image_stamps = tuple(START_STAMP_NS + round(i * 1e9 / DEFAULT_RATE_HZ) for i in range(n))
        how = f"default {DEFAULT_RATE_HZ:g} Hz"
    if image_stamps is not None and any(b <= a for a, b in pairwise(image_stamps)):
        raise ImageFolderError(f"--rate {rate_hz:g} Hz is too fast to give {n} distinct nanosecond stamps")
    if unit is not None and not (any(s is not None and s.stamped for s in (odo, truth)) or named):
        warnings.append(
            f"{folder}: --stamp-unit {unit} is not used: no pose file has stamps (KITTI's have none) and"
            f" the images are stamped by {how}"
        )
    return ImageFolder(folder, tuple(images), how, odo, truth, tuple(warnings), image_stamps, stamp_file)
