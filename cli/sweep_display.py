"""What `aslam sweep` shows while it runs: a live table over a progress bar, or one line per task."""

from __future__ import annotations

from collections import deque
from typing import TYPE_CHECKING, Any

from aslam.cli.output import Terminal

if TYPE_CHECKING:
    from aslam.app.sweep import SweepPlan, Task, TaskResult

#: Finished tasks the live table shows (the newest); the files hold them all.
LIVE_ROWS = 15


def figure_text(value: Any) -> str:
    if value is None:
        return "—"
    if isinstance(value, float):
        return f"{value:.4g}"
    return str(value)


def _short_key(key: str) -> str:
    return key.rsplit(".", 1)[-1] if key.count(".") <= 1 else ".".join(key.split(".")[-2:])


def parameters_text(task: Task) -> str:
    return " ".join(f"{name}={value}" for name, value in task.parameters) or "defaults"


def plan_text(plan: SweepPlan) -> str:
    """``12 tasks, 4 already done, 6 to run, 2 shared with an identical recording (first rendering
    1 recording)``: the tasks computed before, to compute now, and rows sharing another's result."""
    shared = f", {plan.shared} shared with an identical recording" if plan.shared else ""
    renders = plan.renders_due
    rendering = f" (first rendering {renders} recording{'s' if renders != 1 else ''})" if renders else ""
    counts = f"{len(plan.tasks)} tasks, {plan.reused} already done, {len(plan.to_run)} to run"
    return counts + shared + rendering


class PlainDisplay:
    """One line per finished task (logs, pipes, --quiet: nothing but the summary line)."""

    def __init__(self, terminal: Terminal, figures: tuple[str, ...]) -> None:
        self.terminal = terminal
        self.figures = figures
        self.total = 0
        self.done = 0

    def __enter__(self) -> PlainDisplay:
        return self

    def __exit__(self, *exc: object) -> None:
        return None

    def plan(self, plan: SweepPlan) -> None:
        self.total = len(plan.tasks)
        self.terminal.info(plan_text(plan))

    def result(self, task: Task, result: TaskResult, reused: bool) -> None:
        self.done += 1
        if reused and not self.terminal.verbose:
            return
        head = f"[{self.done}/{self.total}] {task.source.label} {parameters_text(task)}:"
        if result.ok and result.summary is not None:
            figures = " ".join(f"{_short_key(k)}={figure_text(result.summary.get(k))}" for k in self.figures)
            timing = "already done" if reused else f"{result.estimate_wall_s:.2f} s on {result.worker}"
            if task.same_as is not None:
                timing += f"; task {task.same_as}'s result, the same bytes"
            self.terminal.info(f"{head} {figures} ({timing})")
        else:
            self.terminal.info(f"{head} failed: {result.error}")


class LiveDisplay:
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

    def __enter__(self) -> LiveDisplay:
        self.live.__enter__()
        return self

    def __exit__(self, *exc: object) -> None:
        self.live.__exit__(None, None, None)

    def plan(self, plan: SweepPlan) -> None:
        self.progress.update(self.bar, total=len(plan.tasks))
        renders = plan.renders_due
        if renders:
            self.terminal.console.print(f"rendering {renders} recording{'s' if renders != 1 else ''} first")

    def result(self, task: Task, result: TaskResult, reused: bool) -> None:
        from rich.text import Text

        from aslam.core.errors import printable

        summary = result.summary or {}
        figures = [figure_text(summary.get(k)) for k in self.figures]
        if result.ok:
            wall = "done before" if reused else f"{result.estimate_wall_s:.2f}"
        else:
            self.failed += 1
            wall = ""
        # Text, never markup: a recording's name, a route file's or an error may hold [brackets];
        # printable: a newline or an escape sequence in one neither breaks nor recolours the table
        cells = (task.source.label, parameters_text(task), *figures, wall, result.worker, result.error or "")
        self.rows.append((str(task.index), *(Text(printable(cell)) for cell in cells)))
        self.progress.update(self.bar, advance=1, failed=self.failed)
        self.live.update(self._render())
