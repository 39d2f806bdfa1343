"""Bad recordings through `aslam info`: exit code 2, one line on stderr naming the file, no traceback.

Plus a property test: a valid recording cut at any byte reads as a prefix of itself (with a
warning) or fails with a RecordingError, never anything else.
"""

from __future__ import annotations

import contextlib
import io
import math
import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from conftest import (
    FRAME_NS,
    T0_NS,
    ForeignRecording,
    random_frames,
    write_recording,
    write_with_corrupt_image,
)
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from mcap.writer import Writer as McapWriter

from aslam.cli.app import main
from aslam.data_formats import ros_msgs
from aslam.data_formats.errors import RecordingError
from aslam.data_formats.images import ImageFormat, encode_image
from aslam.data_formats.recording import Recording

PNG = encode_image(np.zeros((24, 32, 3), dtype=np.uint8)).data


def run_info(path: Path, capfd) -> tuple[int, list[str]]:
    code = main(["info", str(path)])
    err = capfd.readouterr().err
    return code, err.splitlines()


def assert_one_error_line(path: Path, capfd, *needles: str) -> str:
    code, lines = run_info(path, capfd)
    assert code == 2, lines
    assert len(lines) == 1, lines
    line = lines[0]
    assert line.startswith(f"aslam: error: {path}: "), line
    assert "Traceback" not in line
    for needle in needles:
        assert needle in line, line
    return line


# --- builders of bad files ----------------------------------------------------------------------


def not_mcap(path: Path) -> None:
    path.write_text("stamp,x,y\n1,2,3\n")


def empty(path: Path) -> None:
    path.write_bytes(b"")


def no_image_topic(path: Path) -> None:
    with ForeignRecording(path) as rec:
        for k in range(3):
            rec.odometry("/odom", T0_NS + k * FRAME_NS, float(k), 0.0, 0.0)


def no_odometry(path: Path) -> None:
    with ForeignRecording(path) as rec:
        for k in range(3):
            rec.compressed_image("/camera/image/compressed", T0_NS + k * FRAME_NS, PNG, "png")


def unknown_raw_encoding(path: Path) -> None:
    with ForeignRecording(path) as rec:
        rec.odometry("/odom", T0_NS, 0.0, 0.0, 0.0)
        rec.raw_image("/camera/image/compressed", T0_NS, np.zeros((24, 32, 3), np.uint8), "32FC1")


def unknown_compressed_format(path: Path) -> None:
    with ForeignRecording(path) as rec:
        rec.odometry("/odom", T0_NS, 0.0, 0.0, 0.0)
        rec.compressed_image("/camera/image/compressed", T0_NS, PNG, "webp")


def corrupt_png(path: Path) -> None:
    write_with_corrupt_image(path, ImageFormat.PNG)


def corrupt_jpeg(path: Path) -> None:
    write_with_corrupt_image(path, ImageFormat.JPEG)


def odometry_value(value: float, field: str) -> Callable[[Path], None]:
    def build(path: Path) -> None:
        with ForeignRecording(path) as rec:
            for k in range(4):
                t = T0_NS + k * FRAME_NS
                pose = {"x": float(k), "y": 0.0, "yaw": 0.0}
                if k == 2:
                    pose[field] = value
                rec.compressed_image("/camera/image/compressed", t, PNG, "png")
                rec.odometry("/odom", t, pose["x"], pose["y"], pose["yaw"])

    return build


def odometry_stamps_backwards(path: Path) -> None:
    with ForeignRecording(path) as rec:
        for k, stamp_k in enumerate([0, 1, 2, 1, 3]):
            log = T0_NS + k * FRAME_NS
            rec.compressed_image("/camera/image/compressed", log, PNG, "png")
            rec.odometry("/odom", T0_NS + stamp_k * FRAME_NS, float(k), 0.0, 0.0, log_time=log)


def images_stamped_from_1970(path: Path) -> None:
    """A camera whose clock was never set (its stamps count from 1970), the odometry's right."""
    with ForeignRecording(path) as rec:
        for k in range(4):
            rec.compressed_image(
                "/camera/image/compressed", (k + 1) * FRAME_NS, PNG, "png", log_time=T0_NS + k
            )
            rec.odometry("/odom", T0_NS + k * FRAME_NS, float(k), 0.0, 0.0)


def undecodable_cdr(path: Path) -> None:
    with path.open("wb") as f:
        writer = McapWriter(f)
        writer.start(profile="ros2", library="test")
        image_schema = writer.register_schema(
            ros_msgs.COMPRESSED_IMAGE,
            "ros2msg",
            ros_msgs.message_definition(ros_msgs.COMPRESSED_IMAGE).encode(),
        )
        odom_schema = writer.register_schema(
            ros_msgs.ODOMETRY, "ros2msg", ros_msgs.message_definition(ros_msgs.ODOMETRY).encode()
        )
        image = writer.register_channel("/camera/image/compressed", "cdr", image_schema)
        odom = writer.register_channel("/odom", "cdr", odom_schema)
        writer.add_message(image, log_time=T0_NS, data=b"\x00\x01\x00\x00\xff\xff", publish_time=T0_NS)
        writer.add_message(odom, log_time=T0_NS, data=b"\x00\x01\x00\x00garbage", publish_time=T0_NS)
        writer.finish()


def wrong_image_type(path: Path) -> None:
    with ForeignRecording(path) as rec:
        rec.odometry("/odom", T0_NS, 0.0, 0.0, 0.0)
        rec.odometry("/camera/image/compressed", T0_NS, 0.0, 0.0, 0.0)


BAD_FILES = {
    "not an MCAP file": (not_mcap, ["not a recording or a bag"]),
    "empty file": (empty, ["empty file"]),
    "no image topic": (no_image_topic, ["no sensor_msgs/msg/Image or CompressedImage topic", "/odom"]),
    "no odometry": (no_odometry, ["no odometry", "/camera/image/compressed"]),
    "unknown raw encoding": (unknown_raw_encoding, ["unknown image encoding '32FC1'"]),
    "unknown compressed format": (unknown_compressed_format, ["unknown image encoding 'webp'"]),
    "corrupt PNG": (corrupt_png, ["corrupt PNG", f"stamp {T0_NS + FRAME_NS} ns"]),
    "corrupt JPEG": (corrupt_jpeg, ["corrupt JPEG", f"stamp {T0_NS + FRAME_NS} ns"]),
    "NaN odometry": (odometry_value(math.nan, "x"), ["not finite", f"stamp {T0_NS + 2 * FRAME_NS} ns"]),
    "infinite odometry": (
        odometry_value(math.inf, "yaw"),
        ["not finite", f"stamp {T0_NS + 2 * FRAME_NS} ns"],
    ),
    "odometry stamps backwards": (odometry_stamps_backwards, ["odometry stamps go backwards"]),
    "images on another clock": (  # was exit 0: an estimate of nothing, the images dropped with a warning
        images_stamped_from_1970,
        [
            "no image on '/camera/image/compressed' is stamped within the odometry on '/odom'",
            f"the images from {FRAME_NS} to {4 * FRAME_NS} ns",
            f"the odometry from {T0_NS} to {T0_NS + 3 * FRAME_NS} ns",
        ],
    ),
    "undecodable CDR": (undecodable_cdr, ["undecodable CDR message on '/camera/image/compressed'"]),
    "wrong image type": (wrong_image_type, ["has type 'nav_msgs/msg/Odometry'"]),
}


@pytest.mark.parametrize("case", list(BAD_FILES))
def test_bad_recording_is_one_line_exit_2(tmp_path, capfd, case):
    build, needles = BAD_FILES[case]
    path = tmp_path / "bad.mcap"
    build(path)
    assert_one_error_line(path, capfd, *needles)
    with pytest.raises(RecordingError):  # the library raises the same, never another exception
        for sample in Recording(path).samples():
            sample.image.decode_gray()


@pytest.mark.parametrize("workers", [0, 1, 2])
def test_a_corrupt_image_stops_estimate_with_its_error_and_no_output(tmp_path, workers):
    """In the calling thread (sweep tasks) or on a pool, the decode error surfaces the same way."""
    from aslam.app.estimate import estimate
    from aslam.core.config import EstimatorConfig

    path, output = tmp_path / "bad.mcap", tmp_path / "out.mcap"
    corrupt_png(path)
    with pytest.raises(RecordingError, match="corrupt PNG"):
        estimate(path, output, EstimatorConfig(), workers=workers, reader_process=False)
    assert list(tmp_path.iterdir()) == [path]


def test_missing_path(tmp_path, capfd):
    assert_one_error_line(tmp_path / "nowhere.mcap", capfd, "no such file")


def test_directory(tmp_path, capfd):
    folder = tmp_path / "rec.mcap"
    folder.mkdir()
    assert_one_error_line(
        folder, capfd, "is a folder with neither a rosbag2 metadata.yaml nor png/jpg images"
    )


def test_truncated_file_is_read_up_to_the_damage(tmp_path, capfd):
    frames = random_frames(12)
    path = write_recording(tmp_path / "r.mcap", frames, chunk_size_bytes=4096)
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: int(len(data) * 0.7)])
    warnings: list[str] = []
    samples = list(Recording(cut, on_warning=warnings.append).samples())
    assert 0 < len(samples) < 12
    assert [s.stamp_ns for s in samples] == [f[0] for f in frames[: len(samples)]]
    assert warnings[0].startswith(f"{cut}: truncated at byte ")
    assert f"of {len(data) * 7 // 10}; read {len(samples)} images, the rest is lost" in warnings[0]
    assert main(["info", str(cut)]) == 0
    err = capfd.readouterr().err
    assert "truncated at byte" in err and "Traceback" not in err


def test_a_cut_file_says_it_is_cut_when_its_images_lost_their_odometry(tmp_path):
    """Cut after a frame's image and before its odometry: the error (no odometry to pair the image
    with) says that the file is truncated, in one line, not only a warning (-q hides it). Cut after
    an image whose odometry is lost: the warning counts the images read and those paired, which
    differ."""
    from mcap.reader import make_reader
    from mcap.writer import Writer

    frames = random_frames(4)
    written = write_recording(tmp_path / "r.mcap", frames)
    path = tmp_path / "channels_first.mcap"  # every channel declared before the first message
    with written.open("rb") as source, path.open("wb") as out:
        reader = make_reader(source)
        summary = reader.get_summary()
        assert summary is not None
        writer = Writer(out, use_chunking=False)
        writer.start("ros2", "test")
        schemas = {i: writer.register_schema(s.name, s.encoding, s.data) for i, s in summary.schemas.items()}
        channels = {
            i: writer.register_channel(c.topic, c.message_encoding, schemas[c.schema_id], c.metadata)
            for i, c in summary.channels.items()
        }
        for _, channel, message in reader.iter_messages(log_time_order=False):
            writer.add_message(channels[channel.id], message.log_time, message.data, message.publish_time)
        writer.finish()
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    errors, counts = set(), set()
    for at in range(200, len(data), 53):
        cut.write_bytes(data[:at])
        warnings: list[str] = []
        try:
            samples = list(Recording(cut, on_warning=warnings.append).samples())
        except RecordingError as err:
            if "no odometry message" in str(err):
                errors.add(str(err))
            continue
        counts.update(
            line.split("; read ")[1] for line in warnings if "paired with odometry" in line and samples
        )
    assert errors and all("; the file is truncated at byte " in e and "\n" not in e for e in errors)
    assert any(c.startswith(f"{n + 1} images ({n} paired with odometry)") for c in counts for n in (1, 2, 3))


# --- truncation at any byte ---------------------------------------------------------------------


@pytest.fixture(scope="module")
def small_recording(tmp_path_factory) -> tuple[bytes, list[int]]:
    path = write_recording(
        tmp_path_factory.mktemp("trunc") / "r.mcap", random_frames(6, seed=5), chunk_size_bytes=3000
    )
    return path.read_bytes(), [s.stamp_ns for s in Recording(path).samples()]


@settings(max_examples=50, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(fraction=st.floats(min_value=0.0, max_value=1.0, exclude_max=True))
def test_any_cut_reads_a_prefix_or_fails_cleanly(small_recording, fraction):
    data, stamps = small_recording
    cut_at = int(len(data) * fraction)
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "cut.mcap"
        path.write_bytes(data[:cut_at])
        warnings: list[str] = []
        try:
            got = []
            for sample in Recording(path, on_warning=warnings.append).samples():
                sample.image.decode_gray()
                got.append(sample.stamp_ns)
        except RecordingError as err:
            assert str(err).startswith(f"{path}: ")
        else:
            assert got == stamps[: len(got)]
            assert any(": truncated at byte " in w for w in warnings)
        out, err = io.StringIO(), io.StringIO()
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            code = main(["info", str(path), "--json", "-"])
        assert code in (0, 2), err.getvalue()
        assert "Traceback" not in err.getvalue() and "internal error" not in err.getvalue()
        # a library's own failure is not an explanation (the magic alone gave ``TypeError: ord() …``)
        assert not any(
            name in err.getvalue() for name in ("TypeError", "ValueError", "IndexError", "KeyError")
        )


@pytest.mark.parametrize("cut_at", [8, 9, 17, 100])
def test_a_recording_cut_in_its_first_records_is_one_clear_line(small_recording, tmp_path, capsys, cut_at):
    """Cut to its magic (8 bytes) it was ``cannot open the bag: TypeError: ord() expected …``."""
    path = tmp_path / "cut.mcap"
    path.write_bytes(small_recording[0][:cut_at])
    assert main(["info", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"aslam: error: {path}: ") and err.count("\n") == 1
    assert not any(name in err for name in ("TypeError", "ValueError", "IndexError", "KeyError"))
    if cut_at >= 100:  # read as a rosbag2 file cut short: both readings are named
        assert "reindex" in err and "an aslam recording cut short that early" in err


def test_an_image_stamped_before_the_one_logged_before_it_is_dropped_and_said(tmp_path: Path):
    """Header stamps run backwards once while the log times run forwards: that image goes, with a
    warning, and the rest of the recording is read (odometry more than 50 ms back is refused:
    ``odometry stamps backwards`` above; less, dropped: tests/test_pose_stamp_order.py)."""
    from aslam.data_formats.recording import Recording

    path = tmp_path / "swapped.mcap"
    with ForeignRecording(path) as rec:
        for k, stamp_k in enumerate([0, 1, 2, 1, 3]):
            log = T0_NS + k * FRAME_NS + 1
            rec.odometry("/odom", T0_NS + k * FRAME_NS, float(k), 0.0, 0.0)
            rec.compressed_image(
                "/camera/image/compressed", T0_NS + stamp_k * FRAME_NS, PNG, "png", log_time=log
            )
    warnings: list[str] = []
    samples = list(Recording(path, on_warning=warnings.append).samples())
    assert [s.stamp_ns for s in samples] == [T0_NS + k * FRAME_NS for k in (0, 1, 2, 3)]
    assert warnings == [f"{path}: dropped 1 image(s) stamped before an image logged earlier (out of order)"]


@pytest.mark.parametrize("indexed", [True, False], ids=["indexed", "read-linearly"])
def test_a_changed_byte_in_a_chunk_is_caught_by_its_crc(tmp_path: Path, indexed: bool):
    """A chunk whose bytes changed but that still decompresses, or is stored uncompressed (a bag's
    raw images, an estimate's place views), was read on: wrong values, exit 0 (a map read by
    ``--map`` changed the run's claims). Each chunk's CRC is now checked, whichever way it is read."""
    from mcap.writer import CompressionType

    from aslam.data_formats.mcap_file import McapFile

    path = tmp_path / "raw.mcap"
    payload = bytes(range(256)) * 4
    with path.open("wb") as f:
        writer = McapWriter(f, compression=CompressionType.NONE)
        writer.start()
        channel = writer.register_channel("/raw", "raw", writer.register_schema("raw", "raw", b""))
        writer.add_message(channel, log_time=1, data=payload, publish_time=1)
        writer.finish()
    data = bytearray(path.read_bytes())
    start = data.find(payload)
    assert next(iter(McapFile(path).messages(None)))[2].data == payload  # intact: read as written
    data[start + 100] ^= 0x01
    # Read linearly: cut after the chunk (its message is its last record), so no summary is left.
    path.write_bytes(data if indexed else data[: start + len(payload)])
    with pytest.raises(RecordingError, match=r"a chunk fails its CRC check \(damaged bytes\)"):
        list(McapFile(path).messages(None))


def test_every_command_names_a_bad_file_as_it_was_given(tmp_path, capfd, monkeypatch):
    """A relative name stays relative in the error line: `estimate` said the absolute path where
    `info` and `report` said the name typed (and its output and --map were absolute too)."""
    monkeypatch.chdir(tmp_path)
    not_mcap(tmp_path / "bad.mcap")
    (tmp_path / "exists.mcap").write_bytes(b"")
    cases = {
        ("info", "bad.mcap"): "bad.mcap: not a recording or a bag",
        ("estimate", "bad.mcap", "-o", "out.mcap"): "bad.mcap: not a recording or a bag",
        ("estimate", "nowhere.mcap", "-o", "out.mcap"): "nowhere.mcap: no such file",
        ("estimate", "bad.mcap", "-o", "nodir/out.mcap"): "nodir/out.mcap: folder nodir does not exist",
        ("estimate", "bad.mcap", "-o", "exists.mcap"): "exists.mcap: already exists",
        ("estimate", "bad.mcap", "-o", "out.mcap", "--map", "nomap.mcap"): "nomap.mcap: no such map",
        ("report", "bad.mcap"): "bad.mcap: not an MCAP file",
    }
    for args, start in cases.items():
        code = main(list(args))
        lines = capfd.readouterr().err.splitlines()
        assert code == 2 and len(lines) == 1, (args, lines)
        assert lines[0].startswith(f"aslam: error: {start}"), (args, lines)
