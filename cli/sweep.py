"""`aslam sweep`: many recordings × estimator parameter sets, as tasks on Dask distributed.

Thin: reads the sweep file (:mod:`aslam.app.sweep_file`), calls :func:`aslam.app.sweep.run_sweep`
with a live rich table (stderr; plain lines when not a terminal), prints the Pareto set on stdout.
Dask and pyarrow are imported only when the command runs.
"""

from __future__ import annotations

from collections import deque
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from aslam.cli.app import app
from aslam.cli.output import QuietOption, Terminal, VerboseOption

if TYPE_CHECKING:
    from aslam.app.sweep import Task, TaskResult

#: Finished tasks the live table shows (the newest); the files hold them all.
LIVE_ROWS = 15


@app.command()
def sweep(
    sweep_file: Annotated[
        Path, typer.Argument(metavar="SWEEP.toml", help="Sweep file (docs/sweep.md).", dir_okay=False)
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
        int | None, typer.Option(help="Worker processes of the local cluster. \\[default: one per core]")
    ] = None,
    scheduler: Annotated[
        str | None,
        typer.Option(help="Use the Dask cluster at this address (tcp://HOST:PORT) instead of a local one."),
    ] = None,
    pareto: Annotated[
        str | None,
        typer.Option(
            help="Print the Pareto set over these figures, e.g. precision,recall,keyframes_per_second"
            " (summary keys or their unique tails; errors and delays are minimised, the rest maximised;"
            " +NAME/-NAME to choose)."
        ),
    ] = None,
    force: Annotated[
        bool, typer.Option("--force", help="Recompute every task, even those already done.")
    ] = False,
    quiet: QuietOption = False,
    verbose: VerboseOption = False,
) -> None:
    """Run every recording under every parameter set of SWEEP.toml on Dask; write results.parquet and .csv.

    Exit codes: 0 every task succeeded, 3 some tasks failed (their rows say why), 2 bad input.
    """
    from aslam.app.sweep import resolve_objectives, run_sweep
    from aslam.app.sweep_file import read_sweep_file

    terminal = Terminal(quiet=quiet, verbose=verbose)
    objectives = resolve_objectives(pareto) if pareto is not None else []
    spec = read_sweep_file(sweep_file)
    display = (
        _LiveDisplay(terminal, spec.figures)
        if terminal.shows_progress
        else _PlainDisplay(terminal, spec.figures)
    )
    with display:
        run = run_sweep(
            spec,
            output,
            workers=workers,
            scheduler=scheduler,
            force=force,
            extra_figures=[o.key for o in objectives],
            on_plan=display.plan,
            on_result=display.result,
        )
    computed = len(run.tasks) - run.reused
    terminal.info(
        f"wrote {run.parquet} and {run.csv.name} ({len(run.tasks)} tasks: {len(run.tasks) - run.failed} ok,"
        f" {run.failed} failed; {computed} run, {run.reused} already done)"
    )
    if objectives:
        _print_pareto(run, objectives)
    run.check()


def _figure_text(value: Any) -> str:
    if value is None:
        return "—"
    if isinstance(value, float):
        return f"{value:.4g}"
    return str(value)


def _short_key(key: str) -> str:
    return key.rsplit(".", 1)[-1] if key.count(".") <= 1 else ".".join(key.split(".")[-2:])


def _parameters_text(task: Task) -> str:
    return " ".join(f"{name}={value}" for name, value in task.parameters) or "defaults"


class _PlainDisplay:
    """One line per finished task (logs, pipes, --quiet: nothing but the summary line)."""

    def __init__(self, terminal: Terminal, figures: tuple[str, ...]) -> None:
        self.terminal = terminal
        self.figures = figures
        self.total = 0
        self.done = 0

    def __enter__(self) -> _PlainDisplay:
        return self

    def __exit__(self, *exc: object) -> None:
        return None

    def plan(self, tasks: Any, to_run: Any) -> None:
        self.total = len(tasks)
        renders = len({t.source.path for t in to_run if t.source.render is not None})
        rendering = f" (first rendering {renders} recording{'s' if renders != 1 else ''})" if renders else ""
        self.terminal.info(
            f"{len(tasks)} tasks, {len(tasks) - len(to_run)} already done, {len(to_run)} to run{rendering}"
        )

    def result(self, task: Task, result: TaskResult, reused: bool) -> None:
        self.done += 1
        if reused and not self.terminal.verbose:
            return
        head = f"[{self.done}/{self.total}] {task.source.label} {_parameters_text(task)}:"
        if result.ok and result.summary is not None:
            figures = " ".join(f"{_short_key(k)}={_figure_text(result.summary.get(k))}" for k in self.figures)
            timing = "already done" if reused else f"{result.estimate_wall_s:.2f} s on {result.worker}"
            self.terminal.info(f"{head} {figures} ({timing})")
        else:
            self.terminal.info(f"{head} failed: {result.error}")


class _LiveDisplay:
    """A progress bar over a table of the newest finished tasks, redrawn in place on stderr."""

    def __init__(self, terminal: Terminal, figures: tuple[str, ...]) -> None:
        from rich.live import Live
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

        self.terminal = terminal
        self.figures = figures
        self.progress = Progress(
            TextColumn("sweep"),
            BarColumn(),
            MofNCompleteColumn(),
            TextColumn("{task.fields[failed]} failed"),
            TimeElapsedColumn(),
            console=terminal.console,
        )
        self.bar = self.progress.add_task("sweep", total=None, failed=0)
        self.rows: deque[tuple[Any, ...]] = deque(maxlen=LIVE_ROWS)
        self.failed = 0
        self.live = Live(self._render(), console=terminal.console, refresh_per_second=4, transient=False)

    def _render(self) -> Any:
        from rich.console import Group
        from rich.table import Table

        table = Table(box=None, pad_edge=False)
        for name in ("#", "recording", "parameters", *map(_short_key, self.figures), "wall s", "worker"):
            table.add_column(name, overflow="fold")
        table.add_column("error", overflow="fold", style="red")
        for row in self.rows:
            table.add_row(*row)
        return Group(table, self.progress)

    def __enter__(self) -> _LiveDisplay:
        self.live.__enter__()
        return self

    def __exit__(self, *exc: object) -> None:
        self.live.__exit__(None, None, None)

    def plan(self, tasks: Any, to_run: Any) -> None:
        self.progress.update(self.bar, total=len(tasks))
        renders = len({t.source.path for t in to_run if t.source.render is not None})
        if renders:
            self.terminal.console.print(f"rendering {renders} recording{'s' if renders != 1 else ''} first")

    def result(self, task: Task, result: TaskResult, reused: bool) -> None:
        from rich.text import Text

        summary = result.summary or {}
        figures = [_figure_text(summary.get(k)) for k in self.figures]
        if result.ok:
            wall = "done before" if reused else f"{result.estimate_wall_s:.2f}"
        else:
            self.failed += 1
            wall = ""
        error = Text(result.error or "")  # plain text: an error may contain [brackets]
        self.rows.append(
            (str(task.index), task.source.label, _parameters_text(task), *figures, wall, result.worker, error)
        )
        self.progress.update(self.bar, advance=1, failed=self.failed)
        self.live.update(self._render())


def _print_pareto(run: Any, objectives: list[Any]) -> None:
    """The Pareto set as a table on stdout (plain text when stdout is not a terminal)."""
    from rich.console import Console
    from rich.table import Table

    from aslam.app.sweep import pareto_front

    front = pareto_front(run.results, objectives)
    table = Table(title=f"Pareto set: {len(front)} of {len(run.results)} tasks", title_justify="left")
    for name in ("task", "recording", "parameters"):
        table.add_column(name)
    for objective in objectives:  # ↑ maximised, ↓ minimised
        table.add_column(("↑ " if objective.maximise else "↓ ") + objective.key)
    for result in front:
        task = run.tasks[result.index]
        values = [_figure_text(result.summary.get(o.key)) for o in objectives]
        table.add_row(str(task.index), task.source.label, _parameters_text(task), *values)
    console = Console()
    if not console.is_terminal:  # a pipe or a file: full names, never cut to 80 columns
        console = Console(width=10_000)
    console.print(table)
