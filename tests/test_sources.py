"""One entry point: a recording and bags of the same messages give the same samples."""

from __future__ import annotations

import json

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
from aslam.data_formats.sources import TopicChoice, open_input


def test_recording_and_bags_agree(tmp_path):
    """The recording holds the bag's samples re-written (lossless PNG): the same stream comes back."""
    import cv2

    bag = write_rosbag2(tmp_path / "bag", storage="sqlite3")
    ros1 = write_rosbag1(tmp_path / "bag.bag")
    choice = TopicChoice(ground_truth="/ground_truth")
    from_bag = list(open_input(bag, choice).samples())
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
    from_recording = list(open_input(recording, TopicChoice()).samples())
    from_ros1 = list(open_input(ros1, choice).samples())
    assert_driver_samples(from_bag)
    assert_driver_samples(from_ros1)
    assert_driver_samples(from_recording)
    for a, b in zip(from_bag, from_recording, strict=True):
        np.testing.assert_array_equal(a.odometry_pose, b.odometry_pose)
    for source in (open_input(bag), open_input(recording), open_input(bag, TopicChoice(image=IMAGE_TOPIC))):
        counted: list[int | None] = []
        assert len(list(source.samples(on_image_count=counted.append))) == N_IMAGES
        assert counted == [N_IMAGES]


def test_an_image_folder_must_be_imported_first(tmp_path):
    import cv2

    (tmp_path / "imgs").mkdir()
    cv2.imwrite(str(tmp_path / "imgs" / "1.png"), np.zeros((4, 4), np.uint8))
    with pytest.raises(BagError, match="make it a recording first: aslam import"):
        open_input(tmp_path / "imgs").samples()


def test_estimate_gives_the_same_result_from_a_recording_and_its_bags(tmp_path, capsys):
    """`aslam estimate` on the bag folders (mcap, sqlite3), a ROS 1 bag and a recording of the same
    messages (grey, lossless): the same keyframes and hypotheses; `info` and `report` read them too."""
    import cv2

    from aslam.cli.app import main
    from aslam.data_formats.estimate import iter_keyframes

    sources = {
        "mcap": write_rosbag2(tmp_path / "bag-mcap", storage="mcap"),
        "sqlite3": write_rosbag2(tmp_path / "bag-sqlite3", storage="sqlite3"),
        "ros1": write_rosbag1(tmp_path / "bag.bag"),
    }
    recording = tmp_path / "rec.mcap"
    with RecordingWriter(recording, camera=CameraIntrinsics(24, 16, 60.0), metadata={}) as writer:
        for sample in open_input(sources["mcap"], TopicChoice(ground_truth="/ground_truth")).samples():
            ok, png = cv2.imencode(".png", sample.image.decode_gray())
            assert ok
            writer.write(
                sample.stamp_ns,
                EncodedImage(ImageFormat.PNG, png.tobytes()),
                sample.odometry_pose,
                sample.ground_truth_pose,
            )
    sources["recording"] = recording
    results = {}
    scored = {}
    for name, path in sources.items():
        out = tmp_path / f"{name}.est.mcap"
        args = ["estimate", str(path), "-o", str(out), "--step-m", "0.15", "--turn-deg", "10", "-q"]
        assert main(args) == 0, capsys.readouterr().err
        results[name] = [(k.stamp_ns, k.action, k.hypotheses) for k in iter_keyframes(out)]
        assert main(["info", str(path), "--json", "-"]) == 0
        assert main(["report", str(out), "--json", "-", "-q"]) == 0
        capsys.readouterr()
        truth = [] if name == "recording" else ["--ground-truth-topic", "/ground_truth"]
        assert main(["report", str(out), "--json", "-", "-q", *truth]) == 0
        scored[name] = json.loads(capsys.readouterr().out)
    assert len(results["recording"]) > 3
    for name in ("mcap", "sqlite3", "ros1"):
        assert results[name] == results["recording"], name
        # estimated without a ground-truth topic, scored with one named at report time
        assert (
            scored[name]["ground_truth"]
            and scored[name]["loop_closure"] == scored["recording"]["loop_closure"]
        )


@pytest.mark.parametrize("kind", ["recording", "bag"])
def test_one_topic_may_be_both_odometry_and_ground_truth(tmp_path, kind):
    """Exact odometry named as the ground truth too: every sample lacked its truth (the topic went
    to the odometry alone), while ``report`` read it."""
    from conftest import random_frames, square_route, write_recording, write_square_bag

    path = tmp_path / "in.mcap"
    if kind == "recording":
        write_recording(path, random_frames(4))
    else:
        write_square_bag(path, square_route()[:6], 3, ground_truth_topic="/truth")
    source = open_input(path, TopicChoice(odometry="/odom", ground_truth="/odom"))
    samples = list(source.samples())
    assert samples and all(sample.ground_truth_pose is not None for sample in samples)
    assert [tuple(s.ground_truth_pose) for s in samples] == [tuple(s.odometry_pose) for s in samples]
