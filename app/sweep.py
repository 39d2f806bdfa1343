"""``run_sweep()``: every (recording, parameter set) of a sweep file as a task on Dask distributed.

Shaped like ``aslam.app.estimate.estimate``: paths and typed inputs in, progress through
callbacks, a typed result back; no terminal. A task calls the application layer
(:func:`aslam.app.estimate.estimate`, then :func:`aslam.app.score.score`) on a worker, from files
the worker can reach: the recordings and ``RESULTS_DIR`` (on a cluster: a shared filesystem, at
the same path on every machine). A recording to render is one render task whose future the
estimate tasks that read it depend on, so it is rendered once, before them, on some worker.

Tasks never raise: a failure becomes a row with its error, and the sweep goes on. Each finished
task is saved at once as ``RESULTS_DIR/tasks/KEY.json``, so an interrupted sweep loses nothing;
a re-run skips tasks whose successful result is saved (``force`` recomputes), and with nothing
left to do writes nothing, so a read-only results folder still gives its rows. A task's key is the
SHA-256 of its recording's identity (the file's SHA-256, or for a recording to render its
configuration, which decides its bytes), its full estimator configuration, the scoring options
and the code version (``provenance.code_version``: the version and a SHA-256 of its source and of
the versions of the libraries that compute with it, so the results of other code, or of other
numpy, are never reused). The tables (``results.parquet``, ``results.csv``) hold
one row per task, in task order (recordings in file order, then parameter sets in grid order), so
the same sweep gives the same rows, except the timing and worker columns.
"""

from __future__ import annotations

import contextlib
import gc
import hashlib
import json
import logging
import os
import re
import shutil
import socket
import tempfile
import time
import weakref
from collections import Counter
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from aslam.app.sweep_file import TOPIC_KEYS, ListedRecording, ScoreOptions, Sweep, estimator_config
from aslam.core.config import EstimatorConfig
from aslam.core.errors import AslamError, ConfigError, InputError, one_line
from aslam.data_formats.files import (
    LOCK_FILE,
    check_folder_free,
    check_output_folder,
    folder_lock,
    full_path,
    remove_stale_partials,
    source_files,
    source_sha256,
    utf8_text,
    write_problem,
)
from aslam.data_formats.provenance import code_version, library_versions
from aslam.data_formats.rosbag_source import BAG_KINDS, SourceKind, open_source, summarize_bag
from aslam.data_formats.sources import TopicChoice, not_an_input
from aslam.data_formats.sweep_files import (
    HASHES_FILE,
    RESULTS_CSV,
    RESULTS_PARQUET,
    TASKS_FOLDER,
    holds,
    read_json_document,
    table_file_bytes,
    task_file,
    write_json_document,
    write_table_file,
)
from aslam.recorder.config import NoiseParams, RecordConfig

if TYPE_CHECKING:
    from aslam.app.estimate import EstimateProgress

ESTIMATES_FOLDER = "estimates"
RENDERS_FOLDER = "recordings"
#: Dask settings of the local cluster :func:`open_client` starts (a cluster at ``--scheduler`` keeps
#: its own); the reason for each is beside it.
LOCAL_CLUSTER_SETTINGS = {
    # None: the variable is not set (Dask's convention); see open_client.
    "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None,
    # The statistical profiler samples each task's stack every 10 ms for a dashboard nobody looks at
    # here (measured: 12 % of CPU).
    "distributed.worker.profile.enabled": False,
    # Housekeeping for dashboards and event-loop diagnostics, at a second instead of every 20-500 ms:
    # idle, the scheduler and two workers took a third of a core; 20 sweep tasks ran 10-15 % faster.
    "distributed.admin.tick.interval": "1s",
    "distributed.admin.system-monitor.interval": "5s",
    "distributed.worker.memory.monitor-interval": "1s",
}
#: Columns of every row besides the parameters (``param.NAME``) and the figures (summary keys).
TIMING_COLUMNS = ("estimate_wall_s", "keyframes_per_second", "task_cpu_s")
#: Columns that legitimately differ between two runs of the same sweep.
VARYING_COLUMNS = (*TIMING_COLUMNS, "timing.keyframes_per_second", "timing.slam_ms_per_keyframe", "worker")


class TasksFailed(AslamError):
    """Some tasks of a sweep failed; their rows say why (exit 3). The others' results are written."""

    exit_code = 3


class ClusterLost(AslamError):
    """The Dask cluster could not run the tasks, or went away (exit 2): no row for tasks that never
    ran; those done are saved, so a run again finishes the rest."""


#: How long a cluster may have no worker (none at the start, or all gone) before the sweep gives up.
WORKERS_WAIT_S = 30.0
#: How often, while no task finishes, the sweep asks the scheduler whether it still has workers.
WORKERS_CHECK_S = 5.0
#: How often, with a task timeout, the workers are asked how long their tasks have been computing.
TIMEOUT_CHECK_S = 1.0
#: How long a scheduler has to say who it is.
SCHEDULER_ANSWER_S = 10.0
#: How long a scheduler file may take to appear: a batch job starts the scheduler and the sweep together.
SCHEDULER_FILE_WAIT_S = 30.0
#: The Dask event topic on which an estimate task says how far it is (a share of its images read).
PROGRESS_TOPIC = "aslam-sweep-progress"
#: How often at most a task says so: events go through the scheduler to every subscribed client.
PROGRESS_EVERY_S = 0.5


def _digest(value: Any) -> str:
    text = json.dumps(value, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode()).hexdigest()


# --- the plan --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Source:
    """Where a task's recording comes from: a file given in the sweep, or a render."""

    path: Path
    """The recording file (for a render: where the render task writes it, under RESULTS_DIR)."""
    identity: str
    """SHA-256 of the file, or of the render configuration (which decides the file's bytes)."""
    name: str
    """What the terminal's tables call the file: its name, or where another recording of the sweep
    has that name, the shortest tail of its path no other has (``a/run.mcap``, ``b/run.mcap``)."""
    render: RecordConfig | None = None
    topics: TopicChoice = field(default_factory=TopicChoice)
    """Its ``[recordings]`` table's topic keys (a render's topics are the standard ones)."""

    @property
    def label(self) -> str:
        if self.render is None:
            named = topics_text(self.topics)
            return f"{self.name} ({named})" if named else self.name
        return f"render {render_text(self.render)} ({self.name})"  # every setting not the default


def topic_keys(topics: TopicChoice) -> dict[str, str]:
    """The topic keys a recording was given, as the sweep file names them (``image_topic``: ``/cam``)."""
    given = ((key, getattr(topics, name)) for key, name in TOPIC_KEYS.items())
    return {key: value for key, value in given if value}


def topics_text(topics: TopicChoice) -> str:
    """Those keys as the tables show them (``image_topic=/cam``); empty for none."""
    return " ".join(f"{key}={value}" for key, value in topic_keys(topics).items())


def distinct_names(paths: Iterable[Path]) -> dict[Path, str]:
    """Each path's shortest tail that no other path ends with: its file name, unless another has
    that name (then ``a/run.mcap`` and ``b/run.mcap``; a whole path at most)."""
    names: dict[Path, str] = {}
    pending = set(paths)
    length = 1
    while pending:
        # A path whose tail of this length is unique cannot share a longer tail with another one.
        tails = Counter(path.parts[-length:] for path in pending)
        for path in list(pending):
            tail = path.parts[-length:]
            if tails[tail] == 1 or length >= len(path.parts):
                names[path] = str(Path(*tail))
                pending.discard(path)
        length += 1
    return names


@dataclass(frozen=True)
class Task:
    """One estimate + score: a recording under one parameter set."""

    index: int
    source: Source
    parameters: tuple[tuple[str, Any], ...]
    """Its grid's values for this task (the rest of the configuration is the default)."""
    config: EstimatorConfig
    score: ScoreOptions
    key: str
    estimate_path: Path
    same_as: int | None = None
    """The earlier task with this key (the same recording bytes under another name, the same
    configuration): computed once, its result is this row's too. None for a task computed itself."""


def render_path(results_dir: Path, config: RecordConfig) -> tuple[Path, str]:
    """Where a render of ``config`` goes, and its identity: the SHA-256 of the configuration and of
    the files it names (a route or world file edited since is another render, not a stale one),
    with every file the world file loads (its buffers, materials, textures), as the recorder says,
    and the code version (another recorder's render is rendered again).

    A file counts by its name and bytes, not its folder, as in the recording: the sweep's folder
    copied elsewhere (another checkout, a CI cache) finds its renders and keeps its task keys.
    """
    from aslam.recorder.routes import PRESETS
    from aslam.recorder.world import scene_companions

    recorded = asdict(config)
    files: dict[str, Any] = {}
    if config.route not in PRESETS and Path(config.route).is_file():
        files["route"] = source_sha256(Path(config.route))
        recorded["route"] = Path(config.route).name
    if config.world is not None and Path(config.world).is_file():
        files["world"] = source_sha256(Path(config.world))
        recorded["world"] = Path(config.world).name
        companions = scene_companions(Path(config.world))
        if companions:  # a self-contained world (a .glb, a bare .obj) has none
            files["world_companions"] = companions
    named = {"files": files} if files else {}  # a preset names no file
    identity = _digest({"render": recorded, **named, "version": code_version()})
    name = f"{Path(config.route).stem}-seed{config.seed}-{identity[:12]}.mcap"
    return results_dir / RENDERS_FOLDER / name, identity


class HashCache:
    """Recordings' SHA-256 kept in ``RESULTS_DIR/hashes.json``, valid while path, size and mtime hold.

    A re-run then reads no recording it has hashed before; a recording rewritten since (another
    size or mtime) is hashed again. The identity stays the content's hash, so a copied or moved
    recording is still the same task.
    """

    def __init__(self, path: Path | None, *, use: bool = True) -> None:
        self.path = path
        self.entries: dict[str, dict[str, Any]] = {}
        if path is not None and use:
            loaded = read_json_document(path)
            self.entries = loaded if isinstance(loaded, dict) else {}
        self.changed = False

    def sha256(self, recording: Path) -> str:
        try:
            # Each file's: a bag folder's own size and mtime stay when a file in it is rewritten in
            # place, and a re-run kept the old bag's results (then failed each new task as "not the
            # bytes planned", for good).
            stamp = {
                "files": [
                    [file.name, status.st_size, status.st_mtime_ns]
                    for file in source_files(recording)
                    for status in (file.stat(),)
                ]
            }
        except OSError as err:
            raise InputError(f"cannot read: {err.strerror or err}", path=recording) from err
        entry = self.entries.get(str(recording))
        if isinstance(entry, dict) and all(entry.get(k) == v for k, v in stamp.items()):
            digest = entry.get("sha256")
            if isinstance(digest, str):
                return digest
        digest = source_sha256(recording)
        self.entries[str(recording)] = {**stamp, "sha256": digest}
        self.changed = True
        return digest

    def save(self) -> None:
        if self.path is not None and self.changed:
            write_json_document(self.path, self.entries)


def _check_inputs(sweep_file: Path, listed: Sequence[ListedRecording]) -> None:
    """ConfigError naming every listed path that is no recording or bag (a README a glob met, an
    estimate, a folder), or a bag whose topics its index shows cannot be read as its table names
    them (a topic not in it, two image topics and none named): told at the dry run, not as failed
    tasks after the others ran (a typo in a topic failed every row of its bags)."""
    problems: list[str] = []
    kinds: dict[Path, SourceKind] = {}
    for path in dict.fromkeys(recording.path for recording in listed):
        try:
            kinds[path] = open_source(path)
        except InputError as err:
            problems.append(str(err))
            continue
        if kinds[path] is SourceKind.IMAGE_FOLDER:
            problems.append(str(not_an_input(path)))
    if problems:
        raise ConfigError(
            "recordings.paths names what a sweep cannot read (a glob such as 'runs/**/*.mcap' names"
            " recordings only): " + "; ".join(problems),
            path=sweep_file,
        )
    for path, topics in listed:
        if kinds[path] in BAG_KINDS:
            try:
                problem = summarize_bag(path, topics.bag_topics()).problem
            except InputError:  # a damaged bag: its rows say how, as a damaged recording's do
                continue
            if problem is not None:
                problems.append(f"{path}: {problem}")
    if problems:
        raise ConfigError(
            "a bag's topics cannot be read as its recordings table names them (keys image_topic,"
            " odometry_topic, ground_truth_topic): " + "; ".join(dict.fromkeys(problems)),
            path=sweep_file,
        )


def plan_tasks(sweep: Sweep, results_dir: Path, *, hashes: HashCache | None = None) -> list[Task]:
    """Every task of ``sweep``, in the stable order the rows take; a configuration two grids both
    name on one recording once, where it first comes.

    Hashes each recording file (one sequential read), or takes its hash from ``hashes``. A listed
    file in the results folder's own subfolders is the sweep's output (a render, an estimate,
    matched by a ``**`` glob on a second run), not a recording: left out. Only those: recordings
    beside them (``-o .`` in the recordings' folder) were all left out too, a sweep of no task,
    exit 0. Two names of the same bytes (a copy, a
    link) each get their tasks, so every recording named has its rows; the later one's tasks have
    ``same_as`` set and share the first's results, computed once.
    """
    results_dir = full_path(results_dir)
    hashes = hashes if hashes is not None else HashCache(None)
    own = [results_dir / name for name in (RENDERS_FOLDER, ESTIMATES_FOLDER, TASKS_FOLDER)]
    listed = [
        recording
        for recording in sweep.recordings
        if not any(full_path(recording.path).is_relative_to(folder) for folder in own)
    ]
    _check_inputs(sweep.path, listed)
    names = distinct_names(dict.fromkeys(recording.path for recording in listed))
    sources = [Source(path, hashes.sha256(path), names[path], topics=topics) for path, topics in listed]
    for render in sweep.renders:
        path, identity = render_path(results_dir, render)
        sources.append(Source(path, identity, path.name, render))
    tasks: list[Task] = []
    first: dict[str, int] = {}  # key -> the task that computes it
    planned: set[tuple[Path, str]] = set()
    for source in sources:
        for parameters in sweep.parameter_sets():
            config = estimator_config(parameters)
            key = _digest(
                {
                    "recording": source.identity,
                    "topics": asdict(source.topics),
                    "config": asdict(config),
                    "score": asdict(sweep.score),
                    "version": code_version(),
                }
            )
            if (source.path, key) in planned:
                continue
            planned.add((source.path, key))
            tasks.append(
                Task(
                    index=len(tasks),
                    source=source,
                    parameters=parameters,
                    config=config,
                    score=sweep.score,
                    key=key,
                    estimate_path=results_dir / ESTIMATES_FOLDER / f"{key[:16]}.mcap",
                    same_as=first.get(key),
                )
            )
            first.setdefault(key, len(tasks) - 1)
    return tasks


# --- what runs on a worker -------------------------------------------------------------------------


@dataclass(frozen=True)
class Rendered:
    """A render task's outcome, handed to the estimate tasks that depend on it."""

    path: Path
    error: str | None = None
    seconds: float = 0.0


@dataclass(frozen=True)
class TaskResult:
    """What a task sends back: the whole summary (every figure), timings, or the error."""

    index: int
    key: str
    summary: dict[str, Any] | None
    """Every dotted leaf of the report summary; None when the task failed."""
    error: str | None
    warnings: tuple[str, ...]
    estimate_wall_s: float | None
    keyframes_per_second: float | None
    worker: str
    task_cpu_s: float | None = None
    """CPU seconds of the worker process during the task (estimate and score; its threads too)."""

    @property
    def ok(self) -> bool:
        return self.error is None


def error_text(err: BaseException) -> str:
    """The one line a failed task shows: an ``AslamError``'s message, else the type and message."""
    return one_line(str(err) if isinstance(err, AslamError) else f"{type(err).__name__}: {err}")


_OPTION_WORDS = re.compile(
    r"(?<![\w/'-])--("
    + "|".join(key.replace("_", "-") for key in TOPIC_KEYS)
    + r")(?![\w/'-])"
    + r"( of estimate or report)?"
)


def in_sweep_words(line: str) -> str:
    """A task's error or warning with the topic options it names as the sweep file's keys: the
    reading says what to give ``aslam estimate`` (``--odom-frame``), and a sweep's user writes
    ``odom_frame`` in ``[recordings]``. Only options standing alone: a path or topic with
    ``--image-topic`` in its name keeps it."""

    def key(match: re.Match[str]) -> str:
        name = match.group(1).replace("-", "_")
        return f"{name} in the sweep file's [recordings]" if match.group(2) else name

    return _OPTION_WORDS.sub(key, line)


def worker_name() -> str:
    """The Dask worker's address, or host:pid outside a worker."""
    try:
        from distributed import get_worker

        return str(get_worker().address)
    except (ImportError, ValueError):
        return f"{socket.gethostname()}:{os.getpid()}"


def _progress_publisher(task: Task) -> Callable[[EstimateProgress], None] | None:
    """On a Dask worker, what tells the sweep's client how far ``task``'s estimate is (a share of its
    images read, at most every ``PROGRESS_EVERY_S``): a sweep of a few long tasks otherwise showed a
    bar at 0 for minutes (40 s on one 10,000-frame task). None outside a worker."""
    try:
        from distributed import get_worker

        worker = get_worker()
    except (ImportError, ValueError):
        return None
    said_at: float | None = None

    def publish(progress: EstimateProgress) -> None:
        nonlocal said_at
        now = time.monotonic()
        if not progress.samples_total or (said_at is not None and now - said_at < PROGRESS_EVERY_S):
            return
        said_at = now
        done = min(1.0, progress.samples / progress.samples_total)
        worker.log_event(PROGRESS_TOPIC, {"key": task.key, "done": done})

    return publish


def render_task(config: RecordConfig, path: Path, force: bool) -> Rendered:
    """Render ``config`` to ``path`` unless it is already there (renders are atomic and deterministic)."""
    from aslam.recorder.record import record

    start = time.perf_counter()
    try:
        if force or not path.exists():
            path.parent.mkdir(parents=True, exist_ok=True)
            record(config, path, force=True)
    except Exception as err:
        return Rendered(path, f"render failed: {error_text(err)}", time.perf_counter() - start)
    return Rendered(path, None, time.perf_counter() - start)


def _file_stamp(path: Path) -> tuple[int, int, int, int]:
    """What changes when a file (or a bag folder's contents) is written or replaced."""
    stat = path.stat()
    return stat.st_dev, stat.st_ino, stat.st_size, stat.st_mtime_ns


def run_task(task: Task, rendered: Rendered | None = None) -> TaskResult:
    """Estimate and score one task, in this process; every failure becomes the result's error.

    The pipeline runs in this thread (``reader_process=False``, ``workers=0``): one task per core
    is the sweep's parallelism, and a reader process or a describing thread per task would only add
    hand-offs between two busy cores (a Dask worker, daemonic, reads in its own process either way:
    :func:`aslam.app.pipeline.can_fork`).
    """
    from aslam.app.estimate import estimate
    from aslam.app.score import leaves, score

    warnings: list[str] = []
    worker = worker_name()
    cpu_start = time.process_time()

    def failed(error: str) -> TaskResult:
        error = in_sweep_words(error)
        return TaskResult(task.index, task.key, None, error, tuple(warnings), None, None, worker)

    if rendered is not None and rendered.error is not None:
        return failed(rendered.error)
    replaced = (
        f"{task.source.path}: not the bytes the sweep planned this task with (another file was written"
        " in its place since); run the sweep again to estimate what is there now"
    )
    try:
        before = _file_stamp(task.source.path)
        task.estimate_path.parent.mkdir(parents=True, exist_ok=True)
        summary = estimate(
            task.source.path,
            task.estimate_path,
            task.config,
            force=True,
            topics=task.source.topics,
            workers=0,
            reader_process=False,
            on_warning=lambda line: warnings.append(in_sweep_words(line)),
            on_progress=_progress_publisher(task),
        )
        if task.source.render is None and summary.recording_sha256 != task.source.identity:
            return failed(replaced)
        report = score(
            task.estimate_path,
            recording=task.source.path,
            radius_m=task.score.radius_m,
            heading_deg=task.score.heading_deg,
            ground_truth_topic=task.source.topics.ground_truth,
            on_warning=lambda line: warnings.append(in_sweep_words(line)),
        )
        # Replaced after the estimate read it, the truth was read from the new file (or, of another
        # size, not at all: a row without precision saved as done).
        if _file_stamp(task.source.path) != before:
            return failed(replaced)
    except Exception as err:
        return failed(error_text(err))
    return TaskResult(
        task.index,
        task.key,
        leaves(report.summary),
        None,
        tuple(warnings),
        summary.wall_s,
        summary.keyframes_per_second,
        worker,
        time.process_time() - cpu_start,
    )


# --- saved results ---------------------------------------------------------------------------------


def save_result(results_dir: Path, result: TaskResult) -> None:
    """Keep a finished task's result (atomically), so that a re-run can skip it."""
    write_json_document(task_file(results_dir, result.key), asdict(result))


def load_result(results_dir: Path, task: Task) -> TaskResult | None:
    """The saved successful result of ``task``, or None (absent, failed, unreadable or another task's)."""
    data = read_json_document(task_file(results_dir, task.key))
    try:
        result = TaskResult(**{**data, "index": task.index, "warnings": tuple(data["warnings"])})
    except (ValueError, TypeError, KeyError):
        return None
    return result if result.ok and result.key == task.key else None


@dataclass(frozen=True)
class SweepPlan:
    """What a sweep has to do in its results folder, found by reading only."""

    tasks: tuple[Task, ...]
    """Every row, in task order."""
    done: Mapping[int, TaskResult]
    """The saved successful results, by task index (none with ``force``)."""
    to_run: tuple[Task, ...]
    """The tasks to compute: those not done, a key once (a copy's rows share the first's result)."""
    cannot_write: str | None = None
    """Why no result could be saved in the results folder (``FOLDER: Read-only file system``), or
    None. A plan with nothing to run needs no writing: a read-only finished sweep is shown as it is."""
    force: bool = False
    """Planned for ``force``: every task to run, every render made again."""

    @property
    def reused(self) -> int:
        """Tasks computed by an earlier run (rows sharing another's result not counted)."""
        return sum(task.same_as is None and task.index in self.done for task in self.tasks)

    @property
    def shared(self) -> int:
        """Rows whose result is another row's (the same bytes under another name)."""
        return sum(task.same_as is not None for task in self.tasks)

    @property
    def renders_due(self) -> int:
        """Recordings the tasks to run render first: those not rendered yet (all, with ``force``; a
        render already there is otherwise used as it is)."""
        paths = {task.source.path for task in self.to_run if task.source.render is not None}
        return len(paths) if self.force else sum(not path.exists() for path in paths)

    def state(self, task: Task) -> str:
        """``done``, ``to run``, or ``shared`` (its result is task ``same_as``'s)."""
        if task.same_as is not None:
            return "shared"
        return "done" if task.index in self.done else "to run"

    def check_writable(self) -> None:
        """:class:`InputError` (exit 2) when there are tasks to run and their results could not be
        saved: said before any task runs, not after the first finished."""
        if self.to_run and self.cannot_write is not None:
            count = len(self.to_run)
            raise InputError(
                f"{self.cannot_write}; the results folder must be writable for the {count}"
                f" task{'s' if count != 1 else ''} to run"
            )

    def as_dict(self) -> dict[str, Any]:
        """The plan as ``aslam sweep --dry-run --json`` writes it: the counts, then every task."""
        return {
            "tasks": len(self.tasks),
            "done": self.reused,
            "to_run": len(self.to_run),
            "shared": self.shared,
            "renders_due": self.renders_due,
            "cannot_write": self.cannot_write,
            "rows": [
                {
                    "task": task.index,
                    "key": task.key[:16],
                    "state": self.state(task),
                    "same_as": task.same_as,
                    "recording": str(task.source.path),
                    "render": "" if task.source.render is None else render_text(task.source.render),
                    "topics": topic_keys(task.source.topics),
                    "parameters": dict(task.parameters),
                }
                for task in self.tasks
            ],
        }

    def copies(self) -> list[tuple[Path, Path]]:
        """Each recording named whose bytes an earlier one has, with that earlier one."""
        pairs = {
            (task.source.path, self.tasks[task.same_as].source.path): None
            for task in self.tasks
            if task.same_as is not None
        }
        return list(pairs)


def plan_sweep(
    sweep: Sweep,
    results_dir: Path,
    *,
    force: bool = False,
    hashes: HashCache | None = None,
    on_warning: Callable[[str], None] | None = None,
) -> SweepPlan:
    """Plan ``sweep`` (:func:`plan_tasks`) and find the tasks done in ``results_dir``; writes nothing.
    ``on_warning`` hears of each recording named whose bytes an earlier one has."""
    results_dir = full_path(results_dir)
    tasks = tuple(plan_tasks(sweep, results_dir, hashes=hashes))
    done: dict[int, TaskResult] = {}
    if not force:
        for task in tasks:
            saved = load_result(results_dir, task)
            if saved is not None:
                done[task.index] = saved
    to_run = tuple(task for task in tasks if task.same_as is None and task.index not in done)
    plan = SweepPlan(tasks, done, to_run, _write_problem(results_dir), force)
    if on_warning is not None:
        for copy, original in plan.copies():
            on_warning(
                f"{copy}: the same bytes as {original};"
                " its rows share that recording's results (computed once)"
            )
    return plan


def dry_run(
    sweep: Sweep,
    results_dir: Path | str,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    force: bool = False,
    task_timeout: float | None = None,
    on_warning: Callable[[str], None] | None = None,
) -> SweepPlan:
    """What :func:`run_sweep` with these arguments would do: its options checked, its tasks planned
    and those done in ``results_dir`` found, without a cluster or a single write (not even the
    hash cache: a recording not hashed before is read). :meth:`SweepPlan.check_writable` says
    whether the run could save its results."""
    _check_options(workers, scheduler, task_timeout)
    results_dir = full_path(results_dir)
    check_output_folder(results_dir, what="results folder")
    hashes = HashCache(results_dir / HASHES_FILE, use=not force)
    return plan_sweep(sweep, results_dir, force=force, hashes=hashes, on_warning=on_warning)


def _check_options(workers: int | None, scheduler: str | None, task_timeout: float | None = None) -> None:
    """The one check of the cluster options (a run, a dry run, ``open_client`` for bench and notebooks)."""
    if scheduler is not None and workers is not None:
        raise InputError("--workers sizes a local cluster; the cluster at --scheduler has its own workers")
    if workers is not None and workers < 1:
        raise InputError(f"--workers must be at least 1, got {workers}")
    if task_timeout is not None and not 0 < task_timeout < float("inf"):
        raise InputError(f"--task-timeout must be a number of seconds above 0, got {task_timeout:g}")


def _write_problem(results_dir: Path) -> str | None:
    """The first of the folders a run writes into (the tables and hashes, the tasks' results, the
    estimates, the renders) that exists and cannot be written, and why."""
    for folder in (
        results_dir,
        *(results_dir / name for name in (TASKS_FOLDER, ESTIMATES_FOLDER, RENDERS_FOLDER)),
    ):
        problem = write_problem(folder)
        if problem is not None:
            return f"{folder}: {problem}"
    return None


# --- running ---------------------------------------------------------------------------------------


@dataclass(frozen=True)
class SweepRun:
    """A finished sweep: every task with its result, and the tables written."""

    tasks: tuple[Task, ...]
    results: tuple[TaskResult, ...]
    """In task order."""
    reused: int
    """Tasks whose results an earlier run saved (rows sharing another's result not counted)."""
    computed: int
    """Tasks computed by this run."""
    shared: int
    """Rows whose result is another row's: the same recording bytes under another name."""
    parquet: Path
    csv: Path
    tables_written: bool
    """False when the tables already held these bytes (a re-run with nothing to do), or the
    results folder could not be written and nothing was run."""

    @property
    def failed(self) -> int:
        return sum(not r.ok for r in self.results)

    def check(self) -> None:
        """Raise :class:`TasksFailed` (exit 3) if any task failed."""
        if self.failed:
            raise TasksFailed(
                f"{self.failed} of {len(self.tasks)} tasks failed; their rows say why", path=self.csv
            )


def scheduler_address(scheduler_file: Path) -> str:
    """The address in the file ``dask scheduler --scheduler-file`` writes (as dask-mpi and HPC job
    scripts use), read with Dask's own reader: a file still being written, or not yet there, is
    waited for up to ``SCHEDULER_FILE_WAIT_S``, as ``Client(scheduler_file=...)`` does."""
    from distributed.utils import json_load_robust

    try:
        info = json_load_robust(str(scheduler_file), timeout=SCHEDULER_FILE_WAIT_S)
    except TimeoutError:
        waited = f"{SCHEDULER_FILE_WAIT_S:g} s"
        problem = (
            f"not a Dask scheduler file (no JSON in it after {waited})"
            if Path(scheduler_file).exists()
            else f"no such Dask scheduler file (waited {waited} for the scheduler to write it)"
        )
        raise InputError(problem, path=scheduler_file) from None
    except OSError as err:  # a folder, no permission
        raise InputError(
            f"cannot read the Dask scheduler file: {error_text(err)}", path=scheduler_file
        ) from err
    address = info.get("address") if isinstance(info, dict) else None
    if not isinstance(address, str) or not address:
        raise InputError("not a Dask scheduler file (no 'address')", path=scheduler_file)
    return address


def open_client(*, workers: int | None, scheduler: str | None) -> Any:
    """A Dask client: of the cluster at ``scheduler``, or of a new local cluster of worker processes.

    The local cluster has ``workers`` processes (default: one per core) of one thread each: the
    estimator holds the GIL, so processes, not threads, use the cores. Its workers start without
    the ``MALLOC_TRIM_THRESHOLD_=65536`` Dask's nanny sets by default: that fixed threshold also
    turns off glibc's adaptive mmap threshold, and every decoded image then costs an mmap/munmap
    and its page faults (measured: twice the CPU time of a task).
    """

    import dask
    from distributed import Client, LocalCluster

    _check_options(workers, scheduler)
    if scheduler is not None:
        _probe_scheduler(scheduler)
        try:
            return Client(scheduler, timeout="10s")
        except (OSError, TimeoutError, ValueError, TypeError) as err:  # ValueError: not an address
            message = f"cannot reach the Dask scheduler at {scheduler}: {error_text(err)}"
        # The half-made Client is a reference cycle (its own handlers) that only the garbage collector
        # frees, closing it then: at a random later moment, and if that is inside another Client's
        # start, distributed deadlocks (the loop runner's lock, held, taken again by the dying
        # client's close; seen in the test suite). Collected here, where nothing else is starting.
        gc.collect()
        raise InputError(message)
    from dask.system import CPU_COUNT  # the cores this process may use: affinity and cgroup quotas

    count = workers if workers is not None else CPU_COUNT
    # The workers' folders and Dask's lock files, which it leaves in $TMPDIR/dask-scratch-space: in a
    # folder of this cluster's own, removed when it is closed (or collected, or at exit).
    scratch = tempfile.mkdtemp(prefix="aslam-dask-")
    try:
        with dask.config.set({**LOCAL_CLUSTER_SETTINGS, "temporary-directory": scratch}):
            cluster = LocalCluster(
                n_workers=count,
                threads_per_worker=1,
                processes=True,
                # Its HTTP server (metrics; no dashboard without bokeh) starts either way: on a free
                # port, since None meant 8787, and where a notebook's own cluster held that, Dask warned.
                dashboard_address=":0",
                silence_logs=logging.CRITICAL,  # a failing task is a row; shutdown chatter is noise
            )
    except BaseException:  # a worker that cannot start, a timeout, Ctrl-C: no folder left behind
        shutil.rmtree(scratch, ignore_errors=True)
        raise
    _SCRATCH[cluster] = weakref.finalize(cluster, shutil.rmtree, scratch, ignore_errors=True)
    return Client(cluster)


#: The scratch folder of each local cluster :func:`open_client` started, removed by calling it.
_SCRATCH: weakref.WeakKeyDictionary[Any, weakref.finalize] = weakref.WeakKeyDictionary()


def _probe_scheduler(address: str) -> None:
    """Ask ``address`` who it is, within ``SCHEDULER_ANSWER_S``: a port where something else
    listens would keep the client waiting for ever; ``tls://`` without its settings fails in the
    client's innards."""
    import asyncio

    from distributed.core import rpc

    async def identity() -> Any:
        remote = rpc(address, timeout=5)
        try:
            return await asyncio.wait_for(remote.identity(), SCHEDULER_ANSWER_S)
        finally:
            await remote.close_rpc()

    from concurrent.futures import ThreadPoolExecutor

    try:  # in a thread of its own: a caller's running event loop (a notebook's) is not disturbed
        with ThreadPoolExecutor(1) as thread:
            thread.submit(asyncio.run, identity()).result()
    except TimeoutError:
        raise InputError(
            f"nothing answers as a Dask scheduler at {address} within {SCHEDULER_ANSWER_S:g} s"
        ) from None
    except MemoryError:  # a service that speaks first (SSH's banner) read as a frame's length
        raise InputError(f"something else answers at {address}: not a Dask scheduler") from None
    except Exception as err:  # refused, not an address, a transport without its settings (tls, ucx)
        raise InputError(f"cannot reach the Dask scheduler at {address}: {error_text(err)}") from err


def check_workers(client: Any, address: str) -> None:
    """A cluster of one's own must have workers, and every one must run this aslam: a worker
    without it never takes a task (the sweep would wait for ever), and one of other code (another
    version, or the same version edited) would file its results under this code's task keys."""
    try:
        client.wait_for_workers(1, timeout=WORKERS_WAIT_S)
    except TimeoutError:
        raise ClusterLost(
            f"the Dask cluster at {address} has no workers (waited {WORKERS_WAIT_S:g} s)"
        ) from None
    try:
        versions = client.run(code_version)  # pickled by reference: a worker must import aslam
    except Exception as err:
        raise ClusterLost(
            f"a worker of the Dask cluster at {address} cannot run aslam: {error_text(err)}"
        ) from err
    ours = code_version()
    for worker, version in sorted(versions.items()):
        if version != ours:
            difference = _library_difference(client, worker) or f"aslam {version}; this is aslam {ours}"
            raise ClusterLost(f"worker {worker} of the Dask cluster at {address} runs {difference}")


def _library_difference(client: Any, worker: str) -> str | None:
    """The first library whose version on ``worker`` is not this process's, as ``numpy 2.5.5; here
    numpy 2.4.6``; None where none differs (its aslam code does), or it cannot say (an aslam older
    than ``library_versions``). Two code versions alone do not tell a user what to reinstall."""
    ours = library_versions()
    try:
        theirs = client.run(library_versions, workers=[worker])[worker]
    except Exception:
        return None
    for library, installed in ours.items():
        if theirs.get(library) != installed:
            return f"{library} {theirs.get(library, '-')}; here {library} {installed}"
    return None


def run_sweep(
    sweep: Sweep,
    results_dir: Path | str,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    force: bool = False,
    task_timeout: float | None = None,
    extra_figures: Sequence[str] = (),
    client: Any | None = None,
    on_plan: Callable[[SweepPlan], None] | None = None,
    on_result: Callable[[Task, TaskResult, bool], None] | None = None,
    on_warning: Callable[[str], None] | None = None,
    on_progress: Callable[[Task, float], None] | None = None,
) -> SweepRun:
    """Run every task of ``sweep`` not already done in ``results_dir``; write the tables.

    Only a sweep with tasks to run needs to write (else :class:`InputError` before any, exit 2):
    one with nothing left to do in a read-only results folder gives its results as they are.

    ``on_plan(plan)`` is called once before work starts (every task, those done, those to run);
    ``on_result(task, result, reused)`` once per task (row) as it finishes (reused ones first);
    ``on_warning(line)`` for what the user should know (a recording named twice under two names);
    ``on_progress(task, done)`` now and then while a task estimates, ``done`` the share of its images
    read (from Dask's event loop thread, and possibly once more after its result). Results
    arrive in completion order; the tables are in task order and hold the sweep's figures and
    ``extra_figures``. A failed task does not stop the others; :meth:`SweepRun.check` says whether
    any failed.
    ``client``: a Dask client to use (and leave open) instead of starting one (a bench, a notebook).
    ``task_timeout``: seconds a task may compute; one still computing then is a failed row, and
    its worker is restarted to stop it (:func:`_stop_overdue`).
    """
    _check_options(workers, scheduler, task_timeout)
    results_dir = full_path(results_dir)
    check_output_folder(results_dir, what="results folder")
    created = False
    if not results_dir.exists():
        try:
            results_dir.parent.mkdir(parents=True, exist_ok=True)
            with contextlib.suppress(FileExistsError):  # another sweep made it this moment
                results_dir.mkdir()
                created = True
            (results_dir / TASKS_FOLDER).mkdir(exist_ok=True)
        except OSError as err:
            raise InputError(f"cannot create: {err.strerror or err}", path=results_dir) from err
    # One sweep at a time in a folder (a second ran every task again beside the first): refused
    # here, before its recordings are hashed; the folder is held once there are tasks to run.
    if write_problem(results_dir) is None:
        check_folder_free(results_dir, holder=_ANOTHER_SWEEP, what=_RESULTS_FOLDER)
    held: list[bool] = []  # set once this sweep holds the folder
    with contextlib.ExitStack() as hold:
        try:
            return _run_in(
                hold,
                held,
                sweep,
                results_dir,
                workers,
                scheduler,
                force,
                task_timeout,
                extra_figures,
                client,
                on_plan,
                on_result,
                on_warning,
                on_progress,
            )
        except BaseException:
            # A sweep that made its folder and then failed before any work was kept (a scheduler out
            # of reach, a bad recording, an early interrupt) leaves nothing; renders or results stay,
            # to resume. Only while the folder is held, by this sweep or now for the removal: a sweep
            # refused because another took the folder while it hashed its recordings removed the
            # other's folder, lock file and all, under it.
            kept = {entry.name for entry in results_dir.iterdir()} - {HASHES_FILE, TASKS_FOLDER, LOCK_FILE}
            if created and not kept and not any((results_dir / TASKS_FOLDER).iterdir()):
                _remove_unless_taken(results_dir, held=bool(held))
            raise


def _remove_unless_taken(results_dir: Path, *, held: bool) -> None:
    """Remove the results folder this sweep made, holding it (already, or now): not when another
    sweep took it meanwhile, whose folder it then is."""
    with contextlib.ExitStack() as removal:
        if not held:
            try:
                removal.enter_context(folder_lock(results_dir, holder=_ANOTHER_SWEEP, what=_RESULTS_FOLDER))
            except InputError:
                return
        shutil.rmtree(results_dir, ignore_errors=True)


def _run_in(
    hold: contextlib.ExitStack,
    held: list[bool],
    sweep: Sweep,
    results_dir: Path,
    workers: int | None,
    scheduler: str | None,
    force: bool,
    task_timeout: float | None,
    extra_figures: Sequence[str],
    client: Any | None,
    on_plan: Callable[[SweepPlan], None] | None,
    on_result: Callable[[Task, TaskResult, bool], None] | None,
    on_warning: Callable[[str], None] | None,
    on_progress: Callable[[Task, float], None] | None,
) -> SweepRun:
    hashes = HashCache(results_dir / HASHES_FILE, use=not force)
    plan = plan_sweep(sweep, results_dir, force=force, hashes=hashes, on_warning=on_warning)
    plan.check_writable()
    if plan.to_run and plan.cannot_write is None:  # until the caller's ``hold`` ends
        hold.enter_context(folder_lock(results_dir, holder=_ANOTHER_SWEEP, what=_RESULTS_FOLDER))
        held.append(True)
    if plan.cannot_write is None:
        _remove_partials_of_killed_writers(results_dir)  # an interrupted run's
        hashes.save()  # a cache: a read-only folder's is only read
    if on_plan is not None:
        on_plan(plan)
    results = dict(plan.done)
    if on_result is not None:
        for index in sorted(results):
            on_result(plan.tasks[index], results[index], True)
    if plan.to_run:
        (results_dir / TASKS_FOLDER).mkdir(exist_ok=True)
        rows_of: dict[str, list[Task]] = {}
        for task in plan.tasks:
            rows_of.setdefault(task.key, []).append(task)
        own = client is None
        with _dask_logs_quiet(), _environment_kept() if own else contextlib.nullcontext():
            client = open_client(workers=workers, scheduler=scheduler) if own else client
            try:
                if own and scheduler is not None:
                    check_workers(client, scheduler)
                computed = _compute(
                    client,
                    plan.to_run,
                    force=force,
                    task_timeout=task_timeout,
                    done_before=plan.reused,
                    total=plan.reused + len(plan.to_run),
                )
                with _progress_heard(client, plan.to_run, on_progress):
                    for task, result in computed:
                        save_result(results_dir, result)
                        for row in rows_of[task.key]:  # a copy's rows too
                            shared = result if row is task else replace(result, index=row.index)
                            results[row.index] = shared
                            if on_result is not None:
                                on_result(row, shared, False)
            finally:
                if own:
                    _close(client, local=scheduler is None)
        _remove_partials_of_killed_writers(results_dir)  # a worker killed mid-task, its task run again
    ordered = tuple(results[task.index] for task in plan.tasks)
    written = write_tables(results_dir, sweep, plan.tasks, ordered, extra_figures, on_warning=on_warning)
    return SweepRun(
        plan.tasks,
        ordered,
        plan.reused,
        len(plan.to_run),
        plan.shared,
        results_dir / RESULTS_PARQUET,
        results_dir / RESULTS_CSV,
        written,
    )


@contextlib.contextmanager
def _progress_heard(
    client: Any, tasks: Sequence[Task], on_progress: Callable[[Task, float], None] | None
) -> Iterator[None]:
    """``on_progress`` hears the progress events of ``tasks`` (``PROGRESS_TOPIC``) while this holds;
    another sweep's on a shared cluster are not theirs."""
    if on_progress is None:
        yield
        return
    by_key = {task.key: task for task in tasks}
    hearing = [on_progress]  # emptied at the end: the client keeps the handler (distributed 2026.8)

    def heard(event: tuple[float, Any]) -> None:
        _time, message = event
        with contextlib.suppress(Exception):  # (in Dask's event loop: nothing may escape)
            task = by_key.get(message["key"])
            if task is not None and hearing:
                hearing[0](task, float(message["done"]))

    client.subscribe_topic(PROGRESS_TOPIC, heard)
    try:
        yield
    finally:
        hearing.clear()
        by_key.clear()
        with contextlib.suppress(Exception):  # the scheduler may be gone
            client.unsubscribe_topic(PROGRESS_TOPIC)


def _remove_partials_of_killed_writers(results_dir: Path) -> None:
    """What workers were writing when they were killed (renders, estimates, task results): a worker
    killed mid-task, whose task Dask then ran again elsewhere, left its partial file behind."""
    for folder in (
        results_dir,
        *(results_dir / name for name in (RENDERS_FOLDER, ESTIMATES_FOLDER, TASKS_FOLDER)),
    ):
        remove_stale_partials(folder)


_ANOTHER_SWEEP = "another sweep"
_RESULTS_FOLDER = "results folder"


def _compute(
    client: Any,
    tasks: Sequence[Task],
    *,
    force: bool,
    task_timeout: float | None,
    done_before: int = 0,
    total: int | None = None,
) -> Iterable[tuple[Task, TaskResult]]:
    """Submit the render tasks, then the estimate tasks depending on them; yield as they finish.

    While none finishes, the scheduler is asked every ``WORKERS_CHECK_S`` whether it still has
    workers: with none for ``WORKERS_WAIT_S``, or the scheduler gone, the sweep stops (``ClusterLost``)
    instead of waiting for ever; tasks that never ran get no row. With ``task_timeout``, every
    ``TIMEOUT_CHECK_S`` the estimate tasks computing longer are stopped, each a failed row.
    """
    from concurrent.futures import CancelledError

    from distributed import wait

    renders: dict[Path, Any] = {}
    futures: dict[Any, Task] = {}
    for task in tasks:
        dependency = None
        render = task.source.render
        if render is not None:
            if task.source.path not in renders:
                renders[task.source.path] = client.submit(
                    render_task, render, task.source.path, force, key=f"render-{task.source.identity[:16]}"
                )
            dependency = renders[task.source.path]
        future = client.submit(run_task, task, dependency, key=f"estimate-{task.key[:16]}", retries=0)
        futures[future] = task
    finished = done_before
    total = len(tasks) + done_before if total is None else total

    def lost(why: str) -> ClusterLost:
        return ClusterLost(
            f"lost the Dask cluster ({why}): {finished} of {total} tasks done and saved; run again to finish"
        )

    alone_since: float | None = None

    def still_served() -> None:
        """Raise ``ClusterLost`` once the scheduler is gone or has had no worker for too long."""
        nonlocal alone_since
        try:
            workers = len(client.nthreads())
        except Exception as err:  # the scheduler itself is gone
            raise lost(f"its scheduler does not answer: {error_text(err)}") from err
        alone_since = None if workers else (alone_since or time.monotonic())
        if alone_since is not None and time.monotonic() - alone_since > WORKERS_WAIT_S:
            raise lost(f"no worker for {WORKERS_WAIT_S:g} s")

    def result_of(future: Any) -> Any:
        # A result held by a worker that died is computed again, which needs a worker.
        while True:
            try:
                return future.result(timeout=WORKERS_CHECK_S)
            except TimeoutError:
                still_served()
            except CancelledError:
                raise lost("its scheduler went away") from None

    pending = set(futures)
    poll = WORKERS_CHECK_S if task_timeout is None else min(WORKERS_CHECK_S, TIMEOUT_CHECK_S)
    checked = time.monotonic()
    while pending:
        try:
            done, pending = wait(pending, timeout=poll, return_when="FIRST_COMPLETED")
        except TimeoutError:
            still_served()
            done = set()
        except CancelledError:  # every future, when the client loses its scheduler
            raise lost("its scheduler went away") from None
        for future in sorted(done, key=lambda f: futures[f].index):
            task = futures[future]
            if future.status == "finished":
                result = result_of(future)
            elif future.status == "cancelled":  # cancelled by no one here: the scheduler went away
                raise lost("its scheduler went away")
            else:  # the worker died, or the task could not be shipped: still one row
                try:
                    error = error_text(future.exception())
                except Exception as err:
                    error = error_text(err)
                result = TaskResult(task.index, task.key, None, error, (), None, None, "")
            future.release()
            finished += 1
            yield task, result
        if task_timeout is not None and time.monotonic() - checked >= TIMEOUT_CHECK_S:
            checked = time.monotonic()
            running = {future.key: future for future in pending}
            try:
                stopped = _stop_overdue(client, running, task_timeout)
            except Exception as err:  # the scheduler itself is gone
                raise lost(f"its scheduler does not answer: {error_text(err)}") from err
            for key, (worker, error, process_gone) in stopped.items():
                pending.discard(running[key])
                task = futures[running[key]]
                if process_gone:  # it may have finished while its worker closed: a failed row has no file
                    task.estimate_path.unlink(missing_ok=True)
                finished += 1
                yield task, TaskResult(task.index, task.key, None, error, (), None, None, worker)


def executing_seconds(dask_worker: Any) -> dict[str, float]:
    """How long each task this worker is computing has been at it, by key (run on a worker by
    ``client.run``, which hands it its worker)."""
    from distributed.metrics import time as dask_time

    now = dask_time()
    return {
        str(state.key): now - state.start_time
        for state in dask_worker.state.executing
        if state.start_time is not None
    }


def _stop_overdue(client: Any, running: Mapping[str, Any], limit: float) -> dict[str, tuple[str, str, bool]]:
    """Stop the futures of ``running`` (by key) that have computed for more than ``limit`` seconds;
    for each, its worker, the row's error and whether the process computing it is gone (restarted).

    Python code running in a worker's thread cannot be interrupted: the future is cancelled (so
    the scheduler gives it to no other worker) and its worker restarted by its nanny, a new
    process. A worker without a nanny (``dask worker --no-nanny``) cannot be restarted and computes
    on; its row says so. Dask refuses the whole restart if one worker named has no nanny, so
    only those with one are named.
    """
    overdue: dict[str, str] = {}  # key -> worker
    for worker, seconds in client.run(executing_seconds, on_error="return").items():
        if isinstance(seconds, dict):  # else the worker left while asked
            overdue.update(
                {key: worker for key, time_s in seconds.items() if key in running and time_s > limit}
            )
    if not overdue:
        return {}
    client.cancel([running[key] for key in overdue])
    known = client.scheduler_info()["workers"]
    nannied = sorted({worker for worker in overdue.values() if known.get(worker, {}).get("nanny")})
    restarted = client.restart_workers(nannied, raise_for_error=False) if nannied else {}
    head = f"timed out: still computing after {limit:g} s (--task-timeout)"
    stopped = {}
    for key, worker in overdue.items():
        status = restarted.get(worker)
        if worker not in known:
            how = "its worker has left the cluster"
        elif status is None:
            how = (
                "its worker has no nanny to restart it (dask worker --no-nanny) and computes on "
                "until the task ends"
            )
        elif status == "OK":
            how = "stopped by restarting its worker"
        else:
            how = f"its worker could not be restarted ({status}) and computes on until the task ends"
        stopped[key] = (worker, f"{head}; {how}", worker in known and status == "OK")
    return stopped


@contextlib.contextmanager
def _dask_logs_quiet() -> Iterator[None]:
    """Dask's own log lines (a lost scheduler's tracebacks, a killed worker's) are not the sweep's
    output: a failure is a row or one error line. Its loggers are hushed while the tasks run."""
    import distributed  # noqa: F401  (its loggers exist once it is imported)

    names = [name for name in logging.root.manager.loggerDict if name.startswith("distributed.")]
    loggers = [logging.getLogger(name) for name in ("distributed", "asyncio", "tornado", *names)]
    levels = [logger.level for logger in loggers]
    for logger in loggers:
        logger.setLevel(logging.CRITICAL + 1)
    try:
        yield
    finally:
        for logger, level in zip(loggers, levels, strict=True):
            logger.setLevel(level)


@contextlib.contextmanager
def _environment_kept() -> Iterator[None]:
    """This process's environment as it was, once the cluster the sweep started is closed.

    Dask's nanny sets its workers' variables (``OMP_NUM_THREADS``, ``MKL_NUM_THREADS`` and
    ``OPENBLAS_NUM_THREADS`` at 1) in the environment of the process that starts them, before each
    spawn, and leaves them there: a notebook that ran a sweep had its later subprocesses and
    thread pools limited to one thread."""
    saved = dict(os.environ)
    try:
        yield
    finally:
        for name in set(os.environ) - set(saved):
            del os.environ[name]
        os.environ.update(saved)


def _close(client: Any, *, local: bool) -> None:
    cluster = client.cluster if local else None
    client.close()
    if cluster is not None:
        cluster.close()
        if (remove := _SCRATCH.pop(cluster, None)) is not None:
            remove()


# --- tables ----------------------------------------------------------------------------------------


def columns(sweep: Sweep, extra_figures: Iterable[str] = ()) -> list[str]:
    """The table's columns, in order."""
    params = [f"param.{name}" for name in sweep.parameter_names()]
    figures = list(dict.fromkeys([*sweep.figures, *extra_figures]))
    return [
        "task",
        "key",
        "status",
        "recording",
        "render",
        "topics",
        "same_as",
        *params,
        *figures,
        *TIMING_COLUMNS,
        "error",
        "warnings",
        "worker",
        "config",
    ]


def rows(
    sweep: Sweep, tasks: Sequence[Task], results: Sequence[TaskResult], extra_figures: Iterable[str] = ()
) -> list[dict[str, Any]]:
    """One dict per task, keyed by :func:`columns`."""
    figures = list(dict.fromkeys([*sweep.figures, *extra_figures]))
    out = []
    for task, result in zip(tasks, results, strict=True):
        summary = result.summary or {}
        row: dict[str, Any] = {
            "task": task.index,
            "key": task.key[:16],
            "status": "ok" if result.ok else "error",
            "recording": str(task.source.path),
            "render": "" if task.source.render is None else render_text(task.source.render),
            "topics": topics_text(task.source.topics),
            "same_as": task.same_as,
        }
        given = dict(task.parameters)
        row.update(
            {f"param.{name}": _effective(name, given, task.config) for name in sweep.parameter_names()}
        )
        row.update({key: summary.get(key) for key in figures})
        row.update(
            {
                "estimate_wall_s": result.estimate_wall_s,
                "keyframes_per_second": result.keyframes_per_second,
                "task_cpu_s": result.task_cpu_s,
                "error": result.error or "",
                "warnings": "; ".join(result.warnings),
                "worker": result.worker,
                "config": json.dumps(asdict(task.config), sort_keys=True),
            }
        )
        out.append(row)
    return out


def render_text(config: RecordConfig) -> str:
    """A render's configuration as the tables show it: its route and seed, then every setting (as
    the sweep file's ``[[render]]`` key) that is not the default, so no two renders read alike."""
    noise, camera = config.noise, config.camera
    usual = RecordConfig()
    usual_noise, usual_camera = NoiseParams.of_model(noise.model), usual.camera  # noise: its model's
    settings = [
        ("laps", config.laps, usual.laps),
        (
            "size",
            f"{camera.width_px}x{camera.height_px}",
            f"{usual_camera.width_px}x{usual_camera.height_px}",
        ),
        ("noise_model", noise.model, usual.noise.model),
        ("noise", noise.noise, usual_noise.noise),
        ("drift_deg_per_m", noise.drift_deg_per_m, usual_noise.drift_deg_per_m),
        ("jitter_m", noise.jitter_m, usual_noise.jitter_m),
        ("jitter_deg", noise.jitter_deg, usual_noise.jitter_deg),
        ("wander_m", noise.wander_m, usual_noise.wander_m),
        ("wander_deg", noise.wander_deg, usual_noise.wander_deg),
        ("wander_length_m", noise.wander_length_m, usual_noise.wander_length_m),
        ("aliasing", config.aliasing, usual.aliasing),
        ("lighting_change", config.lighting_change, usual.lighting_change),
        ("odometry_reset_at", config.odometry_reset_at, usual.odometry_reset_at),
        ("world", config.world, usual.world),
        ("fov_deg", camera.fov_deg, usual_camera.fov_deg),
        ("camera_height_m", camera.height_m, usual_camera.height_m),
        ("fps", config.fps, usual.fps),
        ("jpeg_quality", config.jpeg_quality, usual.jpeg_quality),
    ]
    parts = [f"route={config.route}", f"seed={config.seed}"]
    parts += [f"{key}={_setting_text(value)}" for key, value, usual in settings if value != usual]
    return " ".join(parts)


def _setting_text(value: Any) -> str:
    """``value`` short (``0.5``, not ``0.5000``), yet never two values as one text (``0.1234567``)."""
    if isinstance(value, float) and float(f"{value:g}") == value:
        return f"{value:g}"
    return str(value)


def _effective(name: str, given: dict[str, Any], config: EstimatorConfig) -> Any:
    """A parameter's value in a task: the configuration's, whichever grid named it; for
    ``paper_faithful``, which is no field of the configuration, whether its grid started from it."""
    if name == "paper_faithful":
        return bool(given.get(name, False))
    return getattr(config, name)


def arrow_table(
    sweep: Sweep, tasks: Sequence[Task], results: Sequence[TaskResult], extra_figures: Iterable[str] = ()
) -> Any:
    """The rows as a ``pyarrow.Table``: one typed column each (int, float, bool or string; nulls kept)."""
    import pyarrow as pa

    extra_figures = list(extra_figures)
    names = columns(sweep, extra_figures)
    data = rows(sweep, tasks, results, extra_figures)
    arrays = {}
    for name in names:
        values = [row.get(name) for row in data]
        kind = _arrow_type(name, values)
        if kind == pa.string():  # a recording's name may hold a byte that is not UTF-8
            values = [utf8_text(value) if isinstance(value, str) else value for value in values]
        arrays[name] = pa.array(values, type=kind)
    return pa.table(arrays)


def _arrow_type(name: str, values: list[Any]) -> Any:
    """The summary's own type for its figures (a column of failed tasks is null, not a double);
    for the other columns, what the values are."""
    import pyarrow as pa

    from aslam.app.score import BOOLEAN_KEYS, COUNT_KEYS

    if name in COUNT_KEYS or name == "same_as":  # a task index, null in a sweep without copies
        return pa.int64()
    if name in BOOLEAN_KEYS:
        return pa.bool_()
    present = [v for v in values if v is not None]
    if present and all(isinstance(v, bool) for v in present):
        return pa.bool_()
    if present and all(isinstance(v, int) and not isinstance(v, bool) for v in present):
        return pa.int64()
    if all(isinstance(v, int | float) and not isinstance(v, bool) for v in present):
        return pa.float64()  # also an all-null figure column: a number that could not be measured
    return pa.string()


def table_bytes(
    sweep: Sweep,
    tasks: Sequence[Task],
    results: Sequence[TaskResult],
    extra_figures: Iterable[str] = (),
) -> dict[str, bytes]:
    """``results.parquet`` and ``results.csv`` as they should read, by file name."""
    return table_file_bytes(arrow_table(sweep, tasks, results, extra_figures))


def write_tables(
    results_dir: Path,
    sweep: Sweep,
    tasks: Sequence[Task],
    results: Sequence[TaskResult],
    extra_figures: Iterable[str] = (),
    *,
    on_warning: Callable[[str], None] | None = None,
) -> bool:
    """Write the tables that do not already hold these bytes, each under a temporary name and
    renamed; whether any was written. A re-run with nothing to do writes nothing; in a folder that
    cannot be written, tables out of date (another ``--pareto``'s columns, recordings moved) are
    left as they are, with a warning."""
    tables = table_bytes(sweep, tasks, results, extra_figures)
    stale = {name: data for name, data in tables.items() if not holds(results_dir / name, data)}
    if not stale:
        return False
    problem = write_problem(results_dir)
    if problem is not None:
        if on_warning is not None:
            names = " and ".join(stale)
            on_warning(
                f"{results_dir}: {problem}; {names} left as {'they were' if len(stale) > 1 else 'it was'}"
            )
        return False
    for name, data in stale.items():
        write_table_file(results_dir / name, data)
    return True


# --- selection -------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Objective:
    """A figure to optimise, and in which direction."""

    key: str
    maximise: bool


def resolve_objectives(text: str) -> list[Objective]:
    """``precision,recall,-hypotheses.max`` → objectives; a name is a summary key or its tail
    (:func:`aslam.app.score.summary_key`).

    ``+NAME``/``-NAME`` force maximising/minimising; otherwise
    :func:`aslam.app.score.lower_is_better` decides.
    """
    from aslam.app.score import lower_is_better, summary_key, summary_keys

    known = summary_keys()
    objectives: list[Objective] = []
    problems = []
    for raw in (part.strip() for part in text.split(",")):
        if not raw:
            continue
        sign, name = (raw[0], raw[1:]) if raw[0] in "+-" else ("", raw)
        try:
            key = summary_key(name, known)
        except ValueError as err:
            problems.append(f"--pareto: '{name}' {err}")
            continue
        maximise = sign == "+" if sign else not lower_is_better(key)
        if any(objective.key == key for objective in objectives):  # twice: a column twice, or both ways
            problems.append(f"--pareto: '{name}' names {key} again")
            continue
        objectives.append(Objective(key, maximise))
    if problems:
        raise InputError("; ".join(problems))
    if not objectives:
        raise InputError("--pareto needs at least one figure name")
    return objectives


def pareto_front(results: Sequence[TaskResult], objectives: Sequence[Objective]) -> list[TaskResult]:
    """The successful results no other dominates (at least as good on every objective, better on one).

    Results missing any objective's value (null: not measurable) take no part. Order is kept.
    """
    candidates = []
    for result in results:
        if not result.ok or result.summary is None:
            continue
        values = [v for v in (result.summary.get(o.key) for o in objectives) if v is not None]
        if len(values) < len(objectives):
            continue
        candidates.append(
            (result, [v if o.maximise else -v for v, o in zip(values, objectives, strict=True)])
        )

    def dominates(a: list[float], b: list[float]) -> bool:
        return all(x >= y for x, y in zip(a, b, strict=True)) and any(
            x > y for x, y in zip(a, b, strict=True)
        )

    return [r for r, v in candidates if not any(dominates(w, v) for _other, w in candidates)]
