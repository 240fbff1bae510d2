"""The [C] executor's problem in one call: estimate [C25-26], objective [C9], dampers [C17-24] and
torque rows [C10].
"""

from __future__ import annotations

import numpy as np
from numba import njit

from control.kernels.compliance import (
    acceleration_bounds_fused,
    acceleration_bounds_reference,
    add_task_rows_fused,
    add_task_rows_reference,
    inverse_dynamics_fused,
    inverse_dynamics_reference,
    pose_task_target_fused,
    pose_task_target_reference,
    posture_target_fused,
    posture_target_reference,
    torque_rows_fused,
    torque_rows_reference,
)
from control.kernels.dense_qp import unconstrained_optimum_fused, unconstrained_optimum_reference
from control.kernels.estimation import (
    momentum_observer_fused,
    momentum_observer_reference,
    sensor_high_pass_fused,
    sensor_high_pass_reference,
)


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


def cqp_problem_reference(
    q, dq, M, M_inv, h, J, dJ_dq, tcp_position, tcp_rotation,
    estimate_on, tau_hat_given, M_prev, dq_prev, h_prev, tau_prev, r, wrench, lp, estimator_constants,
    feedback, tau_max, torque_limits,
    pose_on, target_position, target_rotation, target_velocity, target_acceleration, pose_gains,
    q_ref, dq_ref, posture_gains, integral, posture_constants,
    damper_rows, endless, damper_constants,
    objective, A, l, u, lb, ub, no_bound,
    fast_on, tol,
) -> tuple:  # fmt: skip
    """`cqp_problem_fused` by the references of the kernels it calls, one by one (same arguments,
    same buffers written, same values)."""
    n = q.shape[0]
    if estimate_on:
        a, dt, source = estimator_constants[:3]
        r = momentum_observer_reference(M_prev, dq, dq_prev, tau_prev, h_prev, dt, a, r)  # [C25]
        tau_s, high = sensor_high_pass_reference(J, wrench, lp, a)
        tau_hat = r.copy() if source == 1.0 else (r + high if source == 2.0 else np.zeros(n))  # [C26]
    else:
        tau_hat, tau_s = tau_hat_given, tau_hat_given
    P, qv = objective[:n], objective[n]
    P[:], qv[:] = 0.0, 0.0
    ddq_e = M_inv @ tau_hat
    if pose_on:  # [C3-4, C9]
        b = pose_task_target_reference(
            J, dq, dJ_dq, tcp_position, tcp_rotation, target_position, target_rotation, target_velocity,
            target_acceleration, pose_gains[0], pose_gains[1], pose_gains[2:8], pose_gains[8, 1] != 0.0, ddq_e,
        )  # fmt: skip
        add_task_rows_reference(P, qv, J, b, pose_gains[8, 0])
    w, use_ki, use_gamma, dt_posture, inertia_metric = posture_constants[:5]
    b0 = posture_target_reference(
        q, q_ref, dq, dq_ref, posture_gains[0], posture_gains[1], posture_gains[2], use_ki != 0.0, integral,
        dt_posture, posture_gains[3:], use_gamma != 0.0, ddq_e,
    )  # fmt: skip
    metric = M if inertia_metric != 0.0 else np.eye(n)  # [C7] task 0 in the M or identity metric
    P += w * metric
    qv -= w * (metric @ b0)
    lower, upper, crossed = acceleration_bounds_reference(
        q, dq, damper_rows[0], damper_rows[1], damper_rows[2], damper_rows[3], damper_rows[4], damper_constants[0],
        damper_constants[1], damper_constants[2], damper_rows[5], endless, damper_constants[3] != 0.0,
        damper_constants[4], damper_constants[5],
    )  # fmt: skip
    lb[:], ub[:] = lower, upper
    tau_fb = tau_hat if feedback else np.zeros(n)
    torque_rows_reference(M, h, tau_fb, tau_max, A, l, u, torque_limits, no_bound)  # [C10]
    x = np.zeros(n)
    solved = bool(fast_on and not crossed and unconstrained_optimum_reference(P, qv, A, lb, l, ub, u, tol, x))
    if solved:  # [C8]
        tau, tau_cmd, saturated = inverse_dynamics_reference(M, x, h, tau_fb, tau_max, False)
    else:
        tau, tau_cmd, saturated = x, x, False
    return crossed, tau_hat, r, tau_s, solved, x, tau, tau_cmd, saturated
