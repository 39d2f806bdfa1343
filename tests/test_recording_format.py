"""The recording format: what RecordingWriter writes, what iter_samples gives back, and that other
tools (plain mcap + mcap_ros2, none of our code) read the same thing.

Also holds the small recording builders that tests/test_recording_bad_input.py imports.
"""

from __future__ import annotations

import json
import math

import cv2
import numpy as np
import pytest
from conftest import CAMERA, FRAME_NS, T0_NS, ForeignRecording, random_frames, write_recording

from aslam.cli.app import main
from aslam.data_formats.camera import CameraIntrinsics
from aslam.data_formats.errors import RecordingError
from aslam.data_formats.images import ImageFormat, encode_image
from aslam.data_formats.recording import Recording, RecordingTopics
from aslam.data_formats.recording_writer import RecordingWriter


def angle_diff(a: float, b: float) -> float:
    return abs((a - b + math.pi) % (2 * math.pi) - math.pi)


def assert_pose(actual: np.ndarray, expected: np.ndarray, tol: float = 1e-12) -> None:
    assert actual.shape == (3,)
    assert abs(actual[0] - expected[0]) <= tol and abs(actual[1] - expected[1]) <= tol
    assert angle_diff(actual[2], expected[2]) <= tol  # yaw comes back wrapped to (-π, π]


# --- round trip ---------------------------------------------------------------------------------


def test_png_round_trip_gives_back_every_field(tmp_path):
    frames = random_frames(4)
    metadata = {"world": "maze-3", "seed": "42", "route": "loop", "noise": "3%", "tool_version": "0.1.0"}
    path = write_recording(tmp_path / "r.mcap", frames, metadata=metadata)
    warnings: list[str] = []
    samples = list(Recording(path, on_warning=warnings.append).samples())
    assert warnings == []
    assert [s.stamp_ns for s in samples] == [f[0] for f in frames]
    for sample, (_stamp, rgb, odometry, truth) in zip(samples, frames, strict=True):
        assert sample.image.encoding == "png"
        stored = cv2.imdecode(np.frombuffer(sample.image.data, np.uint8), cv2.IMREAD_COLOR)
        assert np.array_equal(stored[:, :, ::-1], rgb)  # lossless
        gray = sample.image.decode_gray()
        assert gray.dtype == np.uint8 and gray.shape == (CAMERA.height_px, CAMERA.width_px)
        assert_pose(sample.odometry_pose, odometry)
        assert_pose(sample.ground_truth_pose, truth)
    assert Recording(path).metadata() == metadata
    assert list(Recording(path).metadata()) == list(metadata)  # order kept
    camera = Recording(path).camera()
    assert camera is not None and (camera.width_px, camera.height_px) == (32, 24)
    assert camera.fov_deg == pytest.approx(CAMERA.fov_deg)
    assert list(Recording(path).ground_truth()) and all(
        stamp == f[0] and np.allclose(pose[:2], f[3][:2])
        for (stamp, pose), f in zip(Recording(path).ground_truth(), frames, strict=True)
    )


def test_jpeg_round_trip_decodes_to_the_right_shape(tmp_path):
    frames = random_frames(3)
    path = write_recording(tmp_path / "r.mcap", frames, fmt=ImageFormat.JPEG)
    samples = list(Recording(path).samples())
    assert len(samples) == 3
    for sample in samples:
        assert sample.image.encoding == "jpeg"
        assert sample.image.decode_gray().shape == (24, 32)


def test_without_ground_truth_the_pose_is_none(tmp_path):
    path = write_recording(tmp_path / "r.mcap", random_frames(2), with_ground_truth=False)
    assert [s.ground_truth_pose for s in Recording(path).samples()] == [None, None]
    assert Recording(path).metadata() == {"seed": "7"}


def test_camera_intrinsics():
    camera = CameraIntrinsics(640, 480, 90.0)
    assert camera.fx == pytest.approx(320.0) and camera.fy == camera.fx
    assert (camera.cx, camera.cy) == (319.5, 239.5)
    matrix = camera.K
    assert matrix == (camera.fx, 0.0, 319.5, 0.0, camera.fy, 239.5, 0.0, 0.0, 1.0)


def test_encode_image_is_deterministic():
    rgb = random_frames(1)[0][1]
    for fmt in ImageFormat:
        assert encode_image(rgb, fmt) == encode_image(rgb.copy(), fmt)


# --- read by other tools ------------------------------------------------------------------------


def test_an_independent_reader_sees_ros2_messages(tmp_path):
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    frames = random_frames(3)
    path = write_recording(tmp_path / "r.mcap", frames, metadata={"world": "w1"})
    images = {f[0]: encode_image(f[1]).data for f in frames}
    seen: dict[str, list[int]] = {}
    with path.open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        header = reader.get_header()
        assert header.profile == "ros2"
        assert [(m.name, m.metadata) for m in reader.iter_metadata()] == [
            ("aslam.recording", {"world": "w1"})
        ]
        by_stamp = {f[0]: f for f in frames}
        for schema, channel, message, decoded in reader.iter_decoded_messages():
            assert schema is not None and schema.encoding == "ros2msg" and channel.message_encoding == "cdr"
            stamp = decoded.header.stamp.sec * 1_000_000_000 + decoded.header.stamp.nanosec
            assert stamp == message.log_time == message.publish_time
            seen.setdefault(channel.topic, []).append(stamp)
            if channel.topic == "/camera/image/compressed":
                assert schema.name == "sensor_msgs/msg/CompressedImage"
                assert decoded.format == "png" and decoded.data == images[stamp]
                assert decoded.header.frame_id == "camera"
            elif channel.topic == "/odom":
                assert schema.name == "nav_msgs/msg/Odometry"
                assert (decoded.header.frame_id, decoded.child_frame_id) == ("odom", "base_link")
                p, q = decoded.pose.pose.position, decoded.pose.pose.orientation
                yaw = math.atan2(2 * (q.w * q.z + q.x * q.y), 1 - 2 * (q.y**2 + q.z**2))
                expected = by_stamp[stamp][2]
                assert (p.x, p.y, p.z) == (expected[0], expected[1], 0.0)
                assert angle_diff(yaw, expected[2]) < 1e-12 and q.x == q.y == 0.0
            elif channel.topic == "/ground_truth/pose":
                assert schema.name == "geometry_msgs/msg/PoseStamped"
                assert decoded.header.frame_id == "world"
                p, q = decoded.pose.position, decoded.pose.orientation
                expected = by_stamp[stamp][3]
                assert (p.x, p.y) == (expected[0], expected[1])
                assert angle_diff(2 * math.atan2(q.z, q.w), expected[2]) < 1e-12
            else:
                assert channel.topic == "/camera/camera_info"
                assert schema.name == "sensor_msgs/msg/CameraInfo"
                assert (decoded.width, decoded.height) == (32, 24)
                assert list(decoded.k) == pytest.approx(list(CAMERA.K))
                assert list(decoded.p) == pytest.approx(
                    [CAMERA.fx, 0, CAMERA.cx, 0, 0, CAMERA.fy, CAMERA.cy, 0, 0, 0, 1, 0]
                )
                assert list(decoded.r) == [1, 0, 0, 0, 1, 0, 0, 0, 1]
                assert decoded.distortion_model == "plumb_bob" and list(decoded.d) == [0.0] * 5
    stamps = [f[0] for f in frames]
    assert seen == {
        "/camera/camera_info": stamps[:1],
        "/camera/image/compressed": stamps,
        "/odom": stamps,
        "/ground_truth/pose": stamps,
    }


def test_schemas_are_full_concatenated_ros2_definitions(tmp_path):
    from mcap.reader import make_reader

    path = write_recording(tmp_path / "r.mcap", random_frames(1))
    with path.open("rb") as f:
        summary = make_reader(f).get_summary()
    texts = {s.name: s.data.decode() for s in summary.schemas.values()}
    sep = "=" * 80
    odometry = texts["nav_msgs/msg/Odometry"]
    assert odometry.startswith("std_msgs/Header header\nstring child_frame_id\n")
    for dep in (
        "std_msgs/Header",
        "builtin_interfaces/Time",
        "geometry_msgs/PoseWithCovariance",
        "geometry_msgs/Pose",
        "geometry_msgs/Point",
        "geometry_msgs/Quaternion",
        "geometry_msgs/TwistWithCovariance",
        "geometry_msgs/Twist",
        "geometry_msgs/Vector3",
    ):
        assert f"\n{sep}\nMSG: {dep}\n" in odometry
    assert f"{sep}\nMSG: sensor_msgs/RegionOfInterest\n" in texts["sensor_msgs/msg/CameraInfo"]
    assert "float64[9] k\nfloat64[9] r\nfloat64[12] p\n" in texts["sensor_msgs/msg/CameraInfo"]
    assert texts["sensor_msgs/msg/CompressedImage"].startswith(
        "std_msgs/Header header\nstring format\nuint8[] data\n"
    )
    assert texts["geometry_msgs/msg/PoseStamped"].startswith("std_msgs/Header header\nPose pose\n")


# --- foreign recordings: raw images, odometry at another rate -----------------------------------


@pytest.mark.parametrize("encoding", ["mono8", "rgb8", "bgr8"])
def test_raw_images_with_odometry_at_three_times_the_camera_rate(tmp_path, encoding):
    rng = np.random.default_rng(3)
    path = tmp_path / "raw.mcap"
    odom_dt = 10_000_000  # 100 Hz odometry, ~33 Hz camera

    def true_pose(t_ns: int) -> tuple[float, float, float]:
        s = (t_ns - T0_NS) / 1e9
        return 1.0 + 2.0 * s, -0.5 * s, 3.0 + 4.0 * s  # yaw crosses +π → −π

    pixels_by_stamp = {}
    with ForeignRecording(path) as rec:
        for k in range(31):
            t = T0_NS + k * odom_dt
            if k % 3 == 1 and k < 28:  # image halfway between two odometry messages
                t_image = t + odom_dt // 2
                shape = (24, 32) if encoding == "mono8" else (24, 32, 3)
                pixels = rng.integers(0, 256, size=shape, dtype=np.uint8)
                pixels_by_stamp[t_image] = pixels
                rec.odometry("/odom", t, *true_pose(t))
                rec.raw_image("/cam/raw", t_image, pixels, encoding)
            else:
                rec.odometry("/odom", t, *true_pose(t))
    topics = RecordingTopics(image="/cam/raw")
    warnings: list[str] = []
    samples = list(Recording(path, on_warning=warnings.append).samples(topics))
    assert warnings == []
    assert [s.stamp_ns for s in samples] == sorted(pixels_by_stamp)
    for sample in samples:
        x, y, yaw = true_pose(sample.stamp_ns)
        assert sample.odometry_pose[:2] == pytest.approx([x, y], abs=1e-9)
        assert angle_diff(sample.odometry_pose[2], yaw) < 1e-9
        assert sample.ground_truth_pose is None
        pixels = pixels_by_stamp[sample.stamp_ns]
        assert sample.image.encoding == encoding
        if encoding == "mono8":
            assert np.array_equal(sample.image.decode_gray(), pixels)
        else:
            bgr = pixels if encoding == "bgr8" else pixels[:, :, ::-1]
            assert np.array_equal(sample.image.decode_gray(), cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY))


def test_a_frame_logged_twice_is_read_once(tmp_path):
    """The same stamp twice on the image topic (a driver or recorder repeating a frame): the repeat
    is dropped and counted; it was a second sample, counted and estimated as another frame."""
    path = tmp_path / "twice.mcap"
    frames = random_frames(3)
    with ForeignRecording(path) as rec:
        for k, (_stamp, pixels, _odometry, _truth) in enumerate(frames):
            t = T0_NS + k * FRAME_NS
            rec.odometry("/odom", t, float(k), 0.0, 0.0)
            rec.compressed_image("/camera/image/compressed", t, encode_image(pixels).data, "png")
            if k == 1:
                rec.compressed_image("/camera/image/compressed", t, encode_image(pixels).data, "png", t + 1)
    warnings: list[str] = []
    samples = list(Recording(path, on_warning=warnings.append).samples())
    assert [s.stamp_ns for s in samples] == [T0_NS, T0_NS + FRAME_NS, T0_NS + 2 * FRAME_NS]
    assert warnings == [
        f"{path}: dropped 1 image(s) stamped the same as the image before (a frame logged twice)"
    ]


def test_images_outside_the_odometry_are_dropped_with_one_warning_each(tmp_path):
    path = tmp_path / "edges.mcap"
    png = encode_image(random_frames(1)[0][1]).data
    with ForeignRecording(path) as rec:
        for k in range(10):
            t = T0_NS + k * FRAME_NS
            if k < 2 or k > 7:
                rec.compressed_image("/camera/image/compressed", t + 1, png, "png")  # outside odometry
            else:
                rec.compressed_image("/camera/image/compressed", t, png, "png")
                rec.odometry("/odom", t, float(k), 0.0, 0.0)
    warnings: list[str] = []
    samples = list(Recording(path, on_warning=warnings.append).samples())
    assert [s.odometry_pose[0] for s in samples] == [2.0, 3.0, 4.0, 5.0, 6.0, 7.0]
    assert len(warnings) == 2
    assert "dropped 2 image(s) stamped before the first odometry" in warnings[0]
    assert "dropped 2 image(s) stamped after the last odometry" in warnings[1]
    assert all(w.startswith(str(path)) for w in warnings)


def test_late_images_are_interpolated_from_the_odometry_history(tmp_path):
    """Camera latency: an image logged after odometry messages stamped later than the image."""
    path = tmp_path / "late.mcap"
    png = encode_image(random_frames(1)[0][1]).data
    with ForeignRecording(path) as rec:
        for k in range(20):
            t = T0_NS + k * 10_000_000
            rec.odometry("/odom", t, float(k), 0.0, 0.0)
            if k % 5 == 4:  # stamped 35 ms earlier than it was logged
                rec.compressed_image("/camera/image/compressed", t - 35_000_000, png, "png", log_time=t + 1)
    samples = list(Recording(path).samples())
    assert [s.odometry_pose[0] for s in samples] == pytest.approx([0.5, 5.5, 10.5, 15.5])


def test_late_images_are_kept_by_time_not_by_message_count(tmp_path):
    """400 Hz odometry and a camera logged 0.8 s late: 320 odometry messages later, still paired
    (a window of 256 messages dropped every image); 12 s late is over both windows: dropped, said."""
    path = tmp_path / "fast.mcap"
    png = encode_image(random_frames(1)[0][1]).data
    period = 2_500_000  # 400 Hz
    with ForeignRecording(path) as rec:
        for k in range(8_000):
            t = T0_NS + k * period
            rec.odometry("/odom", t, k * 0.001, 0.0, 0.0)
            if k in (1_000, 2_000):  # stamped 0.8 s before it is logged
                rec.compressed_image("/camera/image/compressed", t - 800_000_000, png, "png", log_time=t + 1)
            if k == 7_999:  # stamped 12 s before it is logged
                rec.compressed_image(
                    "/camera/image/compressed", t - 12_000_000_000, png, "png", log_time=t + 1
                )
    warnings: list[str] = []
    samples = list(Recording(path, on_warning=warnings.append).samples())
    assert [s.odometry_pose[0] for s in samples] == pytest.approx([0.68, 1.68])
    assert (
        len(warnings) == 1
        and "dropped 1 image(s) that arrived after the odometry at their stamp was let go (the last 10 s"
        in warnings[0]
    )


def test_ground_truth_is_unknown_inside_a_long_gap_as_report_has_it(tmp_path):
    """One rule for the truth at an image's stamp, in reading a recording (info, import) and in
    report (``truth_at_stamps``): interpolated between messages at most 1 s apart, unknown inside
    a longer gap (a motion-capture dropout)."""
    from aslam.app.score import truth_at_stamps

    path = tmp_path / "gap.mcap"
    png = encode_image(random_frames(1)[0][1]).data
    truth = [(T0_NS + k * 500_000_000, np.array([float(k), 0.0, 0.0])) for k in (0, 1, 2, 6, 7)]
    images = [T0_NS + 250_000_000, T0_NS + 2_000_000_000]  # between 0 and 1; inside the 2 s gap
    with ForeignRecording(path) as rec:
        for k in range(9):
            rec.odometry("/odom", T0_NS + k * 500_000_000, float(k), 0.0, 0.0)
        for stamp, pose in truth:
            rec.odometry("/ground_truth/pose", stamp, *pose)
        for stamp in images:
            rec.compressed_image("/camera/image/compressed", stamp, png, "png", log_time=stamp)
    warnings: list[str] = []
    read = [s.ground_truth_pose for s in Recording(path, on_warning=warnings.append).samples()]
    assert read[0] is not None and read[0][0] == pytest.approx(0.5) and read[1] is None
    assert any("1 image(s) have no ground truth" in w and "gap of more than 1 s" in w for w in warnings)
    scored = truth_at_stamps(images, truth)
    assert scored[0][0] == pytest.approx(0.5) and np.isnan(scored[1]).all()


def test_equal_stamps_are_not_going_backwards_and_take_the_exact_pose(tmp_path):
    frames = random_frames(2)
    path = write_recording(tmp_path / "r.mcap", frames)
    for sample, frame in zip(Recording(path).samples(), frames, strict=True):
        assert sample.odometry_pose[0] == frame[2][0] and sample.odometry_pose[1] == frame[2][1]


# --- writer -------------------------------------------------------------------------------------


def test_same_writes_give_identical_bytes(tmp_path):
    frames = random_frames(5)
    a = write_recording(tmp_path / "a.mcap", frames, fmt=ImageFormat.JPEG)
    b = write_recording(tmp_path / "b.mcap", frames, fmt=ImageFormat.JPEG)
    assert a.read_bytes() == b.read_bytes()


def test_writer_uses_a_temporary_name_then_renames(tmp_path):
    path = tmp_path / "r.mcap"
    frame = random_frames(1)[0]
    with RecordingWriter(path, camera=CAMERA, metadata={}) as writer:
        writer.write(frame[0], encode_image(frame[1]), frame[2], frame[3])
        assert not path.exists()
        assert writer.partial_path.exists() and writer.partial_path.parent == tmp_path
        assert writer.partial_path.name.startswith(".r.mcap.partial-")
    assert path.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["r.mcap"]


@pytest.mark.parametrize("exception", [RuntimeError, KeyboardInterrupt])
def test_writer_leaves_nothing_after_an_exception(tmp_path, exception):
    path = tmp_path / "r.mcap"
    frame = random_frames(1)[0]
    with pytest.raises(exception), RecordingWriter(path, camera=CAMERA, metadata={}) as writer:
        writer.write(frame[0], encode_image(frame[1]), frame[2], frame[3])
        raise exception("stop")
    assert list(tmp_path.iterdir()) == []


def test_writer_refuses_to_overwrite_without_force(tmp_path):
    path = tmp_path / "r.mcap"
    path.write_bytes(b"precious")
    with pytest.raises(RecordingError, match=r"r\.mcap: already exists"):
        RecordingWriter(path, camera=CAMERA, metadata={})
    assert path.read_bytes() == b"precious" and len(list(tmp_path.iterdir())) == 1
    write_recording_forced = RecordingWriter(path, camera=CAMERA, metadata={}, force=True)
    with write_recording_forced as writer:
        frame = random_frames(1)[0]
        writer.write(frame[0], encode_image(frame[1]), frame[2], frame[3])
    assert len(list(Recording(path).samples())) == 1


def test_writer_refuses_stamps_that_do_not_increase(tmp_path):
    frame = random_frames(1)[0]
    with pytest.raises(RecordingError, match="not after the previous"):  # noqa: SIM117
        with RecordingWriter(tmp_path / "r.mcap", camera=CAMERA, metadata={}) as writer:
            writer.write(frame[0], encode_image(frame[1]), frame[2], frame[3])
            writer.write(frame[0], encode_image(frame[1]), frame[2], frame[3])
    assert list(tmp_path.iterdir()) == []


# --- aslam info -----------------------------------------------------------------------------------


def test_info_json_describes_the_recording(tmp_path, capsys):
    frames = random_frames(3)
    path = write_recording(tmp_path / "r.mcap", frames, metadata={"world": "w"})
    assert main(["info", str(path), "--json", "-"]) == 0
    captured = capsys.readouterr()
    assert captured.err == ""
    report = json.loads(captured.out)
    assert report["samples"] == 3 and report["samples_with_ground_truth"] == 3
    assert report["duration_s"] == pytest.approx(0.2)
    assert report["image_sizes"] == {"32x24": 3} and report["image_encodings"] == {"png": 3}
    assert report["metadata"]["entries"] == {"world": "w"}
    assert {t["topic"]: t["messages"] for t in report["topics"]} == {
        "/camera/camera_info": 1,
        "/camera/image/compressed": 3,
        "/odom": 3,
        "/ground_truth/pose": 3,
    }
    assert report["truncated"] is False and report["warnings"] == []


def test_info_json_names_the_file_the_same_from_any_folder(tmp_path, capsys, monkeypatch):
    """``path`` was the name as typed: ``info ../r.mcap --json -`` from another folder gave other
    bytes, where every other JSON output names files absolute, ``..`` folded (usage.md)."""
    path = write_recording(tmp_path / "r.mcap", random_frames(2))
    outputs = []
    for folder, name in ((tmp_path, "r.mcap"), (tmp_path / "sub", "../r.mcap"), (tmp_path, str(path))):
        folder.mkdir(exist_ok=True)
        monkeypatch.chdir(folder)
        assert main(["info", name, "--json", "-"]) == 0
        outputs.append(capsys.readouterr().out)
    assert outputs[0] == outputs[1] == outputs[2]
    assert json.loads(outputs[0])["path"] == str(path)


def test_info_json_gives_the_field_of_view_as_recorded(tmp_path, capsys):
    """It comes back from fx through an arctangent: 60° was 59.99999999999999."""
    camera = CameraIntrinsics(width_px=32, height_px=24, fov_deg=60.0)
    path = write_recording(tmp_path / "r.mcap", random_frames(2), camera=camera)
    assert main(["info", str(path), "--json", "-"]) == 0
    assert json.loads(capsys.readouterr().out)["camera"]["fov_deg"] == 60.0


def test_info_reports_progress_against_the_image_count(tmp_path):
    """The application function the command, bench and tests share: one call per image read."""
    from aslam.app.info import describe

    path = write_recording(tmp_path / "r.mcap", random_frames(4))
    calls: list[tuple[int, int | None]] = []
    info = describe(path, on_progress=lambda done, total: calls.append((done, total)))
    assert info.samples == 4 and calls == [(0, 4), (1, 4), (2, 4), (3, 4), (4, 4)]
    assert describe(path) == info


def test_info_json_output_is_checked_first_and_obeys_force(tmp_path, capsys):
    path = write_recording(tmp_path / "r.mcap", random_frames(3))
    out = tmp_path / "info.json"
    out.write_text("keep")
    assert main(["info", str(path), "--json", str(out)]) == 2
    assert "already exists" in capsys.readouterr().err and out.read_text() == "keep"
    assert main(["info", str(path), "--json", str(tmp_path / "missing" / "i.json")]) == 2
    assert "folder" in capsys.readouterr().err
    assert main(["info", str(path), "--json", str(out), "--force"]) == 0
    assert json.loads(out.read_text())["samples"] == 3


def test_info_prints_tables(tmp_path, capsys):
    path = write_recording(tmp_path / "r.mcap", random_frames(2))
    assert main(["info", str(path)]) == 0
    out = capsys.readouterr().out
    assert "/camera/image/compressed" in out and "nav_msgs/msg/Odometry" in out and "seed" in out
