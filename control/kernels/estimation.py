"""External-torque estimation [C25-26]: the momentum observer's step and the F/T sensor's high pass."""

from __future__ import annotations

import numpy as np
from numba import njit


def momentum_observer_reference(M_prev, dq, dq_prev, tau_prev, h_prev, dt, a, r) -> np.ndarray:
    """One step of the momentum observer [C25]: Δ = M_{k−1}(q̇_k − q̇_{k−1}) − (τ_{k−1} − h_{k−1}) δt
    (∫τ_e over the period), r ← a r + (1 − a) Δ/δt (the exact zero-order-hold solution); the new r."""
    delta = M_prev @ (dq - dq_prev) - (tau_prev - h_prev) * dt
    return a * r + (1.0 - a) * (delta / dt)


def sensor_high_pass_reference(J, wrench, lp, a) -> tuple:
    """τ_s = Jᵀ F_s and the high pass s/(K + s) on it as τ_s − LP(τ_s), the low-pass state `lp`
    advanced in place (lp ← a lp + (1 − a) τ_s); (τ_s, τ_s − lp)."""
    tau_s = J.T @ wrench
    lp[:] = a * lp + (1.0 - a) * tau_s
    return tau_s, tau_s - lp


@njit(cache=True)
def momentum_observer_fused(M_prev, dq, dq_prev, tau_prev, h_prev, dt, a, r):
    """Compiled `momentum_observer_reference` (the step of `control.estimation.MomentumObserver`):
    Δ = M_{k−1}(q̇_k − q̇_{k−1}) − (τ_{k−1} − h_{k−1}) δt, r ← a r + (1 − a) Δ/δt [C25]; the new r."""
    n = dq.shape[0]
    out = np.empty(n)
    for i in range(n):
        s = 0.0
        for j in range(n):
            s += M_prev[i, j] * (dq[j] - dq_prev[j])
        delta = s - (tau_prev[i] - h_prev[i]) * dt
        out[i] = a * r[i] + (1.0 - a) * (delta / dt)
    return out


@njit(cache=True)
def sensor_high_pass_fused(J, wrench, lp, a):
    """τ_s = Jᵀ F_s and one step of the high-pass s/(K + s) of `control.estimation.HighPass` on it
    (the low-pass state `lp` advanced in place: lp ← a lp + (1 − a) τ_s); returns (τ_s, τ_s − lp).
    Compiled `sensor_high_pass_reference`."""
    n = J.shape[1]
    tau_s = np.empty(n)
    hp = np.empty(n)
    for i in range(n):
        s = 0.0
        for k in range(J.shape[0]):
            s += J[k, i] * wrench[k]
        tau_s[i] = s
        lp[i] = a * lp[i] + (1.0 - a) * s
        hp[i] = s - lp[i]
    return tau_s, hp
