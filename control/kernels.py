"""Fused compiled kernels for the per-step algebra, each beside its plain-numpy reference.

The snapshot, the coupling blocks and the gradient contraction are small dense algebra on 6×7
matrices: in plain numpy every product and every `np.linalg` call costs more in Python overhead
than in arithmetic. Each `*_fused` function below does the same algebra as the `*_reference`
function of the same name in one compiled call (numba, `cache=True`: compiled once per machine,
then loaded from `__pycache__`). The references are the readable statement of the formulas; the
tests (`tests/test_kernels.py`) hold the fused versions to them (relative 1e-10 over random and
near-singular states of both robots).

Kernels:
- `snapshot_*`: from M (upper triangle, as CRBA fills it) and the TCP Jacobian J: M⁻¹, Λx⁻¹,
  Λx [T3] (damped near singularities), J̄ [T2], N [T4], Λn [T5].
- `coupling_*`: blocks A, B, D [T6, T20], A⁻¹, D̂ [T9], P_f, P_a, P_d (Table I) and W [T22].
- `gradient_contraction_*`: the ∂J part of ∂W/∂q [T24-27] and the vectors whose RNEA
  derivative gives the ∂M part (see `control.coupling.coupling_gradient_direct`).
- `kinematic_hessian_reference`: ∂J/∂q of a serial chain of revolute joints from J alone.
"""

from __future__ import annotations

import numpy as np
from numba import njit

OBJECTIVE_CODES = {"f": 0, "a": 1, "d": 2}


# ==== snapshot [T2-5] ============================================================================
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


@njit(cache=True)
def _matmul_into(A, B, out):
    """out = A @ B (out may be a view; not A or B)."""
    m, k = A.shape
    n = B.shape[1]
    for i in range(m):
        for j in range(n):
            s = 0.0
            for p in range(k):
                s += A[i, p] * B[p, j]
            out[i, j] = s


@njit(cache=True)
def _matmul_bt_into(A, B, out):
    """out = A @ Bᵀ (out may be a view; not A or B)."""
    m, k = A.shape
    n = B.shape[0]
    for i in range(m):
        for j in range(n):
            s = 0.0
            for p in range(k):
                s += A[i, p] * B[j, p]
            out[i, j] = s


@njit(cache=True)
def _matmul(A, B):
    """A @ B, a new array."""
    out = np.empty((A.shape[0], B.shape[1]))
    _matmul_into(A, B, out)
    return out


@njit(cache=True)
def _matmul_bt(A, B):
    """A @ Bᵀ, a new array."""
    out = np.empty((A.shape[0], B.shape[0]))
    _matmul_bt_into(A, B, out)
    return out


@njit(cache=True)
def _symmetrise(A):
    """A ← (A + Aᵀ)/2 in place."""
    n = A.shape[0]
    for i in range(n):
        for j in range(i + 1, n):
            s = 0.5 * (A[i, j] + A[j, i])
            A[i, j] = s
            A[j, i] = s


@njit(cache=True)
def _sym_from_eig(V, f):
    n = V.shape[0]
    out = np.zeros((n, n))
    for i in range(n):
        for j in range(i, n):
            s = 0.0
            for p in range(n):
                s += V[i, p] * f[p] * V[j, p]
            out[i, j] = s
            out[j, i] = s
    return out


@njit(cache=True)
def snapshot_fused(M_upper, J, singular_eig):
    """Compiled `snapshot_reference` (same outputs, same order)."""
    n = J.shape[1]
    M, M_inv, N, Lambda_n = np.empty((n, n)), np.empty((n, n)), np.empty((n, n)), np.empty((n, n))
    Lambda_inv, Lambda, J_bar = np.empty((6, 6)), np.empty((6, 6)), np.empty((n, 6))
    work = snapshot_work(n)
    near_singular, min_eig = snapshot_into(
        M_upper, J, singular_eig, M, M_inv, Lambda_inv, Lambda, J_bar, N, Lambda_n, work, None, np.empty(6)
    )
    if not near_singular:  # `snapshot_into` leaves it to the caller away from a singularity
        min_eig = np.linalg.eigvalsh(Lambda_inv)[0]
    return M, M_inv, Lambda_inv, Lambda, J_bar, N, Lambda_n, min_eig, near_singular


@njit(cache=True)
def snapshot_work(n):
    """Scratch space of `snapshot_into` for an n-joint arm (allocated once by its caller)."""
    return np.empty((4, n, n))


@njit(cache=True)
def _cholesky_into(A, shift, L):
    """Lower Cholesky factor of A − shift·I into L (A symmetric; only its lower triangle is read).
    False (L unusable) when A − shift·I is not positive definite, NaN included."""
    n = A.shape[0]
    for j in range(n):
        s = A[j, j] - shift
        for p in range(j):
            s -= L[j, p] * L[j, p]
        if not s > 0.0:
            return False
        d = np.sqrt(s)
        L[j, j] = d
        for i in range(j + 1, n):
            t = A[i, j]
            for p in range(j):
                t -= L[i, p] * L[j, p]
            L[i, j] = t / d
    return True


@njit(cache=True)
def _spd_inverse_into(A, L, Li, out):
    """out = A⁻¹ for symmetric positive definite A (L, Li: n×n scratch): A = L Lᵀ, A⁻¹ = L⁻ᵀ L⁻¹.
    False (out untouched) when A is not positive definite."""
    n = A.shape[0]
    if not _cholesky_into(A, 0.0, L):
        return False
    for j in range(n):  # L⁻¹, lower triangular
        Li[j, j] = 1.0 / L[j, j]
        for i in range(j + 1, n):
            t = 0.0
            for p in range(j, i):
                t -= L[i, p] * Li[p, j]
            Li[i, j] = t / L[i, i]
    for i in range(n):
        for j in range(i, n):
            s = 0.0
            for p in range(j, n):
                s += Li[p, i] * Li[p, j]
            out[i, j] = s
            out[j, i] = s
    return True


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


@njit(cache=True)
def snapshot_into(M_upper, J, singular_eig, M, M_inv, Lambda_inv, Lambda, J_bar, N, Lambda_n, work, dq, dJ_dq):
    """`snapshot_fused` writing into arrays the caller allocated, with scratch `work`
    (`snapshot_work(n)`), allocating nothing away from a singularity; with `dq` (a serial revolute
    chain; None: the caller fills `dJ_dq`) also J̇q̇ into `dJ_dq` (`tcp_bias_acceleration_into`). Returns (near_singular,
    min eig Λx⁻¹); the eigenvalue is computed only near a singularity, where the damping needs the
    eigen-decomposition, and is NaN elsewhere: there positive definiteness of Λx⁻¹ − ρI, tested by
    its Cholesky factorisation, decides that the smallest eigenvalue exceeds ρ."""
    n = J.shape[1]
    if dq is not None:
        tcp_bias_acceleration_into(J, dq, dJ_dq)
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
    return near_singular, min_eig


# ==== coupling blocks [T6, T9, T10, T20, T22, Table I] =============================================
def coupling_reference(Lambda: np.ndarray, Lambda_inv: np.ndarray, perm: np.ndarray, n_m: int, exact: bool) -> tuple:
    """(A, B, D, A⁻¹, D̂, P_f, P_a, P_d, W_f, W_a, W_d) in (motion, force) order `perm` [T6].

    With `exact` (Λx⁻¹ is the inverse of Λx) the block-inverse identities avoid an inversion:
    with L = Λx⁻¹, D̂ = L_ff⁻¹, BᵀA⁻¹ = −D̂ L_fm and A⁻¹ = L_mm − L_mf D̂ L_fm.
    """
    k = n_m
    Lp = Lambda[np.ix_(perm, perm)]  # [[A, B], [Bᵀ, D]] [T6]
    A, B, D = Lp[:k, :k].copy(), Lp[:k, k:].copy(), Lp[k:, k:].copy()
    P_a = B.T.copy()  # [T20] P_a = S_f Λx S_mᵀ = Bᵀ
    Li = Lambda_inv[np.ix_(perm, perm)]
    P_f = Li[k:, :k].copy()  # S_f Λx⁻¹ S_mᵀ
    if exact:
        D_hat = np.linalg.inv(Li[k:, k:])  # [T9]
        P_d = -(D_hat @ P_f)  # [T10] BᵀA⁻¹
        A_inv = Li[:k, :k] + Li[:k, k:] @ P_d
    else:
        A_inv = np.linalg.inv(A)
        P_d = P_a @ A_inv  # [T10]
        D_hat = D - P_d @ B  # [T9]
    W = [float(np.sum(P * P)) for P in (P_f, P_a, P_d)]  # [T22] W = ‖P‖²_F
    return A, B, D, A_inv, D_hat, P_f, P_a, P_d, W[0], W[1], W[2]


@njit(cache=True)
def _inverse(A):
    """Inverse of a small square matrix by Gauss-Jordan with partial pivoting."""
    n = A.shape[0]
    a = A.copy()
    out = np.eye(n)
    for c in range(n):
        p = c
        for r in range(c + 1, n):
            if abs(a[r, c]) > abs(a[p, c]):
                p = r
        if p != c:
            for j in range(n):
                a[c, j], a[p, j] = a[p, j], a[c, j]
                out[c, j], out[p, j] = out[p, j], out[c, j]
        d = a[c, c]
        for j in range(n):
            a[c, j] /= d
            out[c, j] /= d
        for r in range(n):
            if r != c:
                fct = a[r, c]
                if fct != 0.0:
                    for j in range(n):
                        a[r, j] -= fct * a[c, j]
                        out[r, j] -= fct * out[c, j]
    return out


@njit(cache=True)
def _sqnorm(P):
    s = 0.0
    for i in range(P.shape[0]):
        for j in range(P.shape[1]):
            s += P[i, j] * P[i, j]
    return s


@njit(cache=True)
def coupling_fused(Lambda, Lambda_inv, perm, n_m, exact):
    """Compiled `coupling_reference` (same outputs, same order)."""
    k = n_m
    nf = 6 - k
    Lp = np.empty((6, 6))
    Li = np.empty((6, 6))
    for i in range(6):
        for j in range(6):
            Lp[i, j] = Lambda[perm[i], perm[j]]
            Li[i, j] = Lambda_inv[perm[i], perm[j]]
    A = Lp[:k, :k].copy()
    B = Lp[:k, k:].copy()
    D = Lp[k:, k:].copy()
    P_a = B.T.copy()
    P_f = Li[k:, :k].copy()
    if exact:
        if nf == 1:
            D_hat = np.empty((1, 1))
            D_hat[0, 0] = 1.0 / Li[k, k]
        else:
            D_hat = _inverse(Li[k:, k:].copy())
        P_d = -_matmul(D_hat, P_f)
        A_inv = Li[:k, :k] + _matmul(Li[:k, k:].copy(), P_d)
    else:
        A_inv = _inverse(A)
        P_d = _matmul(P_a, A_inv)
        D_hat = D - _matmul(P_d, B)
    return A, B, D, A_inv, D_hat, P_f, P_a, P_d, _sqnorm(P_f), _sqnorm(P_a), _sqnorm(P_d)


# ==== gradient contraction [T24-27] ===============================================================
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


def _objective_sides(objective, Lambda_inv, P, A_inv, S_f, S_m, perm, n_m):
    """(P, left, right) with ∂P/∂q_k = left ∂Λx_k right [T25-27]."""
    m, f = perm[:n_m], perm[n_m:]
    if objective == "f":  # [T25] ∂P_f = −S_f Λx⁻¹ ∂Λx Λx⁻¹ S_mᵀ
        return -Lambda_inv[f, :], Lambda_inv[:, m]
    if objective == "a":  # [T26] ∂P_a = S_f ∂Λx S_mᵀ
        return S_f, S_m.T
    return S_f - P @ S_m, S_m.T @ A_inv  # [T27] ∂P_d = (S_f − BᵀA⁻¹S_m) ∂Λx S_mᵀ A⁻¹


def gradient_contraction_reference(
    objective: str,
    J: np.ndarray,
    dJ: np.ndarray,
    M_inv: np.ndarray,
    Lambda: np.ndarray,
    Lambda_inv: np.ndarray,
    P: np.ndarray,
    A_inv: np.ndarray,
    perm: np.ndarray,
    n_m: int,
) -> tuple:
    """(term_J, a, b): ∂W/∂q = −2 (term_J − term_M) with term_M[k] = Σ_c a_cᵀ ∂(M b_c)/∂q_k [T24].

    ∂W/∂q_k = 2⟨∂Λx_k, G⟩, G = leftᵀ P rightᵀ, and ∂Λx_k = −Λx ∂(Λx⁻¹)_k Λx with
    ∂(Λx⁻¹)_k = ∂J_k X + Xᵀ∂J_kᵀ − Xᵀ∂M_k X (X = M⁻¹Jᵀ). With H = Λx G Λx = U Vᵀ:
    term_J[k] = ⟨∂J_k, (H + Hᵀ) Xᵀ⟩ and ⟨∂M_k, X H Xᵀ⟩ = Σ_c (X U)_cᵀ ∂M_k (X V)_c.
    """
    eye = np.eye(6)
    S_f, S_m = eye[perm[n_m:]], eye[perm[:n_m]]
    left, right = _objective_sides(objective, Lambda_inv, P, A_inv, S_f, S_m, perm, n_m)
    U = Lambda @ left.T  # (6, n_f)
    V = Lambda @ (P @ right.T).T  # (6, n_f)
    X = M_inv @ J.T
    H = U @ V.T
    n = J.shape[1]
    term_J = dJ.reshape(n, 6 * n) @ ((H + H.T) @ X.T).reshape(6 * n)
    return term_J, X @ U, X @ V


@njit(cache=True)
def gradient_contraction_fused(objective, J, M_inv, Lambda, Lambda_inv, P, A_inv, perm, n_m):
    """Compiled `gradient_contraction_reference` with ∂J from `kinematic_hessian_reference`'s
    formula (serial revolute chain), never forming the (n, 6, n) Hessian. `objective` is 0/1/2
    for f/a/d (`OBJECTIVE_CODES`)."""
    n = J.shape[1]
    nf = 6 - n_m
    left = np.zeros((nf, 6))
    right = np.zeros((6, n_m))
    if objective == 0:  # [T25]
        for r in range(nf):
            for j in range(6):
                left[r, j] = -Lambda_inv[perm[n_m + r], j]
        for j in range(6):
            for c in range(n_m):
                right[j, c] = Lambda_inv[j, perm[c]]
    elif objective == 1:  # [T26]
        for r in range(nf):
            left[r, perm[n_m + r]] = 1.0
        for c in range(n_m):
            right[perm[c], c] = 1.0
    else:  # [T27]
        for r in range(nf):
            left[r, perm[n_m + r]] = 1.0
            for c in range(n_m):
                left[r, perm[c]] -= P[r, c]
        for c in range(n_m):
            for c2 in range(n_m):
                right[perm[c], c2] = A_inv[c, c2]
    U = _matmul_bt(Lambda, left)  # (6, n_f)
    Pr = _matmul_bt(P, right)  # (n_f, 6) = P rightᵀ
    V = _matmul_bt(Lambda, Pr)  # (6, n_f)
    X = _matmul_bt(M_inv, J)  # (n, 6)
    H = _matmul_bt(U, V)
    Hs = H + H.T
    Y = _matmul_bt(Hs, X)  # (6, n)
    term_J = np.zeros(n)
    for k in range(n):
        wk0, wk1, wk2 = J[3, k], J[4, k], J[5, k]
        vk0, vk1, vk2 = J[0, k], J[1, k], J[2, k]
        s = 0.0
        for i in range(n):
            y0, y1, y2 = Y[0, i], Y[1, i], Y[2, i]
            if k < i:  # ∂v_i = ω_k × v_i, ∂ω_i = ω_k × ω_i
                v0, v1, v2 = J[0, i], J[1, i], J[2, i]
                w0, w1, w2 = J[3, i], J[4, i], J[5, i]
                z0, z1, z2 = Y[3, i], Y[4, i], Y[5, i]
                s += y0 * (wk1 * v2 - wk2 * v1) + y1 * (wk2 * v0 - wk0 * v2) + y2 * (wk0 * v1 - wk1 * v0)
                s += z0 * (wk1 * w2 - wk2 * w1) + z1 * (wk2 * w0 - wk0 * w2) + z2 * (wk0 * w1 - wk1 * w0)
            else:  # ∂v_i = ω_i × v_k
                w0, w1, w2 = J[3, i], J[4, i], J[5, i]
                s += y0 * (w1 * vk2 - w2 * vk1) + y1 * (w2 * vk0 - w0 * vk2) + y2 * (w0 * vk1 - w1 * vk0)
        term_J[k] = s
    return term_J, _matmul(X, U), _matmul(X, V)


# ==== the [T] law around the nullspace QP [T7, T9, T11-14] ========================================
def task_wrench_reference(
    J: np.ndarray,
    dq: np.ndarray,
    e: np.ndarray,
    target_velocity: np.ndarray,
    target_acceleration: np.ndarray,
    A: np.ndarray,
    P_d: np.ndarray,
    P_f: np.ndarray,
    Lambda: np.ndarray,
    dJ_dq: np.ndarray,
    F_e: np.ndarray,
    F_hat: np.ndarray,
    u_f_extra: np.ndarray,
    m_idx: np.ndarray,
    f_idx: np.ndarray,
    kp_m: np.ndarray,
    kd_scale_m: np.ndarray,
    force_kp: float,
    force_kd: float,
    shaping: bool,
) -> tuple:
    """(F [T7] before μx, F − Λx J̇q̇, coupled acceleration P_f F_m^e) of the [T] executor.

    e: pose error [p° − p; log(R° Rᵀ)]; `u_f_extra`: the integral term K_f^i ∫e_f (or zeros).
    """
    v = J @ dq
    de = target_velocity - v
    kd_m = kd_scale_m * np.sqrt(A.diagonal())  # [T11] K_m^d = 2ζ√(K_m^p A_ii)
    u_m = A @ target_acceleration[m_idx] + kd_m * de[m_idx] + kp_m * e[m_idx]  # [T11]
    u_f = -F_hat + force_kp * (F_e[f_idx] - F_hat) - force_kd * v[f_idx] + u_f_extra  # [T12]
    F = np.empty(6)
    F[m_idx] = u_m
    F[f_idx] = u_f + P_d @ (u_m + F_e[m_idx]) if shaping else u_f  # [T7] with Λ̂x [T9]
    return F, F - Lambda @ dJ_dq, float(P_f[0] @ F_e[m_idx])


@njit(cache=True)
def task_wrench_fused(
    J,
    dq,
    e,
    target_velocity,
    target_acceleration,
    A,
    P_d,
    P_f,
    Lambda,
    dJ_dq,
    F_e,
    F_hat,
    u_f_extra,
    m_idx,
    f_idx,
    kp_m,
    kd_scale_m,
    force_kp,
    force_kd,
    shaping,
):
    """Compiled `task_wrench_reference` (same outputs, same order)."""
    n = J.shape[1]
    v = np.zeros(6)
    for a in range(6):
        s = 0.0
        for j in range(n):
            s += J[a, j] * dq[j]
        v[a] = s
    nm = m_idx.shape[0]
    nf = f_idx.shape[0]
    u_m = np.empty(nm)
    for i in range(nm):
        s = 0.0
        for j in range(nm):
            s += A[i, j] * target_acceleration[m_idx[j]]
        mi = m_idx[i]
        u_m[i] = s + kd_scale_m[i] * np.sqrt(A[i, i]) * (target_velocity[mi] - v[mi]) + kp_m[i] * e[mi]
    F = np.empty(6)
    for i in range(nm):
        F[m_idx[i]] = u_m[i]
    coupled = 0.0
    for j in range(nm):
        coupled += P_f[0, j] * F_e[m_idx[j]]
    for r in range(nf):
        fr = f_idx[r]
        u_f = -F_hat[r] + force_kp * (F_e[fr] - F_hat[r]) - force_kd * v[fr] + u_f_extra[r]
        if shaping:
            for j in range(nm):
                u_f += P_d[r, j] * (u_m[j] + F_e[m_idx[j]])
        F[fr] = u_f
    F_mu = F.copy()
    for a in range(6):
        s = 0.0
        for b in range(6):
            s += Lambda[a, b] * dJ_dq[b]
        F_mu[a] -= s
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


# ==== nullspace velocity bounds [T17] with first-order dampers ====================================
@njit(cache=True)
def damper_bounds_fused(q, q_lower, q_upper, dq_limit, endless, influence, safety, speed):
    """Compiled `control.nullspace.damper_bounds` (its numpy reference): (l, u) = ±dq_limit
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


# ==== ∂M/∂q contraction for the gradient [T24] =====================================================
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


def inertia_contraction_reference(model, q: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """term_M[k] = aᵀ ∂M/∂q_k b from Pinocchio's RNEA derivatives at q̇ = 0 without gravity:
    ∂(M b)/∂q = ∂τ/∂q of RNEA(q, 0, b) (`model` gravity-free)."""
    import pinocchio as pin

    data = model.createData()
    dtau_dq = pin.computeRNEADerivatives(model, data, q, np.zeros(model.nv), b)[0]
    return np.asarray(dtau_dq).T @ a


@njit(cache=True)
def _cross(a, b, out):
    out[0] = a[1] * b[2] - a[2] * b[1]
    out[1] = a[2] * b[0] - a[0] * b[2]
    out[2] = a[0] * b[1] - a[1] * b[0]


@njit(cache=True)
def _mat3_vec(A, x, out):
    for i in range(3):
        out[i] = A[i, 0] * x[0] + A[i, 1] * x[1] + A[i, 2] * x[2]


@njit(cache=True)
def _mat3_mat(A, B, out):
    for i in range(3):
        for j in range(3):
            out[i, j] = A[i, 0] * B[0, j] + A[i, 1] * B[1, j] + A[i, 2] * B[2, j]


@njit(cache=True)
def inertia_contraction_fused(q, R_place, p_place, axes, mass, lever, inertia, a, b):
    """Compiled aᵀ ∂M/∂q_k b for all k (`inertia_contraction_reference`), from the chain alone.

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


# ==== [C] joint-limit dampers as acceleration bounds [C13-24] =====================================
@njit(cache=True)
def _np_max(a, b):
    """numpy.maximum of two floats (NaN if either is NaN)."""
    if a != a or b != b:
        return np.nan
    return a if a >= b else b


@njit(cache=True)
def acceleration_bounds_fused(
    q, dq, q_lower, q_upper, d_s, d_i, xi, kp, lam, velocity_gain, dq_limit, endless, proposed, dt, no_bound
):
    """Compiled `control.dampers.JointLimitDamper.bounds_reference`: (lower, upper, crossed).

    Per joint and side (upper: e = q⁺ − q, ė = −q̇; lower: e = q − q⁻, ė = q̇): ë_p proposed [C24]
    −λė − k_p(e − d_s) or classic [C15, C17] −(ė − ė_d)/δt below d_i, ë_v = −g(ė + q̇⁺) [C18, C20],
    ë ≥ max(ë_p, ë_v) [C19] capped at `no_bound`; crossed rows go to their midpoint."""
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
            if endless[i]:
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


# ==== the nullspace QP [T15-17] of a 7-joint arm: one-dimensional kernel, closed form ==============
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


# ==== SO(3) log of the orientation error [T11] ==================================================
@njit(cache=True)
def log3_fused(R):
    """log(R) ∈ so(3) as a rotation vector θ·axis, θ ∈ [0, π], from the unit quaternion of R
    (Shepperd's method: accurate at small angles and near π); `pinocchio.log3`'s result, to
    rounding away from θ = π (where the axis' sign is a choice). Tested against it."""
    t = R[0, 0] + R[1, 1] + R[2, 2]
    if t > 0.0:
        S = 2.0 * np.sqrt(t + 1.0)
        w, x, y, z = 0.25 * S, (R[2, 1] - R[1, 2]) / S, (R[0, 2] - R[2, 0]) / S, (R[1, 0] - R[0, 1]) / S
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        S = 2.0 * np.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2])
        w, x, y, z = (R[2, 1] - R[1, 2]) / S, 0.25 * S, (R[0, 1] + R[1, 0]) / S, (R[0, 2] + R[2, 0]) / S
    elif R[1, 1] > R[2, 2]:
        S = 2.0 * np.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2])
        w, x, y, z = (R[0, 2] - R[2, 0]) / S, (R[0, 1] + R[1, 0]) / S, 0.25 * S, (R[1, 2] + R[2, 1]) / S
    else:
        S = 2.0 * np.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1])
        w, x, y, z = (R[1, 0] - R[0, 1]) / S, (R[0, 2] + R[2, 0]) / S, (R[1, 2] + R[2, 1]) / S, 0.25 * S
    if w < 0.0:
        w, x, y, z = -w, -x, -y, -z
    s = np.sqrt(x * x + y * y + z * z)
    k = 2.0 * np.arctan2(s, w) / s if s > 0.0 else 2.0 / w  # θ / sin(θ/2)
    out = np.empty(3)
    out[0], out[1], out[2] = k * x, k * y, k * z
    return out


# ==== the [T] law around the nullspace QP in one call [T7, T9, T11-12, T17, T18, T22-27] ==========
OBJECTIVE_J = 3  # `projection_law_fused`'s code for W_j [T18] (0/1/2: f/a/d, `OBJECTIVE_CODES`)


def law_constants(
    objective: int,
    perm: np.ndarray,
    n_m: int,
    kp_m: np.ndarray,
    kd_scale_m: np.ndarray,
    force_gains: tuple[float, float, float, float],
    shaping: bool,
    k0: float,
    q_lower: np.ndarray,
    q_upper: np.ndarray,
    dq_limit: np.ndarray,
    endless: np.ndarray,
    damper: tuple[float, float, float],
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What `projection_law_fused` reads that changes only with the gains, in three arrays (one
    compiled call's argument checks cost per argument): (axes, gains, limits) =
    ([objective, n_m, perm…] int64; [K_f^p, K_f^d, K_f^i, integral limit, shaping, k0, d_i, d_s, ξ,
    K_m^p…, 2ζ√K_m^p…]; rows q⁻, q⁺, q̇ limit, endless (1/0)). `law_constants_unpacked` reads them back."""
    axes = np.array([objective, n_m, *np.asarray(perm, dtype=np.int64)], dtype=np.int64)
    gains = np.array([*force_gains, float(shaping), k0, *damper, *kp_m, *kd_scale_m], dtype=float)
    limits = np.array([q_lower, q_upper, dq_limit, np.asarray(endless, dtype=float)], dtype=float)
    return axes, gains, limits


def pack_chain(chain: tuple) -> np.ndarray:
    """`chain_constants` as one (n, 28) array (rotation 9, translation 3, axis 3, mass 1, lever 3,
    inertia 9 per joint) for `projection_law_fused`."""
    R, p, axes, mass, lever, inertia = chain
    n = len(mass)
    return np.hstack([R.reshape(n, 9), p, axes, mass[:, None], lever, inertia.reshape(n, 9)])


@njit(cache=True)
def _unpack_chain(packed):
    n = packed.shape[0]
    R = np.ascontiguousarray(packed[:, 0:9]).reshape((n, 3, 3))
    inertia = np.ascontiguousarray(packed[:, 19:28]).reshape((n, 3, 3))
    return R, packed[:, 9:12], packed[:, 12:15], packed[:, 15], packed[:, 16:19], inertia


@njit(cache=True)
def projection_law_fused(
    q,
    dq,
    J,
    M_inv,
    Lambda,
    Lambda_inv,
    dJ_dq,
    exact,
    tcp_position,
    tcp_rotation,
    target_position,
    target_rotation,
    target_velocity,
    target_acceleration,
    target_wrench,
    F_e,
    force_integral,
    q_d,
    axes,
    gains,
    limits,
    chain,
    F_mu,
    qp_data,
):
    """Everything the [T] executor computes before its nullspace QP, in one compiled call of the
    kernels above (the same arithmetic as calling them one by one, as the executor's reference
    path `ProjectionExecutor._step_reference` does):

    the pose error e = [p° − p; log(R° Rᵀ)] (`log3_fused`); the force integral ∫e_f clamped to
    ±limit/K_f^i (anti-windup, when K_f^i > 0) [T12]; `coupling_fused` (A, B, D, P, W [T6, T9,
    T22]); the QP's linear term k0 ∇W with ∇W from `gradient_contraction_fused` and
    `inertia_contraction_fused` [T24-27] (objective 0/1/2: f/a/d), or ∇W_j = q − q_d [T18]
    (objective `OBJECTIVE_J`); `task_wrench_fused` [T7, T11-12]; `damper_bounds_fused` [T17].
    `axes`, `gains`, `limits` are `law_constants(…)`, `chain` is `pack_chain(chain_constants(model))`
    (a serial revolute chain).

    Writes F − Λx J̇q̇ into `F_mu` (6,) and the QP's k0 ∇W, lower and upper bounds into the rows of
    `qp_data` (3, n) (the caller's buffers: handing arrays back costs more); returns (F, new force
    integral, W, W_f, W_a, W_d, P_f F_m^e, F̂_f[0] − F_f^e[0]).
    """
    objective, n_m = axes[0], axes[1]
    perm = axes[2:]
    m_idx, f_idx = perm[:n_m], perm[n_m:]
    force_kp, force_kd, force_ki, force_integral_limit = gains[0], gains[1], gains[2], gains[3]
    shaping, k0 = gains[4] != 0.0, gains[5]
    kp_m, kd_scale_m = gains[9 : 9 + n_m], gains[9 + n_m : 9 + 2 * n_m]
    q_lower, q_upper, dq_limit, endless = limits[0], limits[1], limits[2], limits[3] != 0.0
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
    integral = force_integral.copy()
    u_f_extra = np.zeros(nf)
    for r in range(nf):
        F_hat[r] = target_wrench[f_idx[r]]
        if force_ki > 0:
            lim = force_integral_limit / force_ki
            integral[r] = min(max(integral[r] + (F_e[f_idx[r]] - F_hat[r]) * 1e-3, -lim), lim)
            u_f_extra[r] = force_ki * integral[r]
    A, _B, _D, A_inv, _D_hat, P_f, P_a, P_d, W_f, W_a, W_d = coupling_fused(Lambda, Lambda_inv, perm, n_m, exact)
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
        term_J, a_, b_ = gradient_contraction_fused(objective, J, M_inv, Lambda, Lambda_inv, P, A_inv, perm, n_m)
        R_place, p_place, joint_axes, mass, lever, inertia = _unpack_chain(chain)
        term_M = np.zeros(n)
        for c in range(a_.shape[1]):
            term_M += inertia_contraction_fused(
                q, R_place, p_place, joint_axes, mass, lever, inertia, a_[:, c], b_[:, c]
            )
        W = W_f if objective == 0 else (W_a if objective == 1 else W_d)
        for i in range(n):
            grad[i] = -2.0 * (term_J[i] - term_M[i])
    for i in range(n):
        grad[i] = k0 * grad[i]
    F, F_mu_, coupled = task_wrench_fused(
        J, dq, e, target_velocity, target_acceleration, A, P_d, P_f, Lambda, dJ_dq, F_e, F_hat, u_f_extra,
        m_idx, f_idx, kp_m, kd_scale_m, force_kp, force_kd, shaping,
    )  # fmt: skip
    lower, upper = damper_bounds_fused(q, q_lower, q_upper, dq_limit, endless, gains[6], gains[7], gains[8])
    F_mu[:] = F_mu_
    qp_data[0] = grad
    qp_data[1] = lower
    qp_data[2] = upper
    return F, integral, W, W_f, W_a, W_d, coupled, F_hat[0] - F_e[f_idx[0]]


@njit(cache=True)
def projection_step_fused(
    q, dq, J, M_inv, Lambda, Lambda_inv, dJ_dq, exact, tcp_position, tcp_rotation, target_position,
    target_rotation, target_velocity, target_acceleration, target_wrench, F_e, force_integral, q_d, axes,
    gains, limits, chain, F_mu, qp_data, closed_form, N, Lambda_n, kn, h, x, tau,
):  # fmt: skip
    """`projection_law_fused`, then, with `closed_form` (the nullspace QP's 7-joint line form applies),
    the QP [T15-17] by `nullspace_line_qp_fused` into `x` and the torque [T13-14] by
    `joint_torque_fused` into `tau`: the whole [T] step in one call. Returns the law's values and the
    number of active bounds (0 or 1), or −1 when the QP was not solved here (`x`, `tau` untouched:
    the caller solves it with its backend)."""
    F, integral, W, W_f, W_a, W_d, coupled, force_error = projection_law_fused(
        q, dq, J, M_inv, Lambda, Lambda_inv, dJ_dq, exact, tcp_position, tcp_rotation, target_position,
        target_rotation, target_velocity, target_acceleration, target_wrench, F_e, force_integral, q_d, axes,
        gains, limits, chain, F_mu, qp_data,
    )  # fmt: skip
    active = -1
    if closed_form:
        active = nullspace_line_qp_fused(J, qp_data[0], qp_data[1], qp_data[2], x)
        if active >= 0:
            tau[:] = joint_torque_fused(J, F_mu, N, Lambda_n, kn, x, dq, h)
    return F, integral, W, W_f, W_a, W_d, coupled, force_error, active


# ==== [C] task rows and the QP objective [C3-9] ===================================================
@njit(cache=True)
def pose_task_target_fused(
    J, dq, dJ_dq, tcp_position, tcp_rotation, target_position, target_rotation, target_velocity,
    target_acceleration, kp, kd, gamma, use_gamma, ddq_e,
):  # fmt: skip
    """Compiled `control.compliance_qp.PoseTask.rows_reference`'s right-hand side: b = ẍ° + ë* − J̇q̇
    (+ Γ J q̈_e when Γ ≠ 0) [C4, C9], ë* = −K_d ė − K_p e [C3], e = [p − p°; log(R R°ᵀ)]."""
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
    if use_gamma:
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
def posture_target_fused(q, q_ref, dq, dq_ref, kp, kd, ki, use_ki, integral, dt, gamma, use_gamma, ddq_e):
    """Compiled `control.compliance_qp.PostureTask.rows_reference`'s right-hand side: q̈*₀ =
    −K_d (q̇ − q̇_ref) − K_p e − K_i ∫e, e = q − q_ref (the integral advanced in place when K_i ≠ 0),
    plus Γ₀ q̈_e when Γ₀ ≠ 0 [C7, C9]."""
    n = q.shape[0]
    b = np.empty(n)
    for i in range(n):
        e = q[i] - q_ref[i]
        if use_ki:
            integral[i] += e * dt
        b[i] = -kd[i] * (dq[i] - dq_ref[i]) - kp[i] * e - ki[i] * integral[i]
    if use_gamma:
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


# ==== [C] external-torque estimation [C25-26] ======================================================
@njit(cache=True)
def momentum_observer_fused(M_prev, dq, dq_prev, tau_prev, h_prev, dt, a, r):
    """Compiled `control.estimation.MomentumObserver.update_reference`'s step: Δ = M_{k−1}(q̇_k −
    q̇_{k−1}) − (τ_{k−1} − h_{k−1}) δt, r ← a r + (1 − a) Δ/δt [C25]; returns the new r."""
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
    (the low-pass state `lp` advanced in place: lp ← a lp + (1 − a) τ_s); returns (τ_s, τ_s − lp)."""
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


# ==== wrench transport (the F/T reading moved to the TCP) =========================================
def move_wrench_reference(wrench: np.ndarray, p_from: np.ndarray, p_to: np.ndarray) -> np.ndarray:
    """A wrench [f; m] (world axes) about `p_from` as the same wrench about `p_to`: f is unchanged,
    m_to = m_from + (p_from − p_to) × f."""
    f, m = wrench[:3], wrench[3:]
    return np.concatenate([f, m + np.cross(p_from - p_to, f)])


@njit(cache=True)
def move_wrench_fused(wrench, p_from, p_to):
    """Compiled `move_wrench_reference` (a new array)."""
    r0, r1, r2 = p_from[0] - p_to[0], p_from[1] - p_to[1], p_from[2] - p_to[2]
    f0, f1, f2 = wrench[0], wrench[1], wrench[2]
    out = np.empty(6)
    out[0], out[1], out[2] = f0, f1, f2
    out[3] = wrench[3] + (r1 * f2 - r2 * f1)
    out[4] = wrench[4] + (r2 * f0 - r0 * f2)
    out[5] = wrench[5] + (r0 * f1 - r1 * f0)
    return out


# ==== elbow swivel of the joint anchors (a polish signal every step) ==============================
@njit(cache=True)
def swivel_of_anchors_fused(anchors, shoulder, elbow, wrist):
    """`control.planner.swivel_of_points` (rad) of rows `shoulder`, `elbow`, `wrist` of an (m, 3)
    array of points (MuJoCo's joint anchors), the same arithmetic in one compiled call."""
    s0, s1, s2 = anchors[shoulder, 0], anchors[shoulder, 1], anchors[shoulder, 2]
    u0, u1, u2 = anchors[wrist, 0] - s0, anchors[wrist, 1] - s1, anchors[wrist, 2] - s2
    norm = np.sqrt(u0 * u0 + u1 * u1 + u2 * u2)
    u0, u1, u2 = u0 / norm, u1 / norm, u2 / norm
    r0, r1, r2 = -u2 * u0, -u2 * u1, 1.0 - u2 * u2
    if np.sqrt(r0 * r0 + r1 * r1 + r2 * r2) < 1e-9:
        r0, r1, r2 = 1.0 - u0 * u0, -u0 * u1, -u0 * u2
    norm = np.sqrt(r0 * r0 + r1 * r1 + r2 * r2)
    r0, r1, r2 = r0 / norm, r1 / norm, r2 / norm
    e0, e1, e2 = anchors[elbow, 0] - s0, anchors[elbow, 1] - s1, anchors[elbow, 2] - s2
    along = e0 * u0 + e1 * u1 + e2 * u2
    d0, d1, d2 = e0 - along * u0, e1 - along * u1, e2 - along * u2
    c0, c1, c2 = r1 * d2 - r2 * d1, r2 * d0 - r0 * d2, r0 * d1 - r1 * d0
    return np.arctan2(u0 * c0 + u1 * c1 + u2 * c2, r0 * d0 + r1 * d1 + r2 * d2)
