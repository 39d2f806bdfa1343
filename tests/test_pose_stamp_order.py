"""Odometry and ground truth whose stamps go back (``pose_sync.StampOrder``), alike in a ROS 1 bag, a
ROS 2 bag and one of our MCAP recordings: a stamp that jitters back (two messages logged swapped, a
message logged twice) is dropped and counted in a warning; a clock stepped back, two publishers on
one topic, stamps that go back again and again are refused in one line naming the file, the topic
and the stamps. Before, a stamp back by any amount refused the whole file in one line naming the two
stamps; a message logged twice was kept in silence."""

from __future__ import annotations

import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import T0_NS, ForeignRecording
from test_rosbag_source import (
    IMAGE_LATENCY_NS,
    IMAGE_TOPIC,
    odometry_msg,
    odometry_pose,
    pose_stamped_msg,
    raw_image_msg,
    tf_msg,
    true_pose,
    write_ros1_rows,
    write_rosbag2,
)

from aslam.data_formats.errors import RecordingError
from aslam.data_formats.images import encode_image
from aslam.data_formats.recording import Recording
from aslam.data_formats.rosbag_source import BagTopics, iter_bag_ground_truth, iter_bag_samples

MS = 1_000_000
CAMERA_PERIOD_NS = 100 * MS  # 10 Hz
IMAGES = 10
KINDS = ["ROS 1", "ROS 2", "MCAP"]
Rows = list[tuple[int, int]]  # (log time, header stamp) of each message of a topic, in log order


def steady(hz: int, seconds: float = IMAGES * CAMERA_PERIOD_NS / 1e9) -> Rows:
    """A topic at ``hz`` from 7 ms before the first image to past the last, logged 1 ms late."""
    period = 1_000_000_000 // hz
    stamps = range(T0_NS - 7 * MS, T0_NS + int(seconds * 1e9) + period, period)
    return [(stamp + MS, stamp) for stamp in stamps]


def write(kind: str, folder: Path, odometry: Rows, truth: Rows | None = None, *, tf: bool = False) -> Path:
    """A ROS 1 or ROS 2 bag (raw images on IMAGE_TOPIC, Odometry on /odom or transforms on /tf,
    PoseStamped truth on /ground_truth) or our MCAP layout (PNG images, /odom, /ground_truth/pose)
    of images at 10 Hz and the pose topics given; each pose is the one of its stamp."""
    truth = steady(100) if truth is None else truth
    images = [T0_NS + i * CAMERA_PERIOD_NS for i in range(IMAGES)]
    frame = np.zeros((16, 24, 3), np.uint8)
    if kind == "MCAP":
        assert not tf
        path = folder / "recording.mcap"
        png = encode_image(frame).data
        rows: list[tuple[int, Callable[[ForeignRecording], None]]] = []
        for log, stamp in odometry:
            rows.append(
                (log, lambda rec, s=stamp, t=log: rec.odometry("/odom", s, *odometry_pose(s), log_time=t))
            )
        for log, stamp in truth:
            rows.append(
                (log, lambda rec, s=stamp, t=log: rec.pose("/ground_truth/pose", s, true_pose(s), log_time=t))
            )
        for stamp in images:
            log = stamp + IMAGE_LATENCY_NS
            rows.append(
                (
                    log,
                    lambda rec, s=stamp, t=log: rec.compressed_image(
                        "/camera/image/compressed", s, png, "png", t
                    ),
                )
            )
        with ForeignRecording(path) as rec:
            for _log, put in sorted(rows, key=lambda row: row[0]):
                put(rec)
        return path
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC if kind == "ROS 1" else Stores.ROS2_HUMBLE)
    if kind == "ROS 1":
        ts.register(
            get_types_from_msg("geometry_msgs/TransformStamped[] transforms", "tf2_msgs/msg/TFMessage")
        )
    messages: list[tuple[int, str, str, Any]] = []
    for log, stamp in odometry:
        pose = odometry_pose(stamp)
        if tf:
            messages.append(
                (log, "/tf", "tf2_msgs/msg/TFMessage", tf_msg(ts, stamp, [("odom", "base_link", pose)]))
            )
        else:
            messages.append((log, "/odom", "nav_msgs/msg/Odometry", odometry_msg(ts, stamp, pose)))
    for log, stamp in truth:
        messages.append(
            (
                log,
                "/ground_truth",
                "geometry_msgs/msg/PoseStamped",
                pose_stamped_msg(ts, stamp, true_pose(stamp)),
            )
        )
    for stamp in images:
        messages.append(
            (stamp + IMAGE_LATENCY_NS, IMAGE_TOPIC, "sensor_msgs/msg/Image", raw_image_msg(ts, stamp, frame))
        )
    messages.sort(key=lambda row: row[0])
    if kind == "ROS 2":
        return write_rosbag2(folder / "bag", messages=messages)
    return write_ros1_rows(folder / "driver.bag", ts, messages)


def read(path: Path) -> tuple[list, list[str]]:
    """The samples and the warnings, as ``estimate`` reads the file."""
    warnings: list[str] = []
    if path.suffix == ".mcap":
        samples = list(Recording(path, on_warning=warnings.append).samples())
    else:
        samples = list(
            iter_bag_samples(path, BagTopics(ground_truth="/ground_truth"), on_warning=warnings.append)
        )
    return samples, warnings


# --- the stamps of a driver ----------------------------------------------------------------------


def swapped(rows: Rows, k: int) -> Rows:
    """Messages k and k + 1 logged swapped (a driver's two threads)."""
    rows = list(rows)
    (log_a, a), (log_b, b) = rows[k], rows[k + 1]
    rows[k], rows[k + 1] = (log_a, b), (log_b, a)
    return rows


def repeated(rows: Rows, k: int) -> Rows:
    """Message k logged twice, 0.1 ms apart."""
    log, stamp = rows[k]
    return [*rows[: k + 1], (log + MS // 10, stamp), *rows[k + 1 :]]


def stepped_back(rows: Rows, k: int, by_ns: int) -> Rows:
    """The clock stepped back by ``by_ns`` before message k (NTP; a driver restarted)."""
    return [(log, stamp - by_ns * (i >= k)) for i, (log, stamp) in enumerate(rows)]


def second_publisher(rows: Rows, offset_ns: int) -> Rows:
    """Every other message from a second publisher whose stamps are ``offset_ns`` from the first's."""
    return [(log, stamp + offset_ns * (i % 2)) for i, (log, stamp) in enumerate(rows)]


# --- what is kept --------------------------------------------------------------------------------


@pytest.mark.parametrize("kind", KINDS)
def test_two_odometry_messages_logged_swapped_at_1_khz_lose_the_late_one_not_the_file(tmp_path, kind):
    """Was refused: `odometry stamps go backwards on '/odom': N ns after M ns`, exit 2, for 1 ms."""
    path = write(kind, tmp_path, swapped(steady(1000), 500))
    samples, warnings = read(path)
    assert len(samples) == IMAGES
    assert warnings == [
        f"{path}: dropped 1 odometry message(s) on '/odom' stamped before a message logged earlier "
        "(out of order, at most 1 ms back)"
    ]
    (tmp_path / "intact").mkdir()
    intact, _ = read(write(kind, tmp_path / "intact", steady(1000)))
    for sample, expected in zip(samples, intact, strict=True):  # the odometry is linear in time
        assert np.allclose(sample.odometry_pose, expected.odometry_pose, atol=1e-9)


@pytest.mark.parametrize("kind", KINDS)
def test_an_odometry_message_logged_twice_is_read_once_and_said(tmp_path, kind):
    """Was kept in silence, as a second pose at the same instant."""
    path = write(kind, tmp_path, repeated(steady(1000), 500))
    samples, warnings = read(path)
    assert len(samples) == IMAGES
    assert warnings == [
        f"{path}: dropped 1 odometry message(s) on '/odom' stamped the same as the message before "
        "(logged twice)"
    ]


@pytest.mark.parametrize("kind", KINDS)
def test_ground_truth_logged_swapped_loses_the_late_message_for_estimate_and_report(tmp_path, kind):
    """Was refused: for estimate, the whole file; for report, the ground truth (scored without it)."""
    truth = swapped(steady(100), 50)
    path = write(kind, tmp_path, steady(1000), truth)
    kept = [stamp for _, stamp in steady(100) if stamp != truth[51][1]]  # the earlier, logged later
    samples, warnings = read(path)
    assert len(samples) == IMAGES and all(s.ground_truth_pose is not None for s in samples)
    topic = "/ground_truth/pose" if kind == "MCAP" else "/ground_truth"
    said = (
        f"{path}: dropped 1 ground-truth message(s) on '{topic}' stamped before a message logged "
        "earlier (out of order, at most 10 ms back)"
    )
    assert warnings == [said]
    report: list[str] = []
    if kind == "MCAP":
        stream = list(Recording(path, on_warning=report.append).ground_truth())
    else:
        stream = list(iter_bag_ground_truth(path, topic, on_warning=report.append))
    assert [stamp for stamp, _ in stream] == kept and report == [said]


@pytest.mark.parametrize("kind", ["ROS 1", "ROS 2"])
def test_transforms_logged_swapped_or_twice_on_tf_are_dropped_and_said(tmp_path, kind):
    """A swapped pair was refused; a repeat was dropped in silence. (``odom → base_link``, the only
    child and REP 105's, is taken without a word.)"""
    path = write(kind, tmp_path, repeated(swapped(steady(1000), 500), 300), tf=True)
    samples, warnings = read(path)
    assert len(samples) == IMAGES
    assert warnings == [
        f"{path}: dropped 1 odometry message(s) on '/tf' (from frame 'odom') stamped the same as the message "
        "before (logged twice)",
        f"{path}: dropped 1 odometry message(s) on '/tf' (from frame 'odom') stamped before a message logged "
        "earlier (out of order, at most 1 ms back)",
    ]


# --- what is refused -----------------------------------------------------------------------------


def refusal(path: Path) -> str:
    with pytest.raises(RecordingError) as caught:
        read(path)
    return str(caught.value)


@pytest.mark.parametrize("kind", KINDS)
def test_a_clock_stepped_back_5_s_is_refused_naming_the_step(tmp_path, kind):
    rows = stepped_back(steady(1000), 500, 5_000_000_000)
    path = write(kind, tmp_path, rows)
    (_, last), (_, now) = rows[499], rows[500]
    assert refusal(path) == (
        f"{path}: odometry stamps go backwards on '/odom': {now} ns after {last} ns, 4.999 s back, more than "
        "the 50 ms a stamp may jitter: a clock stepped back (NTP), a driver restarted, or a publisher on "
        "another clock"
    )


@pytest.mark.parametrize("kind", KINDS)
def test_two_publishers_on_two_clocks_are_refused(tmp_path, kind):
    """A second driver's odometry on /odom, its clock 10 s behind: the first of its messages."""
    path = write(kind, tmp_path, second_publisher(steady(1000), -10_000_000_000))
    assert re.fullmatch(
        rf"{re.escape(str(path))}: odometry stamps go backwards on '/odom': \d+ ns after \d+ ns, "
        r"9\.999 s back, more than the 50 ms a stamp may jitter: .*",
        refusal(path),
    )


@pytest.mark.parametrize("kind", KINDS)
def test_two_publishers_a_few_milliseconds_apart_are_refused_by_their_count(tmp_path, kind):
    """Each message of the second goes back 2 ms, no more than jitter; every other one does."""
    rows = second_publisher(steady(1000), -3 * MS)
    path = write(kind, tmp_path, rows)
    (_, last), (_, now) = rows[4], rows[5]
    assert refusal(path) == (
        f"{path}: odometry stamps go backwards on '/odom' at 3 of 6 messages (now {now} ns after {last} ns): "
        "two publishers on one topic, or a clock that jumps back and forth"
    )


@pytest.mark.parametrize("kind", KINDS)
def test_stamps_that_go_back_again_and_again_are_refused_by_their_count(tmp_path, kind):
    """1 kHz odometry stamped ±3 ms off: a quarter of its messages go back, each by a little."""
    jitter = np.random.default_rng(0).integers(-3 * MS, 3 * MS, 1100)
    rows = [(log, stamp + int(j)) for (log, stamp), j in zip(steady(1000), jitter, strict=False)]
    path = write(kind, tmp_path, rows)
    assert re.fullmatch(
        rf"{re.escape(str(path))}: odometry stamps go backwards on '/odom' at \d+ of \d+ messages "
        r"\(now \d+ ns after \d+ ns\): two publishers on one topic, or a clock that jumps back and forth",
        refusal(path),
    )


def test_odometry_at_1_hz_logged_swapped_is_refused_a_second_is_no_jitter(tmp_path):
    """The tolerance is 50 ms whatever the rate: two messages of a 1 Hz odometry swapped are a
    second apart, as a clock stepped back by a second is."""
    rows = swapped(steady(1, seconds=5.0), 2)
    path = write("ROS 2", tmp_path, rows)
    assert "odometry stamps go backwards on '/odom': " in refusal(path)
    assert ", 1.000 s back, more than the 50 ms a stamp may jitter" in refusal(path)


@pytest.mark.parametrize("kind", KINDS)
def test_report_says_the_ground_truth_it_dropped_though_it_stops_at_its_last_keyframe(tmp_path, kind):
    """``report`` reads the truth up to its last keyframe's stamp and closes the stream there
    (``truth_at_stamps``); the warning of the messages dropped came after the stream's last message,
    so a report of a recording whose truth runs past its last keyframe (most do) never said it."""
    from contextlib import closing

    from aslam.app.score import truth_at_stamps

    path = write(kind, tmp_path, steady(1000), swapped(steady(100), 50))
    topic = "/ground_truth/pose" if kind == "MCAP" else "/ground_truth"
    report: list[str] = []
    if kind == "MCAP":
        stream = Recording(path, on_warning=report.append).ground_truth()
    else:
        stream = iter_bag_ground_truth(path, topic, on_warning=report.append)
    with closing(stream):
        poses = truth_at_stamps([T0_NS + i * CAMERA_PERIOD_NS for i in range(IMAGES)], stream)
    assert not np.isnan(poses).any()
    assert report == [
        f"{path}: dropped 1 ground-truth message(s) on '{topic}' stamped before a message logged "
        "earlier (out of order, at most 10 ms back)"
    ]


def test_how_far_back_a_stamp_went_is_said_in_a_unit_that_shows_it_against_the_50_ms():
    """In seconds to the millisecond, a stamp 50.4 ms back was refused as ``0.050 s back, more than
    the 50 ms a stamp may jitter``, and one 1 ns back was said to be ``at most 1e-06 ms back``."""
    from aslam.data_formats.pose_sync import StampOrder

    order = StampOrder(Path("odom.mcap"), "odometry", "'/odom'")
    assert order.admits(T0_NS) and not order.admits(T0_NS - 1)
    assert order.dropped() == [
        "odom.mcap: dropped 1 odometry message(s) on '/odom' stamped before a message logged earlier "
        "(out of order, at most 1 ns back)"
    ]
    with pytest.raises(RecordingError, match=r", 50\.4 ms back, more than the 50 ms a stamp may jitter"):
        order.admits(T0_NS - 50_400_000)
    with pytest.raises(RecordingError, match=r", 50\.000001 ms back, more than the 50 ms"):
        order.admits(T0_NS - 50_000_001)
