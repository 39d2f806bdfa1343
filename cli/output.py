"""What every command shares on the terminal: --quiet/--verbose, warning lines, topic options.

Results go to stdout (tables, JSON); everything about the run (progress, "wrote …", warnings) goes
to stderr, so a pipeline can take stdout as it is.
"""

from __future__ import annotations

import os
import sys
from typing import TYPE_CHECKING, Annotated

import typer

if TYPE_CHECKING:
    from rich.console import Console

QuietOption = Annotated[
    bool, typer.Option("--quiet", "-q", help="Print errors only: no progress, no warnings, no summary line.")
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
ImageTopicOption = Annotated[
    str | None,
    typer.Option(help="Image topic (CompressedImage or Image). \\[default: /camera/image/compressed]"),
]
OdometryTopicOption = Annotated[str | None, typer.Option(help="Odometry topic. \\[default: /odom]")]
GroundTruthTopicOption = Annotated[
    str | None, typer.Option(help="Ground-truth pose topic. \\[default: /ground_truth/pose]")
]


def _surely_not_a_terminal() -> bool:
    """stderr is a file or a pipe and no variable tells rich otherwise: decided without importing
    rich's console (20 ms of an estimate's start-up, before its reader starts); rich decides the rest."""
    if "TTY_COMPATIBLE" in os.environ or "FORCE_COLOR" in os.environ:
        return False
    try:
        return not sys.stderr.isatty()
    except (AttributeError, ValueError):  # no stderr, or a closed one
        return False


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
        """A live bar only on a terminal, and never with --quiet (logs and pipes get the summary line)."""
        return not self.quiet and not _surely_not_a_terminal() and self.console.is_terminal

    def _line(self, text: str) -> None:
        if self._console is not None and self._console.is_terminal:
            self._console.print(text, markup=False, highlight=False, soft_wrap=True)
        else:
            sys.stderr.write(text + "\n")
            sys.stderr.flush()

    def warning(self, message: str) -> None:
        if not self.quiet:
            from aslam.cli.app import one_line

            self._line(f"aslam: warning: {one_line(message)}")

    def info(self, message: str) -> None:
        """A line about the run (what was written, how fast); not with --quiet."""
        if not self.quiet:
            self._line(message)

    def detail(self, message: str) -> None:
        """A line only --verbose shows."""
        if self.verbose:
            self._line(message)
