"""Physical plausibility of the poses a recording claims (docs/formats.md, "Poses").

A finite pose can still be absurd: odometry at 1e100 m or a jump of 1e20 m between two messages
overflows the pose arithmetic downstream (covariances, the χ² gate, the JSON writer). No ground
robot this tool serves leaves a 10,000 km square or moves 10 km between two odometry messages,
so such a pose is refused as bad data, naming the message's stamp.
"""

from __future__ import annotations

import math

import numpy as np

MAX_POSITION_M = 1e7
"""|x| and |y| of any pose (10,000 km)."""
MAX_STEP_M = 1e4
"""Distance between two consecutive poses of one topic (10 km)."""
MAX_YAW_RAD = 1e9
"""|yaw| of a heading written as an angle (a CSV pose file's yaw, perhaps unwrapped): float64 still
resolves it to 1e-6 rad; a yaw of 1e308 rad names no heading at all (its wrap is rounding noise)."""


def implausible(pose: np.ndarray, previous: np.ndarray | None) -> str | None:
    """Why ``(x_m, y_m, yaw_rad)`` is not a plausible pose after ``previous`` (None: it is)."""
    x_m, y_m = float(pose[0]), float(pose[1])
    if not (abs(x_m) <= MAX_POSITION_M and abs(y_m) <= MAX_POSITION_M):
        return f"is at x={x_m:g} m, y={y_m:g} m, beyond the plausible ±{MAX_POSITION_M:g} m"
    if previous is not None:
        step_m = math.hypot(x_m - float(previous[0]), y_m - float(previous[1]))
        if not step_m <= MAX_STEP_M:
            return f"jumps {step_m:g} m from the previous pose (more than {MAX_STEP_M:g} m)"
    return None
