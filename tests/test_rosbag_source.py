"""ROS bags as a robot driver writes them, written here with rosbags' own writers: raw bgr8 images on
``/camera/color/image_raw`` at 10 Hz, odometry at 5× the camera rate and out of phase, messages
logged a little after their stamps. The same messages as a rosbag2 folder (mcap, sqlite3, split,
zstd-compressed), a lone rosbag2 .mcap file and a ROS 1 bag must give the same samples.

Also holds the bag builders other tests import.
"""

from __future__ import annotations

import math
import os
import shutil
import subprocess
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from conftest import one_error_line

from aslam.core.errors import InputError
from aslam.data_formats.errors import RecordingError
from aslam.data_formats.images import encode_image
from aslam.data_formats.recording import Recording
from aslam.data_formats.recording_writer import RecordingWriter
from aslam.data_formats.rosbag_source import (
    BagError,
    BagTopics,
    SourceKind,
    describe_bag,
    iter_bag_samples,
    open_source,
    summarize_bag,
)

T0_NS = 1_700_000_000_000_000_000
CAMERA_PERIOD_NS = 100_000_000  # 10 Hz
ODOMETRY_PERIOD_NS = CAMERA_PERIOD_NS // 5
ODOMETRY_PHASE_NS = -7_000_000  # odometry starts 7 ms before the first image, and stays out of phase
IMAGE_LATENCY_NS = 30_000_000  # images are logged 30 ms after their stamp (odometry 1 ms)
WIDTH, HEIGHT = 24, 16
IMAGE_TOPIC = "/camera/color/image_raw"
N_IMAGES = 12


def true_pose(stamp_ns: int) -> np.ndarray:
    """A constant-velocity arc: linear interpolation between odometry messages is exact."""
    t = (stamp_ns - T0_NS) / 1e9
    return np.array([0.8 * t, 0.3 * t, math.remainder(0.5 * t + 3.0, 2 * math.pi)])


def odometry_pose(stamp_ns: int) -> np.ndarray:
    t = (stamp_ns - T0_NS) / 1e9
    return np.array([1.0 + 0.75 * t, -2.0 + 0.35 * t, math.remainder(0.45 * t - 3.0, 2 * math.pi)])


def bgr_image(i: int) -> np.ndarray:
    rng = np.random.default_rng(i)
    return rng.integers(0, 256, size=(HEIGHT, WIDTH, 3), dtype=np.uint8)


def image_stamps() -> list[int]:
    return [T0_NS + i * CAMERA_PERIOD_NS for i in range(N_IMAGES)]


def odometry_stamps() -> list[int]:
    end = T0_NS + N_IMAGES * CAMERA_PERIOD_NS
    return list(range(T0_NS + ODOMETRY_PHASE_NS, end, ODOMETRY_PERIOD_NS))


# --- messages, for either ROS version ------------------------------------------------------------


def _time(ts: Any, stamp_ns: int) -> Any:
    sec, nanosec = divmod(stamp_ns, 1_000_000_000)
    return ts.types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec)


def _header(ts: Any, stamp_ns: int, frame: str) -> Any:
    header = ts.types["std_msgs/msg/Header"]
    if "seq" in header.__dataclass_fields__:  # ROS 1
        return header(seq=0, stamp=_time(ts, stamp_ns), frame_id=frame)
    return header(stamp=_time(ts, stamp_ns), frame_id=frame)


def _pose_msg(ts: Any, pose: np.ndarray) -> Any:
    t = ts.types
    half = 0.5 * float(pose[2])
    return t["geometry_msgs/msg/Pose"](
        position=t["geometry_msgs/msg/Point"](x=float(pose[0]), y=float(pose[1]), z=0.0),
        orientation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=math.sin(half), w=math.cos(half)),
    )


def odometry_msg(ts: Any, stamp_ns: int, pose: np.ndarray) -> Any:
    t = ts.types
    zero = t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
    return t["nav_msgs/msg/Odometry"](
        header=_header(ts, stamp_ns, "odom"),
        child_frame_id="base_link",
        pose=t["geometry_msgs/msg/PoseWithCovariance"](pose=_pose_msg(ts, pose), covariance=np.zeros(36)),
        twist=t["geometry_msgs/msg/TwistWithCovariance"](
            twist=t["geometry_msgs/msg/Twist"](linear=zero, angular=zero), covariance=np.zeros(36)
        ),
    )


def pose_stamped_msg(ts: Any, stamp_ns: int, pose: np.ndarray) -> Any:
    return ts.types["geometry_msgs/msg/PoseStamped"](
        header=_header(ts, stamp_ns, "world"), pose=_pose_msg(ts, pose)
    )


def tf_msg(ts: Any, stamp_ns: int, transforms: list[tuple[str, str, np.ndarray]]) -> Any:
    t = ts.types
    items = []
    for parent, child, pose in transforms:
        half = 0.5 * float(pose[2])
        items.append(
            t["geometry_msgs/msg/TransformStamped"](
                header=_header(ts, stamp_ns, parent),
                child_frame_id=child,
                transform=t["geometry_msgs/msg/Transform"](
                    translation=t["geometry_msgs/msg/Vector3"](x=float(pose[0]), y=float(pose[1]), z=0.0),
                    rotation=t["geometry_msgs/msg/Quaternion"](
                        x=0.0, y=0.0, z=math.sin(half), w=math.cos(half)
                    ),
                ),
            )
        )
    return t["tf2_msgs/msg/TFMessage"](transforms=items)


def raw_image_msg(ts: Any, stamp_ns: int, bgr: np.ndarray, encoding: str = "bgr8", padding: int = 0) -> Any:
    """A raw Image as a driver fills it; rows padded with ``padding`` bytes (``step`` > row)."""
    if encoding == "bgr8":
        pixels = bgr
    elif encoding == "bgra8":
        pixels = cv2.cvtColor(bgr, cv2.COLOR_BGR2BGRA)
    elif encoding == "mono8":
        pixels = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
    elif encoding == "mono16":
        pixels = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY).astype("<u2") * 257
    else:
        raise ValueError(encoding)
    rows = np.ascontiguousarray(pixels).view(np.uint8).reshape(pixels.shape[0], -1)
    rows = np.concatenate([rows, np.zeros((rows.shape[0], padding), np.uint8)], axis=1)
    return ts.types["sensor_msgs/msg/Image"](
        header=_header(ts, stamp_ns, "camera_color_optical_frame"),
        height=bgr.shape[0],
        width=bgr.shape[1],
        encoding=encoding,
        is_bigendian=0,
        step=rows.shape[1],
        data=rows.reshape(-1),
    )


def compressed_image_msg(ts: Any, stamp_ns: int, bgr: np.ndarray) -> Any:
    ok, png = cv2.imencode(".png", bgr)
    assert ok
    return ts.types["sensor_msgs/msg/CompressedImage"](
        header=_header(ts, stamp_ns, "camera"), format="png", data=png.reshape(-1)
    )


def camera_info_msg(ts: Any, stamp_ns: int) -> Any:
    fields = ts.types["sensor_msgs/msg/CameraInfo"].__dataclass_fields__
    names = ("d", "k", "r", "p") if "k" in fields else ("D", "K", "R", "P")  # ROS 1 spells them upper case
    roi = ts.types["sensor_msgs/msg/RegionOfInterest"](
        x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
    )
    values = dict(
        zip(
            names,
            (
                np.zeros(5),
                np.array([20.0, 0, 11.5, 0, 20.0, 7.5, 0, 0, 1]),
                np.eye(3).reshape(-1),
                np.zeros(12),
            ),
            strict=True,
        )
    )
    return ts.types["sensor_msgs/msg/CameraInfo"](
        header=_header(ts, stamp_ns, "camera"),
        height=HEIGHT,
        width=WIDTH,
        distortion_model="plumb_bob",
        binning_x=0,
        binning_y=0,
        roi=roi,
        **values,
    )


@dataclass(frozen=True)
class Options:
    """What goes into a test bag."""

    encoding: str = "bgr8"
    padding: int = 0
    odometry: str = "odometry"  # "odometry" (nav_msgs/Odometry on /odom), "tf", or "none"
    ground_truth: bool = True
    extra_image_topic: bool = False
    compressed: bool = False  # CompressedImage PNGs instead of raw images
    camera_info: bool = True


def bag_messages(ts: Any, options: Options = Options()) -> list[tuple[int, str, str, Any]]:
    """``(log_time_ns, topic, type, message)`` in log-time order."""
    out: list[tuple[int, str, str, Any]] = []
    for stamp in odometry_stamps():
        log = stamp + 1_000_000
        if options.odometry == "odometry":
            out.append((log, "/odom", "nav_msgs/msg/Odometry", odometry_msg(ts, stamp, odometry_pose(stamp))))
        elif options.odometry == "tf":
            transforms = [("odom", "base_footprint", odometry_pose(stamp)), ("map", "odom", np.zeros(3))]
            out.append((log, "/tf", "tf2_msgs/msg/TFMessage", tf_msg(ts, stamp, transforms)))
        if options.ground_truth:
            out.append(
                (
                    log,
                    "/ground_truth",
                    "geometry_msgs/msg/PoseStamped",
                    pose_stamped_msg(ts, stamp, true_pose(stamp)),
                )
            )
    for i, stamp in enumerate(image_stamps()):
        log = stamp + IMAGE_LATENCY_NS
        if options.compressed:
            out.append(
                (
                    log,
                    "/camera/color/image_raw/compressed",
                    "sensor_msgs/msg/CompressedImage",
                    compressed_image_msg(ts, stamp, bgr_image(i)),
                )
            )
        else:
            msg = raw_image_msg(ts, stamp, bgr_image(i), options.encoding, options.padding)
            out.append((log, IMAGE_TOPIC, "sensor_msgs/msg/Image", msg))
        if options.extra_image_topic:
            depth = raw_image_msg(ts, stamp, bgr_image(i), "mono16")
            out.append((log, "/camera/depth/image_rect_raw", "sensor_msgs/msg/Image", depth))
        if options.camera_info and i == 0:
            out.append(
                (log, "/camera/color/camera_info", "sensor_msgs/msg/CameraInfo", camera_info_msg(ts, stamp))
            )
    out.sort(key=lambda row: row[0])
    return out


def write_rosbag2(
    path: Path,
    options: Options = Options(),
    *,
    storage: str = "mcap",
    compression: str | None = None,
    messages: list[tuple[int, str, str, Any]] | None = None,
) -> Path:
    from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    rows = bag_messages(ts, options) if messages is None else messages
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    writer = Writer(path, version=9, storage_plugin=plugin)
    if compression is not None:
        writer.set_compression(CompressionMode[compression.upper()], CompressionFormat.ZSTD)
    with writer:
        connections: dict[str, Any] = {}
        for log, topic, msgtype, msg in rows:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msgtype, typestore=ts)
            writer.write(connections[topic], log, ts.serialize_cdr(msg, msgtype))
    return path


def write_rosbag1(
    path: Path,
    options: Options = Options(),
    *,
    edit: Callable[[list[tuple[int, str, str, Any]]], None] | None = None,
) -> Path:
    """A ROS 1 bag of ``bag_messages``, changed in place by ``edit`` (its rows, in log-time order)."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC)
    # rosbags' Noetic store has no tf2_msgs; the definition is ROS's own.
    ts.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms", "tf2_msgs/msg/TFMessage"))
    rows = bag_messages(ts, options)
    if edit is not None:
        edit(rows)
    return write_ros1_rows(path, ts, rows)


def write_ros1_rows(path: Path, ts: Any, rows: list[tuple[int, str, str, Any]]) -> Path:
    """A ROS 1 bag of ``rows`` (log time, topic, type, message of typestore ``ts``), one connection
    per topic, written by rosbags."""
    from rosbags.rosbag1 import Writer

    with Writer(path) as writer:
        connections: dict[str, Any] = {}
        for log, topic, msgtype, msg in rows:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msgtype, typestore=ts)
            writer.write(connections[topic], log, ts.serialize_ros1(msg, msgtype))
    return path


def driver_bag(folder: Path, ros: int, edit: Callable[[list[tuple[int, str, str, Any]]], None]) -> Path:
    """The driver bag of ``bag_messages`` as ROS 1 (``driver.bag``) or ROS 2 (``bag/``), its rows
    changed in place by ``edit``."""
    if ros == 1:
        return write_rosbag1(folder / "driver.bag", edit=edit)
    from rosbags.typesys import Stores, get_typestore

    rows = bag_messages(get_typestore(Stores.ROS2_HUMBLE))
    edit(rows)
    return write_rosbag2(folder / "bag", messages=rows)


def write_split_rosbag2(path: Path, options: Options = Options()) -> Path:
    """A rosbag2 folder split in two files (what ``ros2 bag record --max-bag-size`` leaves)."""
    from rosbags.typesys import Stores, get_typestore
    from ruamel.yaml import YAML

    rows = bag_messages(get_typestore(Stores.ROS2_HUMBLE), options)
    half = len(rows) // 2
    first = write_rosbag2(path, messages=rows[:half])
    second = write_rosbag2(path.with_name(path.name + "-second"), messages=rows[half:])
    yaml = YAML(typ="safe")
    meta_first = yaml.load((first / "metadata.yaml").read_text())
    meta_second = yaml.load((second / "metadata.yaml").read_text())
    info, other = meta_first["rosbag2_bagfile_information"], meta_second["rosbag2_bagfile_information"]
    second_file = other["relative_file_paths"][0]
    moved = f"{path.name}_1.mcap"
    shutil.move(second / second_file, first / moved)
    shutil.rmtree(second)
    info["relative_file_paths"].append(moved)
    counts = {t["topic_metadata"]["name"]: t for t in info["topics_with_message_count"]}
    for topic in other["topics_with_message_count"]:
        name = topic["topic_metadata"]["name"]
        if name in counts:
            counts[name]["message_count"] += topic["message_count"]
        else:
            info["topics_with_message_count"].append(topic)
    info["message_count"] += other["message_count"]
    end = other["starting_time"]["nanoseconds_since_epoch"] + other["duration"]["nanoseconds"]
    info["duration"]["nanoseconds"] = end - info["starting_time"]["nanoseconds_since_epoch"]
    info["files"].append({**other["files"][0], "path": moved})
    with (first / "metadata.yaml").open("w") as f:
        yaml.dump(meta_first, f)
    return first


# --- expectations ---------------------------------------------------------------------------------


def expected_gray(i: int) -> np.ndarray:
    return cv2.cvtColor(bgr_image(i), cv2.COLOR_BGR2GRAY)


def assert_driver_samples(samples: list, *, ground_truth: bool = True, gray_tolerance: int = 0) -> None:
    """Every image has odometry around it (odometry starts first, ends after), so all come out.

    PNG decoding to grey (libpng's own conversion) may round differently from OpenCV's: ±1.
    """
    assert [s.stamp_ns for s in samples] == image_stamps()
    for i, sample in enumerate(samples):
        np.testing.assert_allclose(sample.odometry_pose, odometry_pose(sample.stamp_ns), atol=1e-9)
        if ground_truth:
            np.testing.assert_allclose(sample.ground_truth_pose, true_pose(sample.stamp_ns), atol=1e-9)
        else:
            assert sample.ground_truth_pose is None
        difference = sample.image.decode_gray().astype(int) - expected_gray(i)
        assert np.abs(difference).max() <= gray_tolerance


WITH_TRUTH = BagTopics(ground_truth="/ground_truth")


# --- tests ---------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def bags(tmp_path_factory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("bags")
    out = {
        "rosbag2-mcap": write_rosbag2(root / "mcap_bag", storage="mcap"),
        "rosbag2-sqlite3": write_rosbag2(root / "sqlite_bag", storage="sqlite3"),
        "rosbag2-mcap-zstd-file": write_rosbag2(root / "zstd_bag", storage="mcap", compression="file"),
        "rosbag2-sqlite3-zstd-message": write_rosbag2(
            root / "zmsg_bag", storage="sqlite3", compression="message"
        ),
        "rosbag2-split": write_split_rosbag2(root / "split_bag"),
        "rosbag1": write_rosbag1(root / "driver.bag"),
    }
    lone = root / "lone.mcap"
    shutil.copy(next((root / "mcap_bag").glob("*.mcap")), lone)
    out["rosbag2-file"] = lone
    return out


KINDS = {
    "rosbag2-mcap": SourceKind.ROSBAG2,
    "rosbag2-sqlite3": SourceKind.ROSBAG2,
    "rosbag2-mcap-zstd-file": SourceKind.ROSBAG2,
    "rosbag2-sqlite3-zstd-message": SourceKind.ROSBAG2,
    "rosbag2-split": SourceKind.ROSBAG2,
    "rosbag1": SourceKind.ROSBAG1,
    "rosbag2-file": SourceKind.ROSBAG2_FILE,
}


@pytest.mark.parametrize("name", sorted(KINDS))
def test_every_bag_kind_gives_the_same_samples(bags, name):
    path = bags[name]
    assert open_source(path) is KINDS[name]
    warnings: list[str] = []
    samples = list(iter_bag_samples(path, WITH_TRUTH, on_warning=warnings.append))
    assert_driver_samples(samples)
    assert warnings == []


def test_without_a_named_ground_truth_topic_there_is_none(bags):
    assert_driver_samples(list(iter_bag_samples(bags["rosbag2-mcap"])), ground_truth=False)


def test_the_split_bag_really_has_two_files(bags):
    summary = summarize_bag(bags["rosbag2-split"])
    assert len(summary.files) == 2
    assert summary.storage == "mcap"


def test_summary_lists_topics_types_and_counts(bags):
    for name in ("rosbag2-sqlite3", "rosbag1", "rosbag2-mcap-zstd-file"):
        summary = summarize_bag(bags[name])
        topics = {t.topic: (t.datatype, t.messages) for t in summary.topics}
        assert topics == {
            "/camera/color/camera_info": ("sensor_msgs/msg/CameraInfo", 1),
            IMAGE_TOPIC: ("sensor_msgs/msg/Image", N_IMAGES),
            "/odom": ("nav_msgs/msg/Odometry", len(odometry_stamps())),
            "/ground_truth": ("geometry_msgs/msg/PoseStamped", len(odometry_stamps())),
        }, name
        assert summary.problem is None
        assert summary.resolved is not None and summary.resolved.image == IMAGE_TOPIC
        assert summary.resolved.odometry == "/odom"
        assert summary.messages == 1 + N_IMAGES + 2 * len(odometry_stamps())
    assert summarize_bag(bags["rosbag2-mcap-zstd-file"]).compression == "zstd (file)"
    assert summarize_bag(bags["rosbag1"]).storage == "rosbag1"


def test_describe_bag_reads_every_sample(bags):
    info = describe_bag(bags["rosbag1"], WITH_TRUTH)
    assert info.samples == N_IMAGES
    assert info.samples_with_ground_truth == N_IMAGES
    assert info.image_encodings == {"bgr8": N_IMAGES}
    assert info.image_sizes == {f"{WIDTH}x{HEIGHT}": N_IMAGES}
    assert info.camera is not None and info.camera.width_px == WIDTH
    assert info.metadata["image_topic"] == IMAGE_TOPIC and info.metadata["kind"] == "rosbag1"
    assert info.as_dict()["samples"] == N_IMAGES
    span = odometry_pose(image_stamps()[-1])[:2] - odometry_pose(image_stamps()[0])[:2]
    assert info.odometry_distance_m == pytest.approx(float(np.hypot(*span)))


def _with_a_stale_index(bags, tmp_path: Path) -> Path:
    """A copy of the rosbag2 mcap bag whose metadata.yaml says three times its images."""
    from ruamel.yaml import YAML

    bag = tmp_path / "bag"
    shutil.copytree(bags["rosbag2-mcap"], bag)
    yaml = YAML(typ="safe")
    meta = yaml.load((bag / "metadata.yaml").read_text())
    for topic in meta["rosbag2_bagfile_information"]["topics_with_message_count"]:
        if topic["topic_metadata"]["name"] == IMAGE_TOPIC:
            topic["message_count"] = 3 * N_IMAGES
    with (bag / "metadata.yaml").open("w") as f:
        yaml.dump(meta, f)
    return bag


def test_describe_bag_counts_the_topics_it_reads_rather_than_a_stale_index(bags, tmp_path):
    """A rosbag2 folder's metadata.yaml is the index rosbags gives counts from; one left stale (a
    bag trimmed or rewritten by a tool) made ``aslam info`` show counts the bag does not hold."""
    bag = _with_a_stale_index(bags, tmp_path)
    warnings: list[str] = []
    info = describe_bag(bag, WITH_TRUTH, on_warning=warnings.append)
    counts = {t.topic: t.messages for t in info.topics}
    assert counts[IMAGE_TOPIC] == N_IMAGES == info.samples
    said = f"the bag's index says {3 * N_IMAGES} messages on '{IMAGE_TOPIC}'; it holds {N_IMAGES}"
    assert warnings == [f"{bag}: {said}"]
    fresh = {t.topic: t.messages for t in describe_bag(bags["rosbag2-mcap"], WITH_TRUTH).topics}
    assert fresh == counts


def test_an_estimate_of_a_bag_holding_fewer_messages_than_its_index_says_warns(bags, tmp_path, capfd):
    """rosbags skips an MCAP chunk it cannot read (and a sqlite row deleted) without an error: only
    ``info`` compared the counts read with the index's, so ``estimate`` of a damaged bag wrote an
    estimate of part of it, exit 0 and not a word, which ``report`` then scored as complete (found
    by a fuzz of damaged bags: 15 of 40 images). A stale index stands in for the damage here."""
    from aslam.cli.app import main

    bag = _with_a_stale_index(bags, tmp_path)
    said = f"{bag}: the bag's index says {3 * N_IMAGES} messages on '{IMAGE_TOPIC}'; it holds {N_IMAGES}"
    assert main(["estimate", str(bag), "-o", str(tmp_path / "e.mcap")]) == 0
    assert [line for line in capfd.readouterr().err.splitlines() if "warning" in line] == [
        f"aslam: warning: {said}"
    ]
    assert main(["estimate", str(bags["rosbag2-mcap"]), "-o", str(tmp_path / "f.mcap")]) == 0
    assert "warning" not in capfd.readouterr().err


@pytest.mark.parametrize(
    "edit",
    [
        lambda info: info["duration"].update(nanoseconds="abc"),
        lambda info: info.update(message_count=[1]),
        lambda info: info["topics_with_message_count"][0].update(message_count="x"),
        lambda info: info["topics_with_message_count"][0]["topic_metadata"].update(name=[1, 2]),
        lambda info: info["topics_with_message_count"][1]["topic_metadata"].update(type=-5),
        lambda info: info["topics_with_message_count"][0]["topic_metadata"].update(type=None),
        lambda info: info.update(ros_distro=[1]),
    ],
    ids=["duration", "message-count", "topic-count", "topic-name", "topic-type", "no-type", "distro"],
)
def test_a_metadata_field_of_the_wrong_type_is_one_line_naming_the_file(bags, tmp_path, capsys, edit):
    """rosbags reads a rosbag2 folder's metadata.yaml as written and derives counts from it when
    first asked, and passes its names on as written: a topic's count that was a word ended ``aslam
    estimate`` with exit 70, "internal error: TypeError", from the reader process (``info`` said
    "TypeError: unsupported operand"); a type that was a number, or a ros_distro that was a list,
    ended ``info`` with exit 70 where it printed them."""
    from ruamel.yaml import YAML

    from aslam.cli.app import main

    bag = tmp_path / "bag"
    shutil.copytree(bags["rosbag2-mcap"], bag)
    yaml = YAML(typ="safe")
    meta = yaml.load((bag / "metadata.yaml").read_text())
    edit(meta["rosbag2_bagfile_information"])
    with (bag / "metadata.yaml").open("w") as f:
        yaml.dump(meta, f)
    for args in (["info", str(bag)], ["estimate", str(bag), "-o", str(tmp_path / "e.mcap")]):
        assert main(args) == 2
        line = one_error_line(capsys.readouterr().err)
        assert f"{bag}: its metadata.yaml has a field of the wrong type" in line
    assert not (tmp_path / "e.mcap").exists()


def test_a_metadata_yaml_of_megabytes_is_refused_before_it_is_parsed(bags, tmp_path, capsys):
    """A metadata.yaml holding a 50 MB value kept ``info`` parsing it for 44 s and ``estimate`` for
    over a minute (YAML parses at about a megabyte a second); an index is a few kilobytes."""
    from aslam.cli.app import main
    from aslam.data_formats.files import ROSBAG2_METADATA_MAX_BYTES, source_files

    bag = tmp_path / "bag"
    shutil.copytree(bags["rosbag2-mcap"], bag)
    with (bag / "metadata.yaml").open("a") as f:
        f.write(f"notes: {'x' * ROSBAG2_METADATA_MAX_BYTES}\n")
    size = (bag / "metadata.yaml").stat().st_size
    for args in (["info", str(bag)], ["estimate", str(bag), "-o", str(tmp_path / "e.mcap")]):
        assert main(args) == 2
        assert one_error_line(capsys.readouterr().err) == (
            f"aslam: error: {bag}: its metadata.yaml is {size:,} bytes; a rosbag2 index is a few"
            f" kilobytes (at most {ROSBAG2_METADATA_MAX_BYTES:,} are read)"
        )
    assert (bag / "metadata.yaml") in source_files(bag)  # not parsed: every file of the folder


def test_info_opens_a_bag_once(bags, monkeypatch):
    """rosbags decompresses a rosbag2 bag compressed by file whole, into a temporary folder, each
    time it is opened (and reads a ROS 1 bag's whole index): ``aslam info`` opened it four times
    (the image count for the progress bar, the summary, the samples, the camera info), so a
    450 MB bag of 19,801 images was decompressed four times, 0.4-0.7 s each; then twice (the
    count, then the rest); now once, the count coming from the reading's own opening."""
    from aslam.app.info import describe
    from aslam.data_formats import rosbag_source

    opened: list[Path] = []
    real_open = rosbag_source._open_reader

    def counted(path):
        opened.append(path)
        return real_open(path)

    monkeypatch.setattr(rosbag_source, "_open_reader", counted)
    totals = set()
    info = describe(bags["rosbag2-mcap-zstd-file"], on_progress=lambda _done, total: totals.add(total))
    assert info.samples == N_IMAGES and info.camera is not None
    assert totals == {N_IMAGES}
    assert len(opened) == 1


@pytest.mark.parametrize("reader_process", [True, False])
def test_estimate_opens_a_bag_once(bags, tmp_path, monkeypatch, reader_process):
    """``aslam estimate`` opened a bag to count its images (the progress bar's total), then its
    reader opened it again to read it: rosbags decompresses a bag compressed by file whole at each
    open (0.6 s of a 4.4 s estimate of 3,000 images) and reads a ROS 1 bag's whole index. The
    reader's own opening now gives the count, in the reader process where there is one."""
    from aslam.app.estimate import estimate
    from aslam.core.config import EstimatorConfig
    from aslam.data_formats import rosbag_source

    opened = tmp_path / "opened.txt"  # a file: the reader process's opens are counted too
    real_open = rosbag_source._open_reader

    def counted(path):
        with opened.open("a") as log:
            log.write(f"{path}\n")
        return real_open(path)

    monkeypatch.setattr(rosbag_source, "_open_reader", counted)
    totals = []
    summary = estimate(
        bags["rosbag2-mcap-zstd-file"],
        tmp_path / "estimate.mcap",
        EstimatorConfig(),
        reader_process=reader_process,
        on_progress=lambda progress: totals.append(progress.samples_total),
    )
    assert summary.samples == N_IMAGES
    assert len(opened.read_text().splitlines()) == 1
    assert totals[-1] == N_IMAGES


@pytest.mark.parametrize(("encoding", "padding"), [("bgra8", 0), ("mono16", 3), ("mono8", 5), ("bgr8", 2)])
def test_raw_encodings_and_padded_rows(tmp_path, encoding, padding):
    path = write_rosbag2(tmp_path / "bag", Options(encoding=encoding, padding=padding), storage="mcap")
    assert_driver_samples(list(iter_bag_samples(path, WITH_TRUTH)))


def test_compressed_images(tmp_path):
    path = write_rosbag1(tmp_path / "c.bag", Options(compressed=True))
    assert_driver_samples(list(iter_bag_samples(path, WITH_TRUTH)), gray_tolerance=1)


@pytest.mark.parametrize("writer", ["rosbag2", "rosbag1"])
def test_odometry_from_tf_when_there_is_no_odometry_topic(tmp_path, writer):
    """``odom → base_footprint``, REP 105's body frame and odom's only child, is taken without a
    warning: nothing was guessed (a warning on every run of a standard bag said nothing)."""
    options = Options(odometry="tf")
    path = (
        write_rosbag1(tmp_path / "t.bag", options)
        if writer == "rosbag1"
        else write_rosbag2(tmp_path / "t", options)
    )
    warnings: list[str] = []
    assert_driver_samples(list(iter_bag_samples(path, WITH_TRUTH, on_warning=warnings.append)))
    assert warnings == []


def test_tf_without_the_odom_frame_names_the_frames_seen(tmp_path):
    path = write_rosbag2(tmp_path / "t", Options(odometry="tf"))
    with pytest.raises(BagError, match="transforms seen: map → odom, odom → base_footprint"):
        list(iter_bag_samples(path, BagTopics(odom_frame="odom", base_frame="base_link")))


def _tf_rows(edit: Callable[[Any, list[tuple[str, str, np.ndarray]]], list[tuple[str, str, np.ndarray]]]):
    """The test bag's rows with odometry on /tf, each TFMessage's (parent, child, pose) list edited."""
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    rows = bag_messages(ts, Options(odometry="tf"))
    out = []
    for log, topic, datatype, msg in rows:
        if topic == "/tf":
            stamp = msg.transforms[0].header.stamp
            stamp_ns = stamp.sec * 1_000_000_000 + stamp.nanosec
            transforms = []
            for t in msg.transforms:
                move, turn = t.transform.translation, t.transform.rotation
                pose = np.array([move.x, move.y, 2 * math.atan2(turn.z, turn.w)])
                transforms.append((t.header.frame_id, t.child_frame_id, pose))
            msg = tf_msg(ts, stamp_ns, edit(ts, transforms))
        out.append((log, topic, datatype, msg))
    return out


def test_a_marker_published_beside_the_robot_on_tf_is_not_taken_for_it(tmp_path):
    """REP 105's body frame is preferred among odom's children: a constant marker frame listed first
    in each TFMessage was taken for the robot (one keyframe from a whole drive)."""

    def marker_first(_ts, transforms):
        return [("odom", "odom_marker", np.zeros(3)), *transforms]

    path = write_rosbag2(tmp_path / "bag", messages=_tf_rows(marker_first))
    warnings: list[str] = []
    assert_driver_samples(list(iter_bag_samples(path, WITH_TRUTH, on_warning=warnings.append)))
    said = f"{path}: odometry from /tf: odom → base_footprint (its other children: odom_marker;"
    assert said in warnings[0]
    named = BagTopics(ground_truth="/ground_truth", base_frame="odom_marker")  # still the user's to choose
    assert all(not s.odometry_pose.any() for s in iter_bag_samples(path, named))


def test_a_zero_quaternion_on_tf_is_one_line_naming_the_bag(tmp_path, capsys):
    """An odom → base_link transform whose rotation is all zeros ended ``info`` and ``estimate`` with
    exit 70, "internal error: ValueError: the orientation quaternion is zero" (found by a fuzz of
    damaged bags); a pose topic's was already refused."""
    import dataclasses

    from aslam.cli.app import main

    rows = _tf_rows(lambda _ts, transforms: transforms)
    at = [i for i, (_log, topic, _type, _msg) in enumerate(rows) if topic == "/tf"][3]
    log, topic, datatype, msg = rows[at]
    first = msg.transforms[0]
    zero = dataclasses.replace(first.transform.rotation, x=0.0, y=0.0, z=0.0, w=0.0)
    broken = dataclasses.replace(first, transform=dataclasses.replace(first.transform, rotation=zero))
    rows[at] = (log, topic, datatype, dataclasses.replace(msg, transforms=[broken, *msg.transforms[1:]]))
    path = write_rosbag2(tmp_path / "bag", messages=rows)
    for args in (["info", str(path), "-q"], ["estimate", str(path), "-o", str(tmp_path / "e.mcap"), "-q"]):
        assert main(args) == 2
        line = one_error_line(capsys.readouterr().err)
        assert line.startswith(f"aslam: error: {path}: odometry transform odom → base_footprint at stamp ")
        assert line.endswith(" ns: the orientation quaternion is zero")
    assert not (tmp_path / "e.mcap").exists()


def test_a_failed_estimate_of_a_bag_compressed_by_file_leaves_no_copy_in_tmpdir(
    tmp_path, capsys, monkeypatch
):
    """rosbags reads a rosbag2 bag compressed by file from a decompressed copy in TMPDIR, removed when
    the bag is closed. The reader process ended with ``os._exit`` and no closing: every estimate
    that failed (a corrupt image) or was stopped left the whole decompressed bag behind (found by a
    fuzz of damaged bags)."""
    import dataclasses
    import tempfile

    from rosbags.typesys import Stores, get_typestore

    from aslam.cli.app import main

    rows = bag_messages(get_typestore(Stores.ROS2_HUMBLE), Options(compressed=True))
    at = [i for i, (_log, topic, _type, _msg) in enumerate(rows) if "image" in topic][5]
    log, topic, datatype, msg = rows[at]
    garbage = np.frombuffer(b"\x89PNG garbage", np.uint8)
    rows[at] = (log, topic, datatype, dataclasses.replace(msg, data=garbage))
    path = write_rosbag2(tmp_path / "bag", messages=rows, compression="file")
    temporary = tmp_path / "tmp"
    temporary.mkdir()
    monkeypatch.setenv("TMPDIR", str(temporary))
    monkeypatch.setattr(tempfile, "tempdir", None)  # read TMPDIR again, in this process and its fork
    assert main(["estimate", str(path), "-o", str(tmp_path / "e.mcap"), "-q"]) == 2
    assert "image on" in one_error_line(capsys.readouterr().err)
    assert list(temporary.rglob("*")) == []


def test_no_room_to_decompress_a_bag_compressed_by_file_says_where_and_what_to_do(tmp_path):
    """rosbags decompresses a rosbag2 bag compressed by file whole into TMPDIR; where that cannot
    hold it (a small tmpfs /tmp, a quota; here the process's file size limit) the error was a bare
    "No space left on device", with no word of which folder filled or how to point it elsewhere."""
    import resource

    from rosbags.typesys import Stores, get_typestore

    rows = bag_messages(get_typestore(Stores.ROS2_HUMBLE), Options(compressed=True))
    path = write_rosbag2(tmp_path / "bag", messages=rows, compression="file")
    temporary = tmp_path / "tmp"
    temporary.mkdir()

    def small_files() -> None:  # in the child: no file may grow past 4 KiB (Python ignores SIGXFSZ)
        resource.setrlimit(resource.RLIMIT_FSIZE, (4096, 4096))

    done = subprocess.run(
        [sys.executable, "-m", "aslam", "info", str(path)],
        env={**os.environ, "TMPDIR": str(temporary)},
        preexec_fn=small_files,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 2
    line = one_error_line(done.stderr)
    assert line.startswith(f"aslam: error: {path}: cannot open the bag: OSError: [Errno 27] File too large")
    assert line.endswith(
        f"rosbags decompresses a bag compressed by file whole into the temporary folder ({temporary}):"
        " point TMPDIR at a disk with room for the uncompressed bag"
    )
    assert list(temporary.rglob("*")) == []


def test_a_fifo_in_place_of_a_bags_storage_file_is_refused_not_opened(bags, tmp_path, capsys):
    """A FIFO where a rosbag2 folder's storage file should be blocked every command in open() (with
    sqlite3 storage, inside sqlite's C code, where only SIGKILL ended it; found by a bag fuzz)."""
    from aslam.cli.app import main

    bag = tmp_path / "bag"
    shutil.copytree(bags["rosbag2-mcap"], bag)
    (storage,) = [f for f in bag.iterdir() if f.name != "metadata.yaml"]
    storage.unlink()
    os.mkfifo(storage)
    for args in (["info", str(bag)], ["estimate", str(bag), "-o", str(tmp_path / "e.mcap")]):
        assert main(args) == 2
        assert one_error_line(capsys.readouterr().err) == (
            f"aslam: error: {bag}: {storage.name} in it is not a regular file"
            " (a FIFO, socket, device or folder)"
        )


def test_namespaced_tf_frames_are_named_from_the_command_line(tmp_path, capsys, recording):
    """The error told the user to name the frames, which only Python's BagTopics could:
    ``--odom-frame`` and ``--base-frame`` do it for ``estimate`` and ``info``; a recording refuses them."""
    from aslam.cli.app import main
    from aslam.data_formats.estimate import read_estimate

    def namespaced(_ts, transforms):
        return [(f"robot1/{parent}", f"robot1/{child}", pose) for parent, child, pose in transforms]

    path = write_rosbag2(tmp_path / "bag", messages=_tf_rows(namespaced))
    out = tmp_path / "e.mcap"
    assert main(["estimate", str(path), "-o", str(out)]) == 2
    line = one_error_line(capsys.readouterr().err)
    assert "(transforms seen: robot1/map → robot1/odom, robot1/odom → robot1/base_footprint)" in line
    assert "--odom-frame, --base-frame" in line
    frames = ["--odom-frame", "robot1/odom", "--base-frame", "robot1/base_footprint"]
    assert main(["estimate", str(path), "-o", str(out), *frames, "--no-timing"]) == 0
    assert main(["info", str(path), *frames, "--json", str(tmp_path / "i.json")]) == 0
    assert read_estimate(out).metadata.topics == {"image": None, "odometry": None, "ground_truth": None}
    capsys.readouterr()
    assert main(["estimate", str(recording), "-o", str(tmp_path / "f.mcap"), *frames[2:]]) == 2
    assert "--base-frame chooses a bag's odometry on /tf" in one_error_line(capsys.readouterr().err)


def test_two_image_topics_is_one_error_listing_them(tmp_path):
    path = write_rosbag2(tmp_path / "two", Options(extra_image_topic=True), storage="sqlite3")
    with pytest.raises(BagError) as caught:
        next(iter_bag_samples(path))
    message = str(caught.value)
    assert message.startswith(f"{path}: 2 image topics: ")
    assert "/camera/color/image_raw (sensor_msgs/msg/Image)" in message
    assert "/camera/depth/image_rect_raw (sensor_msgs/msg/Image)" in message
    assert "--image-topic" in message and "\n" not in message
    # Naming one resolves it.
    assert_driver_samples(
        list(iter_bag_samples(path, BagTopics(image=IMAGE_TOPIC, ground_truth="/ground_truth")))
    )
    assert summarize_bag(path).problem == message.split(": ", 1)[1]


@pytest.mark.parametrize(
    ("options", "topics", "needle"),
    [
        (Options(odometry="none"), BagTopics(), "no odometry: neither a nav_msgs/msg/Odometry topic nor"),
        (
            Options(odometry="none"),
            BagTopics(),
            "; name a pose topic with --odometry-topic, e.g. /ground_truth (its name says ground truth: "
            "estimated on it, the scores would compare it with itself)",
        ),
        (Options(), BagTopics(ground_truth="/gps"), "no ground-truth topic '/gps' (topics in the bag: "),
        (Options(), BagTopics(odometry=IMAGE_TOPIC), f"odometry topic '{IMAGE_TOPIC}' has type"),
        (Options(), BagTopics(image="/odom"), "image topic '/odom' has type 'nav_msgs/msg/Odometry'"),
    ],
)
def test_topic_problems_are_one_line(tmp_path, options, topics, needle):
    path = write_rosbag2(tmp_path / "bag", options)
    with pytest.raises(BagError) as caught:
        list(iter_bag_samples(path, topics))
    assert needle in str(caught.value) and "\n" not in str(caught.value)


def test_the_no_odometry_hint_names_a_pose_topic_called_odometry_before_the_ground_truth(tmp_path):
    """Without an Odometry topic or /tf the error suggests a pose topic for --odometry-topic: it
    took the first by name, ``/ground_truth`` before ``/wheel/odom_pose``, and a run estimated on
    the truth is scored against itself."""
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    rows = bag_messages(ts, Options(odometry="none"))
    rows += [
        (
            stamp + 1_000_000,
            "/wheel/odom_pose",
            "geometry_msgs/msg/PoseStamped",
            pose_stamped_msg(ts, stamp, odometry_pose(stamp)),
        )
        for stamp in odometry_stamps()
    ]
    path = write_rosbag2(tmp_path / "bag", messages=sorted(rows, key=lambda row: row[0]))
    with pytest.raises(BagError) as caught:
        list(iter_bag_samples(path))
    assert str(caught.value).endswith("; name a pose topic with --odometry-topic, e.g. /wheel/odom_pose")


def test_compressed_images_with_no_format_are_read_by_their_bytes(tmp_path):
    """Some drivers leave CompressedImage.format empty; the bytes say PNG (or JPEG) all the same."""
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    rows = bag_messages(ts, Options(compressed=True))
    images = [msg for _log, topic, _type, msg in rows if topic == f"{IMAGE_TOPIC}/compressed"]
    assert images
    for msg in images:
        msg.format = ""
    path = write_rosbag2(tmp_path / "bag", messages=rows)
    assert_driver_samples(list(iter_bag_samples(path, WITH_TRUTH)), gray_tolerance=1)
    for msg in images:
        msg.data = np.frombuffer(b"GIF89a" + bytes(msg.data[6:]), np.uint8)
    path = write_rosbag2(tmp_path / "gif", messages=rows)
    with pytest.raises(
        RecordingError,
        match=f"encoding '' and its bytes are neither PNG nor JPEG on '{IMAGE_TOPIC}/compressed'",
    ):
        list(iter_bag_samples(path))


def test_a_compressed_depth_topic_is_refused_as_depth_not_as_an_unknown_png(tmp_path):
    """compressed_depth_image_transport's format names png ("16UC1; compressedDepth png") and its data
    is a 12-byte header and a 16-bit PNG of depths: the error said '(accepted: png, jpeg)' alone."""
    import struct

    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    rows = bag_messages(ts, Options(compressed=True))
    for _log, topic, _type, msg in rows:
        if topic == f"{IMAGE_TOPIC}/compressed":
            depth_mm = np.full((HEIGHT, WIDTH), 1500, np.uint16)
            header = struct.pack("<iff", 0, 0.0, 0.0)  # ConfigHeader: format, depthParam[2]
            msg.format = "16UC1; compressedDepth png"
            msg.data = np.frombuffer(header + cv2.imencode(".png", depth_mm)[1].tobytes(), np.uint8)
    path = write_rosbag2(tmp_path / "bag", messages=rows)
    with pytest.raises(RecordingError) as caught:
        list(iter_bag_samples(path))
    assert str(caught.value) == (
        f"{path}: unknown image encoding '16UC1; compressedDepth png' (a depth map, "
        f"compressed_depth_image_transport's, not a camera image) on '{IMAGE_TOPIC}/compressed' at stamp "
        f"{T0_NS} ns (accepted: png, jpeg)"
    )


def test_unknown_encoding_names_topic_and_stamp(tmp_path):
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    rows = bag_messages(ts)
    for _log, topic, _type, msg in rows:
        if topic == IMAGE_TOPIC:
            msg.encoding = "hsv8"
    path = write_rosbag2(tmp_path / "bag", messages=rows)
    with pytest.raises(
        RecordingError, match=f"unknown image encoding 'hsv8' on '{IMAGE_TOPIC}' at stamp {T0_NS} ns"
    ):
        list(iter_bag_samples(path))


def test_truncated_image_data_names_the_stamp(tmp_path):
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    rows = bag_messages(ts)
    for _log, topic, _type, msg in rows:
        if topic == IMAGE_TOPIC:
            msg.data = msg.data[:-1]
    path = write_rosbag2(tmp_path / "bag", messages=rows)
    sample = next(iter_bag_samples(path))
    # The message is named by its topic and stamp, as a bad encoding is (a bag may hold two cameras).
    problem = f"{WIDTH * HEIGHT * 3 - 1} bytes do not hold a {WIDTH}x{HEIGHT} bgr8 image"
    with pytest.raises(
        InputError, match=rf"^{path}: image on '{IMAGE_TOPIC}' at stamp {T0_NS} ns: {problem} "
    ):
        sample.image.decode_gray()


def test_open_source_tells_inputs_apart(tmp_path, bags):
    recording = tmp_path / "ours.mcap"
    from aslam.data_formats.camera import CameraIntrinsics

    with RecordingWriter(recording, camera=CameraIntrinsics(8, 6, 60.0), metadata={"seed": "1"}) as writer:
        writer.write(T0_NS, encode_image(np.zeros((6, 8, 3), np.uint8)), np.zeros(3), None)
    assert open_source(recording) is SourceKind.RECORDING
    assert len(list(Recording(recording).samples())) == 1
    bare = tmp_path / "bare.mcap"  # a recording whose metadata record is empty is still ours
    with RecordingWriter(bare, camera=CameraIntrinsics(8, 6, 60.0), metadata={}) as writer:
        writer.write(T0_NS, encode_image(np.zeros((6, 8, 3), np.uint8)), np.zeros(3), None)
    assert open_source(bare) is SourceKind.RECORDING
    folder = tmp_path / "images"
    folder.mkdir()
    cv2.imwrite(str(folder / "0001.png"), np.zeros((4, 4), np.uint8))
    assert open_source(folder) is SourceKind.IMAGE_FOLDER
    # The frames import takes, and only those: a .jfif or upper-case .JPG is one; macOS's ._NAME.png
    # (AppleDouble metadata, not an image) is not.
    for name, kind in (("0001.JFIF", SourceKind.IMAGE_FOLDER), ("._0001.png", None)):
        other = tmp_path / f"images-{kind}"
        other.mkdir()
        shutil.copy(folder / "0001.png", other / name)
        if kind is None:
            with pytest.raises(BagError, match=r"neither a rosbag2 metadata\.yaml nor png/jpg images"):
                open_source(other)
        else:
            assert open_source(other) is kind
    renamed = tmp_path / "driver.dat"
    shutil.copy(bags["rosbag1"], renamed)
    cases = {
        tmp_path / "missing.bag": "no such file or folder",
        tmp_path: "neither a rosbag2 metadata.yaml nor png/jpg images",
        renamed: "is a ROS 1 bag but its name does not end in '.bag'",
        next(bags["rosbag2-mcap-zstd-file"].glob("*.zstd")): "pass the rosbag2 folder",
    }
    (tmp_path / "notes.txt").write_text("hello")
    cases[tmp_path / "notes.txt"] = "not a recording or a bag"
    for path, needle in cases.items():
        with pytest.raises(BagError) as caught:
            open_source(path)
        assert needle in str(caught.value), path
    with pytest.raises(BagError, match="is a recording, not a ROS bag"):
        iter_bag_samples(recording)


def test_damaged_metadata_is_one_line(tmp_path):
    path = write_rosbag2(tmp_path / "bag")
    (path / "metadata.yaml").write_text("rosbag2_bagfile_information: {version: 9}\n")
    with pytest.raises(BagError) as caught:
        list(iter_bag_samples(path))
    assert str(caught.value).startswith(f"{path}: cannot open the bag: ")
    assert "\n" not in str(caught.value)


@pytest.mark.parametrize("kind", ["rosbag2 mcap file", "rosbag1"])
def test_a_bag_cut_short_says_how_to_rebuild_its_index(tmp_path, kind):
    """A recorder killed before closing its bag leaves no index (an MCAP file with no footer, a ROS 1
    bag with no index records): rosbags cannot read it, so the error says how to repair it."""
    if kind == "rosbag1":
        path = write_rosbag1(tmp_path / "cut.bag")
    else:
        path = next(write_rosbag2(tmp_path / "bag").glob("*.mcap"))
    data = path.read_bytes()
    path.write_bytes(data[: len(data) * 2 // 3])
    with pytest.raises(BagError) as caught:
        list(iter_bag_samples(path))
    message = str(caught.value)
    assert message.startswith(f"{path}: cannot open the bag: ") and "\n" not in message
    assert "rebuild it on a copy with 'ros2 bag reindex' (ROS 2) or 'rosbag reindex' (ROS 1)" in message


def test_our_mcap_reader_agrees_on_the_lone_rosbag2_file(bags):
    """Two independent readers (mcap + mcap_ros2 vs rosbags) of one file: the same samples."""
    from aslam.data_formats.recording import RecordingTopics

    topics = RecordingTopics(image=IMAGE_TOPIC, odometry="/odom", ground_truth="/ground_truth")
    assert_driver_samples(list(Recording(bags["rosbag2-file"]).samples(topics)))


def test_a_sqlite3_bag_without_message_definitions_reads_with_the_latest_types(tmp_path):
    """Bags from before ROS 2 Iron store no definitions; rosbags' own type store stands in."""
    import sqlite3

    path = write_rosbag2(tmp_path / "humble", storage="sqlite3")
    (db,) = path.glob("*.db3")
    with sqlite3.connect(db) as connection:
        connection.execute("DELETE FROM message_definitions")
    assert_driver_samples(list(iter_bag_samples(path, WITH_TRUTH)))


def test_ros1_frames_with_a_leading_slash(tmp_path):
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    rows = bag_messages(ts, Options(odometry="tf"))
    for _log, topic, _type, msg in rows:
        if topic == "/tf":
            for transform in msg.transforms:
                transform.header.frame_id = "/" + transform.header.frame_id
                transform.child_frame_id = "/" + transform.child_frame_id
    path = write_rosbag2(tmp_path / "bag", messages=rows)
    assert_driver_samples(list(iter_bag_samples(path, WITH_TRUTH)))


def _damaged(tmp_path: Path, topic: str, change) -> Path:
    from rosbags.typesys import Stores, get_typestore

    rows = bag_messages(get_typestore(Stores.ROS2_HUMBLE))
    matching = [msg for _log, t, _type, msg in rows if t == topic]
    change(matching)
    return write_rosbag2(tmp_path / "bag", messages=rows)


def test_two_frames_logged_swapped_lose_the_late_one_not_the_bag(tmp_path):
    """A driver's threads log frames 3 and 4 swapped: frame 3, logged after 4, is let go and said."""

    def swap(msgs):
        msgs[3].header.stamp, msgs[4].header.stamp = msgs[4].header.stamp, msgs[3].header.stamp

    path = _damaged(tmp_path, IMAGE_TOPIC, swap)
    warnings: list[str] = []
    samples = list(iter_bag_samples(path, on_warning=warnings.append))
    assert len(samples) == N_IMAGES - 1
    assert [s.stamp_ns for s in samples] == sorted(s.stamp_ns for s in samples)
    assert warnings == [f"{path}: dropped 1 image(s) stamped before an image logged earlier (out of order)"]


def _every_frame_twice(rows: list[tuple[int, str, str, Any]]) -> None:
    rows += [(log + 1_000, topic, kind, msg) for log, topic, kind, msg in rows if topic == IMAGE_TOPIC]
    rows.sort(key=lambda row: row[0])


@pytest.mark.parametrize("ros", [1, 2])
def test_every_frame_logged_twice_is_read_once(tmp_path, ros):
    """A frame repeated at its stamp (a camera topic recorded twice over) is one image: the copies
    are dropped and counted, not paired, counted and estimated as frames of their own (24 samples)."""
    path = driver_bag(tmp_path, ros, _every_frame_twice)
    warnings: list[str] = []
    assert_driver_samples(list(iter_bag_samples(path, WITH_TRUTH, on_warning=warnings.append)))
    assert warnings == [
        f"{path}: dropped {N_IMAGES} image(s) stamped the same as the image before (a frame logged twice)"
    ]


def test_a_camera_clock_that_jumps_ahead_is_refused_not_run_on_what_is_left(tmp_path):
    """One frame stamped an hour ahead would put every later frame "out of order": the bag is
    refused, naming the jump, instead of running on the few frames before it."""

    def jump(msgs):
        msgs[2].header.stamp.sec += 3600

    path = _damaged(tmp_path, IMAGE_TOPIC, jump)
    with pytest.raises(
        RecordingError, match=r"bag: image stamps go backwards at 3 of 6 images .* the camera.s clock jumps"
    ):
        list(iter_bag_samples(path))


def _nan_at_10(msgs):
    msgs[10].pose.pose.position.x = float("nan")


def _jump_from_20(msgs):
    for msg in msgs[20:]:
        msg.pose.pose.position.x += 1e6


def _before_1970(msgs):
    for msg in msgs:
        msg.header.stamp.sec -= 1_700_000_005


@pytest.mark.parametrize(
    "change, problem",
    [
        (_nan_at_10, r"odometry pose on '/odom' at stamp \d+ ns is not finite"),
        # a recording's plausibility bounds: a 10⁶ m jump would overflow the pose arithmetic
        (_jump_from_20, r"odometry pose on '/odom' at stamp \d+ ns jumps 1e\+06 m"),
        # an MCAP time is unsigned: a stamp before 1970 could never be written to the estimate file
        (_before_1970, r"odometry stamp on '/odom' is -\d+ ns, before 1970"),
    ],
)
def test_bad_odometry_is_one_error(tmp_path, change, problem):
    with pytest.raises(BagError, match=problem):
        list(iter_bag_samples(_damaged(tmp_path, "/odom", change)))


def test_unset_header_stamps_fall_back_to_the_log_time(tmp_path):
    def unset(msgs):
        for msg in msgs:
            msg.header.stamp.sec, msg.header.stamp.nanosec = 0, 0

    path = _damaged(tmp_path, IMAGE_TOPIC, unset)
    samples = list(iter_bag_samples(path))
    assert [s.stamp_ns for s in samples] == [stamp + IMAGE_LATENCY_NS for stamp in image_stamps()]


def _unset_image_stamps_logged_on(rows: list[tuple[int, str, str, Any]], clock_ns: int) -> None:
    """Images with unset stamps, logged on another clock (``clock_ns`` later) than the odometry's."""
    for k, (log, topic, msgtype, msg) in enumerate(rows):
        if topic == IMAGE_TOPIC:
            msg.header.stamp.sec, msg.header.stamp.nanosec = 0, 0
            rows[k] = (log + clock_ns, topic, msgtype, msg)
    rows.sort(key=lambda row: row[0])


def test_unset_image_stamps_on_another_clock_than_the_odometry_are_refused(tmp_path):
    """Images with unset stamps logged on the wall clock, odometry stamped in a simulator's time:
    no image falls within the odometry. Refused (it was an estimate of nothing, exit 0, behind a
    warning), the error saying which clock the images took."""
    from rosbags.typesys import Stores, get_typestore

    rows = bag_messages(get_typestore(Stores.ROS2_HUMBLE))
    _unset_image_stamps_logged_on(rows, 1_700_000_000_000_000_000)
    path = write_rosbag2(tmp_path / "bag", messages=rows)
    with pytest.raises(
        BagError, match=rf"\({N_IMAGES} image\(s\) had no header stamp and took their log time\)"
    ):
        list(iter_bag_samples(path))


def test_unset_image_stamps_partly_outside_the_odometry_say_which_clock_they_took(tmp_path):
    """Logged 0.3 s late on the odometry's clock, the last images fall after the last odometry
    message: they are dropped, and the warning says the images took their log time."""
    from rosbags.typesys import Stores, get_typestore

    rows = bag_messages(get_typestore(Stores.ROS2_HUMBLE))
    _unset_image_stamps_logged_on(rows, 300_000_000)
    path = write_rosbag2(tmp_path / "bag", messages=rows)
    warnings: list[str] = []
    samples = list(iter_bag_samples(path, on_warning=warnings.append))
    assert 0 < len(samples) < N_IMAGES
    assert any("stamped after the last odometry message" in w for w in warnings)
    assert warnings[-1] == (
        f"{path}: {N_IMAGES} image(s) had no header stamp and took their log time, which may be another "
        "clock than the odometry's (a simulator's, say)"
    )


def _stamped_from_1970(rows: list[tuple[int, str, str, Any]]) -> None:
    """A camera whose clock was never set: its stamps count from 1970 (here, 100 s from its start)."""
    for _log, topic, _type, msg in rows:
        if topic == IMAGE_TOPIC:
            msg.header.stamp.sec -= T0_NS // 1_000_000_000 - 100


@pytest.mark.parametrize("ros", [1, 2])
def test_images_on_another_clock_than_the_odometry_are_refused_naming_both(tmp_path, ros):
    """Every image stamped outside the odometry (a camera clock never set, a driver's own clock, a
    stamp in nanoseconds taken for microseconds) is one error naming the topics and the stamps; it
    was an estimate of no keyframe, exit 0, with a warning that 12 images were dropped."""
    path = driver_bag(tmp_path, ros, _stamped_from_1970)
    first, last = (stamp - T0_NS + 100_000_000_000 for stamp in (image_stamps()[0], image_stamps()[-1]))
    with pytest.raises(BagError) as caught:
        list(iter_bag_samples(path))
    assert str(caught.value) == (
        f"{path}: no image on '{IMAGE_TOPIC}' is stamped within the odometry on '/odom': the images from "
        f"{first} to {last} ns, the odometry from {odometry_stamps()[0]} to {odometry_stamps()[-1]} ns, "
        f"{(odometry_stamps()[0] - last) / 1e9:,.3f} s before it: the two clocks differ (a clock never set "
        "counts from 1970, a driver's own from its start; or stamps in another unit)"
    )


def test_images_on_another_clock_than_the_tf_odometry_are_refused(tmp_path):
    path = write_rosbag1(tmp_path / "driver.bag", Options(odometry="tf"), edit=_stamped_from_1970)
    with pytest.raises(BagError, match=r"within the odometry on '/tf' \(odom → base_footprint\): the images"):
        list(iter_bag_samples(path))


def test_an_odometry_topic_without_messages_is_refused(tmp_path):
    """rosbag2 lists a topic it subscribed to even when nothing was published on it."""
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    path = tmp_path / "bag"
    with Writer(path, version=9) as writer:
        writer.add_connection("/odom", "nav_msgs/msg/Odometry", typestore=ts)
        images = writer.add_connection(IMAGE_TOPIC, "sensor_msgs/msg/Image", typestore=ts)
        for i, stamp in enumerate(image_stamps()):
            msg = raw_image_msg(ts, stamp, bgr_image(i))
            writer.write(images, stamp, ts.serialize_cdr(msg, "sensor_msgs/msg/Image"))
    with pytest.raises(
        BagError,
        match=rf"^{path}: {N_IMAGES} image\(s\) on '{IMAGE_TOPIC}' and no odometry message on '/odom'",
    ):
        list(iter_bag_samples(path))


def test_ground_truth_stream(bags):
    from aslam.data_formats.rosbag_source import iter_bag_ground_truth

    for name in ("rosbag1", "rosbag2-sqlite3"):
        rows = list(iter_bag_ground_truth(bags[name], "/ground_truth"))
        assert [stamp for stamp, _pose in rows] == odometry_stamps()
        for stamp, pose in rows:
            np.testing.assert_allclose(pose, true_pose(stamp), atol=1e-9)
    with pytest.raises(BagError, match="no ground-truth topic '/gps'"):
        list(iter_bag_ground_truth(bags["rosbag1"], "/gps"))
    with pytest.raises(BagError, match="ground-truth topic '/camera/color/image_raw' has type"):
        list(iter_bag_ground_truth(bags["rosbag1"], IMAGE_TOPIC))


def test_ground_truth_far_beyond_any_map_is_refused(tmp_path):
    from aslam.data_formats.rosbag_source import iter_bag_ground_truth

    def far(msgs):
        msgs[5].pose.position.x = 1e300

    path = _damaged(tmp_path, "/ground_truth", far)
    with pytest.raises(BagError, match=r"ground-truth pose on '/ground_truth' .* beyond the plausible"):
        list(iter_bag_ground_truth(path, "/ground_truth"))


def test_a_focal_length_too_short_for_a_field_of_view_is_no_camera(tmp_path):
    def tiny(msgs):
        for msg in msgs:
            msg.k = np.array([1e-300, 0, 11.5, 0, 1e-300, 7.5, 0, 0, 1])

    assert describe_bag(_damaged(tmp_path, "/camera/color/camera_info", tiny)).camera is None


def test_what_the_camera_model_leaves_out_of_a_camera_info_is_said(tmp_path):
    """aslam's camera is a centred pinhole with square pixels and no distortion, from fx alone:
    ``info`` showed a bag's fy 110, principal point (70, 66) and distortion as fy 120 and the
    centre, in silence. A centred, undistorted K (the other tests' bags) says nothing."""

    def real_lens(msgs):
        for msg in msgs:
            msg.k = np.array([20.0, 0, 9.0, 0, 18.0, 7.5, 0, 0, 1])
            msg.d = np.array([-0.3, 0.1, 0.0, 0.0, 0.0])

    warnings: list[str] = []
    path = _damaged(tmp_path, "/camera/color/camera_info", real_lens)
    info = describe_bag(path, WITH_TRUTH, on_warning=warnings.append)
    assert info.camera is not None and info.camera.fx == pytest.approx(20.0)
    said = [w for w in warnings if "camera info" in w]
    assert said == [
        f"{path}: camera info on '/camera/color/camera_info': aslam's camera is a centred pinhole with"
        " square pixels and no distortion, from fx alone; fy 18 (fx 20); principal point (9, 7.5), the"
        " centre being (11.5, 7.5); distortion (-0.3, 0.1, 0, 0, 0): not used"
    ]
    warnings.clear()
    describe_bag(write_rosbag2(tmp_path / "plain"), WITH_TRUTH, on_warning=warnings.append)
    assert not [w for w in warnings if "camera info" in w]


def _camera_bag(
    tmp_path: Path, seconds: float, camera_hz: int, odometry_at: Callable[[int], bool], odometry_hz: int = 50
) -> Path:
    """Raw images at ``camera_hz`` for ``seconds``, odometry at ``odometry_hz`` (from 7 ms before the
    first image to after the last) where ``odometry_at(stamp)``."""
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    frame = np.zeros((HEIGHT, WIDTH, 3), np.uint8)
    rows = [
        (stamp + IMAGE_LATENCY_NS, IMAGE_TOPIC, "sensor_msgs/msg/Image", raw_image_msg(ts, stamp, frame))
        for stamp in (T0_NS + i * 1_000_000_000 // camera_hz for i in range(round(seconds * camera_hz)))
    ]
    rows += [
        (stamp + 1_000_000, "/odom", "nav_msgs/msg/Odometry", odometry_msg(ts, stamp, odometry_pose(stamp)))
        for stamp in range(
            T0_NS - 7_000_000,
            T0_NS + int(seconds * 1e9) + 1_000_000_000 // odometry_hz,
            1_000_000_000 // odometry_hz,
        )
        if odometry_at(stamp)
    ]
    return write_rosbag2(tmp_path / "bag", messages=sorted(rows, key=lambda row: row[0]))


def test_images_at_60_hz_after_odometry_that_ended_early_are_counted_after_it(tmp_path):
    """Odometry stops 11 s before a 60 Hz camera: 660 images wait for it, more than the 512 held.
    Every one is after the last odometry message; the first 148 let go were said to be "in odometry
    gaps" (a gap the odometry never closed)."""
    path = _camera_bag(tmp_path, 14.0, 60, lambda stamp: stamp < T0_NS + 3_000_000_000)
    warnings: list[str] = []
    assert len(list(iter_bag_samples(path, on_warning=warnings.append))) == 180
    last = T0_NS + 2_993_000_000
    assert warnings == [
        f"{path}: dropped 660 image(s) stamped after the last odometry message (at {last} ns)"
    ]


def test_images_at_60_hz_in_a_long_odometry_gap_are_counted_in_it(tmp_path):
    """A 10 s gap in the odometry (1.993 s to 12.013 s, logged 1 ms later) has 600 images at 60 Hz
    wait for it (the one at 12 s is logged after): the 88 beyond the 512 held are let go, counted as
    in a gap once the odometry comes back (as before the images after the last odometry message
    were told apart)."""
    path = _camera_bag(tmp_path, 14.0, 60, lambda stamp: not T0_NS + 2e9 < stamp < T0_NS + 12e9)
    warnings: list[str] = []
    assert len(list(iter_bag_samples(path, on_warning=warnings.append))) == 840 - 88
    assert warnings == [
        f"{path}: dropped 88 image(s) in odometry gaps longer than 512 images or 256 MiB of them",
        f"{path}: 513 image(s) between odometry messages more than 2 s apart, their poses a straight line "
        f"across the gap (the longest 10.020 s, from {T0_NS + 1_993_000_000} to {T0_NS + 12_013_000_000} ns)",
    ]


def test_images_paired_across_a_gap_in_the_odometry_are_said(tmp_path):
    """Odometry silent for 3 s (a dropout): the 31 images in it are paired with a straight line
    across it, and a warning says so (nothing was said)."""
    path = _camera_bag(tmp_path, 8.0, 10, lambda stamp: not T0_NS + 2e9 < stamp < T0_NS + 5e9)
    warnings: list[str] = []
    assert len(list(iter_bag_samples(path, on_warning=warnings.append))) == 80
    assert warnings == [
        f"{path}: 31 image(s) between odometry messages more than 2 s apart, their poses a straight line "
        f"across the gap (the longest 3.020 s, from {T0_NS + 1_993_000_000} to {T0_NS + 5_013_000_000} ns)"
    ]


def test_odometry_at_1_hz_is_no_gap(tmp_path):
    path = _camera_bag(tmp_path, 5.0, 10, lambda stamp: True, odometry_hz=1)
    warnings: list[str] = []
    assert len(list(iter_bag_samples(path, on_warning=warnings.append))) == 50
    assert warnings == []


def test_a_ros1_bag_whose_drivers_restarted_reads_as_one(tmp_path):
    """Each topic in two connections (the drivers restarted halfway: new caller ids): rosbags merges
    them by log time, and the samples are those of the bag written in one go."""
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC)
    rows = bag_messages(ts, Options(ground_truth=False))
    restart = image_stamps()[N_IMAGES // 2]
    path = tmp_path / "restarted.bag"
    with Writer(path) as writer:
        connections: dict[tuple[str, bool], Any] = {}
        for log, topic, msgtype, msg in rows:
            key = (topic, log > restart)
            if key not in connections:
                callerid = f"/driver_{'after' if key[1] else 'before'}"
                connections[key] = writer.add_connection(topic, msgtype, typestore=ts, callerid=callerid)
            writer.write(connections[key], log, ts.serialize_ros1(msg, msgtype))
    warnings: list[str] = []
    assert_driver_samples(list(iter_bag_samples(path, on_warning=warnings.append)), ground_truth=False)
    assert warnings == []


@pytest.mark.parametrize("kind", ["rosbag2-mcap", "rosbag1"])
def test_the_geometric_check_reads_a_bags_camera_info(bags, tmp_path, kind):
    """``--geometric-check-m`` scales pixels by the bag's CameraInfo: with one, the estimate runs and
    records the setting; without, one error naming the bag (exit 2's InputError)."""
    from aslam.app.estimate import estimate
    from aslam.core.config import EstimatorConfig
    from aslam.core.errors import InputError
    from aslam.data_formats.estimate import read_estimate

    config = EstimatorConfig(geometric_check_m=0.45)
    summary = estimate(bags[kind], tmp_path / "estimate.mcap", config)
    assert summary.samples == N_IMAGES
    assert read_estimate(tmp_path / "estimate.mcap").metadata.config["geometric_check_m"] == 0.45
    blind = write_rosbag1(tmp_path / "blind.bag", Options(camera_info=False))
    with pytest.raises(InputError, match="camera") as raised:
        estimate(blind, tmp_path / "blind-estimate.mcap", config)
    assert raised.value.path == str(blind) and not (tmp_path / "blind-estimate.mcap").exists()


def test_a_topic_of_two_types_names_both(tmp_path):
    """rosbags gives no type for a topic that carries two; the error said type ''."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    rows = bag_messages(ts)
    stamp = odometry_stamps()[0]
    rows.append(
        (stamp + 1, "/odom", "geometry_msgs/msg/PoseStamped", pose_stamped_msg(ts, stamp, true_pose(stamp)))
    )
    path = tmp_path / "bag"
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        connections: dict[tuple[str, str], Any] = {}
        for log, topic, msgtype, msg in sorted(rows, key=lambda row: row[0]):
            if (topic, msgtype) not in connections:
                connections[topic, msgtype] = writer.add_connection(topic, msgtype, typestore=ts)
            writer.write(connections[topic, msgtype], log, ts.serialize_cdr(msg, msgtype))
    with pytest.raises(
        BagError, match="'/odom' has type 'geometry_msgs/msg/PoseStamped and nav_msgs/msg/Odometry'"
    ):
        list(iter_bag_samples(path, BagTopics(odometry="/odom")))


def test_an_odometry_restart_between_images_is_counted_and_never_interpolated_across(tmp_path):
    """A bag's odometry at 50 Hz restarts on its origin between two 10 Hz images (a driver restarted:
    that message reads exactly (0, 0, 0), the ones after it the motion since). The images before the
    restart have the old frame's poses, and the one between the last message before it and the
    restart takes that last pose, not a blend of the two frames; the ones after, the new frame's,
    and every sample after the restart says so (the estimator's odometry jump)."""
    from rosbags.typesys import Stores, get_typestore

    from aslam.core import se2

    ts = get_typestore(Stores.ROS2_HUMBLE)
    rows = bag_messages(ts, Options(ground_truth=False))
    stamps = odometry_stamps()
    restart_ns, held_ns = stamps[31], stamps[30]  # 613 and 593 ms in: image 6, at 600 ms, between
    origin = odometry_pose(restart_ns)

    def pose(stamp: int) -> np.ndarray:
        return odometry_pose(stamp) if stamp < restart_ns else se2.between(origin, odometry_pose(stamp))

    for k, (log, topic, msgtype, _) in enumerate(rows):
        if topic == "/odom":
            stamp = log - 1_000_000
            message = odometry_msg(ts, stamp, np.zeros(3) if stamp == restart_ns else pose(stamp))
            rows[k] = (log, topic, msgtype, message)
    samples = list(iter_bag_samples(write_rosbag2(tmp_path / "bag", messages=rows)))
    assert [s.stamp_ns for s in samples] == image_stamps()
    assert [s.odometry_restarts for s in samples] == [0] * 7 + [1] * (N_IMAGES - 7)
    for sample in samples:
        stamp = sample.stamp_ns
        expected = odometry_pose(held_ns) if held_ns < stamp < restart_ns else pose(stamp)
        assert np.allclose(sample.odometry_pose, expected, atol=1e-9), stamp
