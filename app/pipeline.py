"""The streaming estimate pipeline behind :func:`aslam.app.estimate.estimate` and the benchmarks.

The floor of an estimate is reading the recording, decoding the keyframe images and computing
their histograms. The pipeline keeps the SLAM step off that critical path:

* a producer iterates the samples (MCAP read, CDR decode) and runs the keyframe test, which
  needs odometry only, so non-keyframe images are never decoded;
* keyframe images go to a small thread pool that decodes them and computes the histogram
  (OpenCV and numpy release the GIL);
* the futures wait in a bounded FIFO, so memory stays bounded and order is kept;
* where the platform can fork, the producer runs in a child process and sends the keyframes
  (stamp, action, histogram: a few hundred bytes each) through a pipe, so the SLAM step, which
  holds the GIL, runs on the other core instead of stalling the decoders.
"""

from __future__ import annotations

import multiprocessing
import os
import signal
import time
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from aslam.core.estimator import Estimator, StepResult
from aslam.core.observation import ObservationModel
from aslam.data_formats.images import LazyImage
from aslam.data_formats.pose_sync import Sample

DEFAULT_WORKERS = 2
DEFAULT_DEPTH = 8


class Keyframe(NamedTuple):
    stamp_ns: int
    action: np.ndarray
    histogram: np.ndarray
    ground_truth_pose: np.ndarray | None


@dataclass
class PipelineCounts:
    """Running counts, readable while the pipeline runs (for a progress display)."""

    samples: int = 0
    keyframes: int = 0
    slam_s: float = 0.0


def _histogram(image: LazyImage, model: ObservationModel) -> np.ndarray:
    return model.describe(image.decode_gray())


def keyframe_histograms(
    samples: Iterable[Sample],
    keyframe_action: Callable[[np.ndarray], np.ndarray | None],
    histogram: ObservationModel,
    *,
    counts: PipelineCounts | None = None,
    workers: int = DEFAULT_WORKERS,
    depth: int = DEFAULT_DEPTH,
) -> Iterator[Keyframe]:
    """The keyframes of ``samples`` with their histograms, in order, computed ``workers`` at a time.

    ``keyframe_action(odometry_pose)`` is the keyframe test (the action, or None). At most ``depth``
    images are decoded or waiting at once. Stopping early (an exception, KeyboardInterrupt, the
    consumer closing the generator) cancels the queued work and joins the pool. ``workers=0``
    computes each histogram in the calling thread: a sweep runs one task per core, and a second
    thread per task there only adds hand-offs.
    """
    counts = counts if counts is not None else PipelineCounts()
    pending: deque[tuple[int, np.ndarray, np.ndarray | None, Future[np.ndarray]]] = deque()
    pool = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="aslam-histogram") if workers else None
    try:
        for sample in samples:
            counts.samples += 1
            action = keyframe_action(sample.odometry_pose)
            if action is not None:
                future = (
                    pool.submit(_histogram, sample.image, histogram)
                    if pool is not None
                    else _computed(_histogram, sample.image, histogram)
                )
                pending.append((sample.stamp_ns, action, sample.ground_truth_pose, future))
                if len(pending) >= depth:
                    yield _take(pending)
                    counts.keyframes += 1
                while pending and pending[0][3].done():
                    yield _take(pending)
                    counts.keyframes += 1
        while pending:
            yield _take(pending)
            counts.keyframes += 1
    finally:
        for *_, future in pending:
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


def _take(pending: deque[tuple[int, np.ndarray, np.ndarray | None, Future[np.ndarray]]]) -> Keyframe:
    stamp_ns, action, truth, future = pending.popleft()
    return Keyframe(stamp_ns, action, future.result(), truth)


SEND_BATCH = 4


def keyframes_from_child_process(
    samples: Iterable[Sample],
    keyframe_action: Callable[[np.ndarray], np.ndarray | None],
    histogram: ObservationModel,
    *,
    counts: PipelineCounts,
    workers: int = DEFAULT_WORKERS,
    depth: int = DEFAULT_DEPTH,
    meanwhile: Callable[[], None] | None = None,
) -> Iterator[Keyframe]:
    """:func:`keyframe_histograms` run in a forked child; the keyframes arrive here in order.

    ``meanwhile`` runs here once the child has started, while it reads its first keyframes.

    ``samples`` must not have been started: the child opens and reads the recording. Errors
    raised in the child (a bad recording) are raised here; closing this generator, or an
    interrupt, stops the child.
    """
    context = multiprocessing.get_context("fork")
    receiver, sender = context.Pipe(duplex=False)

    def produce() -> None:
        signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent handles Ctrl-C and stops us
        receiver.close()
        child_counts = PipelineCounts()
        try:
            batch: list[Keyframe] = []
            for keyframe in keyframe_histograms(
                samples, keyframe_action, histogram, counts=child_counts, workers=workers, depth=depth
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

    process = context.Process(target=produce, name="aslam-reader", daemon=True)
    process.start()
    sender.close()
    try:
        if meanwhile is not None:
            meanwhile()
        while True:
            try:
                kind, payload, samples_read = receiver.recv()
            except EOFError:
                raise RuntimeError("the recording reader process stopped unexpectedly") from None
            counts.samples = samples_read
            if kind == "keyframes":
                for keyframe in payload:
                    counts.keyframes += 1
                    yield keyframe
            elif kind == "error":
                raise payload
            else:
                return
    finally:
        receiver.close()
        if process.is_alive():
            process.terminate()
        process.join()


def can_fork() -> bool:
    return "fork" in multiprocessing.get_all_start_methods()


def run_estimate(
    samples: Iterable[Sample],
    estimator: Estimator,
    *,
    counts: PipelineCounts | None = None,
    workers: int = DEFAULT_WORKERS,
    depth: int = DEFAULT_DEPTH,
    reader_process: bool = True,
    meanwhile: Callable[[], None] | None = None,
) -> Iterator[StepResult]:
    """Feed ``samples`` through ``estimator``; one ``StepResult`` per keyframe, in order.

    ``meanwhile`` is work for this process while the reader starts (e.g. a slow import the end of
    the run needs); it runs before the first keyframe, whether or not the reader is a child.

    ``reader_process=False`` keeps the reader in this process: needed where this process may not
    have children (a daemonic process, such as a Dask worker), and right where one core per run
    is wanted (a sweep running one task per core).
    """
    counts = counts if counts is not None else PipelineCounts()
    describe = estimator.observation_model
    if reader_process and can_fork():
        keyframes = keyframes_from_child_process(
            samples,
            estimator.keyframe_action,
            describe,
            counts=counts,
            workers=workers,
            depth=depth,
            meanwhile=meanwhile,
        )
    else:
        if meanwhile is not None:
            meanwhile()
        keyframes = keyframe_histograms(
            samples, estimator.keyframe_action, describe, counts=counts, workers=workers, depth=depth
        )
    try:
        for keyframe in keyframes:
            start = time.perf_counter()
            step = estimator.add_keyframe(keyframe.stamp_ns, keyframe.action, keyframe.histogram)
            counts.slam_s += time.perf_counter() - start
            yield step
    finally:
        keyframes.close()
