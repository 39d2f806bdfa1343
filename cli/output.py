"""What every command shares on the terminal: --quiet/--verbose, warning lines, topic options.

Results go to stdout (tables, JSON); everything about the run (progress, "wrote …", warnings) goes
to stderr, so a pipeline can take stdout as it is.
"""

from __future__ import annotations

import contextlib
import functools
import os
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

if TYPE_CHECKING:
    from rich.console import Console
    from rich.table import Table
    from rich.text import Text

QUIET = [False]
"""Set by ``--quiet`` as it is parsed: the warnings the command's output handling gives before the
command's own ``Terminal`` exists (a temporary file an interrupted run left) are silenced too."""


def _note_quiet(value: bool) -> bool:
    QUIET[0] = value
    return value


QuietOption = Annotated[
    bool,
    typer.Option(
        "--quiet",
        "-q",
        help="Print errors only: no progress, no warnings, no summary line.",
        callback=_note_quiet,
    ),
]


def _note_force(value: bool) -> bool:
    """Every output of the command follows this one --force (aslam.data_formats.files)."""
    from aslam.data_formats.files import note_force

    note_force(value)
    return value


ForceOption = Annotated[
    bool, typer.Option("--force", help="Overwrite existing output files.", callback=_note_force)
]
VerboseOption = Annotated[bool, typer.Option("--verbose", "-v", help="Also print the details of the run.")]
VerboseAcceptedOption = Annotated[
    bool, typer.Option("--verbose", "-v", help="Accepted, as by every command; adds nothing here.")
]
"""``-v`` of a command with no details to add (``info``, ``import``, ``report``, ``record``)."""


def counted(count: int, noun: str, plural: str | None = None) -> str:
    """``count`` and ``noun``, plural unless one: "1 keyframe", "2 keyframes", "1 hypothesis"."""
    return f"{count} {noun if count == 1 else plural or noun + 's'}"


def output_name(text: str) -> str:
    """An output's name as typed, refused when it names a folder: ``-o out/`` wrote a file named
    ``out`` (``Path`` drops the slash), and ``-o e.mcap/ --force`` replaced ``e.mcap``."""
    if not text:
        raise typer.BadParameter("an empty name; give a file name")
    if text != "-" and (text.endswith(("/", os.sep)) or os.path.basename(text) in (".", "..")):
        raise typer.BadParameter(f"{text!r} names a folder; give a file name")
    return text


def decimal_number(text: str | float) -> float:
    """A float option's value in decimal digits (:func:`aslam.core.decimal_text.parse_decimal`):
    ``--radius-m 0_5`` was 5 and ``--step-m ٥`` 5.0, in silence. A default is a number already."""
    from aslam.core.decimal_text import parse_decimal

    if isinstance(text, int | float):
        return float(text)
    try:
        return parse_decimal(text)
    except ValueError:
        raise typer.BadParameter(f"{text!r} is not a decimal number (digits 0-9, e.g. 0.5 or 1e-3)") from None


def whole_number(text: str | int) -> int:
    """An integer option's value in decimal digits (``--seed ３`` was 3, ``--laps 1_0`` 10)."""
    from aslam.core.decimal_text import parse_whole

    if isinstance(text, int):
        return text
    try:
        return parse_whole(text)
    except ValueError:
        raise typer.BadParameter(f"{text!r} is not a whole number (digits 0-9)") from None


def input_file(text: str) -> Path:
    """An input's name, refused when empty: ``--map ""`` was the current folder, named in an error
    as a folder the user never gave."""
    if not text:
        raise typer.BadParameter("an empty name; give a file name")
    return Path(text)


def output_file(text: str) -> Path:
    """:func:`output_name` as a path (the parser of ``-o``, ``--contact-sheet``)."""
    return Path(output_name(text))


ImageTopicOption = Annotated[
    str | None,
    typer.Option(help="Image topic (CompressedImage or Image). \\[default: /camera/image/compressed]"),
]
OdometryTopicOption = Annotated[str | None, typer.Option(help="Odometry topic. \\[default: /odom]")]
GroundTruthTopicOption = Annotated[
    str | None, typer.Option(help="Ground-truth pose topic. \\[default: /ground_truth/pose]")
]
OdomFrameOption = Annotated[
    str | None,
    typer.Option(help="A bag's odometry from /tf: the odometry frame. \\[default: odom]"),
]
BaseFrameOption = Annotated[
    str | None,
    typer.Option(
        help="A bag's odometry from /tf: the robot's frame. \\[default: base_footprint or base_link if"
        " published, else the first child of the odometry frame]"
    ),
]


def _live_display_wanted() -> bool:
    """A progress bar redraws itself: only on an interactive terminal, decided without importing
    rich's console (20 ms of an estimate's start-up, before its reader starts). stderr must be a
    real terminal: ``FORCE_COLOR`` and ``TTY_COMPATIBLE``, which CI logs set for colour, ask for
    colour, not for a bar redrawn eight times a second into a log. ``TTY_INTERACTIVE=0`` (rich's
    own variable) turns the bar off on a terminal too."""
    if os.environ.get("TTY_INTERACTIVE") == "0":
        return False
    try:
        return sys.stderr.isatty() and os.environ.get("TERM", "").lower() not in ("dumb", "unknown")
    except (AttributeError, ValueError):  # no stderr, or a closed one
        return False


def table_console(*, stderr: bool = False) -> Console:
    """The console a command's tables (its result) are printed on: no markup or emoji codes read
    in the text (a path or topic ``a[/x]b`` is printed as it is, never parsed), and in a pipe or a
    file full width, so a log never holds a name or a number cut at 80 columns; control
    characters shown as escapes (:func:`_printable_console_class`)."""
    stream = sys.stderr if stderr else sys.stdout
    try:
        terminal = stream.isatty()  # the stream itself: FORCE_COLOR asks for colour, not a width
    except (AttributeError, ValueError):
        terminal = False
    width = None if terminal else UNCUT_WIDTH
    console_class = _printable_console_class()
    return console_class(stderr=stderr, markup=False, emoji=False, highlight=False, width=width)


UNCUT_WIDTH = 10_000
"""The width of a table in a pipe or a file: as wide as its content (:func:`table_console`)."""


def print_table(console: Console, table: Table) -> None:
    """Print ``table`` with no cell cut to "…": no column is made narrower than its longest word (a
    path, a figure), nor a ``no_wrap`` column (figures kept on one line) than its longest cell.
    On a window too narrow for that the table is wider than the window, and the terminal wraps its
    lines: on a 40-column terminal the report's errors read "0.1…" for 0.159."""
    from rich.measure import Measurement

    options = console.options
    for column in table.columns:
        cells = [*column.cells, *([column.header] if table.show_header else [])]
        widths = [Measurement.get(console, options, cell) for cell in cells]
        needed = [width.maximum if column.no_wrap else width.minimum for width in widths]
        column.min_width = max([column.min_width or 0, *needed])
    needed_width = Measurement.get(console, options.update_width(UNCUT_WIDTH), table).minimum
    console.print(_AtLeast(table, needed_width), crop=False)


class _AtLeast:
    """A renderable drawn at least ``width`` columns wide, wider than the console if need be
    (``Console.print``'s own ``width`` is capped at the console's)."""

    def __init__(self, renderable: Any, width: int) -> None:
        self.renderable, self.width = renderable, width

    def __rich_console__(self, console: Console, options: Any) -> Any:
        yield from console.render(self.renderable, options.update_width(max(options.max_width, self.width)))


@functools.cache
def _printable_console_class() -> type[Console]:
    """Made at first use: rich is imported by the commands that print, never at start-up."""
    from rich.console import Console

    class PrintableConsole(Console):
        """Every text printed (a line, a table's cell) made :func:`~aslam.core.errors.printable`:
        a file name, topic or metadata value with a newline or an escape sequence in it stays on
        its line and never recolours the terminal."""

        def render_str(self, text: str, **options: Any) -> Text:
            from aslam.core.errors import printable

            return super().render_str(printable(text), **options)

    return PrintableConsole


class Terminal:
    """The stderr side of a command, honouring --quiet and --verbose."""

    def __init__(self, *, quiet: bool = False, verbose: bool = False) -> None:
        if quiet and verbose:
            from aslam.core.errors import InputError

            raise InputError("--quiet and --verbose exclude each other")
        self.quiet = quiet
        self.verbose = verbose
        self._console: Console | None = None

    @property
    def console(self) -> Console:
        if self._console is None:
            from rich.console import Console

            self._console = Console(stderr=True)
        return self._console

    @property
    def shows_progress(self) -> bool:
        """A live bar only on an interactive terminal (:func:`_live_display_wanted`), and never with
        --quiet: logs and pipes get the summary line."""
        return not self.quiet and _live_display_wanted()

    def _line(self, text: str) -> None:
        """One line on stderr. A stderr whose reader is gone (``2>&1 | head -1``) loses the line and
        nothing else: the command runs on, as with stderr closed, and its exit code says how it
        ended (it was 141 with no output, the run stopped at its first line about itself). A name in
        it (``wrote a\\nb.mcap``) is :func:`~aslam.core.errors.printable`: one line, no escapes acted on."""
        from aslam.core.errors import printable

        text = printable(text)
        try:
            if self._console is not None and self._console.is_terminal:
                self._console.print(text, markup=False, highlight=False, soft_wrap=True)
            else:
                sys.stderr.write(text + "\n")
                sys.stderr.flush()
        except (OSError, ValueError):
            pass

    def warning(self, message: str) -> None:
        if not self.quiet:
            from aslam.core.errors import one_line

            self._line(f"aslam: warning: {one_line(message)}")

    def info(self, message: str) -> None:
        """A line about the run (what was written, how fast); not with --quiet."""
        if not self.quiet:
            self._line(message)

    def wrote(self, message: str) -> None:
        """A line naming what the command wrote, shown once its outputs are renamed into place
        (``aslam.data_formats.files.command_files``): a command that then fails, or is
        interrupted, never claims a file it leaves no trace of. At once where writes land at once."""
        from aslam.data_formats.files import current

        files = current()
        if files is None:
            self.info(message)
        else:
            files.after_commit.append(lambda: self.info(message))

    def detail(self, message: str) -> None:
        """A line only --verbose shows."""
        if self.verbose:
            self._line(message)


@contextlib.contextmanager
def counted_progress(
    terminal: Terminal, label: str, *, unit: str = ""
) -> Iterator[Callable[[int, int | None], None]]:
    """A bar counting the items done of their total (None until known), with the time left, gone
    when the work ends: yields its update callback ``(done, total)``. Where no bar is shown (logs,
    pipes, --quiet) rich's progress module is not even imported, and the callback only does its
    other duty: ending the work at the next item when a signal arrived that a library swallowed
    (:func:`aslam.cli.app.raise_if_interrupted`)."""
    from aslam.cli.app import raise_if_interrupted

    if not terminal.shows_progress:
        yield lambda _done, _total: raise_if_interrupted()
        return
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    columns = [TextColumn(label), BarColumn(), MofNCompleteColumn()]
    columns += [TextColumn(unit)] if unit else []
    with Progress(*columns, TimeRemainingColumn(), console=terminal.console, transient=True) as bar:
        task = bar.add_task(label, total=None)

        def update(done: int, total: int | None) -> None:
            raise_if_interrupted()
            bar.update(task, completed=done, total=total)

        yield update
