"""The PNG fast path (imagecodecs) gives OpenCV's ``IMREAD_GRAYSCALE`` pixels, or steps aside."""

from __future__ import annotations

import logging
import subprocess
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest
from conftest import ASLAM, CAMERA, one_error_line, random_frames
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from aslam.data_formats.errors import RecordingError
from aslam.data_formats.images import (
    EncodedImage,
    ImageFormat,
    LazyImage,
    encode_image,
    libpng_gray,
    png_gray,
)
from aslam.data_formats.recording_writer import RecordingWriter


def opencv_gray(data: bytes) -> np.ndarray:
    return cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_GRAYSCALE)


def png_of(pixels: np.ndarray, compression: int = 3) -> bytes:
    bgr = cv2.cvtColor(pixels, cv2.COLOR_RGB2BGR) if pixels.ndim == 3 else pixels
    ok, buf = cv2.imencode(".png", bgr, [cv2.IMWRITE_PNG_COMPRESSION, compression])
    assert ok
    return buf.tobytes()


def chunk(kind: bytes, payload: bytes) -> bytes:
    crc = zlib.crc32(kind + payload).to_bytes(4, "big")
    return len(payload).to_bytes(4, "big") + kind + payload + crc


def with_chunk_after_ihdr(data: bytes, extra: bytes) -> bytes:
    ihdr_end = 8 + 12 + 13
    return data[:ihdr_end] + extra + data[ihdr_end:]


def test_every_rgb_colour_greys_as_opencv_does():
    """All 2^24 colours in one 4096 × 4096 PNG: the conversion is libpng's, not an approximation."""
    cube = np.arange(1 << 24, dtype=np.uint32)
    rgb = np.stack([(cube >> 16) & 255, (cube >> 8) & 255, cube & 255], axis=-1).astype(np.uint8)
    rgb = rgb.reshape(4096, 4096, 3)
    assert np.array_equal(libpng_gray(rgb), opencv_gray(png_of(rgb, compression=1)))


@settings(max_examples=60, deadline=None)
@given(
    pixels=st.one_of(
        arrays(np.uint8, st.tuples(st.integers(1, 40), st.integers(1, 40), st.just(3))),
        arrays(np.uint8, st.tuples(st.integers(1, 40), st.integers(1, 40))),
    ),
    compression=st.integers(0, 9),
)
def test_fast_path_matches_opencv(pixels: np.ndarray, compression: int):
    data = png_of(pixels, compression)
    fast = png_gray(data)
    assert fast is not None
    assert fast.dtype == np.uint8
    assert np.array_equal(fast, opencv_gray(data))


def test_pngs_that_are_not_plain_take_opencvs_path():
    rgb = np.random.default_rng(0).integers(0, 256, (24, 32, 3), dtype=np.uint8)
    plain = png_of(rgb)
    gamma = with_chunk_after_ihdr(plain, chunk(b"gAMA", (45455).to_bytes(4, "big")))
    sixteen_bit = png_of(rgb.astype(np.uint16) * 257)
    rgba = cv2.imencode(".png", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGRA))[1].tobytes()
    for data in (gamma, sixteen_bit, rgba, plain[:-12], plain + b"trailing", plain[: len(plain) // 2], b""):
        assert png_gray(data) is None


def test_corrupt_pixel_data_is_still_refused_with_the_file_named(tmp_path):
    rgb = np.random.default_rng(1).integers(0, 256, (24, 32, 3), dtype=np.uint8)
    data = bytearray(png_of(rgb))
    data[60] ^= 0xFF  # inside the IDAT stream: its CRC no longer matches
    image = LazyImage(bytes(data), "png", path=tmp_path / "r.mcap", where="image on '/c' at stamp 5 ns")
    assert png_gray(bytes(data)) is None
    with pytest.raises(RecordingError, match=r"r\.mcap: image on '/c' at stamp 5 ns: corrupt PNG data"):
        image.decode_gray()


def test_a_decoder_warning_stays_off_the_terminal(tmp_path):
    """A damaged frame found by the fuzz (``tests/fuzz.py 1500 --seed 77``, case 716): imagecodecs'
    libpng logs ``PNG warning: IDAT: incorrect data check`` through Python's logging before it
    refuses the image; with no handler that line reached stderr above the error line."""
    data = (Path(__file__).parent / "data" / "png" / "libpng-warns-then-fails.png").read_bytes()
    assert png_gray(data) is None  # the image OpenCV's path then names
    recording = tmp_path / "r.mcap"
    frames = random_frames(2)
    with RecordingWriter(recording, camera=CAMERA, metadata={}) as writer:
        for i, (stamp_ns, rgb, odometry, truth) in enumerate(frames):
            image = EncodedImage(ImageFormat.PNG, data) if i == 1 else encode_image(rgb)
            writer.write(stamp_ns, image, odometry, truth)
    done = subprocess.run(
        [str(ASLAM), "info", str(recording), "-q", "--json", "-"], capture_output=True, text=True
    )
    assert done.returncode == 2
    assert "corrupt PNG data" in one_error_line(done.stderr)


def test_decoding_leaves_the_imagecodecs_logger_as_it_was():
    """A notebook that decodes (``aslam.app.info.describe``, an estimate read in-process) keeps its
    logging: the handler that notes libpng's warnings is there only while an image decodes; it was
    left installed, with the logger's propagation off, so the user's own imagecodecs warnings were
    swallowed from then on."""
    logger = logging.getLogger("imagecodecs")
    warns = (Path(__file__).parent / "data" / "png" / "libpng-warns-then-fails.png").read_bytes()
    plain = png_of(np.random.default_rng(2).integers(0, 256, (24, 32, 3), dtype=np.uint8))
    assert png_gray(warns) is None
    assert png_gray(plain) is not None
    assert logger.handlers == []
    assert logger.propagate
