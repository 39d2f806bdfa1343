"""``estimate()``: stream a recording through the SLAM into an estimate file.

Shaped like ``aslam.recorder.record.record``: paths and a typed configuration in, progress and
warnings out through callbacks, a typed summary back; no terminal.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from aslam.app.pipeline import DEFAULT_WORKERS, EstimateSteps, PipelineCounts, ReaderWarnings, run_estimate
from aslam.core.config import EstimatorConfig
from aslam.core.errors import InputError
from aslam.core.estimator import EstimateResult, Estimator
from aslam.core.mapgraph import GrowableArray
from aslam.data_formats.errors import EstimateError
from aslam.data_formats.files import check_output_path, full_path, source_files
from aslam.data_formats.sources import Input, TopicChoice, open_input

if TYPE_CHECKING:
    from aslam.core.geometry import PinholeCamera
    from aslam.core.mapgraph import PriorMap
    from aslam.data_formats.estimate import MapIdentity

PROGRESS_INTERVAL_S = 0.1


@dataclass(frozen=True)
class EstimateProgress:
    """How far a run is; handed to ``on_progress`` about ten times a second and once at the end."""

    samples: int
    samples_total: int | None
    """Images in the recording, from its summary or a bag's index; None when unknown (e.g. a
    truncated file), and until the reader has opened a bag."""
    keyframes: int
    hypotheses: int
    elapsed_s: float
    finishing: bool = False
    """Every image is read; the map's pose graph and the file are being written (seconds at
    10,000 keyframes, in which a bar at its end would look stalled)."""
    pose_graph_iterations: int = 0
    """Levenberg–Marquardt iterations of the pose graph so far, while finishing (each one reported:
    GTSAM holds the interpreter, so only these reports can move a display)."""


@dataclass(frozen=True)
class EstimateSummary:
    """What one run produced: the estimate file written, and counts and timings of the run (the
    map itself is read back from ``output`` by :func:`aslam.app.score.score`)."""

    output: Path
    samples: int
    """Images read."""
    keyframes: int
    states: int
    """Places of the best hypothesis's map."""
    links: int
    hypotheses: int
    """Hypotheses alive after the last keyframe."""
    wall_s: float
    slam_s: float
    embed_s: float
    """The metric view: the pose-graph optimisation and the Foxglove scene, written at the end."""
    recording_sha256: str
    """SHA-256 of the bytes read (the file opened, whatever is at its name now), as the estimate
    file records it: a sweep checks it against the hash it planned the task with."""
    odometry_restarts: int = 0
    """Keyframes after an odometry restart on its origin, each taken as an odometry jump (the
    estimator's; ``data_formats.pose_sync.PoseTrack``): a user learns the bag's odometry restarted."""

    @property
    def keyframes_per_second(self) -> float:
        return self.keyframes / max(self.wall_s, 1e-9)


class FileHasher:
    """SHA-256 of the input being read (:meth:`RecordingInput.sha256`, :meth:`BagInput.sha256`),
    computed in a background thread while the estimate runs.

    A second, sequential read (mostly from the page cache); hashlib releases the GIL on large
    buffers, so it costs the pipeline little. ``result()`` joins.
    """

    def __init__(self, source: Input) -> None:
        self._source = source
        self._digest: str | None = None
        self._error: InputError | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="aslam-sha256", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        try:
            self._digest = self._source.sha256(self._stop)
        except InputError as err:
            self._error = err

    def cancel(self) -> None:
        self._stop.set()
        self._thread.join()

    def result(self) -> str:
        self._thread.join()
        if self._error is not None:
            raise self._error
        assert self._digest is not None
        return self._digest


def estimate(
    recording: Path | str,
    output: Path | str,
    config: EstimatorConfig,
    *,
    topics: TopicChoice = TopicChoice(),
    force: bool = False,
    timing: bool = True,
    workers: int = DEFAULT_WORKERS,
    reader_process: bool = True,
    prior: Path | str | None = None,
    on_progress: Callable[[EstimateProgress], None] | None = None,
    on_warning: Callable[[str], None] | None = None,
) -> EstimateSummary:
    """Run the estimator over ``recording`` and write the hypotheses and the map to ``output``.

    ``recording`` is one of our MCAP recordings or a ROS bag (rosbag2 folder or file, ROS 1
    ``.bag``); topics left None are the recording's standard ones or found in the bag. Streams.
    ``output`` appears only when complete; any failure or interrupt leaves nothing under it. With
    ``timing=False`` the same inputs give a byte-identical file.
    ``reader_process=False`` reads in this process (see :func:`aslam.app.pipeline.run_estimate`).
    ``prior`` (``--map``): an earlier estimate file whose map this run starts in, the robot's place
    in it unknown; the output holds the extended map and numbers this run's keyframes after it.
    """
    if workers < 0:
        raise InputError(f"--workers must be at least 0, got {workers}")
    # Messages name the files as the caller spelled them (as record, info and report do); the
    # estimate file records the recording's full path, for a report run from another folder.
    recording, output = Path(recording), Path(output)
    prior = None if prior is None else Path(prior)
    inputs = [recording, *source_files(recording)] + ([] if prior is None else [prior])
    check_output_path(output, force=force, error=EstimateError, inputs=inputs)
    warn = on_warning or (lambda _line: None)
    start_map, map_identity = (None, None) if prior is None else load_prior_map(prior, config)
    if prior is not None and config.candidate_search == "path":
        warn(
            "--candidate-search path (--paper-faithful) follows this run's own path only: in a map it"
            " can place the first keyframe but not follow the map's places after it; give"
            " --candidate-search graph to track the map"
        )
    reading_warnings = ReaderWarnings(warn)  # said here, also by a reader process
    source = open_input(recording, topics, on_warning=reading_warnings)
    camera = geometry_camera(source, recording) if config.geometric_check_m > 0 else None
    estimator = Estimator(config, start_map, odometry_known=source.odometry_known, camera=camera)
    counts = PipelineCounts()
    start = time.perf_counter()

    def progress(keyframes: int, hypotheses: int, *, finishing: bool = False, iterations: int = 0) -> None:
        if on_progress is not None:
            elapsed = time.perf_counter() - start
            on_progress(
                EstimateProgress(
                    counts.samples, counts.images, keyframes, hypotheses, elapsed, finishing, iterations
                )
            )

    def images_counted(images: int | None) -> None:
        counts.images = images

    steps: EstimateSteps | None = None
    hasher: FileHasher | None = None
    try:
        # The reader starts first (a child process): the rest of the set-up overlaps its reading.
        # The image count (the progress bar's total) comes from the reader's own opening of the
        # source: a bag opened here to count its images was opened twice, and rosbags decompresses
        # one compressed by file whole at each open (0.6 s of a 4.4 s estimate of 3,000 images).
        steps = run_estimate(
            source.samples(on_image_count=images_counted),
            estimator,
            counts=counts,
            workers=workers,
            reader_process=reader_process,
            warnings=reading_warnings,
        )
        # What only the output and the end of the run need is imported while the reader reads.
        from aslam.app.metric_view import embed_run, metric_scene, preload
        from aslam.data_formats.estimate import (
            EstimateMetadata,
            EstimateWriter,
            PlaceViews,
            RecordingIdentity,
            Timing,
        )
        from aslam.data_formats.provenance import tool_version

        hasher = FileHasher(source)
        with EstimateWriter(output, tool_version=tool_version(), force=force) as writer:
            # A metric view needs 2 keyframes: its imports, meanwhile (a bag's count may not be in yet).
            if counts.images is None or counts.images >= 2:
                preload()
            last_update = 0.0
            actions = GrowableArray((3,), np.float64)  # 24 bytes a keyframe, for the metric view
            for step in steps:
                writer.write_keyframe(step)
                actions.append(step.action)
                now = time.perf_counter()
                if now - last_update > PROGRESS_INTERVAL_S:
                    last_update = now
                    # This run's keyframes (with --map, ``step.keyframe`` counts on from the map's).
                    progress(len(actions), len(step.hypotheses))
            result = estimator.result()
            wall_s = time.perf_counter() - start
            keyframes = len(result.keyframe_stamps_ns)
            progress(keyframes, len(result.hypotheses), finishing=True)
            metadata = EstimateMetadata(
                tool_version=tool_version(),
                config=asdict(config),
                recording=RecordingIdentity(str(full_path(recording)), source.size_bytes(), hasher.result()),
                topics=source.stored_topics(),
                prior_map=map_identity,
            )
            run_timing = None
            if timing:
                run_timing = Timing(
                    wall_s=wall_s,
                    slam_s=counts.slam_s,
                    keyframes_per_second=keyframes / max(wall_s, 1e-9),
                    samples=counts.samples,
                    keyframes=keyframes,
                )
            embed_start = time.perf_counter()
            embedding = embed_run(
                actions.view,
                result.states,
                result.links,
                config,
                result.first_keyframe,
                on_iteration=lambda iteration: progress(
                    keyframes, len(result.hypotheses), finishing=True, iterations=iteration
                ),
            )
            if embedding is not None and embedding.iterations:  # the rest of the file, after the pose graph
                progress(keyframes, len(result.hypotheses), finishing=True)
            scene = None if embedding is None else metric_scene(embedding, result.keyframe_stamps_ns)
            views = PlaceViews(
                config.observation_model,
                np.array([state.id for state in result.states], dtype=np.int64),
                estimator.place_views(result.states),
            )
            writer.finish(result, metadata, run_timing, scene, views)
            embed_s = time.perf_counter() - embed_start
    finally:
        if steps is not None:
            steps.close()
        if hasher is not None:
            hasher.cancel()
    if not result.keyframe_stamps_ns:
        warn(f"{recording}: no keyframes (no images with odometry)")
    elif prior is not None and not _entered_the_map(result):
        # The quiet outcome of a map of another season or light without --map-reference-scale.
        across = "; a map made in another season or light needs --map-reference-scale (e.g. 0.95)"
        across = across if config.map_reference_scale == 0 else ""
        warn(f"{recording}: no keyframe was placed in the map of {prior}: all new ground{across}")
    return EstimateSummary(
        output=full_path(output),
        samples=counts.samples,
        keyframes=len(result.keyframe_stamps_ns),
        states=len(result.states),
        links=len(result.links),
        hypotheses=len(result.hypotheses),
        wall_s=time.perf_counter() - start,
        slam_s=counts.slam_s,
        embed_s=embed_s,
        recording_sha256=metadata.recording.sha256,
        odometry_restarts=counts.odometry_restarts,
    )


def _entered_the_map(result: EstimateResult) -> bool:
    """Whether the final map puts any keyframe of this run in a place of the prior map."""
    first = result.first_keyframe
    return any(state.id < first and any(k >= first for k in state.keyframes) for state in result.states)


def geometry_camera(source: Input, recording: Path) -> PinholeCamera:
    """The pinhole camera of ``source``'s images, which ``--geometric-check-m`` needs (InputError,
    naming the file, where no camera info gives it)."""
    from aslam.core.geometry import PinholeCamera

    intrinsics = source.camera()
    if intrinsics is None:
        raise InputError(
            "--geometric-check-m needs the camera's intrinsics, and this input gives none: it needs"
            " one sensor_msgs/CameraInfo topic whose K has a focal length above 0 and whose image size"
            " is set (an uncalibrated driver publishes K = 0); leave the check off (0)",
            path=recording,
        )
    return PinholeCamera(
        intrinsics.fx, intrinsics.cx, intrinsics.cy, intrinsics.width_px, intrinsics.height_px
    )


def load_prior_map(path: Path, config: EstimatorConfig) -> tuple[PriorMap, MapIdentity]:
    """The map of the estimate file ``path``, to start a run in; EstimateError when it cannot be:
    not an estimate, no stored views, views another observation model made."""
    from aslam.app.metric_view import estimator_config
    from aslam.core.estimator import prior_map
    from aslam.core.observation import descriptor_key
    from aslam.data_formats.estimate import (
        MapIdentity,
        map_digest,
        open_estimate,
        read_estimate,
        read_place_views,
    )

    if not path.exists():
        raise InputError("no such map (an estimate file from `aslam estimate`)", path=path)
    # opened once: the graph, the views and the digest are one file's, if it is replaced meanwhile
    source = open_estimate(path)
    info = read_estimate(source)
    if not info.graph.states:  # no views are stored for no places: not a map made before views were
        raise EstimateError(
            "the map is empty (its run had no keyframes): nothing to start in; estimate without --map",
            path=path,
        )
    views = read_place_views(source)
    try:
        made_with = estimator_config(info.metadata.config)
    except ValueError as err:
        raise EstimateError(str(err), path=path) from err
    if descriptor_key(made_with) != descriptor_key(config):
        raise EstimateError(
            f"the map's views were made with {descriptor_key(made_with)}, this run's would be made with"
            f" {descriptor_key(config)}: give this run the map's options",
            path=path,
        )
    try:
        start = prior_map(info.graph.keyframes, info.graph.states, info.graph.links, views.views)
    except ValueError as err:
        raise EstimateError(f"not a usable map: {err}", path=path) from err
    if not np.array_equal(start.states, views.states):
        raise EstimateError("the stored views are not those of the map's places", path=path)
    digest = map_digest(info.graph)
    identity = MapIdentity(str(full_path(path)), source.sha256(), info.graph.keyframes, digest)
    return start, identity
