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
    δt (s), whether its metric is M [C7, C9], and its state: the integral ∫(q − q_ref) (n,)
    (`control.compliance_qp.PostureTask.integral` is a view of it)."""
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
            ("integral", np.float64, (n,)),
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


# what the estimator's record holds besides `EstimatorGains` and its constants: the observer's and the
# filter's state, which the fused step advances in place, and the step's inputs and estimate
ESTIMATOR_STATE_FIELDS = (
    "observed", "M_prev", "dq_prev", "h_prev", "r", "filtered", "lp", "tau_prev", "wrench", "estimate_on",
    "tau_hat", "tau_s",
)  # fmt: skip


@functools.cache
def estimator_record_dtype(n: int) -> np.dtype:
    """`EstimatorGains` (K_I), the estimator's pole a, δt and source code (0 none, 1 residual,
    2 fusion, −1 oracle: not computed in the call) [C25-26], and its state
    (`control.estimation.ExternalTorqueEstimator`: the observer's and the filter's attributes are
    views of it): whether the observer holds a last state (`observed`) and that state M, q̇, h
    (`M_prev`, `dq_prev`, `h_prev`), the residual r, whether the high pass has started (`filtered`)
    and its low-pass state `lp`, the torque applied over the last period `tau_prev`; the step's
    F/T wrench at the TCP (6,) and whether the fused step estimates (`estimate_on`, else `tau_hat` is
    given); the estimate τ̂_e `tau_hat` and τ_s = Jᵀ F_s `tau_s`."""
    vector = (("dq_prev", "h_prev", "r", "lp", "tau_prev", "tau_hat", "tau_s"), (n,))
    shapes = {"M_prev": (n, n), "wrench": (6,), **dict.fromkeys(vector[0], vector[1])}
    state = tuple(
        (name, np.float64, shapes[name]) if name in shapes else (name, np.bool_) for name in ESTIMATOR_STATE_FIELDS
    )
    return record_dtype((EstimatorGains,), (("a", np.float64), ("dt", np.float64), ("source_code", np.float64), *state))


@functools.cache
def cqp_workspace_dtype(n: int, m: int) -> np.dtype:
    """The record of one [C] step's work (`control.compliance_qp.AccelerationQP.work`: its arrays are
    views of it): the posture reference `q_ref`, `dq_ref` (n,) the step reads; the QP's objective
    ½ q̈ᵀP q̈ + qvᵀq̈ [C9] `P` (n, n), `qv` (n,), its rows `A` (m, n), `l`, `u` (m,) [C10] and box
    `lb`, `ub` (n,) [C17-24], which the step writes; and the step's results: the damper bounds
    `crossed`, whether the fast path `solved` the QP, q̈ `x`, τ_d `tau`, the command `tau_cmd`
    (n,) and whether it `saturated`."""
    vec, rows = (np.float64, (n,)), (np.float64, (m,))
    return record_dtype(
        (),
        (
            ("q_ref", *vec), ("dq_ref", *vec), ("P", np.float64, (n, n)), ("qv", *vec), ("A", np.float64, (m, n)),
            ("l", *rows), ("u", *rows), ("lb", *vec), ("ub", *vec), ("crossed", np.bool_), ("solved", np.bool_),
            ("x", *vec), ("tau", *vec), ("tau_cmd", *vec), ("saturated", np.bool_),
        ),
    )  # fmt: skip


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
def cqp_problem_fused(snap, estimator, target, pose, posture, damper, settings, work):
    """What `control.compliance_qp.ComplianceQPExecutor._step_reference` computes before the QP,
    for a TCP pose task (when `pose_on`) and the posture task, in one call of the kernels it calls
    one by one, every argument a record read and written by field name:

    with the estimator's `estimate_on`, the estimate τ̂_e of
    `control.estimation.ExternalTorqueEstimator.update` (observer and sensor both started): the
    observer's new residual r [C25] (`momentum_observer_fused`, from the stored M, q̇, h and
    `tau_prev`; then this step's M, q̇, h stored), τ_s = Jᵀ F_s and its high pass
    (`sensor_high_pass_fused`, `lp` advanced), τ̂_e = 0, r or r + high pass [C26] for the
    `source_code` 0/1/2 (none, residual, fusion), into the record's `r`, `tau_s`, `tau_hat`; else
    τ̂_e is the record's `tau_hat`, as given;
    q̈_e = M⁻¹ τ̂_e; the objective [C9] ½ q̈ᵀP q̈ + qvᵀq̈ written into the workspace's `P`, `qv`: the
    pose task's rows (`pose_task_target_fused`, `add_task_rows_fused`), then the posture task's
    (`posture_target_fused` on the workspace's `q_ref`, `dq_ref` and the posture record's
    `integral`, advanced), identity metric (P += w I, qv −= w b) or inertia metric (P += w M,
    qv −= w M b); the dampers' box `lb` ≤ q̈ ≤ `ub` [C17-24] (`acceleration_bounds_fused`); the torque
    rows [C10] of `A`, `l`, `u` (`torque_rows_fused`, τ_fb = τ̂_e with `feedback`, else 0); with
    `fast_on` (the objective is final: no other task adds rows), the dense backend's exact fast path
    on that QP (`unconstrained_optimum_fused`, primal tolerance `eps`) and, when it holds,
    τ_d = M q̈ + h − τ_fb [C8] (`inverse_dynamics_fused`).

    Writes the workspace's results: `crossed` (damper bounds crossed), `solved` (the fast path held),
    and then q̈ `x`, τ_d `tau`, the command `tau_cmd` and `saturated` (else x = τ_d = command = 0).

    The records: `snap` the snapshot's (`Dynamics.record`); `estimator` `estimator_record_dtype`;
    `target` the task target's (`TaskTarget.record`); `pose` `pose_record_dtype` (read only with
    `settings.pose_on`); `posture` `posture_record_dtype`; `damper` `damper_record_dtype`;
    `settings` `settings_record_dtype`; `work` `cqp_workspace_dtype`."""
    s, e, w_ = snap[0], estimator[0], work[0]
    q, dq, M, M_inv, h, J = s.q, s.dq, s.M, s.M_inv, s.h, s.J
    pc, sc = posture[0], settings[0]
    n = q.shape[0]
    tau_hat = e.tau_hat
    if e.estimate_on:
        a, source = e.a, e.source_code
        r = momentum_observer_fused(e.M_prev, dq, e.dq_prev, e.tau_prev, e.h_prev, e.dt, a, e.r)
        tau_s, high = sensor_high_pass_fused(J, e.wrench, e.lp, a)
        for i in range(n):
            e.r[i] = r[i]
            e.tau_s[i] = tau_s[i]
            e.dq_prev[i] = dq[i]
            e.h_prev[i] = h[i]
            for j in range(n):
                e.M_prev[i, j] = M[i, j]
            if source == 1.0:  # residual
                tau_hat[i] = r[i]
            elif source == 2.0:  # fusion [C26]
                tau_hat[i] = r[i] + high[i]
            else:
                tau_hat[i] = 0.0
    P, qv = w_.P, w_.qv
    ddq_e = np.empty(n)  # q̈_e = M⁻¹ τ̂_e
    for i in range(n):
        acc = 0.0
        for j in range(n):
            acc += M_inv[i, j] * tau_hat[j]
        ddq_e[i] = acc
    for i in range(n):
        qv[i] = 0.0
        for j in range(n):
            P[i, j] = 0.0
    if sc.pose_on:
        b = pose_task_target_fused(snap, target, pose, ddq_e)
        add_task_rows_fused(P, qv, J, b, pose[0].weight)
    b0 = posture_target_fused(snap, w_.q_ref, w_.dq_ref, pc.integral, posture, ddq_e)
    w = pc.weight
    if pc.inertia_metric:  # (Iᵀ M) w I = w M, (Iᵀ M) w b0 = w M b0
        for i in range(n):
            acc = 0.0
            for j in range(n):
                P[i, j] += M[i, j] * w
                acc += M[i, j] * w * b0[j]
            qv[i] -= acc
    else:
        for i in range(n):
            P[i, i] += w
            qv[i] -= w * b0[i]
    lower, upper, crossed = acceleration_bounds_fused(q, dq, damper)
    lb, ub = w_.lb, w_.ub
    for i in range(n):
        lb[i] = lower[i]
        ub[i] = upper[i]
    feedback, tau_max = sc.feedback, sc.tau_max
    tau_fb = np.zeros(n)
    if feedback:
        tau_fb[:] = tau_hat
    torque_rows_fused(M, h, tau_fb, tau_max, w_.A, w_.l, w_.u, sc.torque_limits, sc.no_bound)
    x = w_.x
    x[:] = 0.0
    solved = False
    if sc.fast_on and not crossed:
        solved = unconstrained_optimum_fused(P, qv, w_.A, lb, w_.l, ub, w_.u, sc.eps, x)
    w_.crossed, w_.solved = crossed, solved
    if solved:  # [C8] for an exact solution (no clipping of τ_d)
        tau, tau_cmd, saturated = inverse_dynamics_fused(M, x, h, tau_fb, tau_max, False)
        w_.tau[:] = tau
        w_.tau_cmd[:] = tau_cmd
        w_.saturated = saturated
    else:
        w_.tau[:] = 0.0
        w_.tau_cmd[:] = 0.0
        w_.saturated = False


def cqp_problem_reference(snap, estimator, target, pose, posture, damper, settings, work) -> None:
    """`cqp_problem_fused` by the references of the kernels it calls, one by one (same records, same
    fields written, same values)."""
    s, e, w_ = snap[0], estimator[0], work[0]
    q, dq, M, M_inv, h, J = s["q"], s["dq"], s["M"], s["M_inv"], s["h"], s["J"]
    pc, sc = posture[0], settings[0]
    n = q.shape[0]
    tau_hat = e["tau_hat"]
    if e["estimate_on"]:
        a, dt, source = float(e["a"]), float(e["dt"]), float(e["source_code"])
        r = momentum_observer_reference(e["M_prev"], dq, e["dq_prev"], e["tau_prev"], e["h_prev"], dt, a, e["r"])
        tau_s, high = sensor_high_pass_reference(J, e["wrench"], e["lp"], a)  # [C25], then the state stored
        e["r"], e["tau_s"], e["M_prev"], e["dq_prev"], e["h_prev"] = r, tau_s, M, dq, h
        tau_hat[:] = r if source == 1.0 else (r + high if source == 2.0 else np.zeros(n))  # [C26]
    P, qv = w_["P"], w_["qv"]
    P[:], qv[:] = 0.0, 0.0
    ddq_e = M_inv @ tau_hat
    if sc["pose_on"]:  # [C3-4, C9]
        b = pose_task_target_reference(snap, target, pose, ddq_e)
        add_task_rows_reference(P, qv, J, b, float(pose[0]["weight"]))
    w = float(pc["weight"])
    b0 = posture_target_reference(snap, w_["q_ref"], w_["dq_ref"], pc["integral"], posture, ddq_e)
    metric = M if pc["inertia_metric"] else np.eye(n)  # [C7] task 0 in the M or identity metric
    P += w * metric
    qv -= w * (metric @ b0)
    lower, upper, crossed = acceleration_bounds_reference(q, dq, damper)
    w_["lb"], w_["ub"] = lower, upper
    feedback, tau_max = bool(sc["feedback"]), sc["tau_max"]
    tau_fb = tau_hat.copy() if feedback else np.zeros(n)
    A, l, u = w_["A"], w_["l"], w_["u"]
    torque_rows_reference(M, h, tau_fb, tau_max, A, l, u, bool(sc["torque_limits"]), float(sc["no_bound"]))  # [C10]
    x = np.zeros(n)
    fast_on, tol = bool(sc["fast_on"]), float(sc["eps"])
    solved = bool(
        fast_on and not crossed and unconstrained_optimum_reference(P, qv, A, w_["lb"], l, w_["ub"], u, tol, x)
    )
    w_["x"], w_["crossed"], w_["solved"] = x, crossed, solved
    if solved:  # [C8]
        w_["tau"], w_["tau_cmd"], w_["saturated"] = inverse_dynamics_reference(M, x, h, tau_fb, tau_max, False)
    else:
        w_["tau"], w_["tau_cmd"], w_["saturated"] = 0.0, 0.0, False
