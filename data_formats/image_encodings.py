"""Raw ``sensor_msgs/Image`` pixels → grey (or BGR) uint8, for every encoding robots commonly send.

Pure functions over the message's fields (``data``, ``encoding``, ``width``, ``height``, ``step``,
``is_bigendian``), so any reader (our MCAP recordings, rosbag2, ROS 1 bags) decodes the same way.

Conventions, those of ``cv_bridge``:

- 16-bit values become 8-bit by full-range scaling, ``round(v · 255 / 65535)`` (cv_bridge's
  ``mono16 → mono8``); a depth image in millimetres therefore comes out nearly black.
- ``8UC3`` (and ``8UC4``) carry no channel order; they are read as BGR(A), OpenCV's order, which
  is what ``cv_bridge`` writes for a three-channel ``cv::Mat``.
- ``yuv422`` is UYVY (ROS's name for it), ``yuv422_yuy2`` is YUYV; grey is the Y (luma) plane.
- Bayer mosaics are demosaiced by OpenCV; ROS ``bayer_rggb8`` is OpenCV's ``BayerBG`` (OpenCV
  names the pattern from the second row), as in cv_bridge.

rosbags-image (the rosbags family's converter) ignores ``step`` (padded rows come out sheared) and
cannot turn ``8UC3`` into grey, so the conversions are OpenCV's, called here directly.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from aslam.data_formats.errors import RecordingError


class ImageEncodingError(RecordingError):
    """Raw image bytes that cannot be decoded (unknown encoding, size mismatch); exit 2."""


@dataclass(frozen=True)
class _Layout:
    bytes_per_channel: int  # 1 or 2
    channels: int  # per pixel, as stored (yuv422: 2 bytes per pixel, stored as 2 uint8 channels)
    kind: str  # "gray", "rgb", "bgr", "rgba", "bgra", "uyvy", "yuyv", "bayer_rg", ...


def _layouts() -> dict[str, _Layout]:
    out: dict[str, _Layout] = {}
    for bits, size in ((8, 1), (16, 2)):
        for kind in ("rgb", "bgr", "rgba", "bgra"):
            out[f"{kind}{bits}"] = _Layout(size, len(kind), kind)
        for pattern in ("rggb", "bggr", "gbrg", "grbg"):
            out[f"bayer_{pattern}{bits}"] = _Layout(size, 1, f"bayer_{pattern}")
        out[f"mono{bits}"] = _Layout(size, 1, "gray")
        out[f"{bits}uc1"] = _Layout(size, 1, "gray")
        out[f"{bits}uc3"] = _Layout(size, 3, "bgr")
        out[f"{bits}uc4"] = _Layout(size, 4, "bgra")
    for name in ("yuv422", "uyvy"):
        out[name] = _Layout(1, 2, "uyvy")
    for name in ("yuv422_yuy2", "yuyv"):
        out[name] = _Layout(1, 2, "yuyv")
    return out


_LAYOUTS = _layouts()

#: Every raw encoding accepted (lower case; ``8UC3`` and ``8uc3`` are the same).
RAW_ENCODINGS: frozenset[str] = frozenset(_LAYOUTS)


def is_raw_encoding(encoding: str) -> bool:
    return encoding.lower() in _LAYOUTS


def _error(problem: str, where: str, path: Path | str | None) -> ImageEncodingError:
    return ImageEncodingError(f"{where}: {problem}" if where else problem, path=path)


def _pixels(
    data: bytes,
    encoding: str,
    width: int,
    height: int,
    step: int,
    is_bigendian: bool,
    where: str,
    path: Path | str | None,
) -> tuple[np.ndarray, _Layout]:
    """The pixels as ``(H, W)`` or ``(H, W, C)`` in native byte order, uint8 or uint16."""
    layout = _LAYOUTS.get(encoding.lower())
    if layout is None:
        raise _error(
            f"unknown image encoding '{encoding}' (accepted: {', '.join(sorted(_LAYOUTS))})", where, path
        )
    row_bytes = width * layout.channels * layout.bytes_per_channel
    if width <= 0 or height <= 0:
        raise _error(f"{width}x{height} {encoding} image: no pixels", where, path)
    if step < row_bytes or len(data) < step * height:
        raise _error(
            f"{len(data)} bytes do not hold a {width}x{height} {encoding} image with step {step} "
            f"(needs step ≥ {max(row_bytes, 0)} and {max(step, row_bytes, 0) * max(height, 0)} bytes)",
            where,
            path,
        )
    rows = np.frombuffer(data, dtype=np.uint8, count=step * height).reshape(height, step)[:, :row_bytes]
    values: np.ndarray
    if layout.bytes_per_channel == 2:
        dtype = np.dtype(">u2" if is_bigendian else "<u2")
        values = np.ascontiguousarray(rows).view(dtype).astype(np.uint16)
    else:
        values = rows
    shape = (height, width) if layout.channels == 1 else (height, width, layout.channels)
    return values.reshape(shape), layout


def _to_8bit(values: np.ndarray) -> np.ndarray:
    """16-bit → 8-bit by full-range scaling with rounding half up; 8-bit passes through."""
    if values.dtype == np.uint8:
        return values
    return ((values.astype(np.uint32) * 255 + 32767) // 65535).astype(np.uint8)


def _bayer_code(kind: str, target: str) -> int:
    import cv2

    # ROS names the pattern from the first row, OpenCV from the second.
    opencv = {"bayer_rggb": "BG", "bayer_bggr": "RG", "bayer_gbrg": "GR", "bayer_grbg": "GB"}[kind]
    return getattr(cv2, f"COLOR_Bayer{opencv}2{target}")


def raw_to_gray(
    data: bytes,
    encoding: str,
    width: int,
    height: int,
    step: int,
    is_bigendian: bool,
    *,
    where: str = "",
    path: Path | str | None = None,
) -> np.ndarray:
    """Grey uint8 ``(height, width)`` of one raw image message.

    ``path`` and ``where`` (the message in it, ``LazyImage.where``) only name the image in the
    ``ImageEncodingError`` raised for an unknown encoding or bytes that do not hold the stated size.
    """
    import cv2

    values, layout = _pixels(data, encoding, width, height, step, is_bigendian, where, path)
    kind = layout.kind
    if kind == "gray":
        return np.ascontiguousarray(_to_8bit(values))
    if kind == "uyvy":
        return np.ascontiguousarray(values[:, :, 1])
    if kind == "yuyv":
        return np.ascontiguousarray(values[:, :, 0])
    if kind.startswith("bayer_"):
        return _to_8bit(cv2.cvtColor(np.ascontiguousarray(values), _bayer_code(kind, "GRAY")))
    code = {
        "rgb": cv2.COLOR_RGB2GRAY,
        "bgr": cv2.COLOR_BGR2GRAY,
        "rgba": cv2.COLOR_RGBA2GRAY,
        "bgra": cv2.COLOR_BGRA2GRAY,
    }[kind]
    return cv2.cvtColor(np.ascontiguousarray(_to_8bit(values)), code)
