"""Pairing images with poses (``data_formats.pose_sync.SampleAssembler``): whatever order the three
streams interleave in, each image gets the poses at its stamp or is dropped, and counted, for the
reason the documentation gives."""

from __future__ import annotations

import itertools
import math
from bisect import bisect_left
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from aslam.core import se2
from aslam.data_formats.images import LazyImage
from aslam.data_formats.pose_sync import TRUTH_MAX_GAP_NS, PoseTrack, SampleAssembler

PATH = Path("test.mcap")
GAP = TRUTH_MAX_GAP_NS
pose_values = st.tuples(
    st.floats(-100, 100), st.floats(-100, 100), st.floats(-math.pi, math.pi, exclude_max=True)
)


@st.composite
def track(
    draw, gaps: st.SearchStrategy[int], min_size: int, origin: bool = False
) -> list[tuple[int, np.ndarray]]:
    """Poses at strictly increasing stamps; with ``origin``, now and then exactly the origin (an
    odometry restart, where the pose before was not)."""
    values = st.one_of(pose_values, st.just((0.0, 0.0, 0.0))) if origin else pose_values
    stamp = draw(st.integers(0, 5 * GAP))
    rows = []
    for _ in range(draw(st.integers(min_size, 12))):
        rows.append((stamp, np.array(draw(values))))
        stamp += draw(gaps)
    return rows


# gaps around the ground truth's limit, exactly at it, and anything else
truth_gaps = st.one_of(st.sampled_from([GAP - 1, GAP, GAP + 1]), st.integers(1, 3 * GAP))


def restarted(rows: list[tuple[int, np.ndarray]], j: int) -> bool:
    """Whether odometry message ``j`` restarts odometry: exactly the origin after one that was not,
    unless the robot turned in place there (the pose before on the origin's position) or came by a
    step within 10 % and 0.1 rad of the step before it."""
    if j == 0 or rows[j][1].any() or not rows[j - 1][1].any():
        return False
    last = rows[j - 1][1]
    if last[0] == 0 and last[1] == 0:
        return False
    if j < 2:
        return True
    before, now = se2.between(rows[j - 2][1], last), se2.between(last, np.zeros(3))
    turn = abs(math.remainder(float(now[2] - before[2]), math.tau))
    return not (math.dist(now[:2], before[:2]) <= 0.1 * math.hypot(*before[:2]) and turn <= 0.1)


def expected_pose(
    rows: list[tuple[int, np.ndarray]], stamp: int, max_gap_ns: int | None, restarts: bool = False
) -> np.ndarray | None:
    """The pose at ``stamp``: a message's own at its stamp, else interpolated between the two around
    it (unless they are more than ``max_gap_ns`` apart, or, with ``restarts``, the later one
    restarted odometry: then the earlier one's); None outside the messages."""
    stamps = [s for s, _ in rows]
    if not rows or not stamps[0] <= stamp <= stamps[-1]:
        return None
    j = bisect_left(stamps, stamp)
    if stamps[j] == stamp:
        return rows[j][1]
    (t0, p0), (t1, p1) = rows[j - 1], rows[j]
    if max_gap_ns is not None and t1 - t0 > max_gap_ns:
        return None
    if restarts and restarted(rows, j):
        return p0
    return se2.interpolate(p0, p1, (stamp - t0) / (t1 - t0))


@settings(max_examples=150, deadline=None)
@given(
    odometry=track(st.integers(1, 3 * GAP), min_size=0, origin=True),
    truth=track(truth_gaps, min_size=0),
    expect_truth=st.booleans(),
    data=st.data(),
)
def test_every_image_gets_the_poses_at_its_stamp_or_is_counted_dropped(odometry, truth, expect_truth, data):
    """Each image in stamp order is a sample with the odometry at its stamp (a message's own pose at
    its stamp, interpolated between two otherwise, never across a restart on the origin: the pose
    before holds) and the restarts up to it, and the truth likewise, unknown outside the truth or
    across a gap of more than ``TRUTH_MAX_GAP_NS``; or it is dropped before the first or after the
    last odometry message, or as a repeat of the image before (the same stamp). Every image is
    counted once: a sample or a reason."""
    known = [s for s, _ in odometry + truth]
    span = (min(known, default=0) - GAP, max(known, default=0) + GAP)
    anywhere = st.integers(*span)
    stamps = data.draw(
        st.lists(st.one_of(st.sampled_from(known), anywhere) if known else anywhere, max_size=12)
    )
    stamps += [(a + b) // 2 for (a, _), (b, _) in itertools.pairwise(truth)]  # inside each truth gap
    stamps.sort()  # never out of order: each image is paired or dropped for its stamp alone
    # The order the three streams were logged in: each in its own order, interleaved any way.
    order = data.draw(
        st.permutations(["odometry"] * len(odometry) + ["truth"] * len(truth) + ["image"] * len(stamps))
    )

    assembler = SampleAssembler(PATH, expect_ground_truth=expect_truth)
    streams = {"odometry": iter(odometry), "truth": iter(truth), "image": iter(stamps)}
    samples = []
    for kind in order:
        if kind == "odometry":
            samples += assembler.add_odometry(*next(streams[kind]))
        elif kind == "truth":
            samples += assembler.add_ground_truth(*next(streams[kind]))
        else:
            stamp = next(streams[kind])
            samples += assembler.add_image(stamp, LazyImage(b"", "png", path=PATH))
    samples += assembler.finish()

    unique = sorted(set(stamps))
    expected = []
    for stamp in unique:
        odometry_pose = expected_pose(odometry, stamp, None, restarts=True)
        if odometry_pose is not None:
            expected.append(
                (stamp, odometry_pose, expected_pose(truth, stamp, GAP) if expect_truth else None)
            )
    assert [s.stamp_ns for s in samples] == [stamp for stamp, _, _ in expected]
    for sample, (stamp, odometry_pose, truth_pose) in zip(samples, expected, strict=True):
        assert np.array_equal(sample.odometry_pose, odometry_pose)
        before = [j for j, (s, _) in enumerate(odometry) if s <= stamp]
        assert sample.odometry_restarts == sum(restarted(odometry, j) for j in before)
        assert (sample.ground_truth_pose is None) == (truth_pose is None)
        if truth_pose is not None:
            assert np.array_equal(sample.ground_truth_pose, truth_pose)
    counts = assembler.counts
    first, last = (odometry[0][0], odometry[-1][0]) if odometry else (None, None)
    assert counts.before_first == sum(first is not None and s < first for s in unique)
    assert counts.after_last == sum(first is None or s > last for s in unique)
    repeated = assembler.image_stamps.repeated
    assert repeated == len(stamps) - len(unique)
    assert assembler.image_stamps.out_of_order == counts.late == counts.gap == 0
    assert len(samples) + counts.before_first + counts.after_last + repeated == len(stamps)
    assert len(stamps) == assembler.images
    assert counts.no_ground_truth == sum(s.ground_truth_pose is None for s in samples) * expect_truth


def test_odometry_all_between_two_images_is_refused_for_what_the_stamps_show():
    """Odometry that lies between two images, some images before it and the rest after (a short
    stretch of odometry recorded), pairs no image and is refused; the refusal said ``-5.000 s after
    it: the two clocks differ``, an offset below zero and a cause the stamps do not show."""
    s = 1_000_000_000
    assembler = SampleAssembler(PATH)
    for stamp in (1 * s, 2 * s):
        assert not list(assembler.add_image(stamp, LazyImage(b"", "png", path=PATH)))
    for stamp, x in ((4 * s, 0.0), (5 * s, 1.0), (6 * s, 2.0)):
        assert not list(assembler.add_odometry(stamp, np.array([x, 0.0, 0.0])))
    for stamp in (10 * s, 11 * s):
        assert not list(assembler.add_image(stamp, LazyImage(b"", "png", path=PATH)))
    assert not list(assembler.finish())
    assert assembler.unpaired("'/cam'", "'/odom'") == (
        "no image on '/cam' is stamped within the odometry on '/odom': the images from 1000000000 to "
        "11000000000 ns, the odometry from 4000000000 to 6000000000 ns, all of it between two images "
        "(2 image(s) before it, 2 after)"
    )


@pytest.mark.parametrize(
    ("poses", "restarts"),
    [
        # a perfect loop's pose file: back on the origin's position, then a turn in place onto it
        ([(0, 0, 0), (1, 0, 0), (1, 1, math.pi / 2), (0, 1, math.pi), (0, 0, -math.pi / 2), (0, 0, 0)], 0),
        ([(-2, 0, 0), (-1, 0, 0), (0, 0, 0), (1, 0, 0)], 0),  # driven straight through the origin
        ([(0, 0, 0), (1, 0, 0), (2, 0, 0), (0, 0, 0)], 1),  # a restart: 2 m back in one step
        ([(0, 0, 0), (1, 0, 0), (1.5, 0.5, 0.7), (0, 0, 0)], 1),
        ([(3, 1, 0.5), (0, 0, 0)], 1),  # the first step: nothing to continue
    ],
)
def test_a_pose_that_reaches_the_origin_by_its_motion_is_no_restart(poses, restarts):
    """A noise-free pose file (a simulator's, a perfect loop) lands on the origin exactly by the
    motion it was making: it was read as a restart at each return, and its estimate relocalised."""
    track = PoseTrack(restarts=True)
    for i, pose in enumerate(poses):
        track.add(i * 1_000_000_000, np.array(pose, dtype=float))
    assert track.restarts == restarts


def test_images_waiting_for_odometry_are_bounded_by_their_bytes_too():
    """Odometry stops; a raw camera goes on. 512 waiting frames of 640 × 480 rgb8 held 450 MiB (of
    the largest admitted images 12 GiB): the oldest are let go once the waiting images hold
    ``max_pending_bytes``, and counted in the gap when odometry comes back past them."""
    s = 1_000_000_000
    frame = bytes(1000)
    assembler = SampleAssembler(PATH, max_pending_bytes=10_000)
    assert not list(assembler.add_odometry(0, np.zeros(3)))
    held = []
    for i in range(1, 31):
        assert not list(assembler.add_image(i * s, LazyImage(frame, "rgb8", path=PATH)))
        held.append(assembler._pending_bytes)
    assert max(held) == 10_000  # ten frames, never an eleventh
    samples = list(assembler.add_odometry(40 * s, np.array([40.0, 0.0, 0.0])))
    assert [sample.stamp_ns for sample in samples] == [i * s for i in range(21, 31)]
    assert assembler.counts.gap == 20 and assembler._pending_bytes == 0
    assert not list(assembler.finish())
