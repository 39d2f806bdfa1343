"""Input rules pinned where the suite let a changed rule through (a mutation audit, session 30):
plausible odometry on both axes, the 50 ms stamp jitter, stamps before 1970, KITTI stamps and a
damaged estimate's first keyframe."""

from __future__ import annotations

import numpy as np
import pytest

from aslam.data_formats.pose_limits import implausible


@pytest.mark.parametrize(
    "pose, previous, needle",
    [
        ((0.0, 1e8, 0.0), None, "beyond the plausible"),  # y far out (the reader tests move x only)
        ((0.0, -1e8, 0.0), None, "beyond the plausible"),
        ((0.0, 2e4, 0.0), (0.0, 0.0, 0.0), "jumps"),  # 20 km sideways
        ((8e3, 8e3, 0.0), (0.0, 0.0, 0.0), "jumps"),  # 11.3 km, under 10 km along each axis
        ((7e3, 7e3, 0.0), (0.0, 0.0, 0.0), None),  # 9.9 km: plausible
    ],
)
def test_plausibility_judges_both_axes_and_the_distance(pose, previous, needle):
    """docs/formats.md "Poses": no pose beyond ±10,000 km in x or y, no step over 10 km between two."""
    problem = implausible(np.array(pose), None if previous is None else np.array(previous))
    assert (problem is None) if needle is None else (needle in problem)


def test_a_stamp_exactly_50_ms_back_is_jitter_and_one_nanosecond_more_is_a_clock_stepped_back():
    """POSE_STAMP_JITTER_NS: "How far back an odometry stamp may go and be dropped as jitter"; the
    refusal says "more than the 50 ms". The tests went 50.000001 ms and 50.4 ms back, never 50."""
    from pathlib import Path

    from aslam.data_formats.errors import RecordingError
    from aslam.data_formats.pose_sync import POSE_STAMP_JITTER_NS, StampOrder

    t0 = 1_700_000_000_000_000_000
    order = StampOrder(Path("odom.mcap"), "odometry", "'/odom'")
    assert order.admits(t0)
    assert not order.admits(t0 - POSE_STAMP_JITTER_NS)  # dropped, counted
    assert order.out_of_order == 1
    with pytest.raises(RecordingError, match="more than the 50 ms"):
        order.admits(t0 - POSE_STAMP_JITTER_NS - 1)


def test_a_kitti_stamp_file_with_a_repeated_stamp_is_not_used(tmp_path):
    """kitti_stamps: "A file is only used when it ... has one stamp per image, strictly increasing";
    test_image_folder.py's parametrized test has a stamp going back, none repeated."""
    from test_image_folder import write_images

    from aslam.data_formats.image_folder import open_image_folder

    images = tmp_path / "image_0"
    write_images(images, 3, name=lambda i: f"{i:06d}.png")
    (tmp_path / "times.txt").write_text("0\n0.1\n0.1\n")
    warnings: list[str] = []
    folder = open_image_folder(images)
    assert folder.stamps == "default 1 Hz" and len(list(folder.samples(on_warning=warnings.append))) == 3
    assert warnings == [f"{tmp_path / 'times.txt'}: not used: line 3: not after the line before"]


def test_a_recordings_odometry_stamped_before_1970_is_refused_naming_it(tmp_path, capsys):
    """A ROS 2 header's ``sec`` is signed; no MCAP time is. The bag reader's refusal is tested
    (test_rosbag_source.py, _before_1970), the recording reader's was not: without it the images
    were "not stamped within the odometry", a cause the file does not have."""
    from conftest import FRAME_NS, T0_NS, ForeignRecording, one_error_line, random_frames

    from aslam.cli.app import main
    from aslam.data_formats.images import encode_image

    path = tmp_path / "r.mcap"
    png = encode_image(random_frames(1)[0][1]).data
    with ForeignRecording(path) as rec:
        for k in range(3):
            log_time = T0_NS + k * FRAME_NS
            rec.odometry("/odom", -5_000_000_000 + k * FRAME_NS, float(k), 0.0, 0.0, log_time=log_time)
            rec.compressed_image("/camera/image/compressed", log_time, png, "png")
    assert main(["info", str(path)]) == 2
    line = one_error_line(capsys.readouterr().err)
    assert "odometry stamp on '/odom' is -5000000000 ns, before 1970" in line


def test_an_estimate_whose_first_keyframe_is_beyond_its_keyframes_is_one_line(
    estimate_file, tmp_path, capsys
):
    """An estimate whose graph starts past its own keyframes is damaged: refused in one line."""
    from test_reliability import _graph, one_error_line, rewrite_estimate

    from aslam.cli.app import main

    bad = tmp_path / "bad.mcap"
    rewrite_estimate(estimate_file, bad, _graph(lambda g: g.update(first_keyframe=g["keyframes"] + 1)))
    assert main(["report", str(bad), "-q", "--json", str(tmp_path / "s.json")]) == 2
    one_error_line(capsys, str(bad), "is beyond the")
    assert not (tmp_path / "s.json").exists()


def test_a_config_files_boolean_is_no_number(recording, tmp_path, capsys):
    """config_file.type_problem: "ints are accepted for floats, booleans for nothing": with that
    rule gone ``beta = true`` would be β = 1.0 in silence."""
    from conftest import one_error_line

    from aslam.cli.app import main

    config = tmp_path / "c.toml"
    config.write_text("[estimator]\nbeta = true\n")
    assert main(["estimate", str(recording), "-o", str(tmp_path / "e.mcap"), "--config", str(config)]) == 2
    assert "beta must be a number, got true" in one_error_line(capsys.readouterr().err)


def test_a_prior_map_with_two_places_of_one_id_is_refused():
    """core.estimator.prior_map (a library entry point, not only the estimate reader's): "Raises
    ValueError when the parts do not fit together"."""
    from aslam.core.estimator import MapState, prior_map

    views = np.zeros((2, 16), np.float32)
    with pytest.raises(ValueError, match="do not match"):
        prior_map(2, (MapState(0, (0,)), MapState(0, (1,))), (), views)


@pytest.mark.parametrize(
    ("yaw", "accepted"), [(1e9, True), (-1e9, True), (1.0000001e9, False), (1e308, False)]
)
def test_a_csv_yaw_beyond_what_float64_resolves_is_refused(tmp_path, yaw, accepted):
    """A CSV pose file's yaw is wrapped to (−π, π]; one of 1e308 rad wrapped to rounding noise and was
    imported as a heading. Up to ±1e9 rad (unwrapped, float64 resolves 1e-6 rad) it is an angle."""
    from aslam.data_formats.pose_files import PoseFileError, iter_poses

    path = tmp_path / "poses.csv"
    path.write_text(f"t,x,y,yaw\n0.0,1.0,2.0,{yaw!r}\n")
    if accepted:
        (row,) = iter_poses(path, "csv")
        assert row.pose[2] == pytest.approx(np.remainder(yaw + np.pi, 2 * np.pi) - np.pi, abs=1e-6)
    else:
        with pytest.raises(PoseFileError, match=r"line 2: yaw .* rad is beyond the ±1e\+09 rad"):
            list(iter_poses(path, "csv"))
