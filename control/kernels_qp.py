"""Compiled kernels of the [C] acceleration QP and its executor, each beside its reference.

Like `control.kernels` (same conventions: numba with `cache=True`, a `*_reference` function that
states the algebra readably, `tests/test_kernels.py` holding the fused version to it):

- `dense_qp_load_*`: what `control.qp.DenseBackend` does before DAQP — copy the data into the
  backend's one buffer, refuse NaN and crossed bounds — and its exact fast path: for a strictly
  convex problem without equality rows, the unconstrained minimiser x = −P⁻¹q (Cholesky) that
  meets every bound and row (to the primal tolerance, DAQP's own test of the same candidate) is
  the optimum (the KKT conditions hold with all multipliers zero), so DAQP is not needed.
- `cqp_problem_fused`: the [C] executor's estimate [C25-26] and QP data [C9, C10, C17-24] in one call
  of the `control.kernels` functions the executor's reference path calls one by one
  (`ComplianceQPExecutor._step_reference` is its statement; `tests/test_compliance_qp.py` holds
  the fused step to it).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from control.kernels import (
    acceleration_bounds_fused,
    add_task_rows_fused,
    inverse_dynamics_fused,
    momentum_observer_fused,
    pose_task_target_fused,
    posture_target_fused,
    sensor_high_pass_fused,
    torque_rows_fused,
)

# `dense_qp_load_*` outcomes
FAST_SOLVED = 0  # x holds the optimum (the unconstrained minimiser is feasible)
NEEDS_SOLVER = 1  # data loaded, hand it to DAQP
NON_FINITE_DATA = 2  # NaN (or inf outside the bounds) in the data
CROSSED_BOUNDS = 3  # a lower bound above its upper bound
PIVOT_FLOOR = 1e-12  # Cholesky pivots below this times P's largest diagonal entry: left to DAQP


def dense_qp_buffer(n: int, m: int) -> np.ndarray:
    """The one data buffer of an (n variables, m rows) problem: [P (n·n), A (m·n), q (n), lower
    (n + m: box, then rows), upper (n + m)] (`dense_qp_views` names the parts)."""
    return np.zeros(n * n + m * n + n + 2 * (n + m))


def dense_qp_views(data: np.ndarray, n: int, m: int) -> tuple:
    """(P, A, q, lower, upper) views into a `dense_qp_buffer`."""
    k = n + m
    P = data[: n * n].reshape(n, n)
    A = data[n * n : n * n + m * n].reshape(m, n)
    rest = data[n * n + m * n :]
    return P, A, rest[:n], rest[n : n + k], rest[n + k : n + 2 * k]


def dense_qp_load_reference(
    data: np.ndarray,
    n: int,
    m: int,
    n_eq: int,
    P: np.ndarray | None,
    q: np.ndarray,
    A: np.ndarray | None,
    l: np.ndarray,
    u: np.ndarray,
    lb: np.ndarray,
    ub: np.ndarray,
    no_bound: float,
    tol: float,
    x: np.ndarray,
) -> int:
    """Load min ½xᵀPx + qᵀx s.t. lb ≤ x ≤ ub, l ≤ Ax ≤ u (last n_eq rows equalities; P, A None:
    unchanged) into `data` and try the fast path; returns one of the outcome codes above and, for
    FAST_SOLVED, the optimum in `x`.

    ±inf bounds become ±no_bound (only when the data's sum of squares is not finite, as the
    backend always did); NaN anywhere is NON_FINITE_DATA. The fast path needs no equality rows and
    P positive definite (every Cholesky pivot above PIVOT_FLOOR · max diag P); its candidate
    x = −P⁻¹q must be finite and meet lb − tol ≤ x ≤ ub + tol, l − tol ≤ Ax ≤ u + tol."""
    Pd, Ad, qd, lo, hi = dense_qp_views(data, n, m)
    if P is not None:
        Pd[:] = P
    if A is not None:
        Ad[:] = A
    qd[:] = q
    lo[:n], lo[n:], hi[:n], hi[n:] = lb, l, ub, u
    with np.errstate(over="ignore", invalid="ignore"):
        finite = math.isfinite(float(data @ data))
        if not finite:
            bounds = data[n * n + m * n + n :]
            np.clip(bounds, -no_bound, no_bound, out=bounds)
            finite = math.isfinite(float(data @ data))
    if not finite:
        return NON_FINITE_DATA
    if (lo > hi).any():
        return CROSSED_BOUNDS
    if n_eq > 0:
        return NEEDS_SOLVER
    try:
        L = np.linalg.cholesky(Pd)
    except np.linalg.LinAlgError:
        return NEEDS_SOLVER
    if not np.all(np.diag(L) ** 2 > PIVOT_FLOOR * max(float(np.max(np.diag(Pd))), 0.0)):
        return NEEDS_SOLVER
    cand = -np.linalg.solve(L.T, np.linalg.solve(L, qd))
    rows = Ad @ cand
    if not np.all(np.isfinite(cand)):
        return NEEDS_SOLVER
    if np.any(cand < lo[:n] - tol) or np.any(cand > hi[:n] + tol):
        return NEEDS_SOLVER
    if np.any(rows < lo[n:] - tol) or np.any(rows > hi[n:] + tol):
        return NEEDS_SOLVER
    x[:] = cand
    return FAST_SOLVED


@njit(cache=True)
def dense_qp_load_fused(data, n, m, n_eq, P, q, A, l, u, lb, ub, no_bound, tol, x):
    """`dense_qp_load_reference` in one compiled call (Cholesky and the triangular solves written
    out, on the P held in `data`)."""
    k = n + m
    off_A = n * n
    off_q = off_A + m * n
    off_lo = off_q + n
    off_hi = off_lo + k
    if P is not None:
        for i in range(n):
            for j in range(n):
                data[i * n + j] = P[i, j]
    if A is not None:
        for i in range(m):
            for j in range(n):
                data[off_A + i * n + j] = A[i, j]
    for i in range(n):
        data[off_q + i] = q[i]
        data[off_lo + i] = lb[i]
        data[off_hi + i] = ub[i]
    for i in range(m):
        data[off_lo + n + i] = l[i]
        data[off_hi + n + i] = u[i]
    s = 0.0
    for i in range(data.shape[0]):
        s += data[i] * data[i]
    if not math.isfinite(s):
        for i in range(off_lo, off_hi + k):
            if data[i] > no_bound:
                data[i] = no_bound
            elif data[i] < -no_bound:
                data[i] = -no_bound
        s = 0.0
        for i in range(data.shape[0]):
            s += data[i] * data[i]
        if not math.isfinite(s):
            return NON_FINITE_DATA
    for i in range(k):
        if data[off_lo + i] > data[off_hi + i]:
            return CROSSED_BOUNDS
    if n_eq > 0:
        return NEEDS_SOLVER
    P = data[:off_A].reshape((n, n))
    A = data[off_A:off_q].reshape((m, n))
    lower, upper = data[off_lo:off_hi], data[off_hi : off_hi + k]
    if unconstrained_optimum_fused(P, data[off_q:off_lo], A, lower[:n], lower[n:], upper[:n], upper[n:], tol, x):
        return FAST_SOLVED
    return NEEDS_SOLVER


@njit(cache=True)
def unconstrained_optimum_fused(P, q, A, lb, l, ub, u, tol, x):
    """The fast path of `dense_qp_load_fused`: x = −P⁻¹q by Cholesky (lower triangle of P read;
    every pivot above PIVOT_FLOOR · max diag P) written into `x` when it is finite and meets
    lb − tol ≤ x ≤ ub + tol and l − tol ≤ A x ≤ u + tol; returns whether it did. Data with NaN
    (or a crossed bound) is refused: it is the backend's to report."""
    n, m = P.shape[0], A.shape[0]
    for i in range(n):
        if not (math.isfinite(q[i]) and lb[i] <= ub[i]):
            return False
        for j in range(n):
            if not math.isfinite(P[i, j]):
                return False
    for r in range(m):
        if not l[r] <= u[r]:
            return False
        for j in range(n):
            if not math.isfinite(A[r, j]):
                return False
    L = np.zeros((n, n))
    max_diag = 0.0
    for i in range(n):
        max_diag = max(max_diag, P[i, i])
    floor = PIVOT_FLOOR * max_diag
    for j in range(n):
        d = P[j, j]
        for c in range(j):
            d -= L[j, c] * L[j, c]
        if not d > floor:
            return False
        L[j, j] = math.sqrt(d)
        for i in range(j + 1, n):
            v = P[i, j]
            for c in range(j):
                v -= L[i, c] * L[j, c]
            L[i, j] = v / L[j, j]
    # L y = −q, Lᵀ x = y
    y = np.empty(n)
    for i in range(n):
        v = -q[i]
        for c in range(i):
            v -= L[i, c] * y[c]
        y[i] = v / L[i, i]
    cand = np.empty(n)
    for i in range(n - 1, -1, -1):
        v = y[i]
        for c in range(i + 1, n):
            v -= L[c, i] * cand[c]
        v /= L[i, i]
        if not math.isfinite(v):
            return False
        if v < lb[i] - tol or v > ub[i] + tol:
            return False
        cand[i] = v
    for r in range(m):
        v = 0.0
        for j in range(n):
            v += A[r, j] * cand[j]
        if v < l[r] - tol or v > u[r] + tol:
            return False
    for i in range(n):
        x[i] = cand[i]
    return True


# ==== the [C] executor's problem: objective [C9], dampers [C17-24], torque rows [C10] =============
@njit(cache=True)
def cqp_problem_fused(
    q, dq, M, M_inv, h, J, dJ_dq, tcp_position, tcp_rotation,
    estimate_on, tau_hat_given, M_prev, dq_prev, h_prev, tau_prev, r, wrench, lp, estimator_constants,
    feedback, tau_max, torque_limits,
    pose_on, target_position, target_rotation, target_velocity, target_acceleration, pose_gains,
    q_ref, dq_ref, posture_gains, integral, posture_constants,
    damper_rows, endless, damper_constants,
    objective, A, l, u, lb, ub, no_bound,
    fast_on, tol,
):  # fmt: skip
    """What `control.compliance_qp.ComplianceQPExecutor._step_reference` computes before the QP,
    for a TCP pose task (when `pose_on`) and the posture task, in one call of the kernels it calls
    one by one:

    with `estimate_on`, the estimate τ̂_e of `control.estimation.ExternalTorqueEstimator.update`
    (observer and sensor both started): the observer's new residual r [C25]
    (`momentum_observer_fused`, from the last step's M, q̇, h and τ), τ_s = Jᵀ F_s and its high
    pass (`sensor_high_pass_fused`, the low-pass state `lp` advanced in place), τ̂_e = 0, r or
    r + high pass [C26] for `estimator_constants` = [a (observer and filter pole), δt, source 0/1/2
    (none, residual, fusion)]; else τ̂_e = `tau_hat_given`;
    q̈_e = M⁻¹ τ̂_e; the objective [C9] ½ q̈ᵀP q̈ + qvᵀq̈ written into P, qv: the pose task's
    rows (`pose_task_target_fused`, `add_task_rows_fused`), then the posture task's
    (`posture_target_fused`, its integral advanced in place), identity metric (P += w I, qv −= w b)
    or inertia metric (P += w M, qv −= w M b); the dampers' box lb ≤ q̈ ≤ ub [C17-24]
    (`acceleration_bounds_fused`); the torque rows [C10] of A, l, u (`torque_rows_fused`, τ_fb =
    τ̂_e with `feedback`, else 0); with `fast_on` (the objective is final: no other task adds
    rows), the dense backend's exact fast path on that QP (`unconstrained_optimum_fused`, primal
    tolerance `tol`) and, when it holds, τ_d = M q̈ + h − τ_fb [C8] (`inverse_dynamics_fused`).

    Returns (damper bounds crossed, τ̂_e, r, τ_s, solved, q̈, τ_d, τ command, saturated): r and
    τ_s new only with `estimate_on` (else r and `tau_hat_given`), the last four only when
    `solved` (the fast path held).

    Packed arguments (one compiled call's argument checks cost per argument): `pose_gains` (9, 6)
    = [K_p; K_d; Γ (6 rows); weight, Γ ≠ 0, …]; `posture_gains` (3 + n, n) = [K_p; K_d; K_i; Γ₀]
    and `posture_constants` = [weight, K_i ≠ 0, Γ₀ ≠ 0, δt, inertia metric]; `damper_rows` =
    [q⁻; q⁺; d_s; d_i; ξ; q̇ limit] and `damper_constants` = [k_p, λ, velocity gain, proposed,
    δt, no bound] (`control.dampers.JointLimitDamper`); `objective` (n + 1, n) = [P; qv]."""
    n = q.shape[0]
    if estimate_on:
        a, dt, source = estimator_constants[0], estimator_constants[1], estimator_constants[2]
        r = momentum_observer_fused(M_prev, dq, dq_prev, tau_prev, h_prev, dt, a, r)
        tau_s, high = sensor_high_pass_fused(J, wrench, lp, a)
        tau_hat = np.zeros(n)
        if source == 1.0:  # residual
            tau_hat[:] = r
        elif source == 2.0:  # fusion [C26]
            for i in range(n):
                tau_hat[i] = r[i] + high[i]
    else:
        tau_hat, tau_s = tau_hat_given, tau_hat_given
    P, qv = objective[:n], objective[n]
    w_pose, pose_use_gamma = pose_gains[8, 0], pose_gains[8, 1] != 0.0
    w_posture, posture_dt = posture_constants[0], posture_constants[3]
    posture_use_ki, posture_use_gamma = posture_constants[1] != 0.0, posture_constants[2] != 0.0
    inertia_metric = posture_constants[4] != 0.0
    ddq_e = np.empty(n)  # q̈_e = M⁻¹ τ̂_e
    for i in range(n):
        s = 0.0
        for j in range(n):
            s += M_inv[i, j] * tau_hat[j]
        ddq_e[i] = s
    for i in range(n):
        qv[i] = 0.0
        for j in range(n):
            P[i, j] = 0.0
    if pose_on:
        b = pose_task_target_fused(
            J, dq, dJ_dq, tcp_position, tcp_rotation, target_position, target_rotation, target_velocity,
            target_acceleration, pose_gains[0], pose_gains[1], pose_gains[2:8], pose_use_gamma, ddq_e,
        )  # fmt: skip
        add_task_rows_fused(P, qv, J, b, w_pose)
    b0 = posture_target_fused(
        q, q_ref, dq, dq_ref, posture_gains[0], posture_gains[1], posture_gains[2], posture_use_ki, integral,
        posture_dt, posture_gains[3:], posture_use_gamma, ddq_e,
    )  # fmt: skip
    w = w_posture
    if inertia_metric:  # (Iᵀ M) w I = w M, (Iᵀ M) w b0 = w M b0
        for i in range(n):
            s = 0.0
            for j in range(n):
                P[i, j] += M[i, j] * w
                s += M[i, j] * w * b0[j]
            qv[i] -= s
    else:
        for i in range(n):
            P[i, i] += w
            qv[i] -= w * b0[i]
    lower, upper, crossed = acceleration_bounds_fused(
        q, dq, damper_rows[0], damper_rows[1], damper_rows[2], damper_rows[3], damper_rows[4], damper_constants[0],
        damper_constants[1], damper_constants[2], damper_rows[5], endless, damper_constants[3] != 0.0,
        damper_constants[4], damper_constants[5],
    )  # fmt: skip
    for i in range(n):
        lb[i] = lower[i]
        ub[i] = upper[i]
    if feedback:
        torque_rows_fused(M, h, tau_hat, tau_max, A, l, u, torque_limits, no_bound)
    else:
        torque_rows_fused(M, h, np.zeros(n), tau_max, A, l, u, torque_limits, no_bound)
    x = np.zeros(n)
    solved = False
    if fast_on and not crossed:
        solved = unconstrained_optimum_fused(P, qv, A, lb, l, ub, u, tol, x)
    if solved:  # [C8] for an exact solution (no clipping of τ_d)
        tau, tau_cmd, saturated = inverse_dynamics_fused(M, x, h, tau_hat if feedback else np.zeros(n), tau_max, False)
    else:
        tau, tau_cmd, saturated = x, x, False
    return crossed, tau_hat, r, tau_s, solved, x, tau, tau_cmd, saturated
