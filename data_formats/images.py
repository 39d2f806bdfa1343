"""Camera images as recordings store them: PNG/JPEG bytes or raw pixels, decoded on request."""

from __future__ import annotations

import logging
import os
import re
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path
from typing import NamedTuple

import numpy as np

from aslam.data_formats.errors import RecordingError
from aslam.data_formats.image_encodings import raw_to_gray


class ImageFormat(StrEnum):
    PNG = "png"
    JPEG = "jpeg"


class EncodedImage(NamedTuple):
    format: ImageFormat
    data: bytes


def encode_image(rgb: np.ndarray, fmt: ImageFormat = ImageFormat.PNG, jpeg_quality: int = 90) -> EncodedImage:
    """PNG or JPEG bytes of an RGB ``(H, W, 3)`` (or grey ``(H, W)``) uint8 image.

    The same input gives the same bytes (same OpenCV build): no timestamps or random state.
    """
    import cv2

    rgb = np.asarray(rgb)
    if rgb.dtype != np.uint8 or not (rgb.ndim == 2 or (rgb.ndim == 3 and rgb.shape[2] == 3)):
        raise ValueError(f"expected a uint8 (H, W, 3) or (H, W) image, got {rgb.dtype} {rgb.shape}")
    pixels = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR) if rgb.ndim == 3 else rgb
    fmt = ImageFormat(fmt)
    if fmt is ImageFormat.PNG:
        # Run-length strategy: the recorder (this function's user) renders frames of long flat runs;
        # against zlib's default strategy (level 3) it encodes them in 0.6 × the time to 0.93 × the
        # bytes, decoding ~0.1 ms a frame slower (docs/recorder.md).
        params = [cv2.IMWRITE_PNG_COMPRESSION, 3, cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_RLE]
        ok, buf = cv2.imencode(".png", pixels, params)
    else:
        if not 0 <= jpeg_quality <= 100:
            raise ValueError(f"jpeg_quality must be in [0, 100], got {jpeg_quality}")
        ok, buf = cv2.imencode(".jpg", pixels, [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)])
    if not ok:
        raise ValueError(f"OpenCV could not encode a {rgb.shape} image as {fmt.value}")
    return EncodedImage(fmt, buf.tobytes())


MAX_SIDE_PX = 8192
MAX_PIXELS = 2048 * 2048
"""The largest image this tool decodes: at most 8192 pixels a side and 4.2 megapixels in all
(docs/formats.md). Read from the PNG or JPEG header (or the raw ``Image`` fields) before decoding,
so a few bytes claiming a huge image cannot claim gigabytes. The pixel bound is the estimator's:
its gradient histogram needs about 150 bytes per pixel, so ``aslam estimate`` peaks at 636 MiB on
2048×2048 images (342 MiB at 1920×1080, 1.23 GiB at 3840×2160, 9.2 GiB at 8192×8192)."""

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
# JPEG start-of-frame markers (SOF0..SOF15 without DHT, JPG and DAC), which carry the size.
_JPEG_SOF = {0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF}


_LIMIT_TEXT = f"the limit is {MAX_SIDE_PX} pixels a side and {MAX_PIXELS:,} pixels in all"


def _within_limits(width: int, height: int) -> bool:
    return width <= MAX_SIDE_PX and height <= MAX_SIDE_PX and width * height <= MAX_PIXELS


def sniffed_format(data: bytes) -> ImageFormat | None:
    """PNG or JPEG from the bytes themselves (a file's name or a message's label may be missing or
    wrong); None for anything else."""
    if data.startswith(_PNG_SIGNATURE):
        return ImageFormat.PNG
    if data.startswith(b"\xff\xd8\xff"):
        return ImageFormat.JPEG
    return None


def header_size(data: bytes) -> tuple[int, int] | None:
    """``(width, height)`` from a PNG's IHDR or a JPEG's start-of-frame, or None if not found."""
    if data.startswith(_PNG_SIGNATURE):
        if len(data) < 24 or data[12:16] != b"IHDR":
            return None
        return int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")
    if not data.startswith(b"\xff\xd8"):
        return None
    i = 2
    while i + 4 <= len(data):
        if data[i] != 0xFF:
            return None
        marker = data[i + 1]
        if marker == 0xFF:  # fill byte
            i += 1
            continue
        if marker in (0xD8, 0x01) or 0xD0 <= marker <= 0xD7:  # no length
            i += 2
            continue
        length = int.from_bytes(data[i + 2 : i + 4], "big")
        if marker in _JPEG_SOF:
            if i + 9 > len(data) or length < 7:
                return None
            return int.from_bytes(data[i + 7 : i + 9], "big"), int.from_bytes(data[i + 5 : i + 7], "big")
        if marker == 0xDA or length < 2:  # scan data before any frame header
            return None
        i += 2 + length
    return None


_PLAIN_PNG_CHUNKS = frozenset({b"IHDR", b"IDAT", b"IEND", b"tEXt", b"zTXt", b"iTXt", b"tIME", b"pHYs"})
"""Chunks that leave a PNG's pixel values alone: a file with any other (gamma, colour profile,
palette, transparency, significant bits) takes OpenCV's path, whose handling of them is the reference."""

_LIBPNG_GRAY = np.array([[9797, 19234, 3737]], dtype=np.float32) / np.float32(32768)
"""libpng's RGB → grey weights (``png_set_rgb_to_gray(0.299, 0.587)`` in 1/32768ths, truncated),
as OpenCV's ``IMREAD_GRAYSCALE`` applies them: grey = ⌊(9797 R + 19234 G + 3737 B) / 32768⌋. Every
partial sum is an integer below 2²⁴ times 2⁻¹⁵, so float32 arithmetic computes it exactly."""


def _plain_png(data: bytes) -> bool:
    """Whether ``data`` is an 8-bit, non-interlaced grey or RGB PNG with no chunk that alters its
    pixels, its chunks ending with IEND at the end of the data (imagecodecs' libpng does not read
    that far; OpenCV refuses a PNG without it). The CRCs are libpng's to check."""
    size = header_size(data)
    if size is None or not (all(size) and _within_limits(*size)) or len(data) < 45:
        return False
    bit_depth, colour_type, compression, filtering, interlace = data[24:29]
    if bit_depth != 8 or colour_type not in (0, 2) or compression or filtering or interlace:
        return False
    offset, end = len(_PNG_SIGNATURE), len(data)
    while offset + 12 <= end:
        length = int.from_bytes(data[offset : offset + 4], "big")
        kind = data[offset + 4 : offset + 8]
        if kind not in _PLAIN_PNG_CHUNKS:
            return False
        offset += 12 + length
        if kind == b"IEND":
            return offset == end
    return False


def png_gray(data: bytes) -> np.ndarray | None:
    """The grey pixels of a plain PNG (:func:`_plain_png`), or None for any other PNG or one the
    decoder refuses (OpenCV's path then decodes it or names the problem).

    The same pixels as OpenCV's ``IMREAD_GRAYSCALE`` (a property test compares them) at four fifths
    of its cost (``bench/decode_bench.py``): imagecodecs' own libpng build, then libpng's own grey
    weights. It releases the GIL, so the reader's threads decode in parallel.
    """
    if not _plain_png(data):
        return None
    import imagecodecs

    _decoder_warned.flag = False
    try:
        with _listening_to_decoder_warnings():
            pixels = imagecodecs.png_decode(data)
    except Exception:  # a refusal (a CRC, a truncated stream): OpenCV decodes it or names it
        return None
    if _decoder_warned.flag or pixels.dtype != np.uint8:  # libpng had doubts: OpenCV's libpng decides
        return None
    return pixels if pixels.ndim == 2 else libpng_gray(pixels)


_decoder_warned = threading.local()
"""Whether imagecodecs logged a warning during this thread's current decode."""


class _NoteDecoderWarning(logging.Handler):
    def emit(self, record: logging.LogRecord) -> None:
        _decoder_warned.flag = True


class _WhileDecoding:
    """A setting held while any thread decodes: ``_hold`` before the first decode, ``_release``
    after the last. Reference counted, so decoding threads can overlap and the caller's own setting
    comes back after the last one."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._users = 0

    def _hold(self) -> None:
        raise NotImplementedError

    def _release(self) -> None:
        raise NotImplementedError

    @contextmanager
    def __call__(self) -> Iterator[None]:
        with self._lock:
            if self._users == 0:
                self._hold()
            self._users += 1
        try:
            yield
        finally:
            with self._lock:
                self._users -= 1
                if self._users == 0:
                    self._release()


class _DecoderWarnings(_WhileDecoding):
    """imagecodecs reports libpng's warnings through the ``imagecodecs`` logger: while any thread
    decodes they are kept off the terminal (the error contract: one line, and nothing on success)
    and noted, so the image a warning was about takes OpenCV's path. After the last decode the
    logger is the caller's again (a notebook's own imagecodecs warnings reach its logging), with no
    handler of ours left on it."""

    def __init__(self) -> None:
        super().__init__()
        self._handler = _NoteDecoderWarning()
        self._saved_propagate = True

    def _hold(self) -> None:
        logger = logging.getLogger("imagecodecs")
        self._saved_propagate = logger.propagate
        logger.addHandler(self._handler)
        logger.propagate = False

    def _release(self) -> None:
        logger = logging.getLogger("imagecodecs")
        logger.removeHandler(self._handler)
        logger.propagate = self._saved_propagate


_listening_to_decoder_warnings = _DecoderWarnings()


def libpng_gray(rgb: np.ndarray) -> np.ndarray:
    """uint8 ``(H, W)`` grey of a uint8 ``(H, W, 3)`` RGB image, exactly as libpng (and so OpenCV's
    PNG decoder) makes it: truncated to the level below, float32 exact (see ``_LIBPNG_GRAY``)."""
    import cv2

    return cv2.transform(rgb.astype(np.float32), _LIBPNG_GRAY).astype(np.uint8)


class _QuietOpenCV(_WhileDecoding):
    """Silence OpenCV's log while any thread decodes, so a corrupt image's warning (``[ WARN:0@…]
    PNG input buffer is incomplete``) does not reach stderr; the error says it instead."""

    def __init__(self) -> None:
        super().__init__()
        self._saved_level = 0

    def _hold(self) -> None:
        import cv2

        self._saved_level = cv2.utils.logging.getLogLevel()
        cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)

    def _release(self) -> None:
        import cv2

        cv2.utils.logging.setLogLevel(self._saved_level)


_quiet_opencv = _QuietOpenCV()

#: libjpeg's warnings that the compressed data is damaged (jerror.h's JWRN_ messages): it prints
#: them and decodes on, recovering (wrong blocks). Its other warnings (an unknown JFIF revision)
#: say nothing of the pixels.
_LIBJPEG_DAMAGE = re.compile(
    rb"Corrupt JPEG data: .*|Premature end of JPEG file|Inconsistent progression sequence .*"
    rb"|Invalid SOS parameters for sequential JPEG"
)


class _LibjpegWarnings:
    """What libjpeg prints while one image decodes. OpenCV leaves libjpeg's own message handler in
    place, which writes to file descriptor 2 (the CLI points it at /dev/null, so the user saw
    nothing at all); imagecodecs and Pillow discard the warnings. So descriptor 2 is pointed at a
    file of ours for the decode, one decode at a time (a lock: a second decoding thread's words
    would be taken for the first's), and what else came meanwhile is written on to descriptor 2.
    3-6 µs an image (0.4 % of a 640×480 JPEG's decode): for ``import`` and ``info``, which decode
    every image once, one after another; ``estimate``'s two decoding threads would wait for each
    other on the lock, so they do not take it."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._made = False
        self._fd: int | None = None

    def first_damage(self, decode: Callable[[], np.ndarray]) -> tuple[np.ndarray, str | None]:
        """``decode()``, and libjpeg's first warning of damage during it (None: no word)."""
        with self._lock:
            if not self._made:
                self._made, self._fd = True, _unnamed_file()
            if self._fd is None:  # nowhere to hear libjpeg on
                return decode(), None
            try:
                saved = os.dup(2)
            except OSError:  # no descriptor 2 at all (a daemon's): nothing to hear libjpeg on
                return decode(), None
            try:
                os.dup2(self._fd, 2)
                try:
                    pixels = decode()
                finally:  # also when the image is refused: its error says what libjpeg said
                    os.dup2(saved, 2)
                    damage = _first_damage(self._take())
            finally:
                os.close(saved)
        return pixels, damage

    def _take(self) -> bytes:
        """What the file holds, emptying it."""
        assert self._fd is not None
        size = os.lseek(self._fd, 0, os.SEEK_CUR)
        if not size:
            return b""
        os.lseek(self._fd, 0, os.SEEK_SET)
        said = os.read(self._fd, size)
        os.ftruncate(self._fd, 0)
        os.lseek(self._fd, 0, os.SEEK_SET)
        return said


_libjpeg_warnings = _LibjpegWarnings()


def _unnamed_file() -> int | None:
    """A descriptor of a file with no name, to hear descriptor 2 on: in memory where the system has
    them (Linux's ``memfd_create``), else in the temporary folder; None where neither can be made
    (libjpeg then goes unheard). A read-only container (``docker run --read-only``) has no temporary
    folder: ``aslam info`` of JPEG images, which writes nothing, failed there, ``No usable temporary
    directory found``."""
    try:
        if hasattr(os, "memfd_create"):
            return os.memfd_create("aslam-libjpeg-warnings")
        import tempfile

        with tempfile.TemporaryFile() as file:  # its descriptor duplicated: it lives while that does
            return os.dup(file.fileno())
    except OSError:
        return None


def _first_damage(said: bytes) -> str | None:
    """libjpeg's first warning of damage in ``said``; its other lines go on to descriptor 2."""
    lines = said.splitlines(keepends=True)
    damage = [line.rstrip() for line in lines if _LIBJPEG_DAMAGE.fullmatch(line.rstrip())]
    rest = b"".join(line for line in lines if not _LIBJPEG_DAMAGE.fullmatch(line.rstrip()))
    if rest:
        os.write(2, rest)
    return damage[0].decode("ascii", "replace") if damage else None


@dataclass
class JpegDamage:
    """The JPEG images of one input whose compressed data libjpeg found damaged, for one warning
    line. Refusing them would refuse real cameras' images: UVC (USB) cameras' MJPEG frames often
    have bytes after their data ("extraneous bytes before marker 0xd9"), and libjpeg decodes every
    such image, recovering what it can; but a user should know the images are not what the camera
    saw, and which one to look at."""

    damaged: int = 0
    first: str | None = None
    """The first damaged image, named, with libjpeg's words."""

    def decode_gray(self, image: LazyImage) -> np.ndarray:
        """``image.decode_gray()``, noting libjpeg's word on a JPEG (:class:`_LibjpegWarnings`)."""
        if sniffed_format(image.data) is not ImageFormat.JPEG or image.encoding not in ("png", "jpeg"):
            return image.decode_gray()
        pixels, damage = _libjpeg_warnings.first_damage(image.decode_gray)
        if damage is not None:
            self.damaged += 1
            if self.first is None:
                self.first = f"{image.where or image.path.name}: {damage}"
        return pixels

    def warning(self, path: Path, images: int) -> str | None:
        """The warning line for ``path``, of ``images`` images in all; None when none was damaged."""
        if not self.damaged:
            return None
        return (
            f"{path}: {self.damaged} of {images} images have damaged JPEG data, read as libjpeg recovers"
            f" them (wrong blocks); the first: {self.first}"
        )


class LazyImage:
    """One camera image as stored: encoded bytes (PNG/JPEG) or raw pixels, decoded only on request.

    ``encoding`` is ``"png"``, ``"jpeg"`` or a raw ``sensor_msgs/Image`` encoding
    (``image_encodings.RAW_ENCODINGS``: mono8/16, rgb8, bgra8, yuv422, Bayer, …); ``width``,
    ``height``, ``step`` and ``is_bigendian`` are known up front only for raw images. ``where``
    names the image within ``path`` for an error: a message of a bag or recording (``"image on
    '/camera' at stamp 5 ns"``), or nothing where ``path`` is the image file itself (an image
    folder's frame, whose stamp may be made up: a default rate).
    """

    __slots__ = ("data", "encoding", "height", "is_bigendian", "path", "step", "where", "width")

    def __init__(
        self,
        data: bytes,
        encoding: str,
        *,
        path: Path | str,
        where: str = "",
        width: int = 0,
        height: int = 0,
        step: int = 0,
        is_bigendian: bool = False,
    ) -> None:
        self.data = data
        self.encoding = encoding
        self.path = Path(path)
        self.where = where
        self.width = width
        self.height = height
        self.step = step
        self.is_bigendian = is_bigendian

    def __repr__(self) -> str:
        return f"LazyImage({self.encoding}, {len(self.data)} bytes, {self.where or self.path.name})"

    def _error(self, problem: str) -> RecordingError:
        return RecordingError(f"{self.where}: {problem}" if self.where else problem, path=self.path)

    def _check_header(self) -> None:
        """Refuse, before decoding, an image whose header is missing or claims more than the limit."""
        size = header_size(self.data)
        if size is None:
            raise self._error(f"corrupt {self.encoding.upper()} data (no readable header)")
        width, height = size
        if width == 0 or height == 0:
            raise self._error(f"corrupt {self.encoding.upper()} data (header claims {width}x{height} pixels)")
        if not _within_limits(width, height):
            raise self._error(
                f"{self.encoding.upper()} header claims {width}x{height} pixels ({_LIMIT_TEXT})"
            )

    def _imdecode(self, flags: int) -> np.ndarray:
        import cv2

        self._check_header()
        buf = np.frombuffer(self.data, dtype=np.uint8)
        try:
            with _quiet_opencv():
                pixels = cv2.imdecode(buf, flags) if buf.size else None
        except cv2.error as err:
            raise self._error(f"corrupt {self.encoding.upper()} data ({err})") from err
        if pixels is None:
            raise self._error(f"corrupt {self.encoding.upper()} data ({len(self.data)} bytes)")
        return pixels

    def decode_gray(self) -> np.ndarray:
        """uint8 ``(H, W)``: for PNG and JPEG the pixels of OpenCV's ``IMREAD_GRAYSCALE``."""
        if self.encoding == "png" and (gray := png_gray(self.data)) is not None:
            return gray
        if self.encoding in ("png", "jpeg"):
            import cv2

            return self._imdecode(cv2.IMREAD_GRAYSCALE)
        if not (self.width > 0 and self.height > 0):
            raise self._error(f"{self.width}x{self.height} {self.encoding} image: no pixels")
        if not _within_limits(self.width, self.height):
            raise self._error(f"{self.width}x{self.height} {self.encoding} image ({_LIMIT_TEXT})")
        return raw_to_gray(
            self.data,
            self.encoding,
            self.width,
            self.height,
            self.step,
            self.is_bigendian,
            where=self.where,
            path=self.path,
        )
