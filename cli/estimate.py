"""`aslam estimate RECORDING.mcap -o ESTIMATE.mcap`: run the SLAM over a recording, streaming.

Every ``EstimatorConfig`` parameter is an option, generated from ``EstimatorConfig.parameters()``
(one source for the dataclass, the options, config files and docs). Precedence:
option > ``--config`` file > ``--paper-faithful`` base > default.
"""

from __future__ import annotations

import hashlib
import inspect
import sys
import threading
import time
import tomllib
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from aslam.cli.app import app, tool_version
from aslam.core.config import EstimatorConfig
from aslam.core.errors import ConfigError, InputError

if TYPE_CHECKING:
    from rich.console import Console

CONFIG_TABLE = "estimator"
_ESTIMATOR_PANEL = "Estimator parameters (override --config and --paper-faithful)"


def _warning_line(console: Console | None, message: str) -> None:
    line = f"aslam: warning: {' '.join(message.split())}"
    if console is not None and console.is_terminal:
        console.print(line, markup=False, highlight=False, soft_wrap=True)
    else:
        sys.stderr.write(line + "\n")
        sys.stderr.flush()


# --- configuration ---------------------------------------------------------------------------------


def option_name(field: str) -> str:
    return "--" + field.replace("_", "-")


def read_config_file(path: Path) -> dict[str, Any]:
    """The ``[estimator]`` table of a TOML file, checked: every unknown key and wrong type at once."""
    try:
        with path.open("rb") as f:
            document = tomllib.load(f)
    except FileNotFoundError as err:
        raise ConfigError("no such file", path=path) from err
    except IsADirectoryError as err:
        raise ConfigError("is a directory, not a TOML file", path=path) from err
    except OSError as err:
        raise ConfigError(f"cannot read: {err.strerror or err}", path=path) from err
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as err:
        raise ConfigError(f"not valid TOML ({err})", path=path) from err
    unknown = [key for key in document if key != CONFIG_TABLE]
    table = document.get(CONFIG_TABLE, {})
    if not isinstance(table, dict):
        raise ConfigError(f"'{CONFIG_TABLE}' must be a table ([{CONFIG_TABLE}])", path=path)
    types = {name: kind for name, kind, _default, _help in EstimatorConfig.parameters()}
    unknown += [f"{CONFIG_TABLE}.{key}" for key in table if key not in types]
    if unknown:
        known = ", ".join(types)
        raise ConfigError(
            f"unknown key{'s' if len(unknown) > 1 else ''} {', '.join(unknown)} "
            f"(keys go in an [{CONFIG_TABLE}] table; known: {known})",
            path=path,
        )
    problems = []
    values: dict[str, Any] = {}
    for key, value in table.items():
        kind = types[key]
        if isinstance(value, bool) or not isinstance(value, int | float):
            problems.append(f"{key} must be a number, got {value!r}")
        elif kind is int and not isinstance(value, int):
            problems.append(f"{key} must be a whole number, got {value!r}")
        else:
            values[key] = kind(value)
    if problems:
        raise ConfigError("; ".join(problems), path=path)
    return values


def build_config(
    *, paper_faithful: bool, config_file: Path | None, options: dict[str, Any]
) -> EstimatorConfig:
    """Defaults, then ``--paper-faithful``, then the file, then the options that were given."""
    values: dict[str, Any] = {}
    if paper_faithful:
        base = EstimatorConfig.paper_faithful()
        values.update({name: getattr(base, name) for name, *_ in EstimatorConfig.parameters()})
    from_file = read_config_file(config_file) if config_file is not None else {}
    values.update(from_file)
    values.update({k: v for k, v in options.items() if v is not None})
    try:
        return EstimatorConfig(**values)
    except ConfigError as err:
        raise ConfigError(
            f"bad estimator configuration: {err}", path=config_file if from_file else None
        ) from err


# --- the recording's identity --------------------------------------------------------------------


class FileHasher:
    """SHA-256 of a file, computed in a background thread while the estimate runs.

    A second, sequential read of the file (mostly from the page cache); hashlib releases the GIL
    on large buffers, so it costs the pipeline little. ``result()`` joins.
    """

    def __init__(self, path: Path) -> None:
        self.path = path
        self._digest: str | None = None
        self._error: OSError | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="aslam-sha256", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        sha = hashlib.sha256()
        try:
            with self.path.open("rb") as f:
                while not self._stop.is_set():
                    block = f.read(4 * 1024 * 1024)
                    if not block:
                        break
                    sha.update(block)
        except OSError as err:
            self._error = err
            return
        self._digest = sha.hexdigest()

    def cancel(self) -> None:
        self._stop.set()
        self._thread.join()

    def result(self) -> str:
        self._thread.join()
        if self._error is not None:
            raise InputError(f"cannot read: {self._error.strerror or self._error}", path=self.path)
        assert self._digest is not None
        return self._digest


def image_count(path: Path, topic: str) -> int | None:
    """Messages on ``topic`` from the MCAP summary's statistics, or None when unknown."""
    try:
        from mcap.reader import SeekingReader

        with path.open("rb") as f:
            summary = SeekingReader(f, record_size_limit=path.stat().st_size).get_summary()
        if summary is None or summary.statistics is None:
            return None
        ids = [cid for cid, channel in summary.channels.items() if channel.topic == topic]
        return sum(summary.statistics.channel_message_counts.get(cid, 0) for cid in ids) or None
    except Exception:  # no summary or a damaged one: the reader will say what is wrong
        return None


# --- the command ---------------------------------------------------------------------------------


def estimate(**options: Any) -> None:
    """Run the estimator over a recording; write the hypotheses and the map to an estimate file.

    Streams the recording. The output appears only when complete (Ctrl-C: nothing, exit 130).

    Parameters: option > --config file (TOML, an \\[estimator] table) > --paper-faithful > default.
    """
    recording: Path = options.pop("recording")
    output: Path = options.pop("output")
    config_file: Path | None = options.pop("config")
    paper_faithful: bool = options.pop("paper_faithful")
    force: bool = options.pop("force")
    no_timing: bool = options.pop("no_timing")
    workers: int = options.pop("workers")
    topics_given = {
        "image": options.pop("image_topic"),
        "odometry": options.pop("odom_topic"),
        "ground_truth": options.pop("ground_truth_topic"),
    }
    config = build_config(paper_faithful=paper_faithful, config_file=config_file, options=options)
    if workers < 1:
        raise InputError(f"--workers must be at least 1, got {workers}")
    run_estimate_command(
        recording,
        output,
        config,
        topics_given=topics_given,
        force=force,
        timing=not no_timing,
        workers=workers,
    )


def run_estimate_command(
    recording: Path,
    output: Path,
    config: EstimatorConfig,
    *,
    topics_given: dict[str, str | None],
    force: bool,
    timing: bool,
    workers: int,
) -> None:
    from contextlib import closing
    from dataclasses import asdict

    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from aslam.cli.pipeline import PipelineCounts, run_estimate
    from aslam.core.estimator import Estimator
    from aslam.data_formats.estimate import (
        EstimateMetadata,
        EstimateWriter,
        RecordingIdentity,
        Timing,
        check_output_path,
    )
    from aslam.data_formats.recording import RecordingTopics, iter_samples

    defaults = RecordingTopics()
    topics = RecordingTopics(
        image=topics_given["image"] or defaults.image,
        odometry=topics_given["odometry"] or defaults.odometry,
        ground_truth=topics_given["ground_truth"] or defaults.ground_truth,
    )
    recording = recording.absolute()
    output = output.absolute()
    if output == recording:
        raise InputError("the output would overwrite the recording", path=output)
    check_output_path(output, force=force)
    console = Console(stderr=True)
    samples = iter_samples(recording, topics, on_warning=lambda line: _warning_line(console, line))
    size = recording.stat().st_size
    total = image_count(recording, topics.image)
    estimator = Estimator(config)
    counts = PipelineCounts()
    hasher = FileHasher(recording)
    progress = Progress(
        TextColumn("estimate"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("images · {task.fields[keyframes]} keyframes · {task.fields[hypotheses]} hypotheses"),
        TextColumn("· {task.fields[rate]:.1f} keyframes/s"),
        TimeElapsedColumn(),
        console=console,
        disable=not console.is_terminal,
        transient=False,
    )
    start = time.perf_counter()
    last_step = None
    try:
        with (
            progress,
            EstimateWriter(output, tool_version=tool_version(), force=force) as writer,
            closing(run_estimate(samples, estimator, counts=counts, workers=workers)) as steps,
        ):
            task = progress.add_task("estimate", total=total, keyframes=0, hypotheses=0, rate=0.0)
            last_update = 0.0
            for step in steps:
                writer.write_keyframe(step)
                last_step = step
                now = time.perf_counter()
                if now - last_update > 0.1:
                    last_update = now
                    progress.update(
                        task,
                        completed=counts.samples,
                        keyframes=step.keyframe + 1,
                        hypotheses=len(step.hypotheses),
                        rate=(step.keyframe + 1) / max(now - start, 1e-9),
                    )
            result = estimator.result()
            wall_s = time.perf_counter() - start
            keyframes = len(result.keyframe_stamps_ns)
            progress.update(
                task,
                completed=counts.samples,
                total=counts.samples,
                keyframes=keyframes,
                hypotheses=len(result.hypotheses),
                rate=keyframes / max(wall_s, 1e-9),
            )
            metadata = EstimateMetadata(
                tool_version=tool_version(),
                config=asdict(config),
                recording=RecordingIdentity(str(recording), size, hasher.result()),
                topics=asdict(topics),
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
            writer.finish(result, metadata, run_timing)
    finally:
        hasher.cancel()
    if last_step is None:
        _warning_line(console, f"{recording}: no keyframes (no images with odometry)")
    wall_s = time.perf_counter() - start
    typer.echo(
        f"wrote {output} ({len(result.keyframe_stamps_ns)} keyframes from {counts.samples} images, "
        f"{len(result.states)} states, {len(result.links)} links, {len(result.hypotheses)} hypotheses; "
        f"{len(result.keyframe_stamps_ns) / max(wall_s, 1e-9):.1f} keyframes/s)"
    )


def _signature() -> inspect.Signature:
    """The command's parameters: the fixed ones, then one option per estimator parameter."""
    P = inspect.Parameter
    kw = P.KEYWORD_ONLY
    fixed = [
        P(
            "recording",
            kw,
            annotation=Annotated[
                Path,
                typer.Argument(help="The recording (.mcap) to read.", dir_okay=False, show_default=False),
            ],
        ),
        P(
            "output",
            kw,
            annotation=Annotated[
                Path,
                typer.Option("-o", "--output", help="Estimate file (.mcap) to write.", dir_okay=False),
            ],
        ),
        P(
            "config",
            kw,
            default=None,
            annotation=Annotated[
                Path | None,
                typer.Option(
                    "--config",
                    help="TOML file with estimator parameters in an \\[estimator] table.",
                    dir_okay=False,
                ),
            ],
        ),
        P(
            "paper_faithful",
            kw,
            default=False,
            annotation=Annotated[
                bool,
                typer.Option(
                    "--paper-faithful",
                    help="Start from the paper's estimator (one global histogram, path-only candidates).",
                ),
            ],
        ),
        P(
            "image_topic",
            kw,
            default=None,
            annotation=Annotated[
                str | None,
                typer.Option(
                    help="Image topic (CompressedImage or Image). \\[default: /camera/image/compressed]"
                ),
            ],
        ),
        P(
            "odom_topic",
            kw,
            default=None,
            annotation=Annotated[str | None, typer.Option(help="Odometry topic. \\[default: /odom]")],
        ),
        P(
            "ground_truth_topic",
            kw,
            default=None,
            annotation=Annotated[
                str | None,
                typer.Option(help="Ground-truth topic (for report). \\[default: /ground_truth/pose]"),
            ],
        ),
        P(
            "force",
            kw,
            default=False,
            annotation=Annotated[bool, typer.Option("--force", help="Overwrite an existing output file.")],
        ),
        P(
            "no_timing",
            kw,
            default=False,
            annotation=Annotated[
                bool,
                typer.Option(
                    "--no-timing",
                    help="Omit the wall-clock metadata, so the same input gives a byte-identical file.",
                ),
            ],
        ),
        P(
            "workers",
            kw,
            default=2,
            annotation=Annotated[int, typer.Option(help="Threads decoding images and computing histograms.")],
        ),
    ]
    generated = []
    for name, kind, default, help_text in EstimatorConfig.parameters():
        generated.append(
            P(
                name,
                kw,
                default=None,
                annotation=Annotated[
                    kind | None,
                    typer.Option(
                        option_name(name),
                        help=f"{help_text} \\[default: {default}]",
                        show_default=False,
                        rich_help_panel=_ESTIMATOR_PANEL,
                    ),
                ],
            )
        )
    return inspect.Signature(fixed + generated)


estimate.__signature__ = _signature()  # type: ignore[attr-defined]
app.command()(estimate)


def estimator_options_markdown() -> str:
    """The estimator-parameter table of docs/usage.md (a test keeps the doc equal to this)."""
    rows = ["| option | config key | type | default | meaning |", "|---|---|---|---|---|"]
    for name, kind, default, help_text in EstimatorConfig.parameters():
        meaning = help_text.replace("|", "/")
        rows.append(f"| `{option_name(name)}` | `{name}` | {kind.__name__} | {default} | {meaning} |")
    return "\n".join(rows) + "\n"
