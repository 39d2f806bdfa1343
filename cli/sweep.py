"""`aslam sweep`: many recordings × estimator parameter sets, as tasks on Dask distributed.

Thin: reads the sweep file (:mod:`aslam.app.sweep_file`), calls :func:`aslam.app.sweep.run_sweep`
with a live rich table (stderr; plain lines when not a terminal), prints the Pareto set on stdout;
``--dry-run`` prints :func:`aslam.app.sweep.dry_run`'s plan instead. Dask and pyarrow are imported
only when the command runs.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Annotated, Any

import typer

from aslam.cli.app import app
from aslam.cli.output import (
    QuietOption,
    Terminal,
    VerboseOption,
    counted,
    decimal_number,
    output_name,
    print_table,
    table_console,
    whole_number,
)
from aslam.cli.sweep_display import LiveDisplay, PlainDisplay, figure_text, parameters_text, plan_text


def _print_example(value: bool) -> None:
    if value:
        from aslam.app.sweep_file import example_sweep_file

        typer.echo(example_sweep_file(), nl=False)
        raise typer.Exit()


@app.command()
def sweep(
    sweep_file: Annotated[
        Path,
        typer.Argument(
            metavar="SWEEP.toml",
            help="Sweep file (docs/sweep.md; `aslam sweep --example > sweep.toml` writes one to start from).",
            dir_okay=False,
        ),
    ],
    output: Annotated[
        Path,
        typer.Option(
            "-o",
            "--output",
            help="Results folder (created if missing; re-runs skip tasks done in it).",
            file_okay=False,
        ),
    ],
    workers: Annotated[
        int | None,
        typer.Option(
            parser=whole_number,
            metavar="INTEGER",
            help="Worker processes of the local cluster. \\[default: one per core]",
        ),
    ] = None,
    scheduler: Annotated[
        str | None,
        typer.Option(help="Use the Dask cluster at this address (tcp://HOST:PORT) instead of a local one."),
    ] = None,
    scheduler_file: Annotated[
        Path | None,
        typer.Option(
            help="Use the Dask cluster whose scheduler wrote this file (`dask scheduler --scheduler-file`,"
            " dask-mpi, a batch job's script); waited for up to 30 s.",
            show_default=False,
        ),
    ] = None,
    pareto: Annotated[
        str | None,
        typer.Option(
            help="Print the Pareto set over these figures, e.g. precision,recall,keyframes_per_second"
            " (summary keys or their tails, as report --fail-on reads them; errors and delays are minimised,"
            " the rest maximised;"
            " +NAME/-NAME to choose)."
        ),
    ] = None,
    force: Annotated[
        bool, typer.Option("--force", help="Recompute every task, even those already done.")
    ] = False,
    task_timeout: Annotated[
        float | None,
        typer.Option(
            parser=decimal_number,
            metavar="SECONDS",
            help="A task still computing after this long is stopped (its worker restarted) and is a"
            " failed row. \\[default: none]",
            show_default=False,
        ),
    ] = None,
    dry_run: Annotated[
        bool,
        typer.Option(
            "--dry-run",
            help="Check the sweep file and the options, and list the tasks, those done in the results"
            " folder and those that would run; start no cluster, write nothing.",
        ),
    ] = False,
    json_out: Annotated[
        str | None,
        typer.Option(
            "--json",
            help="With --dry-run: write the plan as one JSON object here; '-': stdout.",
            parser=output_name,
            metavar="<file>",
        ),
    ] = None,
    example: Annotated[
        bool,
        typer.Option(
            "--example",
            callback=_print_example,
            is_eager=True,
            help="Print an example sweep file (every table, commented) and exit.",
        ),
    ] = False,
    quiet: QuietOption = False,
    verbose: VerboseOption = False,
) -> None:
    """Run every recording under every parameter set of SWEEP.toml on Dask; write results.parquet and .csv.

    Exit codes: 0 every task succeeded, 3 some tasks failed (their rows say why), 2 bad input.
    """
    from aslam.app.sweep import resolve_objectives, run_sweep, scheduler_address
    from aslam.app.sweep_file import read_sweep_file
    from aslam.core.errors import InputError

    terminal = Terminal(quiet=quiet, verbose=verbose)
    if json_out is not None and not dry_run:
        raise InputError("--json writes the plan of --dry-run; give both")
    if scheduler_file is not None and scheduler is not None:
        raise InputError("--scheduler and --scheduler-file both name the cluster; give one")
    objectives = resolve_objectives(pareto) if pareto is not None else []
    spec = read_sweep_file(sweep_file)
    if json_out is not None and json_out != "-":  # before the recordings are hashed
        recordings = list(dict.fromkeys(recording.path for recording in spec.recordings))
        _check_plan_output(Path(json_out), sweep_file, recordings, output, force=force)
    if scheduler_file is not None:
        # A dry run contacts no scheduler, so it waits for no scheduler file either (it waited 30 s
        # for one not yet written, then exit 2); its options are checked as the run's would be.
        scheduler = f"the cluster of {scheduler_file}" if dry_run else scheduler_address(scheduler_file)
    # what a run and a dry run both take, so that the dry run plans exactly what the run would do
    options: dict[str, Any] = {
        "workers": workers,
        "scheduler": scheduler,
        "force": force,
        "task_timeout": task_timeout,
    }
    if dry_run:
        _dry_run(spec, output, options, json_out, terminal)
        return
    display = (
        LiveDisplay(terminal, spec.figures)
        if terminal.shows_progress
        else PlainDisplay(terminal, spec.figures)
    )
    with display:
        run = run_sweep(
            spec,
            output,
            **options,
            extra_figures=[o.key for o in objectives],
            on_plan=display.plan,
            on_result=display.result,
            on_warning=terminal.warning,
            on_progress=display.task_progress,
        )
    if objectives:  # first: a stdout that cannot be written fails the command before its `wrote` line
        _print_pareto(run, objectives)
    shared = f", {run.shared} shared with an identical recording" if run.shared else ""
    tables = f"{'wrote' if run.tables_written else 'kept'} {run.parquet} and {run.csv.name}"
    terminal.info(
        f"{tables} ({counted(len(run.tasks), 'task')}: {len(run.tasks) - run.failed} ok,"
        f" {run.failed} failed; {run.computed} run, {run.reused} already done{shared})"
    )
    run.check()


def _check_plan_output(
    path: Path, sweep_file: Path, recordings: Sequence[Path], output: Path, *, force: bool
) -> None:
    """The plan's JSON replaces an existing file only with ``--force``, and never an input (the sweep
    file, a recording, a file inside a bag folder) or a file of the results folder, which the dry
    run reads: it replaced a recording the sweep reads, in silence."""
    from aslam.core.errors import InputError
    from aslam.data_formats.files import check_output_path, real_path

    real = real_path(path)
    for folder in (output, *(recording for recording in recordings if recording.is_dir())):
        if real.is_relative_to(real_path(folder)):
            raise InputError(
                f"is inside {folder}, which this sweep reads; refusing to write there", path=path
            )
    check_output_path(path, force=force, inputs=[sweep_file, *recordings])


def _dry_run(
    spec: Any, output: Path, options: dict[str, Any], json_out: str | None, terminal: Terminal
) -> None:
    """The plan on stdout (a line and the tasks to run, or JSON); exit 2 as the run would, when it
    could not save its results."""
    from rich.table import Table

    from aslam.app.sweep import dry_run
    from aslam.data_formats.files import write_text_output
    from aslam.data_formats.json_text import json_text

    plan = dry_run(spec, output, **options, on_warning=terminal.warning)
    if json_out is not None:
        written = write_text_output(json_out, json_text(plan.as_dict(), indent=2))
        if written is not None:
            terminal.wrote(f"wrote {written}")
    else:
        console = table_console()
        console.print(plan_text(plan), soft_wrap=True)
        if plan.to_run:
            table = Table(
                title=f"To run: {len(plan.to_run)} of {len(plan.tasks)} tasks", title_justify="left"
            )
            for name in ("task", "recording", "parameters"):
                table.add_column(name)
            for task in plan.to_run:
                table.add_row(str(task.index), task.source.label, parameters_text(task))
            print_table(console, table)
    plan.check_writable()


def _print_pareto(run: Any, objectives: list[Any]) -> None:
    """The Pareto set as a table on stdout (plain text when stdout is not a terminal)."""
    from rich.table import Table

    from aslam.app.sweep import pareto_front

    front = pareto_front(run.results, objectives)
    table = Table(title=f"Pareto set: {len(front)} of {len(run.results)} tasks", title_justify="left")
    for name in ("task", "recording", "parameters"):
        table.add_column(name)
    for objective in objectives:  # ↑ maximised, ↓ minimised
        table.add_column(("↑ " if objective.maximise else "↓ ") + objective.key, no_wrap=True)
    for result in front:
        task = run.tasks[result.index]
        assert result.summary is not None  # the front holds successful results only
        values = [figure_text(result.summary.get(o.key)) for o in objectives]
        table.add_row(str(task.index), task.source.label, parameters_text(task), *values)
    print_table(table_console(), table)
