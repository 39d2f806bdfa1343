"""One entry point: a recording and bags of the same messages give the same samples."""

from __future__ import annotations

import numpy as np
import pytest
from test_rosbag_source import (
    IMAGE_TOPIC,
    N_IMAGES,
    assert_driver_samples,
    write_rosbag1,
    write_rosbag2,
)

from aslam.data_formats.camera import CameraIntrinsics
from aslam.data_formats.images import EncodedImage, ImageFormat
from aslam.data_formats.recording_writer import RecordingWriter
from aslam.data_formats.rosbag_source import BagError
from aslam.data_formats.sources import TopicChoice, iter_source_samples, source_image_count


def test_recording_and_bags_agree(tmp_path):
    """The recording holds the bag's samples re-written (lossless PNG): the same stream comes back."""
    import cv2

    bag = write_rosbag2(tmp_path / "bag", storage="sqlite3")
    ros1 = write_rosbag1(tmp_path / "bag.bag")
    choice = TopicChoice(ground_truth="/ground_truth")
    from_bag = list(iter_source_samples(bag, choice))
    recording = tmp_path / "rec.mcap"
    with RecordingWriter(recording, camera=CameraIntrinsics(24, 16, 60.0), metadata={}) as writer:
        for sample in from_bag:
            ok, png = cv2.imencode(".png", sample.image.decode_gray())
            assert ok
            writer.write(
                sample.stamp_ns,
                EncodedImage(ImageFormat.PNG, png.tobytes()),
                sample.odometry_pose,
                sample.ground_truth_pose,
            )
    from_recording = list(iter_source_samples(recording, TopicChoice()))
    from_ros1 = list(iter_source_samples(ros1, choice))
    assert_driver_samples(from_bag)
    assert_driver_samples(from_ros1)
    assert_driver_samples(from_recording)
    for a, b in zip(from_bag, from_recording, strict=True):
        np.testing.assert_array_equal(a.odometry_pose, b.odometry_pose)
    assert source_image_count(bag) == N_IMAGES
    assert source_image_count(recording) == N_IMAGES
    assert source_image_count(bag, TopicChoice(image=IMAGE_TOPIC)) == N_IMAGES


def test_an_image_folder_must_be_imported_first(tmp_path):
    import cv2

    (tmp_path / "imgs").mkdir()
    cv2.imwrite(str(tmp_path / "imgs" / "1.png"), np.zeros((4, 4), np.uint8))
    with pytest.raises(BagError, match="make it a recording first: aslam import"):
        iter_source_samples(tmp_path / "imgs")
