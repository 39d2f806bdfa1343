"""The `aslam` console script: Ctrl-C, SIGTERM and SIGHUP are honoured from the first line of our code.

Importing the command line (typer, rich) takes a moment; a signal arriving then is remembered
here and :func:`aslam.cli.app.main` ends at once with the interrupted exit code, instead of a
traceback out of some import or a signal lost in a library.
"""

from __future__ import annotations

import atexit
import contextlib
import errno
import io
import os
import signal
import sys
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from _typeshed import ReadableBuffer


def _hold_standard_descriptors() -> None:
    """Descriptors 0-2 closed at the start (``>&- 2>&-``) are held, so no file this process opens
    lands on one: with both closed, the descriptor of the file ``import`` was writing became 2, and
    libjpeg's warnings went into the recording (exit 0, a file no command could read); with stdout
    closed, a copy of stderr became 1, and ``-o /dev/stdout`` wrote the MCAP onto the terminal.
    Stdout becomes a pipe no one reads (a result written there is a closed pipe: exit 141, as
    ``| head -0``); stdin and stderr, /dev/null. Python's own ``sys.stdout``/``sys.stderr`` stay
    None for the code below to handle."""
    for descriptor in (0, 1, 2):
        try:
            os.fstat(descriptor)
            continue
        except OSError:
            pass
        if descriptor == 1:
            reader, writer = os.pipe()  # the lowest free descriptors: the reader may be 1
            os.dup2(writer, 1)  # closes the reader if it was 1
            for extra in (reader, writer):
                if extra != 1:
                    with contextlib.suppress(OSError):
                        os.close(extra)
        else:
            held = os.open(os.devnull, os.O_RDONLY if descriptor == 0 else os.O_WRONLY)
            if held != descriptor:
                os.dup2(held, descriptor)
                os.close(held)


_hold_standard_descriptors()

# aslam parallelises by processes (the estimate's reader, a sweep's workers) and its matrices are
# 3 × 3: OpenBLAS's own threads only spin. Started with numpy, they cost 70 ms of every command's
# start-up (measured: `aslam estimate` of one image, 551 → 482 ms). A user's own setting wins.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

_received: list[int] = []

#: A child that multiprocessing's spawn started (a sweep's Dask worker) runs the console script
#: again, as ``__mp_main__``, to find its functions: it imports this module but runs no command.
#: It ignores Ctrl-C, the command's to handle (it closes its workers), and SIGTERM and SIGHUP end it:
#: with our handlers it swallowed them (``kill PID`` of a worker left it computing).
_SPAWNED_CHILD = "__mp_main__" in sys.modules


def _remember(signum: int, _frame: object) -> None:
    _received.append(signum)


if _SPAWNED_CHILD:
    signal.signal(signal.SIGINT, signal.SIG_IGN)
else:
    for _signum in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        if signal.getsignal(_signum) is not signal.SIG_IGN:  # nohup, a background job: stay ignored
            signal.signal(_signum, _remember)


class _ClosedStdout(io.TextIOBase):
    """stdout closed before we started (``>&-``): writing a result to it is writing into a closed
    pipe (exit 141, as with ``| head``); a command with no result on stdout succeeds."""

    def write(self, _text: str) -> int:
        raise BrokenPipeError(errno.EPIPE, "stdout is closed")


class _Stdout(io.FileIO):
    """Descriptor 1, whose write errors name it: ``aslam info R.mcap > /dev/full`` is ``stdout: No
    space left on device``, not a bare ``No space left on device``."""

    def write(self, data: ReadableBuffer) -> int:
        try:
            return super().write(data)
        except OSError as err:
            raise type(err)(err.errno, err.strerror, "stdout") from None


def _results_stdout(stream: io.TextIOWrapper) -> io.TextIOWrapper:
    """``stream`` (stdout) rebuilt over :class:`_Stdout`, always with a buffer.

    ``PYTHONUNBUFFERED=1`` (set in many CI images and Dockerfiles) leaves stdout without one, and
    Python's text layer then drops what a short write did not take: on a nearly full disk
    ``aslam report E.mcap --graph - > F`` kept the first 4 KiB of its JSON and exited 0. A buffer
    writes the rest or raises; unbuffered output is flushed at every line instead, as prompt.
    """
    try:
        raw = _Stdout(stream.fileno(), "wb", closefd=False)
    except (AttributeError, OSError, ValueError):
        return stream
    return io.TextIOWrapper(
        io.BufferedWriter(raw),
        encoding=stream.encoding,
        errors=stream.errors,
        line_buffering=stream.line_buffering or stream.write_through,
    )


if sys.stdout is None:
    sys.stdout = _ClosedStdout()
else:  # still the process's own stdout, as aslam.cli.app tells it by ``sys.__stdout__``
    # The interpreter's stdout is a TextIOWrapper (typeshed: TextIO), and __stdout__ is no Final to us.
    sys.stdout = sys.__stdout__ = _results_stdout(sys.stdout)  # type: ignore[arg-type, misc]
if sys.stderr is None:  # nothing can be told: messages go nowhere, the exit code still says it
    sys.stderr = open(os.devnull, "w")  # noqa: SIM115 (the process's own stderr, kept to the end)
for _stream in (sys.stdout, sys.stderr):
    # A terminal or pipe that is not UTF-8 (PYTHONIOENCODING=ascii, a C locale): "—" and the
    # tables' box characters written as \u escapes, never a UnicodeEncodeError (exit 70).
    with contextlib.suppress(AttributeError, ValueError):
        _stream.reconfigure(errors="backslashreplace")  # type: ignore[union-attr]


def run() -> None:
    """Run the command, then exit without the interpreter's teardown.

    By then every output is renamed into place and every child process joined; what teardown
    would add is unloading modules, whose native destructors (GTSAM's, OpenCV's) take 0.1 s, a
    tenth of an estimate's run. The exit functions libraries registered still run (well under a
    millisecond) where the command ran to its end: matplotlib's removes the cache folder it made in
    TMPDIR when HOME is read-only, which every `report --plots` left behind. atexit runs them in
    public only from the teardown skipped here; ``atexit._run_exitfuncs``, private but in every
    CPython 3, runs the same list. Not after a signal: there Dask's would close a cluster that is
    being torn down, and a sweep's SIGTERM took about a second longer to exit.
    """
    from aslam.cli.app import EXIT_CLOSED_PIPE, EXIT_HUNG_UP, EXIT_INTERRUPTED, EXIT_TERMINATED, main

    code = main(startup_signals=_received)
    try:
        sys.stdout.flush()
    except (OSError, ValueError):  # stdout closed at the very end (``| head``)
        code = code or EXIT_CLOSED_PIPE
    if code not in (EXIT_INTERRUPTED, EXIT_TERMINATED, EXIT_HUNG_UP):
        atexit._run_exitfuncs()
    with contextlib.suppress(OSError, ValueError):
        sys.stderr.flush()
    os._exit(code)
