"""The motion model: how uncertain an odometry action is, and how that uncertainty travels.

A relative pose with its covariance is a flat tuple ``(x, y, yaw, cxx, cxy, cxt, cyy, cyt, ctt)``
("rel"): the graph search composes thousands of them per keyframe and plain floats are several
times faster than tiny numpy arrays there. Covariances compose with the SE(2) Jacobians:
``Σ_ac = J₁ Σ_ab J₁ᵀ + J₂ Σ_bc J₂ᵀ``.

No BLAS or LAPACK here: their kernels are chosen for the CPU when they load, and a 3×3 product or
inverse came out a last bit apart on AVX2 and AVX-512 machines (a hypothesis' belief with it).
Products are written out and stacks contracted with ``einsum``, which sums in a fixed order on
every CPU (docs/usage.md, "Same inputs, same bytes").
"""

from __future__ import annotations

import math
from typing import TypeVar

import numpy as np

from aslam.core import portable_math, se2
from aslam.core.config import MotionNoise

Rel = tuple[float, float, float, float, float, float, float, float, float]
_F = TypeVar("_F", float, np.ndarray)
IDENTITY_REL: Rel = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


def action_covariance(action: np.ndarray, noise: MotionNoise) -> np.ndarray:
    """3×3 covariance of an odometry action ``(dx, dy, dyaw)`` in its start frame."""
    dx, dy, dyaw = (float(v) for v in action)
    distance = math.hypot(dx, dy)
    along = noise.fraction * distance + noise.floor_m
    lateral = 0.5 * noise.drift_rad_per_m * distance * distance + noise.floor_m
    heading = noise.fraction * abs(dyaw) + noise.drift_rad_per_m * distance + noise.floor_rad
    direction = math.atan2(dy, dx) if distance > 0.0 else 0.0
    c, s = math.cos(direction), math.sin(direction)
    along2, lateral2 = along**2, lateral**2
    cross = c * s * (along2 - lateral2)
    return np.array(
        [
            [c * c * along2 + s * s * lateral2, cross, 0.0],
            [cross, s * s * along2 + c * c * lateral2, 0.0],
            [0.0, 0.0, heading**2],
        ]
    )


def to_rel(pose: np.ndarray, covariance: np.ndarray) -> Rel:
    """Pack a pose and its covariance into a rel tuple."""
    x, y, yaw = (float(v) for v in pose)
    c = covariance
    return (x, y, yaw, c[0, 0], c[0, 1], c[0, 2], c[1, 1], c[1, 2], c[2, 2])


def rel_covariance(rel: Rel) -> np.ndarray:
    _, _, _, cxx, cxy, cxt, cyy, cyt, ctt = rel
    return np.array([[cxx, cxy, cxt], [cxy, cyy, cyt], [cxt, cyt, ctt]])


def compose_rel(a: Rel, b: Rel) -> Rel:
    """``a ⊕ b`` with first-order covariance propagation (a and b independent)."""
    ax, ay, at, a11, a12, a13, a22, a23, a33 = a
    bx, by, bt, b11, b12, b13, b22, b23, b33 = b
    c, s = math.cos(at), math.sin(at)
    rx = c * bx - s * by
    ry = s * bx + c * by
    yaw = at + bt
    if yaw >= math.pi:
        yaw -= 2.0 * math.pi
    elif yaw < -math.pi:
        yaw += 2.0 * math.pi
    j13, j23 = -ry, rx  # ∂(position)/∂(a's heading)
    cc, ss, cs = c * c, s * s, c * s
    return (
        ax + rx,
        ay + ry,
        yaw,
        a11 + 2.0 * j13 * a13 + j13 * j13 * a33 + cc * b11 - 2.0 * cs * b12 + ss * b22,
        a12 + j13 * a23 + j23 * (a13 + j13 * a33) + cs * (b11 - b22) + (cc - ss) * b12,
        a13 + j13 * a33 + c * b13 - s * b23,
        a22 + 2.0 * j23 * a23 + j23 * j23 * a33 + ss * b11 + 2.0 * cs * b12 + cc * b22,
        a23 + j23 * a33 + s * b13 + c * b23,
        a33 + b33,
    )


def inverse_rel(a: Rel) -> Rel:
    """``⊖a`` with its covariance ``J Σ Jᵀ``: what a link looks like when walked backwards."""
    x, y, yaw, a11, a12, a13, a22, a23, a33 = a
    c, s = math.cos(yaw), math.sin(yaw)
    # J = [[-c, -s, j13], [s, -c, j23], [0, 0, -1]]
    j13 = s * x - c * y
    j23 = c * x + s * y
    # rows of J Σ
    r11, r12, r13 = (
        -c * a11 - s * a12 + j13 * a13,
        -c * a12 - s * a22 + j13 * a23,
        -c * a13 - s * a23 + j13 * a33,
    )
    r21, r22, r23 = (
        s * a11 - c * a12 + j23 * a13,
        s * a12 - c * a22 + j23 * a23,
        s * a13 - c * a23 + j23 * a33,
    )
    return (
        -c * x - s * y,
        s * x - c * y,
        -yaw if yaw != -math.pi else yaw,
        -c * r11 - s * r12 + j13 * r13,
        s * r11 - c * r12 + j23 * r13,
        -r13,
        s * r21 - c * r22 + j23 * r23,
        -r23,
        a33,
    )


def fuse_rel(a: Rel, b: Rel) -> Rel:
    """Information-weighted fusion of two measurements of the same link (traversed again)."""
    ax, ay, at = a[:3]
    bx, by, bt = b[:3]
    bt = at + float(se2.wrap_angle(bt - at))  # average headings on the short arc
    info_a, info_b = _inverse(a[3:]), _inverse(b[3:])
    c11, c12, c13, c22, c23, c33 = covariance = _inverse(
        tuple(p + q for p, q in zip(info_a, info_b, strict=True))
    )
    ia11, ia12, ia13, ia22, ia23, ia33 = info_a
    ib11, ib12, ib13, ib22, ib23, ib33 = info_b
    vx = ia11 * ax + ia12 * ay + ia13 * at + ib11 * bx + ib12 * by + ib13 * bt
    vy = ia12 * ax + ia22 * ay + ia23 * at + ib12 * bx + ib22 * by + ib23 * bt
    vt = ia13 * ax + ia23 * ay + ia33 * at + ib13 * bx + ib23 * by + ib33 * bt
    x = c11 * vx + c12 * vy + c13 * vt
    y = c12 * vx + c22 * vy + c23 * vt
    yaw = float(se2.wrap_angle(c13 * vx + c23 * vy + c33 * vt))
    return (x, y, yaw, *covariance)


def _inverse(covariance: tuple[float, ...]) -> tuple[float, float, float, float, float, float]:
    """The inverse of a symmetric 3×3 matrix given as ``(c11, c12, c13, c22, c23, c33)``, in the
    same order."""
    c11, c12, c13, c22, c23, c33 = covariance
    m11, m12, m13, m22, m23, m33, determinant = _cofactors(c11, c12, c13, c22, c23, c33)
    return (
        m11 / determinant,
        m12 / determinant,
        m13 / determinant,
        m22 / determinant,
        m23 / determinant,
        m33 / determinant,
    )


def _cofactors(c11: _F, c12: _F, c13: _F, c22: _F, c23: _F, c33: _F) -> tuple[_F, _F, _F, _F, _F, _F, _F]:
    """The cofactors ``(m11, m12, m13, m22, m23, m33)`` of a symmetric 3×3 matrix given by its upper
    triangle, and its determinant: of floats, or elementwise of arrays (a stack), in one order of
    operations for both, so a link's fusion and a revisit's likelihood invert alike."""
    m11 = c22 * c33 - c23 * c23
    m12 = c13 * c23 - c12 * c33
    m13 = c12 * c23 - c13 * c22
    m22 = c11 * c33 - c13 * c13
    m23 = c12 * c13 - c11 * c23
    m33 = c11 * c22 - c12 * c12
    return m11, m12, m13, m22, m23, m33, c11 * m11 + c12 * m12 + c13 * m13


LEVER_ARM_M = 5.0
"""Distance over which a link's heading error is assumed to act on position, for :func:`link_weight`."""


def link_weight(rel: Rel) -> float:
    """A link's uncertainty as one number (m²): position variance plus heading variance × lever².

    The graph search orders and bounds itself by the sum of these along a path, which costs one
    addition per edge; full covariances are then composed only along the chosen paths.
    """
    return rel[3] + rel[6] + LEVER_ARM_M * LEVER_ARM_M * rel[8]


def revisit_residuals(
    state_poses: np.ndarray,
    state_covariances: np.ndarray,
    action: np.ndarray,
    action_cov: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Where the robot would stand in each candidate state's frame, and how uncertain that is.

    ``state_poses`` (n, 3) and ``state_covariances`` (n, 3, 3) are the candidates seen from the
    robot's previous state; ``action`` is the odometry since then. For a true revisit of state k
    the residual ``⊖T_k ⊕ u`` is near zero. Returns residuals (n, 3) and covariances (n, 3, 3).
    """
    inv = se2.inverse(state_poses)
    residual = se2.compose(inv, action)
    x, y, yaw = state_poses[:, 0], state_poses[:, 1], state_poses[:, 2]
    c, s = np.cos(yaw), np.sin(yaw)
    n = len(state_poses)
    j_inv = np.zeros((n, 3, 3))
    j_inv[:, 0, 0], j_inv[:, 0, 1], j_inv[:, 0, 2] = -c, -s, s * x - c * y
    j_inv[:, 1, 0], j_inv[:, 1, 1], j_inv[:, 1, 2] = s, -c, c * x + s * y
    j_inv[:, 2, 2] = -1.0
    # d = inv(T) ⊕ u: ∂d/∂inv(T) = J₁, ∂d/∂u = R(heading of inv(T)).
    ci, si = np.cos(inv[:, 2]), np.sin(inv[:, 2])
    ux, uy = float(action[0]), float(action[1])
    j1 = np.zeros((n, 3, 3))
    j1[:, 0, 0] = j1[:, 1, 1] = j1[:, 2, 2] = 1.0
    j1[:, 0, 2] = -si * ux - ci * uy
    j1[:, 1, 2] = ci * ux - si * uy
    j2 = np.zeros((n, 3, 3))
    j2[:, 0, 0], j2[:, 0, 1] = ci, -si
    j2[:, 1, 0], j2[:, 1, 1] = si, ci
    j2[:, 2, 2] = 1.0
    a = np.einsum("nij,njk->nik", j1, j_inv)
    covariance = np.einsum("nij,njk,nlk->nil", a, state_covariances, a) + np.einsum(
        "nij,jk,nlk->nil", j2, action_cov, j2
    )
    return residual, covariance


def mahalanobis2_and_logdet(residuals: np.ndarray, covariances: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``rᵀ Σ⁻¹ r`` and ``log |Σ|`` of each residual (n, 3) under its covariance (n, 3, 3), by the
    cofactors of Σ (symmetric: its upper triangle is read)."""
    m11, m12, m13, m22, m23, m33, determinant = _cofactors(
        covariances[:, 0, 0],
        covariances[:, 0, 1],
        covariances[:, 0, 2],
        covariances[:, 1, 1],
        covariances[:, 1, 2],
        covariances[:, 2, 2],
    )
    x, y, t = residuals[:, 0], residuals[:, 1], residuals[:, 2]
    quadratic = m11 * x * x + m22 * y * y + m33 * t * t + 2.0 * (m12 * x * y + m13 * x * t + m23 * y * t)
    return quadratic / determinant, portable_math.log(np.abs(determinant))
