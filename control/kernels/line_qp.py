"""The nullspace QP [T15-17] of a 7-joint arm: a one-dimensional kernel, solved in closed form."""

from __future__ import annotations

import numpy as np
from numba import njit

LINE_QP_TINY = 1e-12  # |z_i| below this: joint i cannot move along the kernel (its box must hold 0)


LINE_QP_RANK = 1e-10  # min |R_kk| / max |R_kk| of the QR of Jᵀ below this: J is rank deficient


def nullspace_line_qp_reference(
    J: np.ndarray, g: np.ndarray, lower: np.ndarray, upper: np.ndarray
) -> tuple[np.ndarray, int] | None:
    """min ½‖x‖² + gᵀx s.t. J x = 0, l ≤ x ≤ u [T15-17] for a (6, 7) J of full rank.

    The kernel of J is the line x = t z (z the unit right-singular vector of the zero singular
    value), so the optimum is t* = −gᵀz clipped to the interval of t the box allows [T17].
    Returns (x, number of active bounds: 0 or 1), or None when the closed form does not apply
    (J rank deficient, no t meets the box, non-finite input): the general solver decides then.
    """
    if J.shape != (6, 7) or not (np.all(np.isfinite(J)) and np.all(np.isfinite(g))):
        return None
    if np.any(np.isnan(lower)) or np.any(np.isnan(upper)):
        return None
    s = np.linalg.svd(J, compute_uv=False)
    if s[-1] <= LINE_QP_RANK * s[0]:
        return None
    z = np.linalg.svd(J)[2][-1]
    small = np.abs(z) < LINE_QP_TINY
    if np.any(small & ((lower > 0) | (upper < 0))):
        return None
    with np.errstate(divide="ignore", invalid="ignore"):
        a, b = lower / z, upper / z
    lo = float(np.max(np.where(small, -np.inf, np.where(z > 0, a, b))))
    hi = float(np.min(np.where(small, np.inf, np.where(z > 0, b, a))))
    if lo > hi:
        return None
    t_free = -float(g @ z)
    t = min(max(t_free, lo), hi)
    return t * z, int(t != t_free)


def nullspace_line_qp_into_reference(
    J: np.ndarray, g: np.ndarray, lower: np.ndarray, upper: np.ndarray, x: np.ndarray
) -> int:
    """`nullspace_line_qp_reference` as the compiled kernel reports it: x written, the number of
    active bounds returned, or −1 (x untouched) where the closed form does not apply."""
    out = nullspace_line_qp_reference(J, g, lower, upper)
    if out is None:
        return -1
    x[:] = out[0]
    return out[1]


@njit(cache=True)
def nullspace_line_qp_fused(J, g, lower, upper, x):
    """Compiled `nullspace_line_qp_reference`, z from a Householder QR of Jᵀ (z = H_1…H_6 e_7,
    the unit normal of the range of Jᵀ, the same line as the SVD's up to sign). Writes x and
    returns the number of active bounds (0 or 1), or −1 where the reference returns None."""
    n = J.shape[1]
    if J.shape[0] != 6 or n != 7:
        return -1
    total = 0.0
    for i in range(n):
        total += g[i] * g[i]
        if lower[i] != lower[i] or upper[i] != upper[i]:
            return -1
        for a in range(6):
            total += J[a, i] * J[a, i]
    if not np.isfinite(total):
        return -1
    A = np.empty((n, 6))  # Jᵀ, reduced in place to R
    for i in range(n):
        for a in range(6):
            A[i, a] = J[a, i]
    V = np.zeros((6, n))  # Householder vectors, v_k in V[k, k:]
    vv = np.empty(6)
    r_min, r_max = np.inf, 0.0
    for k in range(6):
        norm2 = 0.0
        for i in range(k, n):
            norm2 += A[i, k] * A[i, k]
        norm = np.sqrt(norm2)
        alpha = -norm if A[k, k] >= 0.0 else norm
        for i in range(k, n):
            V[k, i] = A[i, k]
        V[k, k] -= alpha
        s = 0.0
        for i in range(k, n):
            s += V[k, i] * V[k, i]
        vv[k] = s
        if s > 0.0:
            for c in range(k, 6):  # A[k:, c] −= 2 v (vᵀ A[k:, c]) / vᵀv
                d = 0.0
                for i in range(k, n):
                    d += V[k, i] * A[i, c]
                d *= 2.0 / s
                for i in range(k, n):
                    A[i, c] -= d * V[k, i]
        r = abs(alpha)
        r_min = min(r_min, r)
        r_max = max(r_max, r)
    if not r_min > LINE_QP_RANK * r_max:
        return -1
    z = np.zeros(n)
    z[n - 1] = 1.0
    for k in range(5, -1, -1):
        if vv[k] > 0.0:
            d = 0.0
            for i in range(k, n):
                d += V[k, i] * z[i]
            d *= 2.0 / vv[k]
            for i in range(k, n):
                z[i] -= d * V[k, i]
    lo, hi = -np.inf, np.inf
    for i in range(n):
        zi = z[i]
        if abs(zi) < LINE_QP_TINY:
            if lower[i] > 0.0 or upper[i] < 0.0:
                return -1
        elif zi > 0.0:
            lo = max(lo, lower[i] / zi)
            hi = min(hi, upper[i] / zi)
        else:
            lo = max(lo, upper[i] / zi)
            hi = min(hi, lower[i] / zi)
    if lo > hi:
        return -1
    t_free = 0.0
    for i in range(n):
        t_free -= g[i] * z[i]
    t = min(max(t_free, lo), hi)
    for i in range(n):
        x[i] = t * z[i]
    return 0 if t == t_free else 1
