"""SE(2) poses as ``(x_m, y_m, yaw_rad)`` arrays, composed without any global frame.

Every function accepts a single pose of shape ``(3,)`` or a stack of shape ``(n, 3)`` and
broadcasts, so the map code can move whole neighbourhoods at once.
"""

from __future__ import annotations

import math

import numpy as np

Pose2 = np.ndarray  # shape (3,) or (n, 3): x_m, y_m, yaw_rad


def wrap_angle(angle_rad: np.ndarray | float) -> np.ndarray | float:
    """The same direction in [-π, π): π and -π both give -π. One float gives +π, the one just
    below -π, whose remainder rounds up to a whole turn: the same direction, left as it is since
    any other arithmetic here would change estimates (``test_wrap_angle_keeps_the_direction…``)."""
    return (np.asarray(angle_rad) + np.pi) % (2.0 * np.pi) - np.pi


def compose(a: Pose2, b: Pose2) -> Pose2:
    """``a ⊕ b``: pose ``b`` (expressed in frame ``a``) expressed in ``a``'s parent frame."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    if a.ndim == 1 and b.ndim == 1:  # one pose: the same float64 arithmetic, without np.stack
        ax, ay, ayaw = a
        bx, by, byaw = b
        c, s = np.cos(ayaw), np.sin(ayaw)
        return np.array([ax + c * bx - s * by, ay + s * bx + c * by, wrap_angle(ayaw + byaw)])
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    return np.stack(
        [
            a[..., 0] + c * b[..., 0] - s * b[..., 1],
            a[..., 1] + s * b[..., 0] + c * b[..., 1],
            wrap_angle(a[..., 2] + b[..., 2]),
        ],
        axis=-1,
    )


def inverse(a: Pose2) -> Pose2:
    """``⊖a``: the parent frame seen from frame ``a``."""
    a = np.asarray(a, dtype=float)
    if a.ndim == 1:  # one pose: the same float64 arithmetic, without np.stack
        x, y, yaw = a
        c, s = np.cos(yaw), np.sin(yaw)
        return np.array([-c * x - s * y, s * x - c * y, wrap_angle(-yaw)])
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    return np.stack(
        [
            -c * a[..., 0] - s * a[..., 1],
            s * a[..., 0] - c * a[..., 1],
            wrap_angle(-a[..., 2]),
        ],
        axis=-1,
    )


def between(a: Pose2, b: Pose2) -> Pose2:
    """``⊖a ⊕ b``: pose ``b`` seen from pose ``a`` (the action that takes ``a`` to ``b``)."""
    return compose(inverse(a), b)


def interpolate(a: Pose2, b: Pose2, fraction: float, turn_rad: float | None = None) -> Pose2:
    """Pose a fraction of the way from ``a`` to ``b`` (straight line, shortest turn).

    The one interpolation of the tool: poses between render frames, odometry and ground truth at
    image stamps, truth at keyframe stamps. Two headings alone cannot say which way a half turn
    or more went; where the motion's own turn is known (a commanded ``turn_rad``), the heading
    turns the way of ``b − a`` nearest it instead, so a 180° or 270° turn is swept as commanded.
    """
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    xy = a[:2] + fraction * (b[:2] - a[:2])
    turn = wrap_angle(b[2] - a[2])
    if turn_rad is not None and (laps := round((turn_rad - float(turn)) / (2.0 * np.pi))):
        turn = turn + 2.0 * np.pi * laps
    yaw = wrap_angle(a[2] + fraction * turn)
    return np.array([xy[0], xy[1], float(yaw)])


def yaw_quaternion(yaw_rad: float) -> tuple[float, float, float, float]:
    """``(w, x, y, z)`` of a rotation by ``yaw_rad`` about +z (REP 103: counter-clockwise seen from
    above): how every file we write (ROS messages, Foxglove scenes, evo trajectories) holds a heading."""
    half = 0.5 * float(yaw_rad)
    return (math.cos(half), 0.0, 0.0, math.sin(half))


def dead_reckoning(actions: np.ndarray, start: np.ndarray | None = None) -> np.ndarray:
    """(n, 3) poses from composing the keyframe actions (the first action is the start's)."""
    poses = np.zeros((len(actions), 3))
    pose = np.zeros(3) if start is None else np.asarray(start, dtype=float)
    for i, action in enumerate(actions):
        pose = pose if i == 0 else compose(pose, action)
        poses[i] = pose
    return poses
