"""The streaming estimate pipeline behind :func:`aslam.app.estimate.estimate` and the benchmarks.

The floor of an estimate is reading the recording, decoding the keyframe images and describing
them (the observation model's ``describe``). The pipeline keeps the SLAM step off that critical path:

* a producer iterates the samples (MCAP read, CDR decode) and runs the keyframe test, which
  needs odometry only, so non-keyframe images are never decoded — except on a dense stream
  (``keyframe_window_m`` > 0), where every frame a few centimetres from the last is described
  and the keyframes are taken next to the map (:func:`keyframes_taken`);
* those images go to a small thread pool that decodes and describes them
  (OpenCV and numpy release the GIL);
* the futures wait in a bounded FIFO, so memory stays bounded and order is kept;
* where the platform can fork, the producer runs in a child process and sends the keyframes or
  frames (stamp, pose or action, view: 3.2 KiB each at the defaults, the view's 768 numbers) through
  a pipe of 1 MiB where Linux allows it, so the SLAM step, which holds the GIL, runs on the other
  core instead of stalling the decoders, and the reader does not wait on the parent's own start-up.
"""

from __future__ import annotations

import contextlib
import math
import multiprocessing
import os
import signal
import threading
import time
import weakref
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from aslam.core import se2
from aslam.core.errors import AslamError, InputError
from aslam.core.estimator import Estimator, Keyframer, StepResult, StillClock
from aslam.core.geometry import PinholeCamera, ViewFeatures, view_features
from aslam.core.observation import ObservationModel
from aslam.data_formats.images import LazyImage
from aslam.data_formats.pose_sync import Sample

DEFAULT_WORKERS = 2
DESCRIBE_DEPTH = 8
"""Images described ahead of the one the SLAM step waits for: the FIFO that bounds memory."""


class Frame(NamedTuple):
    """One described frame of a dense stream: enough to take it as a keyframe."""

    stamp_ns: int
    odometry_pose: np.ndarray
    view: np.ndarray
    still_ns: int
    """The stream's :class:`StillClock` at this frame."""
    odometry_restarts: int = 0
    """The odometry's restarts up to this frame (``Sample.odometry_restarts``)."""
    features: ViewFeatures | None = None
    """The image's features, for the geometric check (``geometric_check_m``); None without it."""


class Keyframe(NamedTuple):
    stamp_ns: int
    action: np.ndarray
    """Odometry since the previous keyframe."""
    view: np.ndarray
    still_ns: int
    """The stream's :class:`StillClock` at this keyframe."""
    odometry_restarts: int = 0
    """The odometry's restarts up to this keyframe (``Sample.odometry_restarts``)."""
    features: ViewFeatures | None = None
    """The image's features, for the geometric check (``geometric_check_m``); None without it."""


class Clocked(NamedTuple):
    """A sample with the stream's :class:`StillClock` at it, clocked before any sample is skipped."""

    sample: Sample
    still_ns: int


def still_clocked(samples: Iterable[Sample], counts: PipelineCounts) -> Iterator[Clocked]:
    """Each sample, counted, with the stream's still clock at it."""
    clock = StillClock()
    for sample in samples:
        counts.samples += 1
        yield Clocked(sample, clock.tick(sample.stamp_ns, sample.odometry_pose))


@dataclass
class PipelineCounts:
    """Running counts, readable while the pipeline runs (for a progress display)."""

    samples: int = 0
    keyframes: int = 0
    odometry_restarts: int = 0
    """Keyframes after which odometry had restarted on its origin: each an odometry jump."""
    slam_s: float = 0.0
    images: int | None = None
    """Images in the source, once its reader has opened it (its index or summary says); None before,
    or where it cannot say. The reader sets it: a bag opened for the count alone, then again to
    be read, was opened twice (rosbags decompresses a bag compressed by file whole at each open)."""


WINDOW_HEADING_DEG = 20.0
"""A frame is near a keyframe when within ``keyframe_window_m`` and this much heading of it."""
FRAME_SPACING = 1.0 / 16.0
"""On a dense stream a frame is described only once the robot moved this fraction of the window
(or of its heading) since the last frame described: a robot standing still or creeping costs
nothing, and a window never holds more than about 2 / FRAME_SPACING frames."""
MAX_WINDOW_FRAMES = 64
"""At most this many frames before a keyframe, and as many after it, are its alternatives."""
SPARSE_NEIGHBOUR_STEPS = 0.8
"""On a sparse stream (frames farther apart than the window: two per metre, a frame every 0.75 m)
the frame before and the frame after a keyframe are its alternatives when within this many steps
(``step_m``) of it: one pass may keyframe a frame that another skipped (odometry measured it a few
centimetres short of the step), or a route's curves may shift a pass by half a step. A frame a full
step away (one frame per step) is the next keyframe, never an alternative."""


def _near(a: np.ndarray, b: np.ndarray, window_m: float, heading_rad: float) -> bool:
    turn = float(se2.wrap_angle(float(a[2]) - float(b[2])))
    return math.hypot(float(a[0] - b[0]), float(a[1] - b[1])) <= window_m and abs(turn) <= heading_rad


def dense_samples(samples: Iterable[Sample], window_m: float, counts: PipelineCounts) -> Iterator[Clocked]:
    """The samples worth describing on a dense stream, each with the stream's still clock: each one
    at least ``FRAME_SPACING`` of the window away from the last one kept (in distance or heading)."""
    spacing_m = FRAME_SPACING * window_m
    spacing_rad = FRAME_SPACING * math.radians(WINDOW_HEADING_DEG)
    last: np.ndarray | None = None
    for clocked in still_clocked(samples, counts):
        pose = np.asarray(clocked.sample.odometry_pose, dtype=float)
        if last is not None and _near(pose, last, spacing_m, spacing_rad):
            continue
        last = pose
        yield clocked


def keyframes_taken(
    frames: Iterable[Frame], estimator: Estimator, window_m: float
) -> Iterator[tuple[Frame, np.ndarray]]:
    """The keyframes of a dense stream, each taken among the frames near the one odometry chose,
    with its action since the frame taken before.

    The odometry decides when a keyframe is due — a step from the frame *taken* before, so the
    windows follow the places the map holds rather than the odometry's own schedule (which drifts
    against a first lap's places by up to half a step). Of the frames within ``window_m`` and
    ``WINDOW_HEADING_DEG`` of the odometry's keyframe (on a sparse stream, the frames just before and
    after it, within ``SPARSE_NEIGHBOUR_STEPS``) the estimator takes the one most like the places
    its hypotheses predict (:meth:`Estimator.choose_keyframe`); the frames after it are tested again from
    there. Runs interleaved with the estimator's steps: each choice sees the map of every keyframe
    before it.
    """
    heading = math.radians(WINDOW_HEADING_DEG)
    keyframer = estimator.keyframer
    reach = SPARSE_NEIGHBOUR_STEPS * keyframer.step_m
    source = iter(frames)
    replay: deque[Frame] = deque()
    recent: deque[Frame] = deque(maxlen=MAX_WINDOW_FRAMES)
    previous: Frame | None = None

    def pull() -> Frame | None:
        return replay.popleft() if replay else next(source, None)

    while (frame := pull()) is not None:
        action = keyframer.action_if_keyframe(frame.odometry_pose)
        if action is None:
            recent.append(frame)
            continue
        if keyframer.at_previous:  # the frame before, where a turn in place began; this one comes again
            replay.appendleft(frame)
            frame = recent.pop()
        if previous is None:  # the first keyframe: nothing to choose from, nothing to predict
            previous = frame
            recent.clear()
            yield frame, action
            continue
        before = [f for f in recent if _near(f.odometry_pose, frame.odometry_pose, window_m, heading)]
        after: list[Frame] = []
        while (following := pull()) is not None:
            if len(after) >= MAX_WINDOW_FRAMES or not _near(
                following.odometry_pose, frame.odometry_pose, window_m, heading
            ):
                replay.appendleft(following)
                break
            after.append(following)
        # A sparse stream (frames farther apart than the window): the frame just before and the one
        # just after are the alternatives, when within reach of the keyframe.
        sparse = False
        if not before and recent and _near(recent[-1].odometry_pose, frame.odometry_pose, reach, heading):
            before, sparse = [recent[-1]], True
        if not after and replay and _near(replay[0].odometry_pose, frame.odometry_pose, reach, heading):
            after, sparse = [replay.popleft()], True
        options = [frame, *before, *after]
        taken = frame
        if len(options) > 1:
            actions = [se2.between(previous.odometry_pose, o.odometry_pose) for o in options]
            views = [o.view for o in options]
            taken = options[estimator.choose_keyframe(actions, views, sparse=sparse)]
        if taken is not frame:
            keyframer.anchor(taken.odometry_pose)
        later = [f for f in (*before, frame, *after) if f.stamp_ns > taken.stamp_ns]
        replay.extendleft(reversed(later))
        recent.clear()
        yield taken, se2.between(previous.odometry_pose, taken.odometry_pose)
        previous = taken


Described = tuple[np.ndarray, ViewFeatures | None]
"""An image's observation vector, and its features where the geometric check wants them."""


def _describe(image: LazyImage, model: ObservationModel, camera: PinholeCamera | None) -> Described:
    """The image's vector, and its features where ``camera`` (the geometric check's) is given: for
    images of the camera's size only, since its intrinsics are in their pixels."""
    gray = image.decode_gray()
    if camera is None:
        return model.describe(gray), None
    height, width = gray.shape
    if (width, height) != (camera.width_px, camera.height_px):
        where = f"{image.where}: " if image.where else ""
        raise InputError(
            f"{where}the image is {width}×{height} but the camera info is for"
            f" {camera.width_px}×{camera.height_px} images; --geometric-check-m needs the intrinsics"
            " of the images themselves",
            path=image.path,
        )
    return model.describe(gray), view_features(gray)


def _described(
    items: Iterable[tuple[Sample, Any]],
    model: ObservationModel,
    workers: int,
    camera: PinholeCamera | None = None,
) -> Iterator[tuple[Sample, Any, Described]]:
    """``(sample, tag, (view, features))`` for each ``(sample, tag)``, in order, computed ``workers``
    at a time with at most ``DESCRIBE_DEPTH`` waiting. Stopping early (an exception, KeyboardInterrupt, the
    consumer closing the generator) cancels the queued work and joins the pool. ``workers=0``
    describes each image in the calling thread: a sweep runs one task per core, and a second
    thread per task there only adds hand-offs."""
    pending: deque[tuple[Sample, Any, Future[Described]]] = deque()
    pool = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="aslam-describe") if workers else None
    try:
        for sample, tag in items:
            if pool is not None:
                future = pool.submit(_describe, sample.image, model, camera)
            else:
                future = _computed(_describe, sample.image, model, camera)
            pending.append((sample, tag, future))
            while pending and (len(pending) >= DESCRIBE_DEPTH or pending[0][2].done()):
                first, first_tag, done = pending.popleft()
                yield first, first_tag, done.result()
        while pending:
            first, first_tag, done = pending.popleft()
            yield first, first_tag, done.result()
    finally:
        for *_, future in pending:
            future.cancel()
        if pool is not None:
            pool.shutdown(wait=True, cancel_futures=True)


def keyframe_views(
    samples: Iterable[Sample],
    keyframer: Keyframer,
    model: ObservationModel,
    *,
    counts: PipelineCounts | None = None,
    workers: int = DEFAULT_WORKERS,
    camera: PinholeCamera | None = None,
) -> Iterator[Keyframe]:
    """The keyframes of ``samples`` with their views, in order (only keyframes are decoded).

    ``keyframer`` decides from each sample's odometry pose; with ``camera``, each image's
    features too (the geometric check's camera).
    """
    counts = counts if counts is not None else PipelineCounts()
    keyframes = keyframer.keyframes(
        still_clocked(samples, counts), lambda clocked: clocked.sample.odometry_pose
    )
    items = ((clocked.sample, (action, clocked)) for clocked, action in keyframes)
    for sample, (action, clocked), (vector, features) in _described(items, model, workers, camera):
        yield Keyframe(sample.stamp_ns, action, vector, clocked.still_ns, sample.odometry_restarts, features)


def frame_views(
    samples: Iterable[Sample],
    model: ObservationModel,
    window_m: float,
    *,
    counts: PipelineCounts | None = None,
    workers: int = DEFAULT_WORKERS,
    camera: PinholeCamera | None = None,
) -> Iterator[Frame]:
    """Every frame of a dense stream worth describing (:func:`dense_samples`), with its view (and
    features, with ``camera``)."""
    counts = counts if counts is not None else PipelineCounts()
    items = ((clocked.sample, clocked) for clocked in dense_samples(samples, window_m, counts))
    for sample, clocked, (vector, features) in _described(items, model, workers, camera):
        pose = np.asarray(sample.odometry_pose, dtype=float)
        yield Frame(sample.stamp_ns, pose, vector, clocked.still_ns, sample.odometry_restarts, features)


def _computed(function: Callable[..., Described], *args: Any) -> Future[Described]:
    """``function(*args)`` run now, as a finished future (an error is raised where the pool's is)."""
    future: Future[Described] = Future()
    try:
        future.set_result(function(*args))
    except Exception as err:
        future.set_exception(err)
    return future


SEND_BATCH = 4
STOP_WAIT_S = 2.0
"""How long a reader told to stop may take to close its source before it is killed."""

#: What the pipe from the reader holds. The parent imports GTSAM and Foxglove's schemas while the
#: reader starts (90 ms); Linux's default pipe, 64 KiB, holds some 20 frames (3.2 KiB each at the
#: defaults), so the reader stopped, the pipe full, and waited for the parent (estimate of the paper
#: route 1.24 → 1.19× the floor). 1 MiB, some 300 frames, is Linux's limit for an unprivileged
#: process (``/proc/sys/fs/pipe-max-size``); where it cannot be set, the default.
PIPE_BYTES = 1 << 20


def _widen(connection: Any) -> None:
    """Give ``connection``'s pipe ``PIPE_BYTES`` where the system lets us (Linux ``F_SETPIPE_SZ``)."""
    import fcntl

    set_size = getattr(fcntl, "F_SETPIPE_SZ", None)
    if set_size is None:
        return
    with contextlib.suppress(OSError):  # above the system's limit
        fcntl.fcntl(connection.fileno(), set_size, PIPE_BYTES)


class ReaderWarnings:
    """Where a reading's warnings go: ``on_warning``, called in this process. Handed to the source
    (``open_input(on_warning=…)``) and to :func:`run_estimate`: a forked reader sends what the source
    says back through its pipe, so ``on_warning`` runs here, not in the child, where a caller that
    collects the lines (a notebook's list; a truncated recording's "the rest is lost") never saw them.
    """

    def __init__(self, on_warning: Callable[[str], None] | None) -> None:
        self._on_warning = on_warning
        self._send: Callable[[str], None] | None = None  # set in a reader child

    def __call__(self, line: str) -> None:
        if self._send is not None:
            self._send(line)
        else:
            self.heard(line)

    def heard(self, line: str) -> None:
        """A line said here, or by the reader child."""
        if self._on_warning is not None:
            self._on_warning(line)


class ReaderProcess:
    """A reader (``produce(counts)``: an iterator of picklable items, here keyframes or frames) run
    in a forked child, started at construction; iterating yields its items here, in order.

    Started at once, so whatever the caller prepares next (opening the output, the imports the
    end of the run needs) overlaps the child's reading instead of delaying it. The samples it reads
    must not have been started: the child opens and reads the recording. The child counts into its
    own copy of ``counts`` (the fork's), so what the samples set there (``images``, once they have
    opened the source) reaches ``counts`` here with the items. Errors raised in the child (a bad
    recording) are raised here; ``close()``, or an interrupt, stops the child. What the reading says
    to ``warnings`` in the child is said to it here, in order with the items.
    """

    def __init__(
        self,
        produce: Callable[[PipelineCounts], Iterator[Any]],
        *,
        counts: PipelineCounts,
        warnings: ReaderWarnings | None = None,
    ) -> None:
        context = multiprocessing.get_context("fork")
        self._receiver, sender = context.Pipe(duplex=False)
        _widen(sender)
        self._counts = counts
        self._warnings = warnings

        def child() -> None:
            signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent handles Ctrl-C and stops us
            # Below the parent: at equal priority the SLAM step fell behind the decoding threads and
            # caught up alone on one core after the last image (12–49 ms of a 0.6 s estimate).
            os.nice(5)
            self._receiver.close()
            child_counts = self._counts  # this process's copy

            def counted() -> tuple[int, int | None]:
                return child_counts.samples, child_counts.images

            # The parent's close(): the reading stops at the next item and its clean-up runs. A flag,
            # not an exception from the handler: raised inside a weakref callback, Python printed it
            # as a traceback on stderr and went on (close() kills a child that does not stop).
            stop = threading.Event()
            signal.signal(signal.SIGTERM, lambda _signum, _frame: stop.set())
            batch: list[Any] = []

            def said(line: str) -> None:  # after the items read before it
                nonlocal batch
                sender.send(("items", batch, counted()))
                batch = []
                sender.send(("warning", line, counted()))

            if warnings is not None:
                warnings._send = said  # this process's copy
            items = produce(child_counts)
            try:
                for item in items:
                    if stop.is_set():
                        break
                    batch.append(item)
                    if len(batch) >= SEND_BATCH:
                        sender.send(("items", batch, counted()))
                        batch = []
                sender.send(("items", batch, counted()))
                sender.send(("done", None, counted()))
            except BaseException as err:  # handed to the parent, which raises it
                try:
                    sender.send(("error", err, counted()))
                except Exception:  # the error itself does not pickle: keep its words
                    sender.send(("error", RuntimeError(f"{type(err).__name__}: {err}"), counted()))
            finally:
                with contextlib.suppress(BaseException):
                    close = getattr(items, "close", None)
                    if close is not None:
                        close()
                sender.close()
                os._exit(0)

        self._process = context.Process(target=child, name="aslam-reader", daemon=True)
        self._process.start()
        sender.close()

    def __iter__(self) -> Iterator[Any]:
        while True:
            try:
                kind, payload, counted = self._receiver.recv()
            except EOFError:  # the child died without a word: killed from outside
                raise AslamError(self._death()) from None
            except OSError:  # killed in the middle of a message ("got end of file during message")
                self._process.join(timeout=10)
                if self._process.exitcode is None:
                    raise
                raise AslamError(self._death()) from None
            self._counts.samples, self._counts.images = counted
            if kind == "items":
                yield from payload
            elif kind == "warning":
                if self._warnings is not None:
                    self._warnings.heard(payload)
            elif kind == "error":
                raise payload
            else:
                return

    def _death(self) -> str:
        """What ended the child: the kernel's out-of-memory killer (SIGKILL, it picks the largest
        process), or a signal sent to its pid alone (which its inherited handler turns into exit
        status 128 + N). Not a bug of ours: one line, exit 2."""
        self._process.join(timeout=10)
        status = self._process.exitcode
        number = -status if status is not None and status < 0 else (status or 0) - 128
        try:
            how = f"was killed by {signal.Signals(number).name}"
        except ValueError:
            how = f"ended unexpectedly (exit status {status})"
        oom = " (the out-of-memory killer sends SIGKILL)" if number == signal.SIGKILL else ""
        return f"the recording reader (process {self._process.pid}, a child of this one) {how}{oom}"

    def close(self) -> None:
        self._receiver.close()
        if self._process.is_alive():
            self._process.terminate()
            self._process.join(timeout=STOP_WAIT_S)
            if self._process.is_alive():  # busy in one long call (a bag decompressed at its open)
                self._process.kill()
        self._process.join()


def can_fork() -> bool:
    """Whether this process may fork the reader: the platform can, and this is no daemonic process
    (a Dask worker's, a ``multiprocessing`` pool's), which multiprocessing forbids children."""
    return "fork" in multiprocessing.get_all_start_methods() and not multiprocessing.current_process().daemon


class EstimateSteps:
    """The estimator fed keyframe by keyframe from a reader: iterate once for one ``StepResult`` per
    keyframe, in order. The iteration ending in any way (the last step, an error, a ``break``, the
    iterator closed) stops the reader; so does ``close()``, also when never iterated.

    The reader gives keyframes, or on a dense stream (``keyframe_window_m`` > 0) every frame worth
    describing, of which :func:`keyframes_taken` takes the keyframes here, next to the map.
    """

    def __init__(
        self,
        reader: ReaderProcess | Iterator[Keyframe] | Iterator[Frame],
        estimator: Estimator,
        counts: PipelineCounts,
    ) -> None:
        self._reader = reader
        self._estimator = estimator
        self._counts = counts
        self._window_m = estimator.config.keyframe_window_m
        # Steps dropped unread stop their reader too (it was left a zombie until the next fork).
        self._stop_reader = weakref.finalize(self, _close_reader, reader, os.getpid())

    def __iter__(self) -> Iterator[StepResult]:
        estimator, counts = self._estimator, self._counts
        if self._window_m > 0:
            taken: Iterator[tuple[Frame | Keyframe, np.ndarray]] = keyframes_taken(
                self._reader,  # type: ignore[arg-type]  # frames where window_m > 0 (run_estimate's produce)
                estimator,
                self._window_m,
            )
        else:
            taken = ((keyframe, keyframe.action) for keyframe in self._reader)  # type: ignore[union-attr]  # keyframes
        restarts: int | None = None  # the stream's count at the keyframe before
        try:
            for frame, action in taken:
                start = time.perf_counter()
                restarted = restarts is not None and frame.odometry_restarts != restarts
                restarts = frame.odometry_restarts
                counts.odometry_restarts += restarted
                step = estimator.add_keyframe(
                    frame.stamp_ns, action, frame.view, frame.still_ns, frame.features, restarted
                )
                counts.slam_s += time.perf_counter() - start
                counts.keyframes += 1
                yield step
        finally:  # a caller's loop left early must not leave the forked reader blocked on its pipe
            self.close()

    def close(self) -> None:
        self._stop_reader()


def _close_reader(reader: ReaderProcess | Iterator[Keyframe] | Iterator[Frame], owner_pid: int) -> None:
    """Close ``reader``, in the process that made it only: a finalizer is copied into every fork (a
    later reader's child, whose collection or exit would run it), where the reader is another
    process's child, or a copy of a source whose clean-up (a decompressed bag's removal) is the
    parent's."""
    if os.getpid() != owner_pid:
        return
    close = getattr(reader, "close", None)
    if close is not None:
        close()


def run_estimate(
    samples: Iterable[Sample],
    estimator: Estimator,
    *,
    counts: PipelineCounts | None = None,
    workers: int = DEFAULT_WORKERS,
    reader_process: bool = True,
    warnings: ReaderWarnings | None = None,
) -> EstimateSteps:
    """Feed ``samples`` through ``estimator``: iterate the result for one ``StepResult`` per keyframe.

    With a reader process it starts reading at once (:class:`ReaderProcess`): what the caller does
    before iterating runs alongside. ``reader_process=False`` keeps the reader in this process,
    started on the first step: right where one core per run is wanted (a sweep running one task
    per core). Where this process may not have children (:func:`can_fork`: a daemonic process,
    such as a Dask worker) the reader is in this process either way; the steps are the same.
    ``warnings``: the one the samples' source warns to (:class:`ReaderWarnings`), so that a reader
    process's warnings reach its ``on_warning`` in this process.
    """
    counts = counts if counts is not None else PipelineCounts()
    describe = estimator.observation_model
    window_m = estimator.config.keyframe_window_m
    camera = estimator.camera

    def produce(reader_counts: PipelineCounts) -> Iterator[Keyframe] | Iterator[Frame]:
        views: Iterator[Keyframe] | Iterator[Frame]
        if window_m > 0:
            views = frame_views(
                samples,
                describe,
                window_m,
                counts=reader_counts,
                workers=workers,
                camera=camera,
            )
        else:
            views = keyframe_views(
                samples,
                estimator.keyframer,
                describe,
                counts=reader_counts,
                workers=workers,
                camera=camera,
            )
        try:
            yield from views
        finally:
            # However the reading ends (an error, stopped early): the source's own clean-up runs, as
            # rosbags' removal of the copy it decompressed of a bag compressed by file (left in
            # TMPDIR by every failed estimate of one).
            close = getattr(samples, "close", None)
            if close is not None:
                close()

    if reader_process and can_fork():
        return EstimateSteps(ReaderProcess(produce, counts=counts, warnings=warnings), estimator, counts)
    return EstimateSteps(produce(counts), estimator, counts)
