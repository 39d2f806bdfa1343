"""Raw sensor_msgs/Image encodings → grey: random images packed the way a driver packs them (row
padding, either byte order) come back as the grey image OpenCV computes from the original."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from aslam.core.errors import InputError
from aslam.data_formats.image_encodings import (
    RAW_ENCODINGS,
    ImageEncodingError,
    raw_to_gray,
)

sizes = st.tuples(st.integers(1, 9), st.integers(1, 7))  # (width, height)


@st.composite
def rgb_images(draw: st.DrawFn) -> np.ndarray:
    width, height = draw(sizes)
    return draw(arrays(np.uint8, (height, width, 3)))


def pack(pixels: np.ndarray, padding: int, bigendian: bool = False) -> tuple[bytes, int]:
    """Row-major bytes with ``padding`` junk bytes after each row, and the step."""
    height = pixels.shape[0]
    if pixels.dtype == np.uint16:
        pixels = pixels.astype(">u2" if bigendian else "<u2")
    rows = pixels.reshape(height, -1).view(np.uint8).reshape(height, -1)
    junk = np.full((height, padding), 0xA5, np.uint8)
    packed = np.concatenate([rows, junk], axis=1)
    return packed.tobytes(), packed.shape[1]


def gray_of(rgb: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)


@settings(deadline=None)
@given(rgb=rgb_images(), padding=st.integers(0, 5))
def test_colour_encodings_give_opencvs_grey(rgb, padding):
    bgr = rgb[:, :, ::-1]
    alpha = np.full((*rgb.shape[:2], 1), 255, np.uint8)
    expected = gray_of(rgb)
    height, width = rgb.shape[:2]
    for encoding, pixels in (
        ("rgb8", rgb),
        ("bgr8", bgr),
        ("8UC3", bgr),
        ("rgba8", np.concatenate([rgb, alpha], axis=2)),
        ("bgra8", np.concatenate([bgr, alpha], axis=2)),
    ):
        data, step = pack(np.ascontiguousarray(pixels), padding)
        gray = raw_to_gray(data, encoding, width, height, step, False)
        assert gray.dtype == np.uint8 and gray.shape == (height, width)
        np.testing.assert_array_equal(gray, expected, err_msg=encoding)


@settings(deadline=None)
@given(rgb=rgb_images(), padding=st.integers(0, 5), bigendian=st.booleans())
def test_16_bit_colour_scales_to_8_bit(rgb, padding, bigendian):
    height, width = rgb.shape[:2]
    wide = rgb.astype(np.uint16) * 257  # v → v·257 is the exact 8 → 16 bit widening
    data, step = pack(np.ascontiguousarray(wide[:, :, ::-1]), padding, bigendian)
    np.testing.assert_array_equal(raw_to_gray(data, "bgr16", width, height, step, bigendian), gray_of(rgb))


@settings(deadline=None)
@given(
    gray=st.tuples(st.integers(1, 9), st.integers(1, 7)).flatmap(lambda s: arrays(np.uint8, (s[1], s[0]))),
    padding=st.integers(0, 5),
    bigendian=st.booleans(),
)
def test_mono_encodings_round_trip(gray, padding, bigendian):
    height, width = gray.shape
    for encoding in ("mono8", "8UC1"):
        data, step = pack(gray, padding)
        np.testing.assert_array_equal(raw_to_gray(data, encoding, width, height, step, bigendian), gray)
    wide = gray.astype(np.uint16) * 257
    for encoding in ("mono16", "16UC1"):
        data, step = pack(wide, padding, bigendian)
        np.testing.assert_array_equal(raw_to_gray(data, encoding, width, height, step, bigendian), gray)


@settings(deadline=None)
@given(
    gray=st.tuples(st.integers(1, 9), st.integers(1, 7)).flatmap(lambda s: arrays(np.uint8, (s[1], s[0]))),
    seed=st.integers(0, 2**32 - 1),
    padding=st.integers(0, 5),
)
def test_yuv422_grey_is_the_luma_whatever_the_chroma(gray, seed, padding):
    height, width = gray.shape
    chroma = np.random.default_rng(seed).integers(0, 256, size=gray.shape, dtype=np.uint8)
    for encoding, pairs in (
        ("yuv422", np.stack([chroma, gray], axis=2)),  # U Y V Y
        ("uyvy", np.stack([chroma, gray], axis=2)),
        ("yuv422_yuy2", np.stack([gray, chroma], axis=2)),  # Y U Y V
        ("yuyv", np.stack([gray, chroma], axis=2)),
    ):
        data, step = pack(np.ascontiguousarray(pairs), padding)
        np.testing.assert_array_equal(raw_to_gray(data, encoding, width, height, step, False), gray)


def mosaic(rgb: np.ndarray, pattern: str) -> np.ndarray:
    """The Bayer mosaic a sensor with ``pattern`` (e.g. 'rggb': R G on even rows, G B on odd) records."""
    channel = {"r": 0, "g": 1, "b": 2}
    out = np.empty(rgb.shape[:2], rgb.dtype)
    for i, colour in enumerate(pattern):
        dy, dx = divmod(i, 2)
        out[dy::2, dx::2] = rgb[dy::2, dx::2, channel[colour]]
    return out


@settings(max_examples=50, deadline=None)
@given(
    colour=st.tuples(st.integers(0, 255), st.integers(0, 255), st.integers(0, 255)),
    size=st.tuples(st.integers(4, 10), st.integers(4, 10)),
    padding=st.integers(0, 3),
    wide=st.booleans(),
)
def test_bayer_of_a_uniform_colour_gives_its_grey(colour, size, padding, wide):
    """A uniform colour demosaics exactly, so the grey tells R from B: a wrong pattern fails."""
    width, height = size
    rgb = np.empty((height, width, 3), np.uint8)
    rgb[:] = colour
    expected = int(gray_of(rgb[:1, :1])[0, 0])
    for pattern in ("rggb", "bggr", "gbrg", "grbg"):
        raw = mosaic(rgb, pattern)
        encoding = f"bayer_{pattern}{16 if wide else 8}"
        data, step = pack(raw.astype(np.uint16) * 257 if wide else raw, padding)
        gray = raw_to_gray(data, encoding, width, height, step, False)
        assert np.abs(gray.astype(int) - expected).max() <= 1, encoding


def bytes_per_pixel(encoding: str) -> int:
    """Written out independently of the module's table."""
    if encoding in ("yuv422", "uyvy", "yuv422_yuy2", "yuyv"):
        return 2
    bits = 16 if "16" in encoding else 8
    if encoding.startswith(("rgba", "bgra")) or encoding.endswith("c4"):
        channels = 4
    elif encoding.startswith(("rgb", "bgr")) or encoding.endswith("c3"):
        channels = 3
    else:
        channels = 1
    return channels * bits // 8


def test_every_listed_encoding_decodes_exactly_its_size():
    width, height = 4, 2
    for encoding in sorted(RAW_ENCODINGS):
        step = width * bytes_per_pixel(encoding)
        data = bytes(range(step * height))
        gray = raw_to_gray(data, encoding, width, height, step, False)
        assert gray.shape == (height, width) and gray.dtype == np.uint8
        with pytest.raises(ImageEncodingError):  # one byte short of the stated size
            raw_to_gray(data[:-1], encoding, width, height, step, False)
        with pytest.raises(ImageEncodingError):  # a step shorter than a row
            raw_to_gray(data, encoding, width, height, step - 1, False)


@pytest.mark.parametrize(
    ("data", "encoding", "width", "height", "step", "needle"),
    [
        (bytes(11), "mono8", 4, 3, 4, "11 bytes do not hold a 4x3 mono8 image with step 4"),
        (bytes(36), "bgr8", 4, 3, 8, "needs step ≥ 12"),
        (bytes(12), "mono16", 4, 3, 4, "needs step ≥ 8"),
        (bytes(0), "rgb8", 0, 0, 0, "0x0 rgb8 image: no pixels"),
        (bytes(12), "hsv8", 4, 3, 4, "unknown image encoding 'hsv8'"),
    ],
)
def test_bad_raw_image_names_the_message(data, encoding, width, height, step, needle):
    with pytest.raises(ImageEncodingError) as caught:
        where = "image on '/cam' at stamp 1234 ns"
        raw_to_gray(data, encoding, width, height, step, False, where=where, path="bag.mcap")
    assert isinstance(caught.value, InputError)
    message = str(caught.value)
    assert message.startswith("bag.mcap: image on '/cam' at stamp 1234 ns: ")
    assert needle in message and "\n" not in message
