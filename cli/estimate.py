"""`aslam estimate RECORDING.mcap -o ESTIMATE.mcap`: run the SLAM over a recording, streaming.

Every ``EstimatorConfig`` parameter is an option, generated from ``EstimatorConfig.parameters()``
(one source for the dataclass, the options, config files and docs). Precedence:
option > ``--config`` file > ``--paper-faithful`` base > default. The work is
:func:`aslam.app.estimate.estimate`; this module parses, shows progress and prints.
"""

from __future__ import annotations

import contextlib
import gc
import inspect
import json
from collections.abc import Callable
from contextlib import AbstractContextManager
from pathlib import Path
from typing import Annotated, Any

import typer

from aslam.app.config_file import option_name
from aslam.cli.app import app
from aslam.cli.output import (
    BaseFrameOption,
    ForceOption,
    GroundTruthTopicOption,
    ImageTopicOption,
    OdometryTopicOption,
    OdomFrameOption,
    QuietOption,
    Terminal,
    VerboseOption,
    counted,
    decimal_number,
    input_file,
    output_file,
    whole_number,
)
from aslam.core.config import EstimatorConfig

_ESTIMATOR_PANEL = "Estimator parameters (override --config and --paper-faithful)"


def estimate(**options: Any) -> None:
    """Run the estimator over a recording; write the hypotheses and the map to an estimate file.

    Streams the recording. The output appears only when complete (Ctrl-C: nothing, exit 130).

    Parameters: option > --config file (TOML, an \\[estimator] table) > --paper-faithful > default.
    """
    from dataclasses import asdict

    from aslam.app.config_file import build_config
    from aslam.app.estimate import estimate as run_estimate
    from aslam.data_formats.sources import TopicChoice

    fixed = {name: options.pop(name) for name in _FIXED}
    terminal = Terminal(quiet=fixed["quiet"], verbose=fixed["verbose"])
    the_map = _one_file(
        "--map",
        fixed["map"],
        "a run starts in one map; to join sessions, chain them"
        " (estimate B --map A.est.mcap, then C --map B.est.mcap)",
    )
    config_file = _one_file(
        "--config", fixed["config"], "one configuration file is read; put the parameters in one"
    )
    topics = TopicChoice(
        image=fixed["image_topic"],
        odometry=fixed["odometry_topic"],
        ground_truth=fixed["ground_truth_topic"],
        odom_frame=fixed["odom_frame"],
        base_frame=fixed["base_frame"],
    )
    config = build_config(paper_faithful=fixed["paper_faithful"], config_file=config_file, options=options)
    terminal.detail(f"configuration: {json.dumps(asdict(config))}")  # the values the estimate file holds
    progress, on_progress = _progress_bar(terminal)
    # What exists now (modules, the configuration) lives as long as this process, which ends with
    # the command: frozen, no collection scans it again (a full collection late in a run found
    # nothing and cost 16 ms), and the forked reader's collections leave the pages it shares with
    # us alone (the recipe of Python's gc.freeze documentation).
    gc.freeze()
    with progress:
        summary = run_estimate(
            fixed["recording"],
            fixed["output"],
            config,
            topics=topics,
            force=fixed["force"],
            timing=not fixed["no_timing"],
            workers=fixed["workers"],
            prior=the_map,
            on_progress=on_progress,
            on_warning=terminal.warning,
        )
    restarts = summary.odometry_restarts
    restarted = f"; odometry restarted on its origin {restarts}×, each an odometry jump" if restarts else ""
    terminal.wrote(
        f"wrote {fixed['output']} ({counted(summary.keyframes, 'keyframe')} from "
        f"{counted(summary.samples, 'image')}, {counted(summary.states, 'state')}, "
        f"{counted(summary.links, 'link')}, {counted(summary.hypotheses, 'hypothesis', 'hypotheses')}; "
        f"{summary.keyframes_per_second:.1f} keyframes/s{restarted})"
    )
    terminal.detail(
        f"SLAM step {summary.slam_s:.3f} s, metric view (GTSAM + Foxglove scene) {summary.embed_s:.3f} s, "
        f"of {summary.wall_s:.3f} s wall"
    )


def _one_file(option: str, paths: list[Path] | None, why: str) -> Path | None:
    """The one file of ``option``; given twice (click keeps the last in silence) it is exit 2,
    unless both name the same file. ``why``: the use of one, and what to do instead."""
    if not paths:
        return None
    from aslam.core.errors import InputError
    from aslam.data_formats.files import real_path

    if len({real_path(path) for path in paths}) > 1:
        raise InputError(f"{option} given {len(paths)} times ({', '.join(map(str, paths))}): {why}")
    return paths[0]


def progress_columns() -> tuple[Any, ...]:
    """The progress line's columns: "estimate ━━━━━━━━ 51234/100000 images · 20345 kf · 3 hyp ·
    230 kf/s 0:03:40", 75 columns. Where the line is wider than the window, the bar gives way
    before any figure: rich shrank the widest column it may wrap first, the image count's, so at
    a million images (1000000/1000000, 50 hypotheses) an 80-column terminal read "1000000/1000…"."""
    from rich.progress import BarColumn, MofNCompleteColumn, TextColumn, TimeElapsedColumn
    from rich.table import Column

    return (
        TextColumn("{task.description}"),  # "estimate"; "writing" once read; "pose graph 12" as it optimises
        BarColumn(bar_width=8),
        MofNCompleteColumn(table_column=Column(no_wrap=True)),
        TextColumn("images · {task.fields[keyframes]} kf · {task.fields[hypotheses]} hyp"),
        TextColumn("· {task.fields[rate]:.0f} kf/s"),
        TimeElapsedColumn(table_column=Column(no_wrap=True)),
    )


def _progress_bar(terminal: Terminal) -> tuple[AbstractContextManager[Any], Callable[..., None] | None]:
    """The live bar and its update callback; none in logs, pipes or with --quiet, where rich's
    progress module is not even imported (20 ms of the start-up, before the reader starts)."""
    if not terminal.shows_progress:
        return contextlib.nullcontext(), None
    from rich.progress import Progress

    from aslam.app.estimate import EstimateProgress

    progress = Progress(*progress_columns(), console=terminal.console)
    task = progress.add_task("estimate", total=None, keyframes=0, hypotheses=0, rate=0.0)

    def on_progress(p: EstimateProgress) -> None:
        description = "estimate"
        if p.finishing:
            description = f"pose graph {p.pose_graph_iterations}" if p.pose_graph_iterations else "writing"
        progress.update(
            task,
            description=description,
            completed=p.samples,
            total=p.samples_total,
            keyframes=p.keyframes,
            hypotheses=p.hypotheses,
            rate=p.keyframes / max(p.elapsed_s, 1e-9),
            refresh=p.pose_graph_iterations > 0,  # GTSAM holds the interpreter: its own thread cannot redraw
        )

    return progress, on_progress


_MISSING = inspect.Parameter.empty
# The command's own parameters (name → annotation, default), before the generated estimator options.
_FIXED: dict[str, tuple[Any, Any]] = {
    "recording": (
        Annotated[
            Path,
            typer.Argument(
                help="The recording to read: our .mcap, a rosbag2 folder or file, a ROS 1 .bag.",
                show_default=False,
            ),
        ],
        _MISSING,
    ),
    "output": (
        Annotated[
            Path,
            typer.Option(
                "-o", "--output", help="Estimate file (.mcap) to write.", parser=output_file, metavar="<file>"
            ),
        ],
        _MISSING,
    ),
    "config": (
        Annotated[
            list[Path] | None,  # a list only to refuse a second file, which would silently win
            typer.Option(
                "--config",
                help="TOML file with estimator parameters in an \\[estimator] table.",
                parser=input_file,
                metavar="<file>",
            ),
        ],
        None,
    ),
    "map": (
        Annotated[
            list[Path] | None,  # a list only to refuse a second map, which would silently win
            typer.Option(
                "--map",
                help="Start in the map of an earlier estimate file (multi-session): the robot's place in it"
                " is found by appearance, then it is tracked and the map extended. Use the same"
                " observation settings as that run. One map: chain sessions to grow it.",
                parser=input_file,
                metavar="<file>",
            ),
        ],
        None,
    ),
    "paper_faithful": (
        Annotated[
            bool,
            typer.Option(
                "--paper-faithful",
                help="Start from the paper's estimator (one global histogram, path-only candidates).",
            ),
        ],
        False,
    ),
    "image_topic": (ImageTopicOption, None),
    "odometry_topic": (OdometryTopicOption, None),
    "ground_truth_topic": (GroundTruthTopicOption, None),
    "odom_frame": (OdomFrameOption, None),
    "base_frame": (BaseFrameOption, None),
    "force": (ForceOption, False),
    "no_timing": (
        Annotated[
            bool,
            typer.Option(
                "--no-timing",
                help="Omit the wall-clock metadata, so the same input gives a byte-identical file.",
            ),
        ],
        False,
    ),
    "workers": (
        Annotated[
            int,
            typer.Option(
                parser=whole_number,
                metavar="INTEGER",
                help="Threads decoding and describing images (0: in the main thread).",
            ),
        ],
        2,  # app.pipeline.DEFAULT_WORKERS, whose import is not for every command's start (a test binds them)
    ),
    "quiet": (QuietOption, False),
    "verbose": (VerboseOption, False),
}


#: Numbers in decimal digits only (:func:`aslam.cli.output.decimal_number`).
_NUMBER_PARSERS: dict[type, dict[str, Any]] = {
    float: {"parser": decimal_number, "metavar": "FLOAT"},
    int: {"parser": whole_number, "metavar": "INTEGER"},
}


def _signature() -> inspect.Signature:
    """The command's parameters: the fixed ones, then one option per estimator parameter."""
    kw = inspect.Parameter.KEYWORD_ONLY
    fixed = [
        inspect.Parameter(name, kw, annotation=annotation, default=default)
        for name, (annotation, default) in _FIXED.items()
    ]
    generated = [
        inspect.Parameter(
            name,
            kw,
            default=None,
            annotation=Annotated[
                kind | None,
                typer.Option(
                    option_name(name),
                    **_NUMBER_PARSERS.get(kind, {}),
                    help=f"{help_text} \\[default: {default}]",
                    show_default=False,
                    rich_help_panel=_ESTIMATOR_PANEL,
                ),
            ],
        )
        for name, kind, default, help_text in EstimatorConfig.parameters()
    ]
    return inspect.Signature(fixed + generated)


estimate.__signature__ = _signature()  # type: ignore[attr-defined]
app.command()(estimate)
