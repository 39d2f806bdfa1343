"""Real frames: the Nordland fixture (30 frames per season, ``tests/data/nordland``) imported as a
user would (``--rate 2.5``: files are 0.4 s apart, no odometry) and read back unchanged."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from aslam.app.importer import import_image_folder
from aslam.data_formats.image_folder import START_STAMP_NS
from aslam.data_formats.recording import Recording
from aslam.data_formats.rosbag_source import SourceKind, open_source

NORDLAND = Path(__file__).parent / "data" / "nordland"
FRAMES = [f"images-{n:05d}.png" for n in range(1000, 1300, 10)]


@pytest.mark.parametrize("season", ["summer", "winter"])
def test_import_a_season(tmp_path, season):
    folder = NORDLAND / season
    assert sorted(p.name for p in folder.glob("*.png")) == FRAMES
    assert open_source(folder) is SourceKind.IMAGE_FOLDER
    out = tmp_path / f"{season}.mcap"
    result = import_image_folder(folder, out, rate_hz=2.5)
    assert (result.frames, result.width_px, result.height_px) == (30, 64, 32)
    assert not result.odometry_known and result.warnings == ()
    metadata = Recording(out).metadata()
    assert metadata["odometry_known"] == "false" and metadata["stamps"] == "rate 2.5 Hz"
    assert Recording(out).camera().width_px == 64
    samples = list(Recording(out).samples())
    assert [s.stamp_ns for s in samples] == [START_STAMP_NS + i * 400_000_000 for i in range(30)]
    for i, (sample, name) in enumerate(zip(samples, FRAMES, strict=True)):
        assert sample.image.data == (folder / name).read_bytes()
        np.testing.assert_array_equal(
            sample.image.decode_gray(), cv2.imread(str(folder / name), cv2.IMREAD_GRAYSCALE)
        )
        np.testing.assert_array_equal(sample.odometry_pose, [i, 0.0, 0.0])


def test_the_seasons_show_the_same_places_differently():
    """A guard on the fixture itself: aligned, same size, and really different images."""
    for name in FRAMES:
        summer = cv2.imread(str(NORDLAND / "summer" / name), cv2.IMREAD_GRAYSCALE)
        winter = cv2.imread(str(NORDLAND / "winter" / name), cv2.IMREAD_GRAYSCALE)
        assert summer.shape == winter.shape == (32, 64)
        assert np.abs(summer.astype(int) - winter).mean() > 5
