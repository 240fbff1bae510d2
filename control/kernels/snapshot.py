"""The dynamics snapshot [T2-5]: from M (upper triangle, as CRBA fills it) and the TCP Jacobian J:
M⁻¹, Λx⁻¹, Λx [T3] (damped near singularities), J̄ [T2], N [T4], Λn [T5].
"""

from __future__ import annotations

import functools

import numpy as np
from numba import njit

from control.kernels._linalg import (
    _cholesky_into,
    _matmul_bt_into,
    _matmul_into,
    _spd_inverse_into,
    _sym_from_eig,
    _symmetrise,
)
from control.kernels.chain import tcp_bias_acceleration_into, tcp_bias_acceleration_reference
from control.kernels.records import record_dtype


def snapshot_reference(M_upper: np.ndarray, J: np.ndarray, singular_eig: float) -> tuple:
    """(M, M⁻¹, Λx⁻¹, Λx, J̄, N, Λn, min eig Λx⁻¹, near_singular) from CRBA's upper triangle and J."""
    n = J.shape[1]
    M = np.triu(M_upper) + np.triu(M_upper, 1).T  # CRBA fills the upper triangle only
    M_inv = np.linalg.inv(M)
    M_inv = 0.5 * (M_inv + M_inv.T)
    X = M_inv @ J.T  # (n, 6)
    Lambda_inv = J @ X  # J M⁻¹ Jᵀ
    Lambda_inv = 0.5 * (Lambda_inv + Lambda_inv.T)
    w, V = np.linalg.eigh(Lambda_inv)
    min_eig = float(w[0])
    near_singular = min_eig < singular_eig
    if near_singular:  # damped inverse w / (w² + ρ²): bounded as w → 0
        Lambda = (V * (w / (w * w + singular_eig**2))) @ V.T
    else:
        Lambda = (V * (1.0 / w)) @ V.T  # [T3] Λx = (J M⁻¹ Jᵀ)⁻¹
    J_bar = X @ Lambda  # [T2] J̄ = M⁻¹ Jᵀ Λx
    N = np.eye(n) - J_bar @ J  # [T4] N = I − J̄ J
    S = N @ M_inv @ N.T
    Lambda_n = nullspace_inertia_reference(S)  # [T5] Λn = (N M⁻¹ Nᵀ)#
    return M, M_inv, Lambda_inv, Lambda, J_bar, N, Lambda_n, min_eig, near_singular


def nullspace_inertia_reference(S: np.ndarray) -> np.ndarray:
    """(N M⁻¹ Nᵀ)# [T5]: rank n − 6; for one redundant joint S = σ u uᵀ, so S# = S / ‖S‖_F²."""
    if S.shape[0] == 7:
        return S / max(float(np.sum(S * S)), 1e-300)
    w, V = np.linalg.eigh(S)
    cutoff = 1e-8 * max(float(np.max(np.abs(w))), 1e-300)
    w_inv = np.where(np.abs(w) > cutoff, 1.0 / np.where(w == 0, 1.0, w), 0.0)
    return (V * w_inv) @ V.T


# the snapshot's arrays, each a field of its record by the `Dynamics` attribute's name: (name, shape)
# with n the number of joints (`snapshot_record_dtype`)
SNAPSHOT_FIELDS = (
    ("q", ("n",)), ("dq", ("n",)), ("M", ("n", "n")), ("M_inv", ("n", "n")), ("h", ("n",)),
    ("tcp_rotation_world", (3, 3)), ("tcp_position_world", (3,)), ("J", (6, "n")), ("dJ_dq", (6,)),
    ("Lambda_inv", (6, 6)), ("Lambda", (6, 6)), ("J_bar", ("n", 6)), ("N", ("n", "n")), ("Lambda_n", ("n", "n")),
)  # fmt: skip


@functools.cache
def snapshot_record_dtype(n: int) -> np.dtype:
    """The record of one `control.model.Dynamics` snapshot of an n-joint arm
    (`control.kernels.records`): every array of `SNAPSHOT_FIELDS` by its name (the snapshot's
    attributes are views of it) and whether Λx was damped (`near_singular`). The kernels read it by
    field name: `snap[0].J`, `snap[0].Lambda`."""
    fields = tuple((name, np.float64, tuple(n if d == "n" else d for d in shape)) for name, shape in SNAPSHOT_FIELDS)
    return record_dtype((), (*fields, ("near_singular", np.bool_)))


def snapshot_record(J: np.ndarray, q=None, dq=None) -> np.ndarray:
    """A zeroed one-element snapshot record of J's arm with J and, when given, q and q̇ filled in
    (what `snapshot_into` reads of it)."""
    rec = np.zeros(1, snapshot_record_dtype(J.shape[1]))
    row = rec[0]
    row["J"] = J
    if q is not None:
        row["q"] = q
    if dq is not None:
        row["dq"] = dq
    return rec


def snapshot_fused(M_upper, J, singular_eig) -> tuple:
    """`snapshot_reference`'s outputs (same order) by the compiled `snapshot_into` on a fresh record."""
    snap = snapshot_record(J)
    near_singular, min_eig = snapshot_into(M_upper, singular_eig, snap, snapshot_work(J.shape[1]), False)
    if not near_singular:  # `snapshot_into` leaves it to the caller away from a singularity
        min_eig = np.linalg.eigvalsh(snap[0]["Lambda_inv"])[0]
    s = snap[0]
    return (*(s[k].copy() for k in ("M", "M_inv", "Lambda_inv", "Lambda", "J_bar", "N", "Lambda_n")), min_eig,
            bool(near_singular))  # fmt: skip


def snapshot_work(n: int) -> np.ndarray:
    """Scratch space of `snapshot_into` for an n-joint arm (allocated once by its caller)."""
    return np.empty((4, n, n))


@njit(cache=True)
def snapshot_into(M_upper, singular_eig, snap, work, bias):
    """[T2-5] into the snapshot record `snap` (`snapshot_record_dtype`), read and written by field
    name: from CRBA's upper triangle `M_upper` and the record's J, its M, M⁻¹, Λx⁻¹, Λx (damped when
    the smallest eigenvalue of Λx⁻¹ is ≤ ρ = `singular_eig`), J̄, N, Λn and `near_singular`, with
    scratch `work` (`snapshot_work(n)`), allocating nothing away from a singularity; with `bias` (a
    serial revolute chain; else the caller fills J̇q̇) also J̇q̇ from J and the record's q̇
    (`tcp_bias_acceleration_into`). Returns (near_singular, min eig Λx⁻¹); the eigenvalue is computed
    only near a singularity, where the damping needs the eigen-decomposition, and is NaN elsewhere:
    there positive definiteness of Λx⁻¹ − ρI, tested by its Cholesky factorisation, decides that the
    smallest eigenvalue exceeds ρ."""
    s = snap[0]
    J, M, M_inv, Lambda_inv, Lambda = s.J, s.M, s.M_inv, s.Lambda_inv, s.Lambda
    J_bar, N, Lambda_n = s.J_bar, s.N, s.Lambda_n
    n = J.shape[1]
    if bias:
        tcp_bias_acceleration_into(J, s.dq, s.dJ_dq)
    L, Li, X, S = work[0], work[1], work[2, :, :6], work[3]
    for i in range(n):
        for j in range(i, n):
            M[i, j] = M_upper[i, j]
            M[j, i] = M_upper[i, j]
    if not _spd_inverse_into(M, L, Li, M_inv):
        M_inv[:, :] = np.nan
    _matmul_bt_into(M_inv, J, X)  # X = M⁻¹ Jᵀ
    _matmul_into(J, X, Lambda_inv)  # Λx⁻¹ = J M⁻¹ Jᵀ, symmetrised
    _symmetrise(Lambda_inv)
    L6, Li6 = L[:6, :6], Li[:6, :6]
    near_singular = not _cholesky_into(Lambda_inv, singular_eig, L6)  # min eig ≤ ρ (or NaN)
    min_eig = np.nan
    if not near_singular:  # [T3] Λx = (J M⁻¹ Jᵀ)⁻¹, positive definite here: by Cholesky, as M⁻¹
        near_singular = not _spd_inverse_into(Lambda_inv, L6, Li6, Lambda)
    if near_singular:  # damped inverse w / (w² + ρ²) from the eigen-decomposition
        w, V = np.linalg.eigh(Lambda_inv)
        min_eig = w[0]
        f = np.empty(6)
        for i in range(6):
            f[i] = w[i] / (w[i] * w[i] + singular_eig * singular_eig)
        Lambda[:, :] = _sym_from_eig(V, f)
    _matmul_into(X, Lambda, J_bar)  # [T2] J̄ = M⁻¹ Jᵀ Λx
    _matmul_into(J_bar, J, N)  # [T4] N = I − J̄ J
    for i in range(n):
        for j in range(n):
            N[i, j] = -N[i, j]
        N[i, i] += 1.0
    T = L  # N M⁻¹ (L is free again)
    _matmul_into(N, M_inv, T)
    _matmul_bt_into(T, N, S)  # S = N M⁻¹ Nᵀ, symmetrised
    _symmetrise(S)
    if n == 7:  # [T5] rank one: S# = S / ‖S‖_F²
        ss = 0.0
        for i in range(n):
            for j in range(n):
                ss += S[i, j] * S[i, j]
        inv = 1.0 / max(ss, 1e-300)
        for i in range(n):
            for j in range(n):
                Lambda_n[i, j] = S[i, j] * inv
    else:
        ws, Vs = np.linalg.eigh(S)
        cutoff = 1e-8 * max(np.max(np.abs(ws)), 1e-300)
        g = np.zeros(n)
        for i in range(n):
            if abs(ws[i]) > cutoff:
                g[i] = 1.0 / ws[i]
        Lambda_n[:, :] = _sym_from_eig(Vs, g)
    s.near_singular = near_singular
    return near_singular, min_eig


def snapshot_into_reference(M_upper, singular_eig, snap, work, bias) -> tuple[bool, float]:
    """`snapshot_into` by `snapshot_reference` (and J̇q̇ by `tcp_bias_acceleration_reference` with
    `bias`): the same fields of the record written (`work` is scratch, not read), the same
    (near_singular, min eig Λx⁻¹ or NaN away from a singularity)."""
    s = snap[0]
    out = snapshot_reference(M_upper, s["J"], singular_eig)
    for name, value in zip(("M", "M_inv", "Lambda_inv", "Lambda", "J_bar", "N", "Lambda_n"), out[:7], strict=True):
        s[name] = value
    if bias:
        s["dJ_dq"] = tcp_bias_acceleration_reference(s["J"], s["dq"])
    near_singular = bool(out[8])
    s["near_singular"] = near_singular
    return near_singular, (out[7] if near_singular else np.nan)
