"""Bench work as tasks on the local Dask cluster ``aslam sweep`` starts (``aslam.app.sweep.open_client``).

``make bench`` and the robust-revisit matrix both fan their scenarios out this way, so that they
use every core through the project's one engine for parallel work rather than a pool of their own.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

BENCH = Path(__file__).resolve().parent


def as_tasks(
    function: Callable[..., Any], calls: Sequence[tuple[Any, ...]], workers: int | None = None
) -> Iterator[tuple[int, Any]]:
    """``function(*calls[i])`` for every i as a task, one worker process per core by default;
    ``(i, result)`` as they finish. The workers import ``function``'s module from ``bench/``."""
    from distributed import as_completed

    from aslam.app.sweep import open_client

    os.environ["PYTHONPATH"] = os.pathsep.join(filter(None, [str(BENCH), os.environ.get("PYTHONPATH")]))
    client = open_client(workers=workers, scheduler=None)
    try:
        futures = {client.submit(function, *args, pure=False): i for i, args in enumerate(calls)}
        for future in as_completed(futures):
            yield futures[future], future.result()
    finally:
        cluster = client.cluster
        client.close()
        cluster.close()
