"""The `aslam` console script: Ctrl-C and SIGTERM are honoured from the first line of our code.

Importing the command line (typer, rich) takes a moment; a signal arriving then is remembered
here and :func:`aslam.cli.app.main` ends at once with the interrupted exit code, instead of a
traceback out of some import or a signal lost in a library.
"""

from __future__ import annotations

import signal
import sys

_received: list[int] = []


def _remember(signum: int, _frame: object) -> None:
    _received.append(signum)


for _signum in (signal.SIGINT, signal.SIGTERM):
    if signal.getsignal(_signum) is not signal.SIG_IGN:  # nohup, a background job: stay ignored
        signal.signal(_signum, _remember)


def run() -> None:
    from aslam.cli.app import main

    sys.exit(main(startup_signals=_received))
