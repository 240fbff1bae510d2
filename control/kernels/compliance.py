"""The [C] executor's rows: task targets and the QP objective [C3-9], the torque rows [C10], the
inverse dynamics [C8] and the joint-limit dampers as acceleration bounds [C13-24].
"""

from __future__ import annotations

import numpy as np
from numba import njit

from control.kernels._linalg import _np_max
from control.kernels.geometry import log3_fused, log3_reference


@njit(cache=True)
def pose_task_target_fused(snap, target, pose, ddq_e):
    """Compiled `control.compliance_qp.PoseTask.rows_reference`'s right-hand side: b = ẍ° + ë* − J̇q̇
    (+ Γ J q̈_e when Γ ≠ 0) [C4, C9], ë* = −K_d ė − K_p e [C3], e = [p − p°; log(R R°ᵀ)]; from the
    snapshot's record `snap`, the task target's record `target` (`TaskTarget.record`) and the pose task's record `pose`
    (`cqp.pose_record_dtype`: K_p, K_d, Γ by name)."""
    s, ps = snap[0], pose[0]
    J, dq, dJ_dq, tcp_position, tcp_rotation = s.J, s.dq, s.dJ_dq, s.tcp_position_world, s.tcp_rotation_world
    t = target[0]
    target_position, target_rotation = t.position, t.rotation
    target_velocity, target_acceleration = t.velocity, t.acceleration
    kp, kd, gamma = ps.kp, ps.kd, ps.gamma
    n = J.shape[1]
    R = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            R[i, j] = (
                tcp_rotation[i, 0] * target_rotation[j, 0]
                + tcp_rotation[i, 1] * target_rotation[j, 1]
                + tcp_rotation[i, 2] * target_rotation[j, 2]
            )
    w = log3_fused(R)
    b = np.empty(6)
    for a in range(6):
        v = 0.0
        for j in range(n):
            v += J[a, j] * dq[j]
        e = tcp_position[a] - target_position[a] if a < 3 else w[a - 3]
        b[a] = target_acceleration[a] + (-kd[a] * (v - target_velocity[a]) - kp[a] * e) - dJ_dq[a]
    if ps.use_gamma:
        Jx = np.zeros(6)
        for a in range(6):
            for j in range(n):
                Jx[a] += J[a, j] * ddq_e[j]
        for a in range(6):
            s = 0.0
            for c in range(6):
                s += gamma[a, c] * Jx[c]
            b[a] += s
    return b


@njit(cache=True)
def add_task_rows_fused(P, q, J, b, w):
    """P += w JᵀJ and q −= w Jᵀb in place: one soft task's share of the [C9] objective
    ½ q̈ᵀP q̈ + qᵀq̈ (identity metric)."""
    m, n = J.shape
    for i in range(n):
        s = 0.0
        for k in range(m):
            s += J[k, i] * w * b[k]
        q[i] -= s
        for j in range(n):
            s = 0.0
            for k in range(m):
                s += J[k, i] * w * J[k, j]
            P[i, j] += s


@njit(cache=True)
def posture_target_fused(snap, q_ref, dq_ref, integral, posture, ddq_e):
    """Compiled `control.compliance_qp.PostureTask.rows_reference`'s right-hand side: q̈*₀ =
    −K_d (q̇ − q̇_ref) − K_p e − K_i ∫e, e = q − q_ref (the integral advanced in place when K_i ≠ 0),
    plus Γ₀ q̈_e when Γ₀ ≠ 0 [C7, C9]; q, q̇ from the snapshot's record `snap`, the gains from the
    posture task's record `posture` (`cqp.posture_record_dtype`: K_p, K_d, K_i, δt, Γ₀ by name)."""
    s, pc = snap[0], posture[0]
    q, dq = s.q, s.dq
    kp, kd, ki, use_ki, dt, gamma = pc.kp, pc.kd, pc.ki, pc.use_ki, pc.dt, pc.gamma
    n = q.shape[0]
    b = np.empty(n)
    for i in range(n):
        e = q[i] - q_ref[i]
        if use_ki:
            integral[i] += e * dt
        b[i] = -kd[i] * (dq[i] - dq_ref[i]) - kp[i] * e - ki[i] * integral[i]
    if pc.use_gamma:
        for i in range(n):
            s = 0.0
            for j in range(n):
                s += gamma[i, j] * ddq_e[j]
            b[i] += s
    return b


@njit(cache=True)
def torque_rows_fused(M, h, tau_fb, tau_max, A, lower, upper, limits_on, no_bound):
    """The [C10] rows of the acceleration QP in place: A[:n] = M, −τ_max − h + τ_fb ≤ M q̈ ≤ τ_max − h
    + τ_fb (±`no_bound` when the torque limits are off)."""
    n = M.shape[0]
    for i in range(n):
        for j in range(n):
            A[i, j] = M[i, j]
        if limits_on:
            lower[i] = -tau_max[i] - h[i] + tau_fb[i]
            upper[i] = tau_max[i] - h[i] + tau_fb[i]
        else:
            lower[i] = -no_bound
            upper[i] = no_bound


@njit(cache=True)
def inverse_dynamics_fused(M, ddq, h, tau_fb, tau_max, clip_desired):
    """τ_d = M q̈ + h − τ_fb [C8] (clipped to ±τ_max when `clip_desired`: [C10] kept hard for an
    approximate solution), the motors' command clip(τ_d, ±τ_max) and whether τ_d exceeds τ_max."""
    n = M.shape[0]
    tau = np.empty(n)
    cmd = np.empty(n)
    saturated = False
    for i in range(n):
        s = 0.0
        for j in range(n):
            s += M[i, j] * ddq[j]
        t = s + h[i] - tau_fb[i]
        if clip_desired:
            t = min(max(t, -tau_max[i]), tau_max[i])
        tau[i] = t
        cmd[i] = min(max(t, -tau_max[i]), tau_max[i])
        if abs(t) > tau_max[i] + 1e-9:
            saturated = True
    return tau, cmd, saturated


@njit(cache=True)
def acceleration_bounds_fused(q, dq, damper):
    """Compiled `control.dampers.JointLimitDamper.bounds_reference`: (lower, upper, crossed) at (q, q̇),
    the dampers read by name from their record `damper` (`cqp.damper_record_dtype`).

    Per joint and side (upper: e = q⁺ − q, ė = −q̇; lower: e = q − q⁻, ė = q̇): ë_p proposed [C24]
    −λė − k_p(e − d_s) or classic [C15, C17] −(ė − ė_d)/δt below d_i, ë_v = −g(ė + q̇⁺) [C18, C20],
    ë ≥ max(ë_p, ë_v) [C19] capped at `no_bound`; crossed rows go to their midpoint."""
    dc = damper[0]
    q_lower, q_upper, d_s, d_i, xi, dq_limit = dc.q_lower, dc.q_upper, dc.d_s, dc.d_i, dc.xi, dc.dq_limit
    kp, lam, velocity_gain, proposed = dc.kp, dc.lambda_, dc.velocity_gain, dc.proposed
    dt, no_bound, endless = dc.dt, dc.no_bound, dc.endless
    n = q.shape[0]
    lower = np.empty(n)
    upper = np.empty(n)
    crossed = False
    for i in range(n):
        for side in range(2):
            if side == 0:
                e, de = q_upper[i] - q[i], -dq[i]
            else:
                e, de = q[i] - q_lower[i], dq[i]
            if endless[i] != 0.0:
                e_p = -no_bound
            elif proposed:
                e_p = (-lam) * de - kp * (e - d_s[i])  # [C24]
            else:
                de_d = (-xi[i]) * (e - d_s[i]) / (d_i[i] - d_s[i])  # [C15]
                e_p = -(de - de_d) / dt if e < d_i[i] else -no_bound  # [C17]
            e_v = (-velocity_gain) * (de + dq_limit[i])  # [C18]/[C20]
            bound = _np_max(e_p, e_v)  # [C19]
            if bound > no_bound:
                bound = no_bound
            if side == 0:
                upper[i] = -bound
            else:
                lower[i] = bound
    for i in range(n):
        if lower[i] > upper[i]:
            crossed = True
    if crossed:
        for i in range(n):
            if lower[i] > upper[i]:
                mid = 0.5 * (lower[i] + upper[i])
                lower[i] = mid
                upper[i] = mid
    return lower, upper, crossed


def pose_task_target_reference(snap, target, pose, ddq_e) -> np.ndarray:
    """b = ẍ° + ë* − J̇q̇ (+ Γ J q̈_e when `use_gamma`) [C4, C9], ë* = −K_d ė − K_p e [C3],
    e = [p − p°; log(R R°ᵀ)], ė = J q̇ − ẋ°."""
    s, ps = snap[0], pose[0]
    J, dq = s["J"], s["dq"]
    tcp_position, tcp_rotation = s["tcp_position_world"], s["tcp_rotation_world"]
    t = target[0]
    kp, kd, gamma = ps["kp"], ps["kd"], ps["gamma"]
    e = np.concatenate([tcp_position - t["position"], log3_reference(tcp_rotation @ t["rotation"].T)])
    b = t["acceleration"] + (-kd * (J @ dq - t["velocity"]) - kp * e) - s["dJ_dq"]
    return b + gamma @ (J @ ddq_e) if ps["use_gamma"] else b


def add_task_rows_reference(P, q, J, b, w) -> None:
    """P += w JᵀJ, q −= w Jᵀb in place: a soft task's share of the [C9] objective."""
    P += w * (J.T @ J)
    q -= w * (J.T @ b)


def posture_target_reference(snap, q_ref, dq_ref, integral, posture, ddq_e) -> np.ndarray:
    """q̈*₀ = −K_d (q̇ − q̇_ref) − K_p e − K_i ∫e, e = q − q_ref (∫e advanced in place by e δt when
    `use_ki`), + Γ₀ q̈_e when `use_gamma` [C7, C9]."""
    s, pc = snap[0], posture[0]
    e = s["q"] - q_ref
    if pc["use_ki"]:
        integral += e * float(pc["dt"])
    b = -pc["kd"] * (s["dq"] - dq_ref) - pc["kp"] * e - pc["ki"] * integral
    return b + pc["gamma"] @ ddq_e if pc["use_gamma"] else b


def torque_rows_reference(M, h, tau_fb, tau_max, A, lower, upper, limits_on, no_bound) -> None:
    """A[:n] = M, −τ_max − h + τ_fb ≤ M q̈ ≤ τ_max − h + τ_fb [C10] (±`no_bound` without limits)."""
    n = M.shape[0]
    A[:n] = M
    lower[:n] = -tau_max - h + tau_fb if limits_on else -no_bound
    upper[:n] = tau_max - h + tau_fb if limits_on else no_bound


def inverse_dynamics_reference(M, ddq, h, tau_fb, tau_max, clip_desired) -> tuple:
    """(τ_d, clip(τ_d, ±τ_max), τ_d beyond τ_max): τ_d = M q̈ + h − τ_fb [C8], clipped first when
    `clip_desired`."""
    tau = M @ ddq + h - tau_fb
    if clip_desired:
        tau = np.clip(tau, -tau_max, tau_max)
    return tau, np.clip(tau, -tau_max, tau_max), bool(np.any(np.abs(tau) > tau_max + 1e-9))


def acceleration_bounds_reference(q, dq, damper) -> tuple:
    """(lower, upper, crossed) of the joint-limit dampers [C13-24] on both sides at once (upper
    side: e = q⁺ − q, ė = −q̇; lower: e = q − q⁻, ė = q̇): ë ≥ max(ë_p, ë_v) [C19] capped at
    `no_bound`, ë_p proposed [C24] or classic [C15, C17], ë_v [C18, C20]; crossed rows at their
    midpoint."""
    dc = damper[0]
    q_lower, q_upper, d_s, d_i, xi = dc["q_lower"], dc["q_upper"], dc["d_s"], dc["d_i"], dc["xi"]
    dq_limit = dc["dq_limit"]
    kp, lam, velocity_gain, dt = float(dc["kp"]), float(dc["lambda_"]), float(dc["velocity_gain"]), float(dc["dt"])
    no_bound, endless = float(dc["no_bound"]), dc["endless"] != 0.0
    e = np.concatenate([q_upper - q, q - q_lower])
    de = np.concatenate([-dq, dq])
    d_s2, d_i2, xi2 = np.tile(d_s, 2), np.tile(d_i, 2), np.tile(xi, 2)
    if dc["proposed"]:
        e_p = -lam * de - kp * (e - d_s2)  # [C24]
    else:
        de_d = -xi2 * (e - d_s2) / (d_i2 - d_s2)  # [C15]
        e_p = np.where(e < d_i2, -(de - de_d) / dt, -no_bound)  # [C17]
    e_p = np.where(np.tile(endless, 2), -no_bound, e_p)
    e_v = -velocity_gain * (de + np.tile(dq_limit, 2))  # [C18]/[C20]
    side = np.minimum(np.maximum(e_p, e_v), no_bound)  # [C19]
    n = q.shape[0]
    upper, lower = -side[:n], side[n:]
    crossed = bool(np.any(lower > upper))
    mid = 0.5 * (lower + upper)
    swap = lower > upper
    return np.where(swap, mid, lower), np.where(swap, mid, upper), crossed
