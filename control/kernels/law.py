"""The [T] law around the nullspace QP [T7, T9, T11-14, T17, T18, T22-27]: the task wrench, the joint
torque, the velocity dampers' bounds, and the whole law (and step) in one compiled call.
"""

from __future__ import annotations

import functools

import numpy as np
from numba import njit

from control.gains import CONTROL_PERIOD_S, MotionForceGains, NullspaceGains
from control.kernels.chain import (
    inertia_contraction_fused,
    inertia_contraction_reference,
    kinematic_hessian_reference,
    unpack_chain_fused,
    unpack_chain_reference,
)
from control.kernels.coupling import (
    coupling_fused,
    coupling_reference,
    coupling_weights_reference,
)
from control.kernels.geometry import log3_fused, log3_reference
from control.kernels.gradients import gradient_contraction_fused, gradient_contraction_reference
from control.kernels.line_qp import nullspace_line_qp_fused, nullspace_line_qp_into_reference
from control.kernels.records import fill_record, record_dtype


def task_wrench_reference(snap, target, e, A, P_d, P_f, F_e, F_hat, u_f_extra, law) -> tuple:
    """(F [T7] before μx, F − Λx J̇q̇, coupled acceleration P_f F_m^e) of the [T] executor.

    `snap`: the snapshot's record (J, q̇, Λx, J̇q̇ by name); `target`: the task target's record (`TaskTarget.record`);
    e: pose error [p° − p; log(R° Rᵀ)]; A, P_d, P_f: the coupling blocks of `coupling_reference`;
    `u_f_extra`: the integral term K_f^i ∫e_f (or zeros); `law`: the law's record (the axes, K_m^p,
    2ζ√K_m^p, K_f^p, K_f^d and `shaping` by name).
    """
    s, c = snap[0], law[0]
    J, dq, Lambda, dJ_dq = s["J"], s["dq"], s["Lambda"], s["dJ_dq"]
    n_m = int(c["n_m"])
    m_idx, f_idx = c["perm"][:n_m], c["perm"][n_m:]
    kp_m, kd_scale_m = c["kp_m"][:n_m], c["kd_scale_m"][:n_m]
    target_velocity, target_acceleration = target[0]["velocity"], target[0]["acceleration"]
    v = J @ dq
    de = target_velocity - v
    kd_m = kd_scale_m * np.sqrt(A.diagonal())  # [T11] K_m^d = 2ζ√(K_m^p A_ii)
    u_m = A @ target_acceleration[m_idx] + kd_m * de[m_idx] + kp_m * e[m_idx]  # [T11]
    u_f = -F_hat + float(c["force_kp"]) * (F_e[f_idx] - F_hat) - float(c["force_kd"]) * v[f_idx] + u_f_extra  # [T12]
    F = np.empty(6)
    F[m_idx] = u_m
    F[f_idx] = u_f + P_d @ (u_m + F_e[m_idx]) if c["shaping"] else u_f  # [T7] with Λ̂x [T9]
    return F, F - Lambda @ dJ_dq, float(P_f[0] @ F_e[m_idx])


@njit(cache=True)
def task_wrench_fused(snap, target, e, A, P_d, P_f, F_e, F_hat, u_f_extra, law):
    """Compiled `task_wrench_reference` (same outputs, same order)."""
    s, c = snap[0], law[0]
    J, dq, Lambda, dJ_dq = s.J, s.dq, s.Lambda, s.dJ_dq
    target_velocity, target_acceleration = target[0].velocity, target[0].acceleration
    n_m = c.n_m
    perm = c.perm
    m_idx, f_idx = perm[:n_m], perm[n_m:]
    kp_m, kd_scale_m = c.kp_m, c.kd_scale_m
    force_kp, force_kd = c.force_kp, c.force_kd
    n = J.shape[1]
    v = np.zeros(6)
    for a in range(6):
        s_ = 0.0
        for j in range(n):
            s_ += J[a, j] * dq[j]
        v[a] = s_
    nm = m_idx.shape[0]
    nf = f_idx.shape[0]
    u_m = np.empty(nm)
    for i in range(nm):
        s_ = 0.0
        for j in range(nm):
            s_ += A[i, j] * target_acceleration[m_idx[j]]
        mi = m_idx[i]
        u_m[i] = s_ + kd_scale_m[i] * np.sqrt(A[i, i]) * (target_velocity[mi] - v[mi]) + kp_m[i] * e[mi]
    F = np.empty(6)
    for i in range(nm):
        F[m_idx[i]] = u_m[i]
    coupled = 0.0
    for j in range(nm):
        coupled += P_f[0, j] * F_e[m_idx[j]]
    for r in range(nf):
        fr = f_idx[r]
        u_f = -F_hat[r] + force_kp * (F_e[fr] - F_hat[r]) - force_kd * v[fr] + u_f_extra[r]
        if c.shaping:
            for j in range(nm):
                u_f += P_d[r, j] * (u_m[j] + F_e[m_idx[j]])
        F[fr] = u_f
    F_mu = F.copy()
    for a in range(6):
        s_ = 0.0
        for b in range(6):
            s_ += Lambda[a, b] * dJ_dq[b]
        F_mu[a] -= s_
    return F, F_mu, coupled


def joint_torque_reference(
    J: np.ndarray,
    F: np.ndarray,
    N: np.ndarray,
    Lambda_n: np.ndarray,
    kn: np.ndarray,
    dq_goal: np.ndarray,
    dq: np.ndarray,
    h: np.ndarray,
) -> np.ndarray:
    """τ = Jᵀ F + Nᵀ F_n + h [T14] with F_n = Λn K_n^d (q̂̇n − N q̇) [T13] (μn = h)."""
    F_n = Lambda_n @ (kn * (dq_goal - N @ dq))  # [T13]
    return J.T @ F + N.T @ F_n + h  # [T14]


@njit(cache=True)
def joint_torque_fused(J, F, N, Lambda_n, kn, dq_goal, dq, h):
    """Compiled `joint_torque_reference`."""
    n = J.shape[1]
    y = np.empty(n)
    for i in range(n):
        s = 0.0
        for j in range(n):
            s += N[i, j] * dq[j]
        y[i] = kn[i] * (dq_goal[i] - s)
    F_n = np.zeros(n)
    for i in range(n):
        s = 0.0
        for j in range(n):
            s += Lambda_n[i, j] * y[j]
        F_n[i] = s
    tau = h.copy()
    for i in range(n):
        s = 0.0
        for a in range(6):
            s += J[a, i] * F[a]
        for j in range(n):
            s += N[j, i] * F_n[j]
        tau[i] += s
    return tau


def damper_bounds_reference(q, q_lower, q_upper, dq_limit, endless, influence, safety, speed) -> tuple:
    """Velocity bounds (l, u) [T17]: ±dq_limit tightened by first-order dampers inside the influence
    distance d_i of a position limit, to ∓ξ (d − d_s)/(d_i − d_s) (never on endless joints)."""
    slope = speed / (influence - safety)
    d_low, d_up = q - q_lower, q_upper - q
    lo = np.where((d_low < influence) & ~endless, -slope * (d_low - safety), -np.inf)
    up = np.where((d_up < influence) & ~endless, slope * (d_up - safety), np.inf)
    return np.maximum(-dq_limit, lo), np.minimum(dq_limit, up)


@njit(cache=True)
def damper_bounds_fused(q, q_lower, q_upper, dq_limit, endless, influence, safety, speed):
    """Compiled `damper_bounds_reference` (`control.nullspace.damper_bounds`): (l, u) = ±dq_limit
    tightened near the position limits to −ξ (d − d_s)/(d_i − d_s), never on endless joints."""
    n = q.shape[0]
    slope = speed / (influence - safety)
    lower = np.empty(n)
    upper = np.empty(n)
    for i in range(n):
        lo = -dq_limit[i]
        up = dq_limit[i]
        if not endless[i]:
            d_low = q[i] - q_lower[i]
            d_up = q_upper[i] - q[i]
            if d_low < influence:
                lo = max(lo, -slope * (d_low - safety))
            if d_up < influence:
                up = min(up, slope * (d_up - safety))
        lower[i] = lo
        upper[i] = up
    return lower, upper


OBJECTIVE_J = 3  # `projection_law_fused`'s code for W_j [T18] (0/1/2: f/a/d, `OBJECTIVE_CODES`)


LAW_GROUPS = (MotionForceGains, NullspaceGains)  # the groups whose fields the [T] law's record carries


@functools.cache
def law_record_dtype(n: int) -> np.dtype:
    """The record `projection_law_fused` reads (`control.kernels.records`): every numeric field of
    `MotionForceGains` and `NullspaceGains` by its name, and what the executor derives from them and
    the arm: the objective's code (0/1/2 f/a/d, `OBJECTIVE_J`) and its k0, the task axes (n_m motion
    axes first in `perm`), K_m^p and 2ζ√K_m^p of the motion axes (the first n_m entries), the joint
    limits q⁻, q⁺, the damper's speed limit, which joints are endless, the nullspace damping K_n and
    whether the nullspace QP's 7-joint line form applies (`closed_form`)."""
    return record_dtype(
        LAW_GROUPS,
        (
            ("objective", np.int64),
            ("k0", np.float64),
            ("n_m", np.int64),
            ("perm", np.int64, (6,)),
            ("task_scale", np.float64, (6,)),  # `control.coupling.task_scale` of the W's units
            ("kp_m", np.float64, (6,)),
            ("kd_scale_m", np.float64, (6,)),
            ("q_lower", np.float64, (n,)),
            ("q_upper", np.float64, (n,)),
            ("dq_limit", np.float64, (n,)),
            ("endless", np.float64, (n,)),  # 1.0: endless (numba has no boolean subarrays)
            ("kn", np.float64, (n,)),
            ("closed_form", np.bool_),
        ),
    )


def law_record(gains: MotionForceGains, nullspace: NullspaceGains, **derived) -> np.ndarray:
    """The one-element record of `law_record_dtype(n)` (n from `q_lower`): the groups' fields by
    name, and the derived fields given by name (all of them: ValueError naming one missing)."""
    n = len(derived["q_lower"]) if "q_lower" in derived else 0
    return fill_record(law_record_dtype(n), (gains, nullspace), **derived)


@functools.cache
def projection_step_dtype(n: int) -> np.dtype:
    """The record of one [T] step's work (`control.motion_force.ProjectionExecutor`), read and written
    by `projection_law_fused` and `projection_step_fused` by field name: the step's F/T wrench at the
    TCP `F_e` (6,) and W_j's posture `q_d` (n,); the state: the force integral ∫e_f
    `force_integral` (its first n_f entries; [T12]); the QP's data: k0 ∇W `grad`, the velocity bounds
    `lower`, `upper` (n,) [T15-17]; the law's values: F [T7] `F`, F − Λx J̇q̇ `F_mu` (6,), W of the
    objective `W` and `W_f`, `W_a`, `W_d` [T22], P_f F_m^e `coupled`, F̂_f[0] − F_f^e[0]
    `force_error`; and the step's: the nullspace velocity `x`, the torque `tau` (n,) and the number of
    active bounds `active` (0 or 1; −1: the QP was not solved in the call)."""
    vec = (np.float64, (n,))
    scalars = tuple((name, np.float64) for name in ("W", "W_f", "W_a", "W_d", "coupled", "force_error"))
    return record_dtype(
        (),
        (
            ("F_e", np.float64, (6,)), ("q_d", *vec), ("force_integral", np.float64, (6,)), ("grad", *vec),
            ("lower", *vec), ("upper", *vec), ("F", np.float64, (6,)), ("F_mu", np.float64, (6,)), *scalars,
            ("x", *vec), ("tau", *vec), ("active", np.int64),
        ),
    )  # fmt: skip


@njit(cache=True)
def projection_law_fused(snap, target, law, chain, step):
    """Everything the [T] executor computes before its nullspace QP, in one compiled call of the
    kernels above (the same arithmetic as calling them one by one, as the executor's reference
    path `ProjectionExecutor._step_reference` does):

    the pose error e = [p° − p; log(R° Rᵀ)] (`log3_fused`); the force integral ∫e_f clamped to
    ±limit/K_f^i (anti-windup, when K_f^i > 0) [T12]; `coupling_fused` (A, B, D, P, W [T6, T9,
    T22]); the QP's linear term k0 ∇W with ∇W from `gradient_contraction_fused` and
    `inertia_contraction_fused` [T24-27] (objective 0/1/2: f/a/d), or ∇W_j = q − q_d [T18]
    (objective `OBJECTIVE_J`); `task_wrench_fused` [T7, T11-12]; `damper_bounds_fused` [T17].
    `snap` is the snapshot's record (`Dynamics.record`), `target` the task target's
    (`TaskTarget.record`), `law` a `law_record(…)` (the gains), all read by field name; `chain` is
    `pack_chain(chain_constants(model))` (a serial revolute chain); `step` a `projection_step_dtype`
    record: the call reads its `F_e`, `q_d` and `force_integral` and writes the new force integral,
    the QP's `grad` (k0 ∇W), `lower` and `upper`, and the law's `F`, `F_mu`, `W`, `W_f`, `W_a`, `W_d`,
    `coupled` and `force_error`.
    """
    s, st = snap[0], step[0]
    F_e, q_d = st.F_e, st.q_d
    q, J, M_inv, Lambda, Lambda_inv = s.q, s.J, s.M_inv, s.Lambda, s.Lambda_inv
    tcp_position, tcp_rotation = s.tcp_position_world, s.tcp_rotation_world
    t = target[0]
    target_position, target_rotation, target_wrench = t.position, t.rotation, t.wrench
    c = law[0]
    objective, n_m, k0 = c.objective, c.n_m, c.k0
    perm = c.perm
    f_idx = perm[n_m:]
    force_ki, force_integral_limit = c.force_ki, c.force_integral_limit_n
    e = np.empty(6)  # [px py pz rx ry rz], world-aligned
    R_err = np.empty((3, 3))
    for i in range(3):
        e[i] = target_position[i] - tcp_position[i]
        for j in range(3):
            R_err[i, j] = (
                target_rotation[i, 0] * tcp_rotation[j, 0]
                + target_rotation[i, 1] * tcp_rotation[j, 1]
                + target_rotation[i, 2] * tcp_rotation[j, 2]
            )
    e[3:] = log3_fused(R_err)
    nf = f_idx.shape[0]
    F_hat = np.empty(nf)
    integral = st.force_integral
    u_f_extra = np.zeros(nf)
    for r in range(nf):
        F_hat[r] = target_wrench[f_idx[r]]
        if force_ki > 0:
            lim = force_integral_limit / force_ki
            integral[r] = min(max(integral[r] + (F_e[f_idx[r]] - F_hat[r]) * CONTROL_PERIOD_S, -lim), lim)
            u_f_extra[r] = force_ki * integral[r]
    A, _B, _D, A_inv, _D_hat, P_f, P_a, P_d, W_f, W_a, W_d = coupling_fused(
        Lambda, Lambda_inv, perm, n_m, not s.near_singular, c.task_scale
    )
    n = q.shape[0]
    grad = np.empty(n)
    if objective == OBJECTIVE_J:  # [T18] W_j = ½‖q − q_d‖²
        W = 0.0
        for i in range(n):
            grad[i] = q[i] - q_d[i]
            W += grad[i] * grad[i]
        W *= 0.5
    else:  # [T24-27] as `control.coupling.coupling_gradient_direct`
        P = P_f if objective == 0 else (P_a if objective == 1 else P_d)
        weight = np.empty((6 - n_m, n_m))  # `coupling_weights_fused`'s one for this objective
        for r in range(6 - n_m):
            for col in range(n_m):
                s_f = c.task_scale[perm[n_m + r]]
                s_m = c.task_scale[perm[col]]
                weight[r, col] = (
                    1.0 / (s_f * s_m) ** 2
                    if objective == 0
                    else ((s_f * s_m) ** 2 if objective == 1 else (s_f / s_m) ** 2)
                )
        term_J, a_, b_ = gradient_contraction_fused(
            objective, J, M_inv, Lambda, Lambda_inv, P, A_inv, perm, n_m, weight
        )
        R_place, p_place, joint_axes, mass, lever, inertia = unpack_chain_fused(chain)
        term_M = np.zeros(n)
        for col in range(a_.shape[1]):
            term_M += inertia_contraction_fused(
                q, R_place, p_place, joint_axes, mass, lever, inertia, a_[:, col], b_[:, col]
            )
        W = W_f if objective == 0 else (W_a if objective == 1 else W_d)
        for i in range(n):
            grad[i] = -2.0 * (term_J[i] - term_M[i])
    for i in range(n):
        grad[i] = k0 * grad[i]
    F, F_mu, coupled = task_wrench_fused(snap, target, e, A, P_d, P_f, F_e, F_hat, u_f_extra, law)
    lower, upper = damper_bounds_fused(
        q, c.q_lower, c.q_upper, c.dq_limit, c.endless != 0.0, c.damper_influence, c.damper_safety, c.damper_speed
    )
    st.F[:] = F
    st.F_mu[:] = F_mu
    st.grad[:] = grad
    st.lower[:] = lower
    st.upper[:] = upper
    st.W, st.W_f, st.W_a, st.W_d = W, W_f, W_a, W_d
    st.coupled, st.force_error = coupled, F_hat[0] - F_e[f_idx[0]]


@njit(cache=True)
def projection_step_fused(snap, target, law, chain, step):
    """`projection_law_fused`, then, when the law record's `closed_form` holds (the nullspace QP's
    7-joint line form applies), the QP [T15-17] by `nullspace_line_qp_fused` into the step record's
    `x` and the torque [T13-14] by `joint_torque_fused` into its `tau`: the whole [T] step in one
    call. Writes the number of active bounds (0 or 1) into `active`, or −1 when the QP was not solved
    here (`x`, `tau` untouched: the caller solves it with its backend)."""
    projection_law_fused(snap, target, law, chain, step)
    s, st, c = snap[0], step[0], law[0]
    active = -1
    if c.closed_form:
        active = nullspace_line_qp_fused(s.J, st.grad, st.lower, st.upper, st.x)
        if active >= 0:
            st.tau[:] = joint_torque_fused(s.J, st.F_mu, s.N, s.Lambda_n, c.kn, st.x, s.dq, s.h)
    st.active = active


def projection_law_reference(snap, target, law, chain, step) -> None:
    """`projection_law_fused` by the references one by one: e = [p° − p; log(R° Rᵀ)], the clamped
    force integral [T12], `coupling_reference` [T6, T9, T22], k0 ∇W from
    `gradient_contraction_reference` (∂J from `kinematic_hessian_reference`) and
    `inertia_contraction_reference` [T24-27] or ∇W_j = q − q_d [T18], `task_wrench_reference`
    [T7, T11-12] and `damper_bounds_reference` [T17]; the same fields written, the same values."""
    s, st = snap[0], step[0]
    F_e, q_d = st["F_e"], st["q_d"]
    q, J, M_inv, Lambda, Lambda_inv = s["q"], s["J"], s["M_inv"], s["Lambda"], s["Lambda_inv"]
    exact, tcp_position, tcp_rotation = not s["near_singular"], s["tcp_position_world"], s["tcp_rotation_world"]
    t = target[0]
    target_position, target_rotation, target_wrench = t["position"], t["rotation"], t["wrench"]
    c = law[0]
    objective, n_m, k0 = int(c["objective"]), int(c["n_m"]), float(c["k0"])
    perm = c["perm"]
    f_idx = perm[n_m:]
    force_ki, force_integral_limit = float(c["force_ki"]), float(c["force_integral_limit_n"])
    e = np.concatenate([target_position - tcp_position, log3_reference(target_rotation @ tcp_rotation.T)])
    F_hat = target_wrench[f_idx]
    integral, u_f_extra = st["force_integral"][: len(f_idx)], np.zeros(len(f_idx))
    if force_ki > 0:  # [T12] anti-windup: |K_f^i ∫e_f| ≤ limit
        lim = force_integral_limit / force_ki
        integral[:] = np.clip(integral + (F_e[f_idx] - F_hat) * CONTROL_PERIOD_S, -lim, lim)
        u_f_extra = force_ki * integral
    scale = c["task_scale"]
    A, _B, _D, A_inv, _D_hat, P_f, P_a, P_d, W_f, W_a, W_d = coupling_reference(
        Lambda, Lambda_inv, perm, n_m, exact, scale
    )
    if objective == OBJECTIVE_J:  # [T18] W_j = ½‖q − q_d‖²
        grad = q - q_d
        W = 0.5 * float(grad @ grad)
    else:  # [T24-27]
        P = (P_f, P_a, P_d)[objective]
        name = "fad"[objective]
        term_J, a_, b_ = gradient_contraction_reference(
            name, J, kinematic_hessian_reference(J), M_inv, Lambda, Lambda_inv, P, A_inv, perm, n_m,
            coupling_weights_reference(scale, perm, n_m)[objective],
        )  # fmt: skip
        R_place, p_place, joint_axes, mass, lever, inertia = unpack_chain_reference(chain)
        term_M = np.zeros(q.shape[0])
        for k in range(a_.shape[1]):
            term_M += inertia_contraction_reference(
                q, R_place, p_place, joint_axes, mass, lever, inertia, a_[:, k], b_[:, k]
            )
        W = (W_f, W_a, W_d)[objective]
        grad = -2.0 * (term_J - term_M)
    st["F"], st["F_mu"], st["coupled"] = task_wrench_reference(snap, target, e, A, P_d, P_f, F_e, F_hat, u_f_extra, law)
    st["grad"] = k0 * grad
    st["lower"], st["upper"] = damper_bounds_reference(
        q, c["q_lower"], c["q_upper"], c["dq_limit"], c["endless"] != 0.0,
        float(c["damper_influence"]), float(c["damper_safety"]), float(c["damper_speed"]),
    )  # fmt: skip
    st["W"], st["W_f"], st["W_a"], st["W_d"] = W, W_f, W_a, W_d
    st["force_error"] = F_hat[0] - F_e[f_idx[0]]


def projection_step_reference(snap, target, law, chain, step) -> None:
    """`projection_step_fused` by `projection_law_reference`, `nullspace_line_qp_into_reference`
    [T15-17] and `joint_torque_reference` [T13-14]."""
    projection_law_reference(snap, target, law, chain, step)
    s, st, c = snap[0], step[0], law[0]
    active = -1
    if c["closed_form"]:
        active = nullspace_line_qp_into_reference(s["J"], st["grad"], st["lower"], st["upper"], st["x"])
        if active >= 0:
            st["tau"] = joint_torque_reference(
                s["J"], st["F_mu"], s["N"], s["Lambda_n"], c["kn"], st["x"], s["dq"], s["h"]
            )
    st["active"] = active
