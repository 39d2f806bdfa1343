"""The `aslam` command: one typer app, errors mapped to exit codes once, here at the edge.

Heavy modules (pyrender, cv2, matplotlib) are imported inside the commands that need them so
that `aslam --help` stays instant.
"""

from __future__ import annotations

import contextlib
import errno
import io
import os
import signal
import sys
import threading
import warnings
from typing import TYPE_CHECKING, Annotated, NoReturn, TextIO

import typer
import typer.core

from aslam.core.errors import AslamError, QualityGateFailed, one_line
from aslam.data_formats.provenance import tool_version

if TYPE_CHECKING:
    from aslam.data_formats.files import CommandFiles

# An error raised on purpose carries its own code (``exit_code``: aslam.core.errors, and 3 for a
# sweep's failed tasks, app.sweep.TasksFailed); the root command's --help lists every code.
EXIT_OK = 0
EXIT_BAD_INPUT = 2
EXIT_INTERNAL = 70
EXIT_INTERRUPTED = 130
EXIT_CLOSED_PIPE = 141  # 128 + SIGPIPE, what a shell reports for a tool killed by a closed pipe
EXIT_TERMINATED = 143  # 128 + SIGTERM
EXIT_HUNG_UP = 129  # 128 + SIGHUP: the terminal or ssh session went away

app = typer.Typer(
    name="aslam",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    context_settings={"help_option_names": ["-h", "--help"]},
)


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

    record → estimate → report.

    Exit codes:
      0 success
      1 a `report --fail-on` gate failed
      2 bad input or usage
      3 some `sweep` tasks failed
      70 internal error (a bug)
      129 hung up (SIGHUP)
      130 interrupted (Ctrl-C)
      141 stdout closed (e.g. piped into `head`)
      143 terminated (SIGTERM)
    """


#: Each command and the module that registers it.
COMMAND_MODULES = {
    "record": "record",
    "estimate": "estimate",
    "report": "report",
    "info": "info",
    "import": "import_folder",
    "sweep": "sweep",
}


def _register_commands(name: str | None = None) -> None:
    """Import the modules that register the commands: only ``name``'s when it is one (typer then
    builds the options of that one command alone: 40 ms less of every command's start-up), every
    one for the overview, completion or an unknown name."""
    import importlib

    modules = [COMMAND_MODULES[name]] if name in COMMAND_MODULES else list(COMMAND_MODULES.values())
    for module in modules:
        importlib.import_module(f"aslam.cli.{module}")


def error_line(message: str) -> None:
    """One line on stderr, the only thing a user sees of an error."""
    try:
        sys.stderr.write(f"aslam: error: {one_line(message)}\n")
        sys.stderr.flush()
    except (OSError, ValueError):  # stderr itself closed: nothing left to tell
        pass


class Interrupted(KeyboardInterrupt):
    """SIGINT, SIGTERM or SIGHUP arrived; unwinds like Ctrl-C so every ``finally`` cleans up."""


class _Signals:
    """SIGINT, SIGTERM and SIGHUP raise :class:`Interrupted` in the main thread and are remembered.

    Remembered because a library may swallow the exception (a bare ``except`` in an import, a
    ``__del__``): the command still ends as interrupted, with its outputs removed. A forked child
    (the estimate's reader) just exits.
    """

    HANDLED = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
    active: _Signals | None = None
    """The command's, while it runs: whether an error was the interrupt's doing."""

    #: Seconds after the first signal during which more signals are the same request: a supervisor
    #: sending INT then TERM, a hang-up then TERM. Raised again, each broke the first one's clean-up
    #: (a traceback, exit 1; a partial file left). Later than this, a signal raises again: a user
    #: insisting on a command whose clean-up hangs.
    REPEAT_WINDOW_S = 5.0

    def __init__(self) -> None:
        self.received: int | None = None
        self._first_at = 0.0
        self._pid = os.getpid()
        self._saved: dict[int, object] = {}

    def _handle(self, signum: int, _frame: object) -> None:
        import time

        if os.getpid() != self._pid:
            os._exit(128 + signum)
        if self.received is None:
            self.received = signum
            self._first_at = time.monotonic()
        elif time.monotonic() - self._first_at < self.REPEAT_WINDOW_S:
            return  # the first one's unwinding is under way: let it finish
        raise Interrupted(signal.Signals(signum).name)

    def __enter__(self) -> _Signals:
        if threading.current_thread() is threading.main_thread():
            for signum in self.HANDLED:
                if signal.getsignal(signum) is signal.SIG_IGN:
                    continue  # ignored by whoever started us (nohup, a shell's background job): keep it so
                self._saved[signum] = signal.signal(signum, self._handle)
        _Signals.active = self
        return self

    def __exit__(self, *_exc: object) -> None:
        _Signals.active = None
        for signum, handler in self._saved.items():
            signal.signal(signum, handler)  # type: ignore[arg-type]

    @property
    def exit_code(self) -> int:
        return {signal.SIGTERM: EXIT_TERMINATED, signal.SIGHUP: EXIT_HUNG_UP}.get(
            self.received,  # type: ignore[call-overload]
            EXIT_INTERRUPTED,
        )


def raise_if_interrupted() -> None:
    """Raise the interrupt a library swallowed, if one did.

    trimesh (pyrender's import) takes its optional dependencies under ``except BaseException``: a
    Ctrl-C then is kept in a placeholder, and the command ran on to its end (a whole render) before
    the remembered signal ended it. Long work calls this between items (the progress callbacks,
    :func:`aslam.cli.output.counted_progress`) to end at the next one.
    """
    signals = _Signals.active
    if signals is not None and signals.received is not None:
        raise Interrupted(signal.Signals(signals.received).name)


def _ended_by(code: int) -> str:
    return {EXIT_TERMINATED: "terminated", EXIT_HUNG_UP: "hung up"}.get(code, "interrupted")


class _QuietNativeStderr:
    """Point file descriptor 2 at /dev/null for the command while ``sys.stderr`` keeps the terminal.

    C libraries (libpng, libjpeg, OpenCV, Mesa) print their own warnings straight to descriptor 2;
    this way they never reach the terminal as extra lines, and Python's own writes (our one error
    line, warnings, progress) still do. Only when ``sys.stderr`` is the process's real stderr (not
    under a test's capture).
    """

    def __init__(self) -> None:
        self._saved_fd: int | None = None
        self._saved_stderr: TextIO | None = None

    def __enter__(self) -> _QuietNativeStderr:
        stderr = sys.stderr
        if stderr is not sys.__stderr__ or stderr is None or os.environ.get("ASLAM_DEBUG"):
            return self
        try:
            fd = stderr.fileno()
            saved = os.dup(fd)
            devnull = os.open(os.devnull, os.O_WRONLY)
        except (OSError, ValueError, AttributeError):
            return self
        stderr.flush()
        os.dup2(devnull, fd)
        os.close(devnull)
        self._saved_fd, self._saved_stderr = saved, stderr
        sys.stderr = io.TextIOWrapper(
            os.fdopen(saved, "wb", buffering=0, closefd=False),
            encoding=stderr.encoding,
            errors="backslashreplace",
            line_buffering=True,
        )
        return self

    def __exit__(self, *_exc: object) -> None:
        if self._saved_fd is None or self._saved_stderr is None:
            return
        with contextlib.suppress(OSError, ValueError):
            sys.stderr.flush()
        sys.stderr = self._saved_stderr
        os.dup2(self._saved_fd, sys.stderr.fileno())
        os.close(self._saved_fd)
        self._saved_fd = None


class _LibraryLogsDropped:
    """A library's log record, where no handler of its own takes it, is dropped while the command
    runs, as its ``warnings`` are: Python's last-resort handler printed it on stderr, even with
    --quiet. Under a read-only HOME (a CI container) matplotlib logged two lines on
    every `report --plots` ("mkdir -p failed", "created a temporary cache directory")."""

    def __enter__(self) -> _LibraryLogsDropped:
        import logging

        self._handler = logging.NullHandler()
        logging.root.addHandler(self._handler)
        return self

    def __exit__(self, *_exc: object) -> None:
        import logging

        logging.root.removeHandler(self._handler)


def _quiet_closed_stdout() -> None:
    """After a closed pipe: send the rest of stdout to /dev/null so the exit flush cannot fail."""
    stdout = sys.stdout
    if stdout is not sys.__stdout__ or stdout is None:
        return
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError):
        pass


def _is_closed_pipe(err: BaseException | None) -> bool:
    while err is not None:
        if isinstance(err, BrokenPipeError) or (isinstance(err, OSError) and err.errno == errno.EPIPE):
            return True
        err = err.__cause__ or err.__context__
    return False


def main(argv: list[str] | None = None, *, startup_signals: list[int] | None = None) -> int:
    """Console entry point: run the app and map every outcome to a documented exit code.

    The console script (``aslam.cli.entry``) passes the return value to ``sys.exit`` with the
    signals that arrived while it imported this module; tests call it directly. The outputs of
    the commands in :data:`ALL_OR_NOTHING_COMMANDS` are renamed into place only when the command
    succeeds (or only a gate failed); every other ending removes them
    (``aslam.data_formats.files.command_files``).
    """
    from aslam.cli.output import QUIET
    from aslam.data_formats.files import command_files

    QUIET[0] = False  # until this command's --quiet is parsed
    with _Signals() as signals, _QuietNativeStderr(), _LibraryLogsDropped(), warnings.catch_warnings():
        if startup_signals:  # arrived while the console script was importing us
            signals.received = startup_signals[0]
            error_line(_ended_by(signals.exit_code))
            return signals.exit_code
        warnings.simplefilter("ignore")  # numpy, matplotlib, mcap: never extra lines on the terminal
        try:
            staged = _command_name(argv) in ALL_OR_NOTHING_COMMANDS
            with command_files(on_warning=_warning_line) if staged else contextlib.nullcontext() as files:
                code = _dispatch(argv, files)
                raise_if_interrupted()  # one that something swallowed and no checkpoint met
        except _Failed as failed:
            code = failed.code
        except KeyboardInterrupt:
            code = signals.exit_code
            error_line(_ended_by(code))
        except AslamError as err:  # raised while renaming the outputs into place
            error_line(str(err))
            code = err.exit_code
        except BaseException as err:
            if not _is_closed_pipe(err):
                raise
            code = EXIT_CLOSED_PIPE
        if code == EXIT_CLOSED_PIPE:
            _quiet_closed_stdout()
        return code


def _warning_line(message: str) -> None:
    from aslam.cli.output import QUIET

    if QUIET[0]:
        return
    try:
        sys.stderr.write(f"aslam: warning: {one_line(message)}\n")
        sys.stderr.flush()
    except (OSError, ValueError):
        pass


class _Failed(Exception):
    """A command's failure, carrying its exit code out of ``command_files`` so the outputs go."""

    def __init__(self, code: int) -> None:
        super().__init__(code)
        self.code = code


#: Commands whose outputs are staged and renamed together at the end (docs/usage.md, "Inputs and
#: outputs"). A command that writes files it reads back or keeps while it runs (``sweep``'s saved
#: task results, ``import``) is not listed: its writes land at once, each still atomic.
ALL_OR_NOTHING_COMMANDS = frozenset({"record", "estimate", "report", "info"})


def _command_name(argv: list[str] | None) -> str | None:
    args = sys.argv[1:] if argv is None else argv
    return next((arg for arg in args if not arg.startswith("-")), None)


def _dispatch(argv: list[str] | None, files: CommandFiles | None) -> int:
    """Run the typer app; the exit code of a success or a failed gate, else raise ``_Failed``."""
    try:
        _register_commands(_command_name(argv))
        code = app(args=argv, standalone_mode=False, prog_name="aslam")
    except QualityGateFailed as err:  # the report is valid: its outputs stay
        if files is not None:
            files.commit()
        error_line(str(err))
        return err.exit_code
    except AslamError as err:
        interrupt = _interrupt_behind(err)  # a library swallowed the signal, then failed for it
        if interrupt is not None:
            raise interrupt from err
        if _is_closed_pipe(err):  # an output written to a pipe whose reader left (`-o /dev/stdout | head`)
            raise _Failed(EXIT_CLOSED_PIPE) from err
        error_line(str(err))
        raise _Failed(err.exit_code) from err
    except typer.Abort as err:
        raise Interrupted("SIGINT") from err
    except typer.Exit as done:
        if done.exit_code == EXIT_INTERRUPTED:  # typer's own translation of Ctrl-C
            raise Interrupted("SIGINT") from done
        if done.exit_code != EXIT_OK:
            raise _Failed(done.exit_code) from done
        return EXIT_OK
    except SystemExit as done:  # typer exits 1 itself on a closed stdout
        if _is_closed_pipe(done.__context__):
            raise _Failed(EXIT_CLOSED_PIPE) from done
        raise
    except KeyboardInterrupt:
        raise
    except Exception as err:
        interrupt = _interrupt_behind(err)
        if interrupt is not None:
            raise interrupt from err
        _failure(err, _command_name(argv))
    if code == EXIT_INTERRUPTED:
        raise Interrupted("SIGINT")
    return code if isinstance(code, int) else EXIT_OK


def _interrupt_behind(err: Exception) -> Interrupted | None:
    """The interrupt an error stands for, if a signal arrived: raised inside a native module's
    initialisation (GTSAM's pybind11, protobuf), Ctrl-C comes out as ``ImportError:
    initialization failed``, which is no internal error; swallowed by a library's own ``except
    BaseException`` (trimesh's import of networkx), it comes out as the error of what then failed
    (pyrender not loading)."""
    signals = _Signals.active
    if signals is None or signals.received is None:
        return None
    return Interrupted(signal.Signals(signals.received).name)


def _failure(err: Exception, command_name: str | None = None) -> NoReturn:
    """Raise ``_Failed`` with the exit code an error that escaped a command stands for
    (``command_name``: the command the line named)."""
    if isinstance(err, OSError):
        if _is_closed_pipe(err):
            raise _Failed(EXIT_CLOSED_PIPE) from err
        if err.errno in _ENVIRONMENT_ERRNOS:  # a full disk, a read-only folder: not a bug
            where = f"{err.filename}: " if err.filename else ""
            error_line(f"{where}{err.strerror or err}")
            raise _Failed(EXIT_BAD_INPUT) from err
        _internal_error(err)
    usage = _usage_error_line(err, command_name)
    if usage is not None:  # click's usage and parameter errors, made one line
        if usage:  # empty when the help was shown instead (no arguments)
            error_line(usage)
        raise _Failed(EXIT_BAD_INPUT) from err
    _internal_error(err)


#: File-system refusals that reach the edge unwrapped (e.g. creating a --plots folder): exit 2, not 70.
_ENVIRONMENT_ERRNOS = {
    errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM, errno.EFBIG, errno.ENOTDIR,
    errno.EISDIR, errno.ENAMETOOLONG, errno.ELOOP, errno.EEXIST, errno.ENOENT,
}  # fmt: skip


def _internal_error(err: Exception) -> NoReturn:
    if os.environ.get("ASLAM_DEBUG"):
        raise err
    error_line(f"internal error: {type(err).__name__}: {err} (set ASLAM_DEBUG=1 for a traceback)")
    raise _Failed(EXIT_INTERNAL) from err


def _usage_error_line(err: Exception, command_name: str | None = None) -> str | None:
    """The one-line text of a command-line usage error, or None if ``err`` is not one.
    ``command_name``: the command the line named, whose help the text points to where click's
    error carries the top level's context (an option given no value: ``aslam record --route``)."""
    format_message = getattr(err, "format_message", None)
    if format_message is None or not hasattr(err, "exit_code"):
        return None
    ctx = getattr(err, "ctx", None)
    command = ctx.command_path if ctx is not None else "aslam"
    if (ctx is None or ctx.parent is None) and command_name in COMMAND_MODULES:
        command = f"aslam {command_name}"
    message = format_message()
    return f"{message} (see '{command} --help')" if message else ""
