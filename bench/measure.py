"""What every bench script shares: progress lines on stderr (stdout carries the results) and the
spread of repeated timings (the machine is shared: one timing alone says little)."""

from __future__ import annotations

import statistics
import sys


def log(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def spread(values: list[float]) -> dict[str, float]:
    return {"median": statistics.median(values), "min": min(values), "max": max(values)}
