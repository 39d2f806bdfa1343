"""What `aslam sweep` shows while it runs: a live table over a progress bar, or one line per task."""

from __future__ import annotations

import threading
from collections import deque
from typing import TYPE_CHECKING, Any

from aslam.cli.output import Terminal, counted

if TYPE_CHECKING:
    from aslam.app.sweep import SweepPlan, Task, TaskResult

#: Finished tasks the live table shows (the newest); the files hold them all.
LIVE_ROWS = 15

#: The narrowest error column the live table folds an error into; narrower, one line per task.
ERROR_MIN_WIDTH = 24


def figure_text(value: Any) -> str:
    if value is None:
        return "—"
    if isinstance(value, bool):
        return "true" if value else "false"  # as the summary JSON and the gates say it
    if isinstance(value, float):
        return f"{value:.4g}"
    return str(value)


def short_names(keys: tuple[str, ...]) -> tuple[str, ...]:
    """Each summary key by its last part (the last two where there are more: ``x_m.mean``), longer
    where that would name another key too: ``loop_closure.precision`` and ``committed.precision``
    were both ``precision``."""

    def tail(key: str, parts: int) -> str:
        return ".".join(key.split(".")[-parts:])

    names = []
    for key in keys:
        parts = 1 if key.count(".") <= 1 else 2
        while parts <= key.count(".") and any(
            other != key and (other == tail(key, parts) or other.endswith("." + tail(key, parts)))
            for other in keys
        ):
            parts += 1
        names.append(tail(key, parts))
    return tuple(names)


def parameters_text(task: Task) -> str:
    """``name=value`` pairs as the sweep file spells them (``true``, not Python's ``True``)."""
    from aslam.app.config_file import toml_text

    return " ".join(f"{name}={toml_text(value)}" for name, value in task.parameters) or "defaults"


def plan_text(plan: SweepPlan) -> str:
    """``12 tasks, 4 already done, 6 to run, 2 shared with an identical recording (first rendering
    1 recording)``: the tasks computed before, to compute now, and rows sharing another's result."""
    shared = f", {plan.shared} shared with an identical recording" if plan.shared else ""
    renders = plan.renders_due
    rendering = f" (first rendering {counted(renders, 'recording')})" if renders else ""
    counts = f"{counted(len(plan.tasks), 'task')}, {plan.reused} already done, {len(plan.to_run)} to run"
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

    def task_progress(self, task: Task, done: float) -> None:
        """Lines are for finished tasks only."""

    def result(self, task: Task, result: TaskResult, reused: bool) -> None:
        self.done += 1
        if reused and not self.terminal.verbose:
            return
        self.terminal.info(f"[{self.done}/{self.total}] {task_line(task, result, reused, self.figures)}")


def task_line(task: Task, result: TaskResult, reused: bool, figures: tuple[str, ...]) -> str:
    """One finished task as a line: its recording, parameters and figures, or why it failed."""
    head = f"{task.source.label} {parameters_text(task)}:"
    if result.ok and result.summary is not None:
        named = zip(short_names(figures), figures, strict=True)
        values = " ".join(f"{name}={figure_text(result.summary.get(key))}" for name, key in named)
        timing = "already done" if reused else f"{result.estimate_wall_s:.2f} s on {result.worker}"
        if task.same_as is not None:
            timing += f"; task {task.same_as}'s result, the same bytes"
        return f"{head} {values} ({timing})"
    return f"{head} failed: {result.error}"


class LiveDisplay:
    """A progress bar over a table of the newest finished tasks, redrawn in place on stderr.

    A table too wide for the terminal (14 columns at the default figures: every cell folded into
    four-letter strips at 80 columns) first loses its worker column, then becomes one wrapped line
    per task, as the plain display's.
    """

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
        self.finished = 0
        self.running: dict[str, float] = {}  # a running task's key: the share of its images read
        self.ended: set[str] = set()  # keys finished (a late progress event is not taken for one)
        self.lock = threading.Lock()  # progress comes from Dask's event loop thread
        self.rows: deque[tuple[tuple[Any, ...], Any]] = deque(maxlen=LIVE_ROWS)  # (cells, line)
        self.failed = 0
        self.live = Live(self._render(), console=terminal.console, refresh_per_second=4, transient=False)

    def _render(self) -> Any:
        from rich.console import Group
        from rich.table import Table
        from rich.text import Text

        console = self.terminal.console
        unbounded = console.options.update_width(1 << 20)
        names = ("#", "recording", "parameters", *short_names(self.figures), "wall s", "worker", "error")
        # An error folds into what the other columns leave it, if that is a readable width.
        error_width = ERROR_MIN_WIDTH if any(cells[-1].plain for cells, _line in self.rows) else len("error")
        for dropped in ((), ("worker",)):
            kept = [i for i, name in enumerate(names) if name not in dropped]
            tables = [Table(box=None, pad_edge=False) for _ in range(2)]  # shown, and measured
            for i in kept:
                tables[0].add_column(names[i], overflow="fold", style="red" if names[i] == "error" else "")
                if names[i] != "error":
                    tables[1].add_column(names[i])
            for cells, _line in self.rows:
                tables[0].add_row(*(cells[i] for i in kept))
                tables[1].add_row(*(cells[i] for i in kept if names[i] != "error"))
            if console.measure(tables[1], options=unbounded).maximum + 2 + error_width <= console.width:
                return Group(tables[0], self.progress)
        lines = [line for _cells, line in self.rows]
        return Group(*lines, self.progress) if lines else Group(Text(""), self.progress)

    def __enter__(self) -> LiveDisplay:
        self.live.__enter__()
        return self

    def __exit__(self, *exc: object) -> None:
        self.live.__exit__(None, None, None)

    def plan(self, plan: SweepPlan) -> None:
        self.progress.update(self.bar, total=len(plan.tasks))
        renders = plan.renders_due
        if renders:
            self.terminal.console.print(f"rendering {counted(renders, 'recording')} first")

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
        line = Text(printable(f"#{task.index} {task_line(task, result, reused, self.figures)}"))
        if not result.ok:
            line.stylize("red")
        self.rows.append(((str(task.index), *(Text(printable(cell)) for cell in cells)), line))
        with self.lock:
            self.finished += 1
            self.ended.add(task.key)
            self.running.pop(task.key, None)
            self.progress.update(self.bar, completed=self._completed(), failed=self.failed)
        self.live.update(self._render())

    def task_progress(self, task: Task, done: float) -> None:
        """The bar moves within a task (a sweep of a few long tasks sat at 0 for minutes)."""
        with self.lock:
            if task.key not in self.ended:
                self.running[task.key] = done
                self.progress.update(self.bar, completed=self._completed())

    def _completed(self) -> float:
        return self.finished + sum(self.running.values())
