"""The streaming estimate pipeline behind :func:`aslam.app.estimate.estimate` and the benchmarks.

The floor of an estimate is reading the recording, decoding the keyframe images and computing
their histograms. The pipeline keeps the SLAM step off that critical path:

* a producer iterates the samples (MCAP read, CDR decode) and runs the keyframe test, which
  needs odometry only, so non-keyframe images are never decoded (on a dense stream, the frames
  within ``keyframe_window_m`` of a keyframe are, and the estimator picks one: ``run_estimate``);
* keyframe images go to a small thread pool that decodes them and computes the histogram
  (OpenCV and numpy release the GIL);
* the futures wait in a bounded FIFO, so memory stays bounded and order is kept;
* where the platform can fork, the producer runs in a child process and sends the keyframes
  (stamp, action, histogram: a few hundred bytes each) through a pipe, so the SLAM step, which
  holds the GIL, runs on the other core instead of stalling the decoders.
"""

from __future__ import annotations

import math
import multiprocessing
import os
import signal
import time
from collections import deque
from collections.abc import Callable, Generator, Iterable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from aslam.core import se2
from aslam.core.estimator import Estimator, StepResult
from aslam.core.observation import ObservationModel
from aslam.data_formats.images import LazyImage
from aslam.data_formats.pose_sync import Sample

DEFAULT_WORKERS = 2
DEFAULT_DEPTH = 8


class Alternative(NamedTuple):
    """Another frame of a dense stream near a keyframe, which may be taken in its place."""

    stamp_ns: int
    odometry_pose: np.ndarray
    histogram: np.ndarray


class Keyframe(NamedTuple):
    stamp_ns: int
    action: np.ndarray
    """Odometry since the previous keyframe the odometry chose."""
    histogram: np.ndarray
    ground_truth_pose: np.ndarray | None
    odometry_pose: np.ndarray
    alternatives: tuple[Alternative, ...] = ()
    """The other frames within ``keyframe_window_m`` of it, in time order (none unless enabled)."""


@dataclass
class PipelineCounts:
    """Running counts, readable while the pipeline runs (for a progress display)."""

    samples: int = 0
    keyframes: int = 0
    slam_s: float = 0.0


WINDOW_HEADING_DEG = 20.0
"""A frame is near a keyframe when within ``keyframe_window_m`` and this much heading of it."""
MAX_WINDOW_SAMPLES = 32
"""At most this many frames before a keyframe, and as many after it, are its alternatives: a robot
standing still keeps every frame near the keyframe, and memory must not grow with the wait."""


def _near(sample: Sample, keyframe: Sample, window_m: float) -> bool:
    a, b = sample.odometry_pose, keyframe.odometry_pose
    turn = float(se2.wrap_angle(float(a[2]) - float(b[2])))
    return math.hypot(float(a[0] - b[0]), float(a[1] - b[1])) <= window_m and abs(turn) <= math.radians(
        WINDOW_HEADING_DEG
    )


def keyframe_windows(
    samples: Iterable[Sample],
    keyframe_action: Callable[[np.ndarray], np.ndarray | None],
    window_m: float,
    counts: PipelineCounts,
) -> Iterator[tuple[Sample, np.ndarray, tuple[Sample, ...]]]:
    """Each keyframe's sample and action, with the other samples within ``window_m`` of it (those
    just before and just after, in time order). ``window_m`` 0: no others, nothing held back."""
    recent: deque[Sample] = deque(maxlen=MAX_WINDOW_SAMPLES)
    held: tuple[Sample, np.ndarray, list[Sample]] | None = None
    for sample in samples:
        counts.samples += 1
        action = keyframe_action(sample.odometry_pose)
        if held is not None:
            if action is None and _near(sample, held[0], window_m):
                if len(held[2]) < 2 * MAX_WINDOW_SAMPLES:
                    held[2].append(sample)
                continue
            yield held[0], held[1], tuple(held[2])
            held = None
        if action is None:
            if window_m > 0:
                recent.append(sample)
        elif window_m > 0:
            held = (sample, action, [s for s in recent if _near(s, sample, window_m)])
            recent.clear()
        else:
            yield sample, action, ()
    if held is not None:
        yield held[0], held[1], tuple(held[2])


def _histogram(image: LazyImage, model: ObservationModel) -> np.ndarray:
    return model.describe(image.decode_gray())


_Pending = tuple[Sample, np.ndarray, tuple[Sample, ...], list[Future[np.ndarray]]]
"""A keyframe waiting for its histograms: its sample, action, alternatives, and one future each."""


def keyframe_histograms(
    samples: Iterable[Sample],
    keyframe_action: Callable[[np.ndarray], np.ndarray | None],
    histogram: ObservationModel,
    *,
    window_m: float = 0.0,
    counts: PipelineCounts | None = None,
    workers: int = DEFAULT_WORKERS,
    depth: int = DEFAULT_DEPTH,
) -> Iterator[Keyframe]:
    """The keyframes of ``samples`` with their histograms, in order, computed ``workers`` at a time.

    ``keyframe_action(odometry_pose)`` is the keyframe test (the action, or None); with ``window_m``
    each keyframe also carries the frames near it (:func:`keyframe_windows`), decoded too. At most
    ``depth`` images are decoded or waiting at once. Stopping early (an exception,
    KeyboardInterrupt, the consumer closing the generator) cancels the queued work and joins the
    pool. ``workers=0`` computes each histogram in the calling thread: a sweep runs one task per
    core, and a second thread per task there only adds hand-offs.
    """
    counts = counts if counts is not None else PipelineCounts()
    pending: deque[_Pending] = deque()
    images = 0
    pool = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="aslam-histogram") if workers else None

    def describe(image: LazyImage) -> Future[np.ndarray]:
        if pool is not None:
            return pool.submit(_histogram, image, histogram)
        return _computed(_histogram, image, histogram)

    try:
        for sample, action, alternatives in keyframe_windows(samples, keyframe_action, window_m, counts):
            futures = [describe(s.image) for s in (sample, *alternatives)]
            pending.append((sample, action, alternatives, futures))
            images += len(futures)
            while pending and (images >= depth or all(f.done() for f in pending[0][3])):
                images -= len(pending[0][3])
                yield _take(pending)
                counts.keyframes += 1
        while pending:
            yield _take(pending)
            counts.keyframes += 1
    finally:
        for *_, futures in pending:
            for future in futures:
                future.cancel()
        if pool is not None:
            pool.shutdown(wait=True, cancel_futures=True)


def _computed(function: Callable[..., np.ndarray], *args: Any) -> Future[np.ndarray]:
    """``function(*args)`` run now, as a finished future (an error is raised where the pool's is)."""
    future: Future[np.ndarray] = Future()
    try:
        future.set_result(function(*args))
    except Exception as err:
        future.set_exception(err)
    return future


def _take(pending: deque[_Pending]) -> Keyframe:
    sample, action, alternatives, futures = pending.popleft()
    others = tuple(
        Alternative(other.stamp_ns, np.asarray(other.odometry_pose, dtype=float), future.result())
        for other, future in zip(alternatives, futures[1:], strict=True)
    )
    pose = np.asarray(sample.odometry_pose, dtype=float)
    return Keyframe(sample.stamp_ns, action, futures[0].result(), sample.ground_truth_pose, pose, others)


SEND_BATCH = 4


class ReaderProcess:
    """:func:`keyframe_histograms` run in a forked child, started at construction; iterating
    yields its keyframes here, in order.

    Started at once, so whatever the caller prepares next (opening the output, the imports the
    end of the run needs) overlaps the child's reading instead of delaying it. ``samples`` must not
    have been started: the child opens and reads the recording. Errors raised in the child (a bad
    recording) are raised here; ``close()``, or an interrupt, stops the child.
    """

    def __init__(
        self,
        samples: Iterable[Sample],
        keyframe_action: Callable[[np.ndarray], np.ndarray | None],
        histogram: ObservationModel,
        *,
        counts: PipelineCounts,
        window_m: float = 0.0,
        workers: int = DEFAULT_WORKERS,
        depth: int = DEFAULT_DEPTH,
    ) -> None:
        context = multiprocessing.get_context("fork")
        self._receiver, sender = context.Pipe(duplex=False)
        self._counts = counts

        def produce() -> None:
            signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent handles Ctrl-C and stops us
            # Below the parent: at equal priority the SLAM step fell behind the decoding threads and
            # caught up alone on one core after the last image (12–49 ms of a 0.6 s estimate).
            os.nice(5)
            self._receiver.close()
            child_counts = PipelineCounts()
            try:
                batch: list[Keyframe] = []
                for keyframe in keyframe_histograms(
                    samples,
                    keyframe_action,
                    histogram,
                    window_m=window_m,
                    counts=child_counts,
                    workers=workers,
                    depth=depth,
                ):
                    batch.append(keyframe)
                    if len(batch) >= SEND_BATCH:
                        sender.send(("keyframes", batch, child_counts.samples))
                        batch = []
                sender.send(("keyframes", batch, child_counts.samples))
                sender.send(("done", None, child_counts.samples))
            except BaseException as err:  # handed to the parent, which raises it
                try:
                    sender.send(("error", err, child_counts.samples))
                except Exception:  # the error itself does not pickle: keep its words
                    sender.send(("error", RuntimeError(f"{type(err).__name__}: {err}"), child_counts.samples))
            finally:
                sender.close()
                os._exit(0)

        self._process = context.Process(target=produce, name="aslam-reader", daemon=True)
        self._process.start()
        sender.close()

    def __iter__(self) -> Iterator[Keyframe]:
        while True:
            try:
                kind, payload, samples_read = self._receiver.recv()
            except EOFError:
                raise RuntimeError("the recording reader process stopped unexpectedly") from None
            self._counts.samples = samples_read
            if kind == "keyframes":
                for keyframe in payload:
                    self._counts.keyframes += 1
                    yield keyframe
            elif kind == "error":
                raise payload
            else:
                return

    def close(self) -> None:
        self._receiver.close()
        if self._process.is_alive():
            self._process.terminate()
        self._process.join()


def can_fork() -> bool:
    return "fork" in multiprocessing.get_all_start_methods()


class EstimateSteps:
    """The estimator fed keyframe by keyframe from a reader: iterate for one ``StepResult`` per
    keyframe, in order; ``close()`` stops the reader (also when never iterated)."""

    def __init__(
        self, keyframes: ReaderProcess | Generator[Keyframe], estimator: Estimator, counts: PipelineCounts
    ) -> None:
        self._keyframes = keyframes
        self._estimator = estimator
        self._counts = counts

    def __iter__(self) -> Iterator[StepResult]:
        estimator, counts = self._estimator, self._counts
        previous: Keyframe | Alternative | None = None
        for keyframe in self._keyframes:
            start = time.perf_counter()
            taken, action = _take_keyframe(estimator, keyframe, previous)
            step = estimator.add_keyframe(taken.stamp_ns, action, taken.histogram)
            counts.slam_s += time.perf_counter() - start
            previous = taken
            yield step

    def close(self) -> None:
        self._keyframes.close()


def run_estimate(
    samples: Iterable[Sample],
    estimator: Estimator,
    *,
    counts: PipelineCounts | None = None,
    workers: int = DEFAULT_WORKERS,
    depth: int = DEFAULT_DEPTH,
    reader_process: bool = True,
) -> EstimateSteps:
    """Feed ``samples`` through ``estimator``: iterate the result for one ``StepResult`` per keyframe.

    With a reader process it starts reading at once (:class:`ReaderProcess`): what the caller does
    before iterating runs alongside. ``reader_process=False`` keeps the reader in this process,
    started on the first step: needed where this process may not have children (a daemonic
    process, such as a Dask worker), and right where one core per run is wanted (a sweep running
    one task per core).
    """
    counts = counts if counts is not None else PipelineCounts()
    describe = estimator.observation_model
    window_m = estimator.config.keyframe_window_m
    if reader_process and can_fork():
        return EstimateSteps(
            ReaderProcess(
                samples,
                estimator.keyframe_action,
                describe,
                counts=counts,
                window_m=window_m,
                workers=workers,
                depth=depth,
            ),
            estimator,
            counts,
        )
    keyframes = keyframe_histograms(
        samples,
        estimator.keyframe_action,
        describe,
        window_m=window_m,
        counts=counts,
        workers=workers,
        depth=depth,
    )
    return EstimateSteps(keyframes, estimator, counts)


def _take_keyframe(
    estimator: Estimator, keyframe: Keyframe, previous: Keyframe | Alternative | None
) -> tuple[Keyframe | Alternative, np.ndarray]:
    """The frame to take for ``keyframe`` (it, or one of its alternatives the estimator prefers)
    and its action since the previous frame taken."""
    if previous is None:
        return keyframe, keyframe.action
    options = [a for a in keyframe.alternatives if a.stamp_ns > previous.stamp_ns]
    taken: Keyframe | Alternative = keyframe
    if options:
        choice = estimator.choose_keyframe(
            se2.between(previous.odometry_pose, keyframe.odometry_pose),
            [keyframe.histogram, *(a.histogram for a in options)],
        )
        taken = options[choice - 1] if choice else keyframe
    return taken, se2.between(previous.odometry_pose, taken.odometry_pose)
