"""`aslam report ESTIMATE.mcap`: tables, graph JSON, plots, summary JSON and quality gates.

The work is :func:`aslam.app.score.score`; this module parses, prints and writes the files asked for.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Annotated, Any

import typer

from aslam.cli.app import app
from aslam.cli.output import (
    ForceOption,
    QuietOption,
    Terminal,
    VerboseAcceptedOption,
    decimal_number,
    input_file,
    output_name,
    table_console,
)
from aslam.core.config import REVISIT_HEADING_DEG, REVISIT_RADIUS_M
from aslam.core.errors import InputError, QualityGateFailed
from aslam.data_formats.format_names import TrajectoryFormat


@app.command()
def report(
    estimate: Annotated[
        Path, typer.Argument(help="Estimate file (.mcap) written by 'aslam estimate'.", show_default=False)
    ],
    recording: Annotated[
        Path | None,
        typer.Option(
            help="Recording (or bag) with the ground truth. \\[default: the one named in the estimate]",
            parser=input_file,
            metavar="<file>",
        ),
    ] = None,
    graph: Annotated[
        str | None,
        typer.Option(
            "--graph",
            help="Write the map as JSON (docs/graph-json.md); '-': stdout.",
            parser=output_name,
            metavar="<file>",
        ),
    ] = None,
    plots: Annotated[
        Path | None, typer.Option("--plots", help="Write PNG figures into this folder.", file_okay=False)
    ] = None,
    trajectory: Annotated[
        str | None,
        typer.Option(
            help="Write the embedded (GTSAM-optimised) trajectory here, and beside it *.odometry.* and "
            "*.truth.* (for evo).",
            metavar="<file>",
        ),
    ] = None,
    trajectory_format: Annotated[
        TrajectoryFormat | None,
        typer.Option(
            help="Trajectory file format; by default what the name says (.tum, .kitti), else tum.",
            show_default=False,
        ),
    ] = None,
    json_out: Annotated[
        str | None,
        typer.Option(
            "--json",
            help="Write the summary JSON here; '-': stdout (the tables then go to stderr).",
            parser=output_name,
            metavar="<file>",
        ),
    ] = None,
    fail_on: Annotated[
        list[str] | None,
        typer.Option(
            "--fail-on",
            help="Exit 1 if KEY OP NUMBER holds, e.g. 'loop_closure.precision<0.99' (repeatable).",
            show_default=False,
        ),
    ] = None,
    radius_m: Annotated[
        float,
        typer.Option(
            parser=decimal_number,
            metavar="FLOAT",
            help="A revisit is within this distance of the earlier true position (m).",
        ),
    ] = REVISIT_RADIUS_M,
    heading_deg: Annotated[
        float,
        typer.Option(
            parser=decimal_number,
            metavar="FLOAT",
            help="A revisit is within this difference of the earlier true heading (degrees).",
        ),
    ] = REVISIT_HEADING_DEG,
    truth_by_index: Annotated[
        bool,
        typer.Option(
            "--truth-by-index",
            help="Sessions aligned frame by frame (Nordland): the k-th keyframe of each session (this run and"
            " its --map) is the same place; --radius-m then counts keyframes. No recording is read.",
        ),
    ] = False,
    ground_truth_topic: Annotated[
        str | None,
        typer.Option(
            help="Read the ground truth from this pose topic of a bag (default: the topic the estimate"
            " was made with); a --map session without it keeps its own."
        ),
    ] = None,
    force: ForceOption = False,
    quiet: QuietOption = False,
    verbose: VerboseAcceptedOption = False,
) -> None:
    """Score an estimate against the recording's ground truth: tables, graph JSON, plots, gates.

    Without ground truth (no recording found) it reports what needs none.

    Exit 1 when a --fail-on condition holds; a null value (not measurable) fails the gate.
    """

    from aslam.app.gates import failed_conditions, parse_condition
    from aslam.app.score import score, summary_keys

    terminal = Terminal(quiet=quiet, verbose=verbose)
    keys = summary_keys()
    conditions = [parse_condition(text, keys) for text in fail_on or []]
    from aslam.data_formats.files import is_stdout

    to_stdout = [
        name for name, target in (("--graph", graph), ("--json", json_out)) if target and is_stdout(target)
    ]
    if len(to_stdout) > 1:
        raise InputError("--graph and --json cannot both write to stdout")
    outputs = [Path(p) for p in (graph, json_out) if p not in (None, "-")]
    if trajectory is not None:
        from aslam.data_formats.trajectory import export_plan

        outputs += export_plan(trajectory, trajectory_format)[0]
    elif trajectory_format is not None:
        raise InputError("--trajectory-format needs --trajectory")
    inputs = [estimate] if recording is None else [estimate, recording]
    for i, path in enumerate(outputs):  # before any work: a bad path, two outputs that are one file, an input
        _check_output(path, force=force, others=outputs[:i], inputs=inputs)
    if plots is not None:
        from aslam.data_formats.files import check_output_folder

        check_output_folder(plots, what="plots folder", outputs=outputs)
    if plots is not None and plots.is_dir():
        from aslam.app.plots import PLOT_NAMES

        for name in PLOT_NAMES:
            _check_output(plots / name, force=force, others=outputs, inputs=inputs)

    with _status(terminal) as on_stage:
        result = score(
            estimate,
            recording=recording,
            radius_m=radius_m,
            heading_deg=heading_deg,
            truth_by_index=truth_by_index,
            ground_truth_topic=ground_truth_topic,
            on_warning=terminal.warning,
            on_stage=on_stage,
        )
    stdout_taken = bool(to_stdout)  # the tables go to stderr, the document alone to stdout
    if not quiet or not stdout_taken:
        _print_tables(table_console(stderr=stdout_taken), result)
    written: list[Path] = []
    with _status(terminal) as on_stage:  # the plots of a long run take seconds
        stage = on_stage or (lambda _text: None)
        if graph is not None:
            stage("writing the map graph")
            written += _write_json(graph, result.graph_json(), indent=1)
        if trajectory is not None:
            stage("writing the trajectories")
            written += _write_trajectories(
                result, trajectory, trajectory_format, force=force, warn=terminal.warning
            )
        if plots is not None:
            from aslam.app.plots import write_plots

            stage("drawing the plots")
            written += write_plots(plots, result, force=force, on_warning=terminal.warning)
        if json_out is not None:
            written += _write_json(json_out, result.summary, indent=2)
    for path in written:
        terminal.wrote(f"wrote {path}")

    failed = failed_conditions(conditions, result.summary)
    if failed:
        raise QualityGateFailed(f"quality gate failed: {'; '.join(failed)}")


def _print_tables(console: Any, result: Any) -> None:
    """The report's tables. On stdout they are the command's result, so like its documents they are
    written once every file output is in place: a command that then fails (an output written by
    another process meanwhile) prints none. On stderr (stdout taken by a document) at once."""
    from aslam.cli.tables import print_report
    from aslam.data_formats.files import write_text_output

    if console.stderr:
        print_report(console, result)
        return
    with console.capture() as captured:
        print_report(console, result)
    write_text_output("-", captured.get())


def _write_trajectories(
    result: Any, path: str, fmt: TrajectoryFormat | None, *, force: bool, warn: Callable[[str], None]
) -> list[Path]:
    from aslam.app.metric_view import export_trajectories

    if result.embedding is None:  # as a run without ground truth writes no truth file
        from aslam.data_formats.files import remove_superseded
        from aslam.data_formats.trajectory import export_plan

        warn(f"{path}: not written (nor its .odometry and .truth files): the estimate has no keyframes")
        for stale in export_plan(path, fmt)[0]:  # an earlier run's, with --force
            remove_superseded(stale, force=force)
        return []
    paths = export_trajectories(
        path, result.embedding, result.stamps_ns, result.true_poses, fmt, force=force, on_warning=warn
    )
    return list(paths.values())


@contextlib.contextmanager
def _status(terminal: Terminal) -> Iterator[Callable[[str], None] | None]:
    """A spinner naming the stage the scoring is at (only on a terminal, never with --quiet).

    Each update redraws it: GTSAM holds the interpreter while it optimises, so the spinner's own
    refresh thread stood still through the metric view's seconds; its iterations update it."""
    if not terminal.shows_progress:
        yield None
        return
    from rich.live import Live
    from rich.spinner import Spinner

    spinner = Spinner("dots", text="report", style="status.spinner")
    with Live(spinner, console=terminal.console, refresh_per_second=12.5, transient=True) as live:

        def update(text: str) -> None:
            spinner.update(text=f"report: {text}")
            live.refresh()

        yield update


def _check_output(path: Path, *, force: bool, others: list[Path], inputs: list[Path]) -> None:
    """Refused as an input first: ``--json E.mcap`` advised a ``--force`` that was then refused."""
    from aslam.data_formats.files import check_output_path

    check_output_path(path, force=force, outputs=others, inputs=inputs)


def _write_json(target: str, document: dict[str, Any], *, indent: int) -> list[Path]:
    """Write ``document`` to ``target`` ('-': stdout); the paths written."""
    from aslam.data_formats.files import write_text_output
    from aslam.data_formats.json_text import json_text

    written = write_text_output(target, json_text(document, indent=indent))
    return [] if written is None else [written]
