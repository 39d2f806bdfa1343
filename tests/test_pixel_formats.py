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


def _camera_jpeg(seed: int, *, garbled: bool = False) -> bytes:
    """A 160×120 JPEG as a camera writes one (OpenCV, quality 90); ``garbled``: eight bytes flipped
    inside its entropy-coded data, where JPEG has no checksum and libjpeg only warns."""
    rng = np.random.default_rng(seed)
    image = cv2.GaussianBlur(rng.integers(0, 256, (120, 160, 3), dtype=np.uint8), (0, 0), 2)
    data = bytearray(cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 90])[1].tobytes())
    if garbled:
        scan = data.index(b"\xff\xda")
        start, end = scan + 2 + int.from_bytes(data[scan + 2 : scan + 4], "big"), len(data) - 2
        for k in range(1, 9):
            data[start + (end - start) * k // 9] ^= 0x55
    return bytes(data)


def test_jpegs_damaged_inside_their_data_are_read_with_one_warning_naming_the_first(tmp_path, capsys):
    """libjpeg decodes a JPEG garbled inside its compressed data, recovering (wrong blocks), and
    only prints a warning, which the CLI sends to /dev/null with every C library's: ``import`` and
    ``info`` went on without a word. Real cameras' frames have such damage (a UVC camera's MJPEG),
    so they are read, exit 0, and one line says how many and names the first."""
    from conftest import ForeignRecording

    from aslam.app.info import describe
    from aslam.cli.app import main

    folder = tmp_path / "frames"
    folder.mkdir()
    for i in range(4):
        (folder / f"{i}.jpg").write_bytes(_camera_jpeg(i, garbled=i in (1, 3)))
    assert main(["import", str(folder), "-o", str(tmp_path / "rec.mcap")]) == 0
    warnings = [line for line in capsys.readouterr().err.splitlines() if "warning" in line]
    assert len(warnings) == 1, warnings
    assert warnings[0].startswith(
        f"aslam: warning: {folder}: 2 of 4 images have damaged JPEG data, read as libjpeg recovers them"
        " (wrong blocks); the first: 1.jpg: Corrupt JPEG data: "
    )
    recorded = describe(tmp_path / "rec.mcap")
    assert recorded.samples == 4
    assert [line.split("; the first: ")[1].split(": Corrupt")[0] for line in recorded.warnings] == [
        "image on '/camera/image/compressed' at stamp 1600000001000000000 ns"
    ]

    bag = tmp_path / "bag.mcap"
    with ForeignRecording(bag) as writer:
        for i in range(3):
            stamp_ns = 1_000_000_000 * (i + 1)
            writer.compressed_image("/cam/compressed", stamp_ns, _camera_jpeg(i, garbled=i == 2), "jpeg")
            writer.odometry("/odom", stamp_ns, float(i), 0.0, 0.0)
    assert [line.split(": Corrupt JPEG data: ")[0] for line in describe(bag).warnings] == [
        f"{bag}: 1 of 3 images have damaged JPEG data, read as libjpeg recovers them (wrong blocks);"
        " the first: image on '/cam/compressed' at stamp 3000000000 ns"
    ]


def test_what_else_reaches_descriptor_2_while_a_jpeg_decodes_is_passed_on(capfd):
    """libjpeg's words are taken from descriptor 2 for the decode; another library's, or another
    thread's, written meanwhile are not lost."""
    import os

    from aslam.data_formats.images import _libjpeg_warnings

    def decode() -> np.ndarray:
        os.write(2, b"libpng warning: iCCP: known incorrect sRGB profile\n")
        os.write(2, b"Corrupt JPEG data: premature end of data segment\n")
        return np.zeros((2, 2), np.uint8)

    pixels, damage = _libjpeg_warnings.first_damage(decode)
    assert pixels.shape == (2, 2)
    assert damage == "Corrupt JPEG data: premature end of data segment"
    assert capfd.readouterr().err == "libpng warning: iCCP: known incorrect sRGB profile\n"
    assert _libjpeg_warnings.first_damage(lambda: pixels)[1] is None  # nothing left over


def test_libjpeg_is_heard_where_no_temporary_folder_can_be_written(tmp_path, monkeypatch):
    """A read-only container (``docker run --read-only``, no tmpfs on /tmp) has no folder for a
    temporary file, and the file libjpeg's words were heard on was one: ``aslam info R.mcap`` of
    JPEG images, which writes nothing, failed ``aslam: error: No usable temporary directory found
    in [...]``, as did ``import``. libjpeg is now heard on a file in memory where the system has
    them (Linux), and left unheard where no file can be made: the image is read either way."""
    import os
    import tempfile

    from aslam.data_formats.images import LazyImage, _LibjpegWarnings

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "no such folder"))
    image = LazyImage(_camera_jpeg(1, garbled=True), "jpeg", path=tmp_path / "1.jpg")
    pixels, damage = _LibjpegWarnings().first_damage(image.decode_gray)
    assert pixels.shape == (120, 160)
    if hasattr(os, "memfd_create"):
        assert damage is not None and damage.startswith("Corrupt JPEG data: ")
    else:
        assert damage is None
