"""``exp`` and ``log`` of float64 arrays with the same bits on every x86-64 CPU.

numpy computes them with its own AVX-512 code on CPUs that have it and with the C library's on
the others (AVX2 and older), and the two differ in last bits: a hypothesis' belief came out
0.005244013027777437 on one machine and …446 on the other (docs/usage.md, "Same inputs, same
bytes"). Python's ``math`` always calls the C library, so these give what numpy gives without
AVX-512, on any CPU. They cost a Python call per value: for the estimator's short arrays (a step's
candidates, its hypotheses), not for images.
"""

from __future__ import annotations

import math

import numpy as np


def log(values: np.ndarray | float) -> np.ndarray:
    """``np.log`` of positive values (0 gives -inf, as numpy's)."""
    array = np.asarray(values, dtype=np.float64)
    logs = [math.log(v) if v != 0.0 else -math.inf for v in array.ravel().tolist()]
    return np.array(logs, dtype=np.float64).reshape(array.shape)


def exp(values: np.ndarray | float) -> np.ndarray:
    """``np.exp`` of values up to 709 (above, the C library's ``exp`` overflows and ``math`` raises)."""
    array = np.asarray(values, dtype=np.float64)
    return np.array([math.exp(v) for v in array.ravel().tolist()], dtype=np.float64).reshape(array.shape)
