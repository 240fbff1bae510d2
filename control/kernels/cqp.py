"""The [C] executor's problem in one call: estimate [C25-26], objective [C9], dampers [C17-24] and
torque rows [C10].
"""

from __future__ import annotations

import functools

import numpy as np
from numba import njit

from control.gains import ComplianceQPSettings, DamperGains, EstimatorGains, PoseTaskGains, PostureTaskGains
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
from control.kernels.records import record_dtype

# ---- the records `cqp_problem_fused` reads (`control.kernels.records`): each group's numeric fields by
# name, and what its owner derives from them (the per-axis gains, the joint rows)


@functools.cache
def pose_record_dtype() -> np.dtype:
    """`PoseTaskGains` (w) and the pose task's K_p, K_d (6,), Γ (6, 6), Γ ≠ 0 [C3-4, C9]."""
    return record_dtype(
        (PoseTaskGains,),
        (("kp", np.float64, (6,)), ("kd", np.float64, (6,)), ("gamma", np.float64, (6, 6)), ("use_gamma", np.bool_)),
    )


@functools.cache
def posture_record_dtype(n: int) -> np.dtype:
    """`PostureTaskGains` (w₀) and the posture task's K_p, K_d, K_i (n,), Γ₀ (n, n), K_i ≠ 0, Γ₀ ≠ 0,
    δt (s) and whether its metric is M [C7, C9]."""
    return record_dtype(
        (PostureTaskGains,),
        (
            ("kp", np.float64, (n,)),
            ("kd", np.float64, (n,)),
            ("ki", np.float64, (n,)),
            ("gamma", np.float64, (n, n)),
            ("use_ki", np.bool_),
            ("use_gamma", np.bool_),
            ("dt", np.float64),
            ("inertia_metric", np.bool_),
        ),
    )


@functools.cache
def damper_record_dtype(n: int) -> np.dtype:
    """`DamperGains` (λ, M, the fractions, the velocity scale) and the damper's joint rows q⁻, q⁺, d_s,
    d_i, ξ, q̇ limit, endless (1.0) (n,), k_p = λ²/(4M²), the velocity gain, the proposed form, δt and
    the value of no bound [C17-24] (`control.dampers.JointLimitDamper`)."""
    joint = tuple(
        (name, np.float64, (n,)) for name in ("q_lower", "q_upper", "d_s", "d_i", "xi", "dq_limit", "endless")
    )
    return record_dtype(
        (DamperGains,),
        (
            *joint,
            ("kp", np.float64),
            ("velocity_gain", np.float64),
            ("proposed", np.bool_),
            ("dt", np.float64),
            ("no_bound", np.float64),
        ),
    )


@functools.cache
def estimator_record_dtype() -> np.dtype:
    """`EstimatorGains` (K_I) and the estimator's pole a, δt and source code (0 none, 1 residual,
    2 fusion, −1 oracle: not computed in the call) [C25-26]."""
    return record_dtype((EstimatorGains,), (("a", np.float64), ("dt", np.float64), ("source_code", np.float64)))


@functools.cache
def settings_record_dtype(n: int) -> np.dtype:
    """`ComplianceQPSettings` (feedback, torque limits, tolerance, …) and the executor's τ limits (n,),
    the value of no bound, whether a pose task is in the call and whether its fast path may end the
    step (`fast_on`: the objective is final in the call)."""
    return record_dtype(
        (ComplianceQPSettings,),
        (("tau_max", np.float64, (n,)), ("no_bound", np.float64), ("pose_on", np.bool_), ("fast_on", np.bool_)),
    )


@njit(cache=True)
def cqp_problem_fused(snap, estimator, target, pose, posture, damper, settings, buffers):
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

    The arguments: `snap` = the snapshot's record (`Dynamics.record`, read by field name);
    `estimator` = (estimate_on, τ̂_e given, the last step's M, q̇, μ, τ, the residual r, the F/T
    wrench, the filter state lp, the estimator's record); `target` = `records.target_arrays(task
    target)`; the records of the pose task (`pose_record_dtype`; read only with the record
    `settings.pose_on`), the damper and the settings; `posture` = (q_ref, q̇_ref, ∫e, its record);
    `buffers` = (objective (n + 1, n) = [P; qv], A, l, u, lb, ub), written."""
    s = snap[0]
    q, dq, M, M_inv, h, J = s.q, s.dq, s.M, s.M_inv, s.h, s.J
    estimate_on, tau_hat_given, M_prev, dq_prev, h_prev, tau_prev, r, wrench, lp, est_record = estimator
    q_ref, dq_ref, integral, posture_record = posture
    objective, A, l, u, lb, ub = buffers
    e_c, pc, sc = est_record[0], posture_record[0], settings[0]
    n = q.shape[0]
    if estimate_on:
        a, dt, source = e_c.a, e_c.dt, e_c.source_code
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
    if sc.pose_on:
        b = pose_task_target_fused(snap, target, pose, ddq_e)
        add_task_rows_fused(P, qv, J, b, pose[0].weight)
    b0 = posture_target_fused(snap, q_ref, dq_ref, integral, posture_record, ddq_e)
    w = pc.weight
    if pc.inertia_metric:  # (Iᵀ M) w I = w M, (Iᵀ M) w b0 = w M b0
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
    lower, upper, crossed = acceleration_bounds_fused(q, dq, damper)
    for i in range(n):
        lb[i] = lower[i]
        ub[i] = upper[i]
    feedback, tau_max = sc.feedback, sc.tau_max
    if feedback:
        torque_rows_fused(M, h, tau_hat, tau_max, A, l, u, sc.torque_limits, sc.no_bound)
    else:
        torque_rows_fused(M, h, np.zeros(n), tau_max, A, l, u, sc.torque_limits, sc.no_bound)
    x = np.zeros(n)
    solved = False
    if sc.fast_on and not crossed:
        solved = unconstrained_optimum_fused(P, qv, A, lb, l, ub, u, sc.eps, x)
    if solved:  # [C8] for an exact solution (no clipping of τ_d)
        tau, tau_cmd, saturated = inverse_dynamics_fused(M, x, h, tau_hat if feedback else np.zeros(n), tau_max, False)
    else:
        tau, tau_cmd, saturated = x, x, False
    return crossed, tau_hat, r, tau_s, solved, x, tau, tau_cmd, saturated


def cqp_problem_reference(snap, estimator, target, pose, posture, damper, settings, buffers) -> tuple:
    """`cqp_problem_fused` by the references of the kernels it calls, one by one (same arguments,
    same buffers written, same values)."""
    s = snap[0]
    q, dq, M, M_inv, h, J = s["q"], s["dq"], s["M"], s["M_inv"], s["h"], s["J"]
    estimate_on, tau_hat_given, M_prev, dq_prev, h_prev, tau_prev, r, wrench, lp, est_record = estimator
    q_ref, dq_ref, integral, posture_record = posture
    objective, A, l, u, lb, ub = buffers
    e_c, pc, sc = est_record[0], posture_record[0], settings[0]
    n = q.shape[0]
    if estimate_on:
        a, dt, source = float(e_c["a"]), float(e_c["dt"]), float(e_c["source_code"])
        r = momentum_observer_reference(M_prev, dq, dq_prev, tau_prev, h_prev, dt, a, r)  # [C25]
        tau_s, high = sensor_high_pass_reference(J, wrench, lp, a)
        tau_hat = r.copy() if source == 1.0 else (r + high if source == 2.0 else np.zeros(n))  # [C26]
    else:
        tau_hat, tau_s = tau_hat_given, tau_hat_given
    P, qv = objective[:n], objective[n]
    P[:], qv[:] = 0.0, 0.0
    ddq_e = M_inv @ tau_hat
    if sc["pose_on"]:  # [C3-4, C9]
        b = pose_task_target_reference(snap, target, pose, ddq_e)
        add_task_rows_reference(P, qv, J, b, float(pose[0]["weight"]))
    w = float(pc["weight"])
    b0 = posture_target_reference(snap, q_ref, dq_ref, integral, posture_record, ddq_e)
    metric = M if pc["inertia_metric"] else np.eye(n)  # [C7] task 0 in the M or identity metric
    P += w * metric
    qv -= w * (metric @ b0)
    lower, upper, crossed = acceleration_bounds_reference(q, dq, damper)
    lb[:], ub[:] = lower, upper
    feedback, tau_max = bool(sc["feedback"]), sc["tau_max"]
    tau_fb = tau_hat if feedback else np.zeros(n)
    torque_rows_reference(M, h, tau_fb, tau_max, A, l, u, bool(sc["torque_limits"]), float(sc["no_bound"]))  # [C10]
    x = np.zeros(n)
    fast_on, tol = bool(sc["fast_on"]), float(sc["eps"])
    solved = bool(fast_on and not crossed and unconstrained_optimum_reference(P, qv, A, lb, l, ub, u, tol, x))
    if solved:  # [C8]
        tau, tau_cmd, saturated = inverse_dynamics_reference(M, x, h, tau_fb, tau_max, False)
    else:
        tau, tau_cmd, saturated = x, x, False
    return crossed, tau_hat, r, tau_s, solved, x, tau, tau_cmd, saturated
