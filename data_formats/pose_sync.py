"""Pairing camera images with poses interpolated to their stamps, holding only images still waiting.

Real robots publish odometry (and ground truth) at their own rates and latencies; the assembler
turns three time-ordered streams into one ``Sample`` per image with bounded memory.
"""

from __future__ import annotations

from bisect import bisect_right
from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import NamedTuple

import numpy as np

from aslam.core import se2
from aslam.data_formats.errors import RecordingError
from aslam.data_formats.images import LazyImage

# Images held while waiting for the odometry message after them: at most this many, and at most
# MAX_PENDING_BYTES of them as stored. Past either the oldest is dropped (counted and reported):
# memory stays bounded even when odometry stops mid-recording. The bytes bound counts for raw
# cameras: 512 frames of 640 × 480 rgb8 held 450 MiB, of the largest admitted images 12 GiB; it
# still holds 40 raw 1080p frames, over a second of a 30 Hz camera.
MAX_PENDING_IMAGES = 512
MAX_PENDING_BYTES = 256 * 2**20
# Odometry (and ground-truth) poses kept to interpolate images that arrive late, i.e. whose stamp
# is older than the newest pose already read (sensor latency differs between topics): the last
# POSE_HISTORY messages and every one of the last POSE_HISTORY_NS, so neither a slow topic nor a
# fast one (400 Hz fused odometry, a motion-capture truth) loses a late camera; at most
# POSE_HISTORY_MAX, which bounds the memory whatever the rate.
POSE_HISTORY = 256
POSE_HISTORY_NS = 10_000_000_000
POSE_HISTORY_MAX = 65_536
# Messages stamped before one logged earlier on their topic are dropped one by one (two logged
# swapped); once at least this many are, and more than a quarter of the topic's messages so far (a
# clock jumping back and forth, two publishers on one topic), the stamps are refused.
OUT_OF_ORDER_MIN = 3
# How far back an odometry (or ground-truth) stamp may go and be dropped as jitter: a driver's
# threads logging two messages swapped, a stamp taken on receipt, are off by a few milliseconds
# whatever the rate. Further back is a clock that stepped back, which is refused: ntpd steps a clock
# only when it is off by 128 ms or more (it slews it below), a restarted driver's stamps restart,
# another publisher keeps its own clock. A fixed bound, not a number of periods: jitter does not
# grow with the period, and three periods of a 1 Hz odometry would pass a clock stepped back by 3 s.
POSE_STAMP_JITTER_NS = 50_000_000
# Images interpolated between two odometry messages further apart than this are counted and said
# (a dropout, a driver stopped): across it the pose is a straight line, whatever the robot did. Twice
# the period of a 1 Hz odometry, so that slow odometry is not a gap.
ODOMETRY_GAP_WARNED_NS = 2_000_000_000
# Ground truth is interpolated between two messages at most this far apart; inside a longer gap
# (a motion-capture dropout) it is unknown. Odometry is interpolated across any gap: the run needs it.
TRUTH_MAX_GAP_NS = 1_000_000_000


class Sample(NamedTuple):
    stamp_ns: int
    image: LazyImage
    odometry_pose: np.ndarray  # (x_m, y_m, yaw_rad) in the odom frame, at stamp_ns
    ground_truth_pose: np.ndarray | None  # (x_m, y_m, yaw_rad) in the world frame, or None
    odometry_restarts: int = 0  # times odometry restarted on its origin up to stamp_ns (PoseTrack)


_WAIT, _BEFORE, _LATE, _GAP = "wait", "before", "late", "gap"


CONTINUED_STEP = 0.1
"""A step onto the origin within this share of the step before it (in length and direction) continues
that motion (:meth:`PoseTrack._drove_to_origin`)."""
CONTINUED_TURN_RAD = 0.1
"""… and turns within this of the turn before it."""


class PoseTrack:
    """Recent poses of one topic, for interpolation to image stamps.

    An odometry track (``restarts``) also counts the topic's *restarts*: a pose of exactly (0, 0, 0)
    after one that was not. A driver restarted, or odometry reset by a service or by ``aslam record
    --odometry-reset-at``, reports the robot at its origin, so the difference to the pose before
    measures no motion: it reads as a step to wherever the origin lies, in any direction, and one
    short enough passes the estimator's jump test for a motion. Exact, because nothing else lands on
    the origin to the last bit: a robot driving past it misses by some fraction of a millimetre;
    noise-free poses (a simulator's, a pose file of a perfect loop) that land on it by the motion
    they were making, a turn in place there or a step like the one before, are no restart.
    Counted on the messages, before any interpolation, and never interpolated across: an image
    stamped between the last pose before a restart and the restart takes the pose before (the old
    frame's), the next one the new frame's, and each sample says how many restarts came before it
    (the estimator takes the keyframe after one for an odometry jump: docs/estimator.md, "Odometry
    on its origin is a restart"). A restart made while the robot moves, whose first pose is already
    off the origin, is not seen.
    """

    def __init__(
        self,
        history: int = POSE_HISTORY,
        history_ns: int = POSE_HISTORY_NS,
        most: int = POSE_HISTORY_MAX,
        *,
        restarts: bool = False,
    ) -> None:
        self._counts_restarts = restarts  # odometry's; a true pose on the origin is a place like any
        self._stamps: deque[int] = deque(maxlen=most)
        self._poses: deque[np.ndarray] = deque(maxlen=most)
        self._restarts: deque[int] = deque(maxlen=most)  # the count at each pose
        self._history = history
        self._history_ns = history_ns
        self.first_ns: int | None = None
        self.last_ns: int | None = None
        self.count = 0
        self.restarts = 0
        self._at_origin = True  # a track starting at the origin has not restarted

    def add(self, stamp_ns: int, pose: np.ndarray) -> None:
        if self._counts_restarts:
            at_origin = all(float(v) == 0.0 for v in pose)
            if at_origin and not self._at_origin and not self._drove_to_origin():
                self.restarts += 1
            self._at_origin = at_origin
        stamps = self._stamps
        stamps.append(stamp_ns)
        self._poses.append(pose)
        self._restarts.append(self.restarts)
        while len(stamps) > self._history and stamps[0] < stamp_ns - self._history_ns:
            stamps.popleft()
            self._poses.popleft()
            self._restarts.popleft()
        if self.first_ns is None:
            self.first_ns = stamp_ns
        self.last_ns = stamp_ns
        self.count += 1

    def _drove_to_origin(self) -> bool:
        """Whether the robot reached the origin by the motion it was making, not by a restart: a
        turn in place on it (the pose before was there already: a restart would have to find the
        robot on its origin to the last bit), or a step like the one before it (a noise-free pose
        file driven through its origin, or round a loop closed exactly there). Without both, a
        pose file of a perfect loop read as a restart at each return, and its estimate relocalised."""
        if not self._poses:
            return False
        last = self._poses[-1]
        if float(last[0]) == 0.0 and float(last[1]) == 0.0:
            return True
        if len(self._poses) < 2:
            return False
        before = se2.between(self._poses[-2], last)
        now = se2.between(last, np.zeros(3))
        length = float(np.hypot(before[0], before[1]))
        change = float(np.hypot(now[0] - before[0], now[1] - before[1]))
        turn = abs(float(se2.wrap_angle(float(now[2] - before[2]))))
        return change <= CONTINUED_STEP * length and turn <= CONTINUED_TURN_RAD

    def lookup(self, stamp_ns: int, max_gap_ns: int | None = None) -> np.ndarray | str:
        """The pose at ``stamp_ns``, or why not: _WAIT (no pose after it yet), _BEFORE, _LATE, or
        _GAP (between two poses more than ``max_gap_ns`` apart)."""
        return self.lookup_counted(stamp_ns, max_gap_ns)[0]

    def lookup_counted(self, stamp_ns: int, max_gap_ns: int | None = None) -> tuple[np.ndarray | str, int]:
        """``lookup``'s answer, and the restarts up to ``stamp_ns`` (0 where no pose is found)."""
        if self.last_ns is None or stamp_ns > self.last_ns:
            return _WAIT, 0
        stamps = self._stamps
        if stamp_ns < stamps[0]:
            return (_BEFORE if stamps[0] == self.first_ns else _LATE), 0
        j = bisect_right(stamps, stamp_ns) - 1  # the last pose at or before stamp_ns
        restarts = self._restarts[j]
        if stamps[j] == stamp_ns:
            return self._poses[j].copy(), restarts
        t0, t1 = stamps[j], stamps[j + 1]
        if max_gap_ns is not None and t1 - t0 > max_gap_ns:
            return _GAP, 0
        if restarts != self._restarts[j + 1]:  # two frames: the pose before holds
            return self._poses[j].copy(), restarts
        return se2.interpolate(self._poses[j], self._poses[j + 1], (stamp_ns - t0) / (t1 - t0)), restarts

    def span_around(self, stamp_ns: int) -> tuple[int, int]:
        """The stamps of the two poses a ``lookup`` of ``stamp_ns`` found interpolated between (both
        the pose's own when one is at it)."""
        stamps = self._stamps
        j = bisect_right(stamps, stamp_ns) - 1
        return (stamps[j], stamps[j]) if stamps[j] == stamp_ns else (stamps[j], stamps[j + 1])


def _how_far(ns: int) -> str:
    """A step between two stamps, in the unit that shows it against POSE_STAMP_JITTER_NS: seconds
    printed to the millisecond said a stamp 50.4 ms back was ``0.050 s back, more than the 50 ms``."""
    if ns >= 1_000_000_000:
        return f"{ns / 1e9:,.3f} s"
    if ns >= 1_000_000:
        return f"{ns / 1e6:.6f}".rstrip("0").rstrip(".") + " ms"
    return f"{ns:,} ns"


@dataclass
class StampOrder:
    """Which messages of one topic are kept, read in the order logged: those stamped after the last
    kept one. One stamped the same is dropped as a repeat; one stamped before it is dropped as out
    of order, unless it goes back more than ``tolerance_ns`` (a clock stepped back) or at least
    OUT_OF_ORDER_MIN and more than a quarter of the messages so far do (the stamps jump back and
    forth): then the stamps are refused, one RecordingError naming the topic and both stamps."""

    path: Path
    what: str  # whose stamps: "image", "odometry", "ground-truth"
    topic: str | None  # named in the error (None: not known)
    tolerance_ns: int | None = POSE_STAMP_JITTER_NS  # None: any amount back is dropped and counted
    noun: str = "messages"  # what the refusal counts
    cause: str = "two publishers on one topic, or a clock that jumps back and forth"
    messages: int = 0
    repeated: int = 0
    out_of_order: int = 0
    furthest_back_ns: int = 0  # of the out-of-order messages dropped
    last_ns: int | None = None  # of the last message kept

    def admits(self, stamp_ns: int) -> bool:
        """Whether the next message, stamped ``stamp_ns``, is kept (RecordingError: the stamps are
        refused)."""
        self.messages += 1
        last = self.last_ns
        if last is None or stamp_ns > last:
            self.last_ns = stamp_ns
            return True
        if stamp_ns == last:
            self.repeated += 1
            return False
        on = "" if self.topic is None else f" on {self.topic}"
        back_ns = last - stamp_ns
        if self.tolerance_ns is not None and back_ns > self.tolerance_ns:
            raise RecordingError(
                f"{self.what} stamps go backwards{on}: {stamp_ns} ns after {last} ns, {_how_far(back_ns)} "
                f"back, more than the {self.tolerance_ns / 1e6:g} ms a stamp may jitter: a clock stepped "
                "back (NTP), a driver restarted, or a publisher on another clock",
                path=self.path,
            )
        self.out_of_order += 1
        self.furthest_back_ns = max(self.furthest_back_ns, back_ns)
        if self.out_of_order >= OUT_OF_ORDER_MIN and self.out_of_order * 4 > self.messages:
            raise RecordingError(
                f"{self.what} stamps go backwards{on} at {self.out_of_order} of {self.messages} "
                f"{self.noun} (now {stamp_ns} ns after {last} ns): {self.cause}",
                path=self.path,
            )
        return False

    def dropped(self) -> list[str]:
        """The warnings of a pose topic's dropped messages, one line per reason."""
        on = "" if self.topic is None else f" on {self.topic}"
        out = []
        if self.repeated:
            out.append(
                f"{self.path}: dropped {self.repeated} {self.what} message(s){on} stamped the same as the "
                "message before (logged twice)"
            )
        if self.out_of_order:
            out.append(
                f"{self.path}: dropped {self.out_of_order} {self.what} message(s){on} stamped before a "
                f"message logged earlier (out of order, at most {_how_far(self.furthest_back_ns)} back)"
            )
        return out


@dataclass(eq=False)
class _Pending:
    stamp_ns: int
    image: LazyImage
    ground_truth_done: bool = False
    odometry: np.ndarray | None = None
    odometry_restarts: int = 0
    ground_truth: np.ndarray | None = None
    dropped: bool = False


@dataclass
class _Counts:
    before_first: int = 0
    late: int = 0
    gap: int = 0
    after_last: int = 0
    no_ground_truth: int = 0
    in_odometry_gap: int = 0  # paired across a gap of more than ODOMETRY_GAP_WARNED_NS
    longest_odometry_gap: tuple[int, int] = (0, 0)  # (from, to) ns: the longest of those gaps


@dataclass
class SampleAssembler:
    """Pairs images with poses interpolated to their stamps, holding only images still waiting."""

    path: Path
    # The pose topics, as the errors and warnings of their stamps name them (e.g. "'/odom'").
    odometry_topic: str | None = None
    ground_truth_topic: str | None = None
    max_pending: int = MAX_PENDING_IMAGES
    max_pending_bytes: int = MAX_PENDING_BYTES
    # Whether images wait for a ground-truth pose; set once the ground-truth channel is known
    # (on a linear read it may be met after the first images).
    expect_ground_truth: bool = False
    odometry: PoseTrack = field(default_factory=lambda: PoseTrack(restarts=True))
    ground_truth: PoseTrack = field(default_factory=PoseTrack)
    counts: _Counts = field(default_factory=_Counts)
    # Which messages are kept. A reader asks a pose topic's before it reads the pose (a dropped
    # message's is never read, nor checked against the one before): add_odometry and
    # add_ground_truth take only the messages admitted.
    image_stamps: StampOrder = field(init=False)
    odometry_stamps: StampOrder = field(init=False)
    ground_truth_stamps: StampOrder = field(init=False)
    # images whose header stamp was unset, stamped with their log time by the reader
    log_time_images: int = 0
    yielded: int = 0
    first_image_ns: int | None = None
    _pending: deque[_Pending] = field(default_factory=deque)
    _pending_bytes: int = 0  # the stored bytes of the images in _pending
    # Images let go past max_pending while odometry had stopped: in a gap if odometry comes back past
    # the last of them, else after the last odometry message (known only then, or at the end).
    _let_go_waiting: int = 0
    _let_go_last_ns: int = 0

    def __post_init__(self) -> None:
        # An image is dropped however far back (a camera's frames are not interpolated); a clock
        # that jumps ahead would let every later frame go: refused by their count.
        self.image_stamps = StampOrder(
            self.path, "image", None, tolerance_ns=None, noun="images", cause="the camera's clock jumps"
        )
        self.odometry_stamps = StampOrder(self.path, "odometry", self.odometry_topic)
        self.ground_truth_stamps = StampOrder(self.path, "ground-truth", self.ground_truth_topic)

    @property
    def images(self) -> int:
        """Images read, kept or not."""
        return self.image_stamps.messages

    @property
    def last_image_ns(self) -> int | None:
        return self.image_stamps.last_ns

    def add_image(self, stamp_ns: int, image: LazyImage) -> Iterator[Sample]:
        # A frame logged twice (one camera has one view at an instant: a copy would be paired,
        # counted and estimated as another frame) or two logged swapped is let go, and counted.
        if not self.image_stamps.admits(stamp_ns):
            return
        if self.first_image_ns is None:
            self.first_image_ns = stamp_ns
        item = _Pending(stamp_ns, image)
        self._resolve(item)
        if not item.dropped:
            self._pending.append(item)
            self._pending_bytes += len(image.data)
        yield from self._drain()

    def add_odometry(self, stamp_ns: int, pose: np.ndarray) -> Iterator[Sample]:
        """The next odometry pose, stamped after the one before: a reader of messages that may not
        be keeps those ``odometry_stamps`` admits."""
        self.odometry.add(stamp_ns, pose)
        if self._let_go_waiting and stamp_ns >= self._let_go_last_ns:
            self.counts.gap += self._let_go_waiting
            self._let_go_waiting = 0
        for item in self._pending:
            if item.odometry is None and not item.dropped:
                self._resolve(item)
        yield from self._drain()

    def add_ground_truth(self, stamp_ns: int, pose: np.ndarray) -> Iterator[Sample]:
        """The next true pose, stamped after the one before (as ``add_odometry``'s)."""
        self.ground_truth.add(stamp_ns, pose)
        for item in self._pending:
            if not item.ground_truth_done and not item.dropped:
                self._resolve(item)
        yield from self._drain()

    def _resolve(self, item: _Pending) -> None:
        if item.odometry is None:
            found, restarts = self.odometry.lookup_counted(item.stamp_ns)
            if found is _BEFORE or found is _LATE:
                item.dropped = True
                if found is _BEFORE:
                    self.counts.before_first += 1
                else:
                    self.counts.late += 1
                return
            if not isinstance(found, str):
                item.odometry = found
                item.odometry_restarts = restarts
                self._count_gap(item.stamp_ns)
        if self.expect_ground_truth and not item.ground_truth_done:
            found = self.ground_truth.lookup(item.stamp_ns, TRUTH_MAX_GAP_NS)
            if found is _BEFORE or found is _LATE or found is _GAP:
                item.ground_truth_done = True
            elif not isinstance(found, str):
                item.ground_truth = found
                item.ground_truth_done = True

    def _count_gap(self, stamp_ns: int) -> None:
        before, after = self.odometry.span_around(stamp_ns)
        if after - before > ODOMETRY_GAP_WARNED_NS:
            c = self.counts
            c.in_odometry_gap += 1
            if after - before > c.longest_odometry_gap[1] - c.longest_odometry_gap[0]:
                c.longest_odometry_gap = (before, after)

    def _drain(self) -> Iterator[Sample]:
        pending = self._pending
        while pending:
            head = pending[0]
            if head.dropped:
                self._pop()
                continue
            ready = head.odometry is not None and (head.ground_truth_done or not self.expect_ground_truth)
            full = len(pending) > self.max_pending or self._pending_bytes > self.max_pending_bytes
            if not ready and full:
                if head.odometry is None:  # odometry stopped or far too slow: let the oldest go
                    if self.odometry.last_ns is None:
                        self.counts.before_first += 1
                    else:
                        self._let_go_waiting += 1
                        self._let_go_last_ns = head.stamp_ns
                    self._pop()
                    continue
                head.ground_truth_done = True
                ready = True
            if not ready:
                return
            self._pop()
            yield self._sample(head)

    def _pop(self) -> None:
        self._pending_bytes -= len(self._pending.popleft().image.data)

    def _sample(self, item: _Pending) -> Sample:
        self.yielded += 1
        assert item.odometry is not None
        if self.expect_ground_truth and item.ground_truth is None:
            # Counted here, among the samples: an image that odometry drops after its truth was found
            # missing is one dropped image, not also one without ground truth.
            self.counts.no_ground_truth += 1
        return Sample(item.stamp_ns, item.image, item.odometry, item.ground_truth, item.odometry_restarts)

    def finish(self) -> Iterator[Sample]:
        self.counts.after_last += self._let_go_waiting
        self._let_go_waiting = 0
        while self._pending:
            item = self._pending[0]
            self._pop()
            if item.dropped:
                continue
            if item.odometry is None:
                self.counts.after_last += 1
                continue
            yield self._sample(item)

    def unpaired(self, images: str, odometry: str) -> str | None:
        """Why no image was paired, where the images and the odometry never meet: no odometry
        message at all, every image stamped before the first or after the last one (two clocks: a
        camera's never set counts from 1970, a driver's own from its start, a stamp in the wrong unit
        is far off), or the odometry all between two images (some before it, the rest after: no
        offset to give, nor a second clock to blame). The reader refuses with it: an estimate of
        nothing would hide the cause behind a warning. None when an image was paired, none was read,
        or images were lost otherwise (late, in gaps: the warnings say so). ``images`` and
        ``odometry`` name the two streams."""
        c = self.counts
        if self.yielded or self.first_image_ns is None or self.last_image_ns is None or c.late or c.gap:
            return None
        first, last = self.odometry.first_ns, self.odometry.last_ns
        if first is None or last is None:
            return (
                f"{self.images} image(s) on {images} and no odometry message on {odometry} to pair them with"
            )
        a, b = self.first_image_ns, self.last_image_ns
        unset = (
            f" ({self.log_time_images} image(s) had no header stamp and took their log time)"
            if self.log_time_images
            else ""
        )
        if b < first or a > last:
            off_s, side = ((first - b) / 1e9, "before") if b < first else ((a - last) / 1e9, "after")
            why = (
                f"{off_s:,.3f} s {side} it: the two clocks differ (a clock never set counts from 1970, a "
                "driver's own from its start; or stamps in another unit)"
            )
        else:
            why = f"all of it between two images ({c.before_first} image(s) before it, {c.after_last} after)"
        return (
            f"no image on {images} is stamped within the odometry on {odometry}: the images from {a} to "
            f"{b} ns{unset}, the odometry from {first} to {last} ns, {why}"
        )

    def warnings(self) -> list[str]:
        c, first, last = self.counts, self.odometry.first_ns, self.odometry.last_ns
        lines = [
            (
                c.before_first,
                "image(s) stamped before the first odometry message"
                + (f" (at {first} ns)" if first is not None else ""),
            ),
            (
                self.image_stamps.repeated,
                "image(s) stamped the same as the image before (a frame logged twice)",
            ),
            (
                self.image_stamps.out_of_order,
                "image(s) stamped before an image logged earlier (out of order)",
            ),
            (
                c.late,
                "image(s) that arrived after the odometry at their stamp was let go (the last "
                f"{POSE_HISTORY_NS / 1e9:g} s are kept, at least {POSE_HISTORY} and at most "
                f"{POSE_HISTORY_MAX:,} messages)",
            ),
            (
                c.gap,
                f"image(s) in odometry gaps longer than {self.max_pending} images"
                f" or {self.max_pending_bytes / 2**20:g} MiB of them",
            ),
            (
                c.after_last,
                "image(s) stamped after the last odometry message"
                + (f" (at {last} ns)" if last is not None else ""),
            ),
        ]
        out = [f"{self.path}: dropped {count} {what}" for count, what in lines if count]
        out += self.odometry_stamps.dropped() + self.ground_truth_stamps.dropped()
        if self.log_time_images and (c.before_first or c.after_last):
            out.append(
                f"{self.path}: {self.log_time_images} image(s) had no header stamp and took their log time,"
                " which may be another clock than the odometry's (a simulator's, say)"
            )
        if c.in_odometry_gap:
            before, after = c.longest_odometry_gap
            out.append(
                f"{self.path}: {c.in_odometry_gap} image(s) between odometry messages more than "
                f"{ODOMETRY_GAP_WARNED_NS / 1e9:g} s apart, their poses a straight line across the gap "
                f"(the longest {(after - before) / 1e9:.3f} s, from {before} to {after} ns)"
            )
        if c.no_ground_truth:
            out.append(
                f"{self.path}: {c.no_ground_truth} image(s) have no ground truth (stamped outside the "
                f"ground-truth messages, or in a gap of more than {TRUTH_MAX_GAP_NS / 1e9:g} s between two)"
            )
        return out
