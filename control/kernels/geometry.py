"""Small geometry on the TCP: the SO(3) log of the orientation error [T11], a wrench moved between
points (the F/T reading moved to the TCP) and the elbow swivel of the joint anchors.
"""

from __future__ import annotations

import numpy as np
from numba import njit


def log3_reference(R: np.ndarray) -> np.ndarray:
    """log(R) as a rotation vector θ·axis [T11]: θ = atan2(‖v‖, (tr R − 1)/2) with v = (R − Rᵀ)∨/2
    (= sin θ · axis); the axis from v away from π, from the symmetric part (R + Rᵀ)/2 − cos θ I =
    (1 − cos θ) axis axisᵀ past π/2 (its sign from v)."""
    v = 0.5 * np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    s, c = float(np.linalg.norm(v)), float(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))
    theta = float(np.arctan2(s, c))
    if c >= 0.0:
        return v * (theta / s) if s > 0.0 else v
    B = (0.5 * (R + R.T) - c * np.eye(3)) / (1.0 - c)
    i = int(np.argmax(np.diag(B)))
    axis = B[:, i] / np.sqrt(B[i, i])
    return theta * (axis if axis @ v >= 0.0 else -axis)


@njit(cache=True)
def log3_fused(R):
    """log(R) ∈ so(3) as a rotation vector θ·axis, θ ∈ [0, π], from the unit quaternion of R
    (Shepperd's method: accurate at small angles and near π); `pinocchio.log3`'s result, to
    rounding away from θ = π (where the axis' sign is a choice). Tested against it."""
    t = R[0, 0] + R[1, 1] + R[2, 2]
    if t > 0.0:
        S = 2.0 * np.sqrt(t + 1.0)
        w, x, y, z = 0.25 * S, (R[2, 1] - R[1, 2]) / S, (R[0, 2] - R[2, 0]) / S, (R[1, 0] - R[0, 1]) / S
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        S = 2.0 * np.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2])
        w, x, y, z = (R[2, 1] - R[1, 2]) / S, 0.25 * S, (R[0, 1] + R[1, 0]) / S, (R[0, 2] + R[2, 0]) / S
    elif R[1, 1] > R[2, 2]:
        S = 2.0 * np.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2])
        w, x, y, z = (R[0, 2] - R[2, 0]) / S, (R[0, 1] + R[1, 0]) / S, 0.25 * S, (R[1, 2] + R[2, 1]) / S
    else:
        S = 2.0 * np.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1])
        w, x, y, z = (R[1, 0] - R[0, 1]) / S, (R[0, 2] + R[2, 0]) / S, (R[1, 2] + R[2, 1]) / S, 0.25 * S
    if w < 0.0:
        w, x, y, z = -w, -x, -y, -z
    s = np.sqrt(x * x + y * y + z * z)
    k = 2.0 * np.arctan2(s, w) / s if s > 0.0 else 2.0 / w  # θ / sin(θ/2)
    out = np.empty(3)
    out[0], out[1], out[2] = k * x, k * y, k * z
    return out


def move_wrench_reference(wrench: np.ndarray, p_from: np.ndarray, p_to: np.ndarray) -> np.ndarray:
    """A wrench [f; m] (world axes) about `p_from` as the same wrench about `p_to`: f is unchanged,
    m_to = m_from + (p_from − p_to) × f."""
    f, m = wrench[:3], wrench[3:]
    return np.concatenate([f, m + np.cross(p_from - p_to, f)])


@njit(cache=True)
def move_wrench_fused(wrench, p_from, p_to):
    """Compiled `move_wrench_reference` (a new array)."""
    r0, r1, r2 = p_from[0] - p_to[0], p_from[1] - p_to[1], p_from[2] - p_to[2]
    f0, f1, f2 = wrench[0], wrench[1], wrench[2]
    out = np.empty(6)
    out[0], out[1], out[2] = f0, f1, f2
    out[3] = wrench[3] + (r1 * f2 - r2 * f1)
    out[4] = wrench[4] + (r2 * f0 - r0 * f2)
    out[5] = wrench[5] + (r0 * f1 - r1 * f0)
    return out


def swivel_of_anchors_reference(anchors: np.ndarray, shoulder: int, elbow: int, wrist: int) -> float:
    """Elbow swivel (rad) of rows `shoulder`, `elbow`, `wrist` of (m, 3) points: the angle about
    u = shoulder→wrist from r (world +z, or +x when u is vertical, made normal to u) to the elbow's
    offset d normal to u, right-handed (`control.coupling.swivel_angle`'s formula)."""
    s, e, w = anchors[shoulder], anchors[elbow], anchors[wrist]
    u = (w - s) / np.linalg.norm(w - s)
    r = np.array([0.0, 0.0, 1.0]) - u[2] * u
    if np.linalg.norm(r) < 1e-9:
        r = np.array([1.0, 0.0, 0.0]) - u[0] * u
    r = r / np.linalg.norm(r)
    d = (e - s) - ((e - s) @ u) * u
    return float(np.arctan2(u @ np.cross(r, d), r @ d))


@njit(cache=True)
def swivel_of_anchors_fused(anchors, shoulder, elbow, wrist):
    """`control.planner.swivel_of_points` (rad) of rows `shoulder`, `elbow`, `wrist` of an (m, 3)
    array of points (MuJoCo's joint anchors), the same arithmetic in one compiled call."""
    s0, s1, s2 = anchors[shoulder, 0], anchors[shoulder, 1], anchors[shoulder, 2]
    u0, u1, u2 = anchors[wrist, 0] - s0, anchors[wrist, 1] - s1, anchors[wrist, 2] - s2
    norm = np.sqrt(u0 * u0 + u1 * u1 + u2 * u2)
    u0, u1, u2 = u0 / norm, u1 / norm, u2 / norm
    r0, r1, r2 = -u2 * u0, -u2 * u1, 1.0 - u2 * u2
    if np.sqrt(r0 * r0 + r1 * r1 + r2 * r2) < 1e-9:
        r0, r1, r2 = 1.0 - u0 * u0, -u0 * u1, -u0 * u2
    norm = np.sqrt(r0 * r0 + r1 * r1 + r2 * r2)
    r0, r1, r2 = r0 / norm, r1 / norm, r2 / norm
    e0, e1, e2 = anchors[elbow, 0] - s0, anchors[elbow, 1] - s1, anchors[elbow, 2] - s2
    along = e0 * u0 + e1 * u1 + e2 * u2
    d0, d1, d2 = e0 - along * u0, e1 - along * u1, e2 - along * u2
    c0, c1, c2 = r1 * d2 - r2 * d1, r2 * d0 - r0 * d2, r0 * d1 - r1 * d0
    return np.arctan2(u0 * c0 + u1 * c1 + u2 * c2, r0 * d0 + r1 * d1 + r2 * d2)
