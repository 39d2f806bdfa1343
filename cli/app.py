"""The `aslam` command: one typer app, errors mapped to exit codes once, here at the edge.

Heavy modules (pyrender, cv2, matplotlib) are imported inside the commands that need them so
that `aslam --help` stays instant.
"""

from __future__ import annotations

import os
import sys
from typing import Annotated

import typer
import typer.core

from aslam.core.errors import AslamError
from aslam.data_formats.provenance import tool_version

EXIT_OK = 0
EXIT_BAD_INPUT = 2
EXIT_TASKS_FAILED = 3  # `aslam sweep`: some tasks failed (aslam.app.sweep.TasksFailed)
EXIT_INTERNAL = 70
EXIT_INTERRUPTED = 130

app = typer.Typer(
    name="aslam",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    context_settings={"help_option_names": ["-h", "--help"]},
)

_display_type_rich = typer.core.TyperOption.display_type_rich


def _no_flag_placeholder(self: typer.core.TyperOption, ctx: typer.Context) -> str | None:
    """Flags take no value, so the help shows none (typer would print ``<bool>``)."""
    return None if self.is_flag else _display_type_rich(self, ctx)


typer.core.TyperOption.display_type_rich = _no_flag_placeholder  # type: ignore[method-assign]


def _print_version(value: bool) -> None:
    if value:
        typer.echo(f"aslam {tool_version()}")
        raise typer.Exit()


@app.callback()
def _root(
    show_version: Annotated[
        bool,
        typer.Option("--version", callback=_print_version, is_eager=True, help="Print the version and exit."),
    ] = False,
) -> None:
    """Appearance-based SLAM with a tree of path hypotheses, over MCAP recordings.

    record → estimate → report.  Exit codes: 0 success, 1 a `report --fail-on` gate failed,
    2 bad input or usage, 3 some `sweep` tasks failed, 70 internal error (a bug), 130 interrupted.
    """


def _register_commands() -> None:
    from aslam.cli import estimate, import_folder, info, record, report, sweep  # noqa: F401  (registers the commands)


def error_line(message: str) -> None:
    """One line on stderr, the only thing a user sees of an error."""
    sys.stderr.write(f"aslam: error: {' '.join(message.split())}\n")
    sys.stderr.flush()


def main(argv: list[str] | None = None) -> int:
    """Console entry point: run the app and map every outcome to a documented exit code.

    The console script passes the return value to ``sys.exit``; tests call it directly.
    """
    _register_commands()
    try:
        code = app(args=argv, standalone_mode=False, prog_name="aslam")
        if code == EXIT_INTERRUPTED:  # typer turns Ctrl-C into a silent exit 130
            error_line("interrupted")
    except AslamError as err:
        error_line(str(err))
        return err.exit_code
    except (KeyboardInterrupt, typer.Abort):
        error_line("interrupted")
        return EXIT_INTERRUPTED
    except typer.Exit as done:
        if done.exit_code == EXIT_INTERRUPTED:  # typer's own translation of Ctrl-C
            error_line("interrupted")
        return done.exit_code
    except Exception as err:
        usage = _usage_error_line(err)
        if usage is not None:  # click's usage and parameter errors, made one line
            if usage:  # empty when the help was shown instead (no arguments)
                error_line(usage)
            return EXIT_BAD_INPUT
        if os.environ.get("ASLAM_DEBUG"):
            raise
        error_line(f"internal error: {type(err).__name__}: {err} (set ASLAM_DEBUG=1 for a traceback)")
        return EXIT_INTERNAL
    return code if isinstance(code, int) else EXIT_OK


def _usage_error_line(err: Exception) -> str | None:
    """The one-line text of a command-line usage error, or None if ``err`` is not one."""
    format_message = getattr(err, "format_message", None)
    if format_message is None or not hasattr(err, "exit_code"):
        return None
    ctx = getattr(err, "ctx", None)
    command = ctx.command_path if ctx is not None else "aslam"
    message = format_message()
    return f"{message} (see '{command} --help')" if message else ""
