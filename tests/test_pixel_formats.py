"""The pixel formats of docs/real-data.md ("Pixel formats") as users' files hold them, made with real
encoders (OpenCV, Pillow): the grey image each gives is the one that table says."""

from __future__ import annotations

import io

import cv2
import numpy as np
from PIL import Image

from aslam.data_formats.image_encodings import raw_to_gray
from aslam.data_formats.images import LazyImage, libpng_gray


def gray(data: bytes, encoding: str) -> np.ndarray:
    return LazyImage(data, encoding, path="frame").decode_gray()


def pillow(image: Image.Image, fmt: str, **options: object) -> bytes:
    out = io.BytesIO()
    image.save(out, fmt, **options)
    return out.getvalue()


def test_a_16_bit_png_is_scaled_over_the_full_range_within_a_level_of_raw_mono16():
    values = np.arange(65536, dtype=np.uint32).reshape(256, 256).astype(np.uint16)
    from_png = gray(cv2.imencode(".png", values)[1].tobytes(), "png")
    np.testing.assert_array_equal(from_png, values >> 8)  # neither clipped at 255 nor wrapped
    from_raw = raw_to_gray(values.astype("<u2").tobytes(), "mono16", 256, 256, 512, False)
    assert np.abs(from_png.astype(int) - from_raw).max() == 1


def test_a_jpeg_turned_by_its_exif_orientation_is_read_as_the_camera_was_held():
    stored = np.zeros((48, 64, 3), np.uint8)
    stored[:, 32:] = 255  # dark left half, bright right half, as the sensor wrote it
    exif = Image.Exif()
    exif[0x0112] = 6  # display turned a quarter clockwise: the left column becomes the top row
    upright = gray(pillow(Image.fromarray(stored), "JPEG", exif=exif.tobytes(), quality=95), "jpeg")
    assert upright.shape == (64, 48)
    assert upright[:24].mean() < 10 and upright[40:].mean() > 245


def test_alpha_is_ignored_and_a_palette_expanded():
    rgb = np.random.default_rng(3).integers(0, 256, (12, 16, 3), dtype=np.uint8)
    transparent = np.dstack([rgb, np.zeros((12, 16), np.uint8)])
    np.testing.assert_array_equal(
        gray(pillow(Image.fromarray(transparent, "RGBA"), "PNG"), "png"), libpng_gray(rgb)
    )
    palette = Image.fromarray(rgb).convert("P", palette=Image.Palette.ADAPTIVE, colors=8)
    expanded = libpng_gray(np.asarray(palette.convert("RGB")))
    np.testing.assert_array_equal(gray(pillow(palette, "PNG", transparency=0), "png"), expanded)


def test_a_cmyk_jpeg_greys_as_its_colours_do():
    rgb = np.zeros((16, 32, 3), np.uint8)
    rgb[:, :16] = (200, 30, 30)
    rgb[:, 16:] = (20, 220, 90)
    cmyk = pillow(Image.fromarray(rgb).convert("CMYK"), "JPEG", quality=95)
    difference = gray(cmyk, "jpeg").astype(int) - cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    assert np.abs(difference).max() <= 2
