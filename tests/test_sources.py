"""One entry point: a recording and bags of the same messages give the same samples."""

from __future__ import annotations

import json

import numpy as np
import pytest
from test_rosbag_source import (
    IMAGE_TOPIC,
    N_IMAGES,
    assert_driver_samples,
    true_pose,
    write_rosbag1,
    write_rosbag2,
)

from aslam.data_formats.camera import CameraIntrinsics
from aslam.data_formats.images import EncodedImage, ImageFormat
from aslam.data_formats.recording_writer import RecordingWriter
from aslam.data_formats.rosbag_source import BagError, iter_bag_samples
from aslam.data_formats.sources import TopicChoice, open_input


def test_recording_and_bags_agree(tmp_path):
    """The recording holds the bag's samples re-written (lossless PNG): the same stream comes back,
    and the same ground truth. The samples an estimate reads carry no truth (it has no use for it:
    ``report`` reads it with ``ground_truth()``)."""
    import cv2

    bag = write_rosbag2(tmp_path / "bag", storage="sqlite3")
    ros1 = write_rosbag1(tmp_path / "bag.bag")
    choice = TopicChoice(ground_truth="/ground_truth")
    from_bag = list(iter_bag_samples(bag, choice.bag_topics()))
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
    assert_driver_samples(from_ros1, ground_truth=False)
    assert_driver_samples(from_recording, ground_truth=False)
    for a, b in zip(from_bag, from_recording, strict=True):
        np.testing.assert_array_equal(a.odometry_pose, b.odometry_pose)
    truths = [list(open_input(recording).ground_truth())]
    truths += [list(open_input(path, choice).ground_truth()) for path in (bag, ros1)]
    assert all(truths) and [stamp for stamp, _ in truths[0]] == [s.stamp_ns for s in from_bag]
    for stamp_ns, pose in (one for truth in truths for one in truth):
        np.testing.assert_allclose(pose, true_pose(stamp_ns), atol=1e-9)
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
        with_truth = TopicChoice(ground_truth="/ground_truth").bag_topics()
        for sample in iter_bag_samples(sources["mcap"], with_truth):
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

    from aslam.data_formats.recording import Recording

    path = tmp_path / "in.mcap"
    choice = TopicChoice(odometry="/odom", ground_truth="/odom")
    if kind == "recording":
        write_recording(path, random_frames(4))
        samples = list(Recording(path).samples(choice.recording_topics()))
    else:
        write_square_bag(path, square_route()[:6], 3, ground_truth_topic="/truth")
        samples = list(iter_bag_samples(path, choice.bag_topics()))
    assert samples and all(sample.ground_truth_pose is not None for sample in samples)
    assert [tuple(s.ground_truth_pose) for s in samples] == [tuple(s.odometry_pose) for s in samples]
    truth = dict(open_input(path, choice).ground_truth())
    assert all(tuple(truth[s.stamp_ns]) == tuple(s.odometry_pose) for s in samples)


def test_an_estimate_reads_no_ground_truth_so_a_broken_one_stops_only_the_report(tmp_path):
    """The samples an estimate reads leave the truth unread (0.1 s of 0.3 s of reading 721
    keyframes): a truth pose at 1e300 m stops the reader that reads it, not the estimate's."""
    from test_rosbag_source import _damaged

    def far(msgs):
        msgs[0].pose.position.x = 1e300

    bag = _damaged(tmp_path, "/ground_truth", far)
    choice = TopicChoice(ground_truth="/ground_truth")
    samples = list(open_input(bag, choice).samples())
    assert len(samples) == N_IMAGES and all(s.ground_truth_pose is None for s in samples)
    with pytest.raises(BagError, match="beyond the plausible"):
        list(iter_bag_samples(bag, choice.bag_topics()))
    with pytest.raises(BagError, match="beyond the plausible"):
        list(open_input(bag, choice).ground_truth())
