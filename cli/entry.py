"""The `aslam` console script: Ctrl-C and SIGTERM are honoured from the first line of our code.

Importing the command line (typer, rich) takes a moment; a signal arriving then is remembered
here and :func:`aslam.cli.app.main` ends at once with the interrupted exit code, instead of a
traceback out of some import or a signal lost in a library.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys

# aslam parallelises by processes (the estimate's reader, a sweep's workers) and its matrices are
# 3 × 3: OpenBLAS's own threads only spin. Started with numpy, they cost 70 ms of every command's
# start-up (measured: `aslam estimate` of one image, 551 → 482 ms). A user's own setting wins.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

_received: list[int] = []


def _remember(signum: int, _frame: object) -> None:
    _received.append(signum)


for _signum in (signal.SIGINT, signal.SIGTERM):
    if signal.getsignal(_signum) is not signal.SIG_IGN:  # nohup, a background job: stay ignored
        signal.signal(_signum, _remember)


def run() -> None:
    """Run the command, then exit without the interpreter's teardown.

    By then every output is renamed into place and every child process joined; what teardown
    would add is unloading modules, whose native destructors (GTSAM's, OpenCV's) take 0.1 s, a
    tenth of an estimate's run.
    """
    from aslam.cli.app import EXIT_CLOSED_PIPE, main

    code = main(startup_signals=_received)
    try:
        sys.stdout.flush()
    except (OSError, ValueError):  # stdout closed at the very end (``| head``)
        code = code or EXIT_CLOSED_PIPE
    with contextlib.suppress(OSError, ValueError):
        sys.stderr.flush()
    os._exit(code)
