"""A serial chain of revolute joints: ∂J/∂q from J alone, J̇q̇, the chain's constants and the ∂M/∂q
contraction of the gradient [T24].
"""

from __future__ import annotations

import numpy as np
from numba import njit

from control.kernels._linalg import _cross, _mat3_mat, _mat3_vec


def kinematic_hessian_reference(J: np.ndarray) -> np.ndarray:
    """(n, 6, n) ∂J/∂q_k of a serial chain of revolute joints from its world-aligned J = [v; ω].

    Joint k turns everything distal to it about ω_k: for k < i, ∂ω_i = ω_k × ω_i and
    ∂v_i = ω_k × v_i; for k ≥ i only the end point moves (by v_k): ∂v_i = ω_i × v_k, ∂ω_i = 0.
    """
    n = J.shape[1]
    v, w = J[:3].T, J[3:].T
    H = np.zeros((n, 6, n))
    for k in range(n):
        for i in range(n):
            if k < i:
                H[k, :3, i] = np.cross(w[k], v[i])
                H[k, 3:, i] = np.cross(w[k], w[i])
            else:
                H[k, :3, i] = np.cross(w[i], v[k])
    return H


def tcp_bias_acceleration_reference(J: np.ndarray, dq: np.ndarray) -> np.ndarray:
    """J̇ q̇ (6,) of a serial revolute chain from J and q̇: Σ_k (∂J/∂q_k) q̇_k q̇, the classical
    acceleration [a; α] of the TCP at q̈ = 0, with ∂J/∂q_k from `kinematic_hessian_reference`."""
    return np.einsum("kai,k,i->a", kinematic_hessian_reference(J), dq, dq)


@njit(cache=True)
def tcp_bias_acceleration_into(J, dq, out):
    """Compiled `tcp_bias_acceleration_reference` in O(n) with running sums: with ω̄_i = Σ_{k<i} q̇_k ω_k
    and v̄_i = Σ_{k≥i} q̇_k v_k, J̇q̇ = Σ_i q̇_i [ω̄_i × v_i + ω_i × v̄_i ; ω̄_i × ω_i]."""
    n = J.shape[1]
    for r in range(6):
        out[r] = 0.0
    w0 = w1 = w2 = 0.0  # ω̄_i
    t0 = t1 = t2 = 0.0  # v̄_i, built from the far end
    for k in range(n):
        t0 += dq[k] * J[0, k]
        t1 += dq[k] * J[1, k]
        t2 += dq[k] * J[2, k]
    for i in range(n):
        d = dq[i]
        v0, v1, v2 = J[0, i], J[1, i], J[2, i]
        o0, o1, o2 = J[3, i], J[4, i], J[5, i]
        out[0] += d * ((w1 * v2 - w2 * v1) + (o1 * t2 - o2 * t1))
        out[1] += d * ((w2 * v0 - w0 * v2) + (o2 * t0 - o0 * t2))
        out[2] += d * ((w0 * v1 - w1 * v0) + (o0 * t1 - o1 * t0))
        out[3] += d * (w1 * o2 - w2 * o1)
        out[4] += d * (w2 * o0 - w0 * o2)
        out[5] += d * (w0 * o1 - w1 * o0)
        w0, w1, w2 = w0 + d * o0, w1 + d * o1, w2 + d * o2
        t0, t1, t2 = t0 - d * v0, t1 - d * v1, t2 - d * v2


def chain_constants(model) -> tuple:
    """(placement rotations (n,3,3), placement translations (n,3), joint axes (n,3), masses (n,),
    levers (n,3), rotational inertias about the COM (n,3,3)) of a serial chain of revolute joints
    (a Pinocchio model with `RobotModel.revolute_chain`): what `inertia_contraction_fused` needs."""
    n = model.njoints - 1
    R = np.empty((n, 3, 3))
    p = np.empty((n, 3))
    axes = np.zeros((n, 3))
    mass = np.empty(n)
    lever = np.empty((n, 3))
    inertia = np.empty((n, 3, 3))
    for i in range(n):
        placement, joint, body = model.jointPlacements[i + 1], model.joints[i + 1], model.inertias[i + 1]
        R[i], p[i] = placement.rotation, placement.translation
        kind = joint.shortname()
        if kind in ("JointModelRX", "JointModelRY", "JointModelRZ"):
            axes[i, "XYZ".index(kind[-1])] = 1.0
        else:  # JointModelRevoluteUnaligned
            axes[i] = np.asarray(joint.extract().axis, dtype=float)
        mass[i], lever[i], inertia[i] = body.mass, body.lever, body.inertia
    return R, p, axes, mass, lever, inertia


@njit(cache=True)
def inertia_contraction_fused(q, R_place, p_place, axes, mass, lever, inertia, a, b):
    """Compiled aᵀ ∂M/∂q_k b for all k (`inertia_contraction_reference`; tested also against
    Pinocchio's RNEA derivatives, `RobotModel.mass_matrix_derivative_times`), from the chain alone.

    With S_i the joint axes as world twists [v; ω], V_j(x) = Σ_{i≤j} S_i x_i and I_j the world
    inertia of body j: aᵀMb = Σ_j V_j(a)ᵀ I_j V_j(b) (+ constant armature). Joint k moves the
    bodies j ≥ k: ∂V_j = S_k × (V_j − V_k) and ∂I_j = S_k×* I_j − I_j S_k×, which sum to
    aᵀ ∂M_k b = −[(S_k × V_k(a))·H_k(b) + (S_k × V_k(b))·H_k(a)], H_k(x) = Σ_{j≥k} I_j V_j(x)
    (× the spatial motion cross product, · the motion-force pairing).
    """
    n = q.shape[0]
    Rw = np.eye(3)
    tmp = np.empty((3, 3))
    Rj = np.empty((3, 3))
    pw = np.zeros(3)
    v3 = np.empty(3)
    Sv = np.empty((n, 3))  # joint twists: linear part at the world origin p × ω
    Sw = np.empty((n, 3))  # and the axis ω, world
    com = np.empty((n, 3))
    Ic = np.empty((n, 3, 3))
    for i in range(n):  # forward kinematics: oMi = oM(i-1) · placement_i · exp(axis_i q_i)
        _mat3_vec(Rw, p_place[i], v3)
        for r in range(3):
            pw[r] += v3[r]
        _mat3_mat(Rw, R_place[i], tmp)
        x, y, z = axes[i, 0], axes[i, 1], axes[i, 2]
        c, s = np.cos(q[i]), np.sin(q[i])
        t = 1.0 - c
        Rj[0, 0], Rj[0, 1], Rj[0, 2] = c + x * x * t, x * y * t - z * s, x * z * t + y * s
        Rj[1, 0], Rj[1, 1], Rj[1, 2] = y * x * t + z * s, c + y * y * t, y * z * t - x * s
        Rj[2, 0], Rj[2, 1], Rj[2, 2] = z * x * t - y * s, z * y * t + x * s, c + z * z * t
        _mat3_mat(tmp, Rj, Rw)
        _mat3_vec(Rw, axes[i], Sw[i])
        _cross(pw, Sw[i], Sv[i])
        _mat3_vec(Rw, lever[i], v3)
        for r in range(3):
            com[i, r] = pw[r] + v3[r]
        _mat3_mat(Rw, inertia[i], tmp)
        for r in range(3):
            for cc in range(3):
                Ic[i, r, cc] = tmp[r, 0] * Rw[cc, 0] + tmp[r, 1] * Rw[cc, 1] + tmp[r, 2] * Rw[cc, 2]
    V = np.zeros((2, n, 6))  # V_j(a), V_j(b) as [v; ω]
    for side in range(2):
        x = a if side == 0 else b
        for j in range(n):
            for r in range(3):
                prev_v = V[side, j - 1, r] if j > 0 else 0.0
                prev_w = V[side, j - 1, 3 + r] if j > 0 else 0.0
                V[side, j, r] = prev_v + Sv[j, r] * x[j]
                V[side, j, 3 + r] = prev_w + Sw[j, r] * x[j]
    H = np.zeros((2, 6))  # running Σ_{j≥k} I_j V_j as [p; L]
    lin = np.empty(3)
    ang = np.empty(3)
    out = np.empty(n)
    for k in range(n - 1, -1, -1):
        for side in range(2):
            v, w = V[side, k, :3], V[side, k, 3:]
            _cross(w, com[k], v3)
            for r in range(3):
                lin[r] = mass[k] * (v[r] + v3[r])  # p = m (v + ω × c)
            _cross(com[k], lin, v3)
            _mat3_vec(Ic[k], w, ang)
            for r in range(3):
                H[side, r] += lin[r]
                H[side, 3 + r] += v3[r] + ang[r]  # L = c × p + I_c ω
        total = 0.0
        for side in range(2):  # (S_k × V_k(x))·H_k(other)
            v, w = V[side, k, :3], V[side, k, 3:]
            sv, sw = Sv[k], Sw[k]
            other = 1 - side
            cv0 = sw[1] * v[2] - sw[2] * v[1] + sv[1] * w[2] - sv[2] * w[1]
            cv1 = sw[2] * v[0] - sw[0] * v[2] + sv[2] * w[0] - sv[0] * w[2]
            cv2 = sw[0] * v[1] - sw[1] * v[0] + sv[0] * w[1] - sv[1] * w[0]
            cw0 = sw[1] * w[2] - sw[2] * w[1]
            cw1 = sw[2] * w[0] - sw[0] * w[2]
            cw2 = sw[0] * w[1] - sw[1] * w[0]
            h = H[other]
            total += cv0 * h[0] + cv1 * h[1] + cv2 * h[2] + cw0 * h[3] + cw1 * h[4] + cw2 * h[5]
        out[k] = -total
    return out


def pack_chain(chain: tuple) -> np.ndarray:
    """`chain_constants` as one (n, 28) array (rotation 9, translation 3, axis 3, mass 1, lever 3,
    inertia 9 per joint) for `projection_law_fused`."""
    R, p, axes, mass, lever, inertia = chain
    n = len(mass)
    return np.hstack([R.reshape(n, 9), p, axes, mass[:, None], lever, inertia.reshape(n, 9)])


@njit(cache=True)
def unpack_chain_fused(packed):
    n = packed.shape[0]
    R = np.ascontiguousarray(packed[:, 0:9]).reshape((n, 3, 3))
    inertia = np.ascontiguousarray(packed[:, 19:28]).reshape((n, 3, 3))
    return R, packed[:, 9:12], packed[:, 12:15], packed[:, 15], packed[:, 16:19], inertia


def tcp_bias_acceleration_into_reference(J: np.ndarray, dq: np.ndarray, out: np.ndarray) -> None:
    """`tcp_bias_acceleration_into` by `tcp_bias_acceleration_reference` (into `out`)."""
    out[:] = tcp_bias_acceleration_reference(J, dq)


def unpack_chain_reference(packed: np.ndarray) -> tuple:
    """`pack_chain`'s inverse: the six arrays of `chain_constants` (`unpack_chain_fused` compiled)."""
    n = packed.shape[0]
    return (
        packed[:, 0:9].reshape(n, 3, 3), packed[:, 9:12], packed[:, 12:15], packed[:, 15], packed[:, 16:19],
        packed[:, 19:28].reshape(n, 3, 3),
    )  # fmt: skip


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def _motion_cross(S: np.ndarray) -> np.ndarray:
    """The 6×6 spatial motion cross product S× for twists [v; ω]."""
    X = np.zeros((6, 6))
    X[:3, :3], X[:3, 3:], X[3:, 3:] = _skew(S[3:]), _skew(S[:3]), _skew(S[3:])
    return X


def inertia_contraction_reference(q, R_place, p_place, axes, mass, lever, inertia, a, b) -> np.ndarray:
    """term_M[k] = aᵀ ∂M/∂q_k b from the chain's constants in 6×6 spatial algebra (world frame, twists
    [v; ω] at the origin): M = Σ_j J_jᵀ I_j J_j with J_j = [S_0 … S_j 0 …], so aᵀMb = Σ_j V_j(a)ᵀ I_j
    V_j(b), V_j(x) = Σ_{i≤j} S_i x_i; joint k turns the bodies j ≥ k: ∂V_j = S_k× (V_j − V_k) and
    ∂I_j = −(S_k×)ᵀ I_j − I_j S_k×. The product rule summed term by term (no simplification: the
    compiled `inertia_contraction_fused` uses the simplified sum)."""
    n = q.shape[0]
    R, p = np.eye(3), np.zeros(3)
    S, inertia6 = np.zeros((n, 6)), np.zeros((n, 6, 6))
    for i in range(n):  # oMi = oM(i-1) · placement_i · exp(axis_i q_i)
        p = p + R @ p_place[i]
        K = _skew(axes[i])
        R = R @ R_place[i] @ (np.eye(3) + np.sin(q[i]) * K + (1.0 - np.cos(q[i])) * (K @ K))
        w = R @ axes[i]
        S[i, :3], S[i, 3:] = np.cross(p, w), w
        c = p + R @ lever[i]
        C = _skew(c)
        Ic = R @ inertia[i] @ R.T
        inertia6[i] = np.block([[mass[i] * np.eye(3), -mass[i] * C], [mass[i] * C, Ic - mass[i] * C @ C]])
    Va, Vb = np.cumsum(S * a[:, None], axis=0), np.cumsum(S * b[:, None], axis=0)
    out = np.zeros(n)
    for k in range(n):
        X = _motion_cross(S[k])
        for j in range(k, n):
            dVa, dVb = X @ (Va[j] - Va[k]), X @ (Vb[j] - Vb[k])
            dI = -X.T @ inertia6[j] - inertia6[j] @ X
            out[k] += dVa @ inertia6[j] @ Vb[j] + Va[j] @ dI @ Vb[j] + Va[j] @ inertia6[j] @ dVb
    return out
