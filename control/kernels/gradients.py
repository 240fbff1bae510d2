"""The gradient contraction [T24-27]: the ∂J part of ∂W/∂q and the vectors whose RNEA derivative
gives the ∂M part (see `control.coupling.coupling_gradient_direct`).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from control.kernels._linalg import _matmul, _matmul_bt

OBJECTIVE_CODES = {"f": 0, "a": 1, "d": 2}


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
    weight: np.ndarray,
) -> tuple:
    """(term_J, a, b): ∂W/∂q = −2 (term_J − term_M) with term_M[k] = Σ_c a_cᵀ ∂(M b_c)/∂q_k [T24].

    W = Σ weight ∘ P² (`weight` (n_f, n_m) from `coupling_weights_reference`; ones: ‖P‖²_F [T22]),
    so ∂W/∂q_k = 2⟨∂Λx_k, G⟩, G = leftᵀ (weight ∘ P) rightᵀ, and ∂Λx_k = −Λx ∂(Λx⁻¹)_k Λx with
    ∂(Λx⁻¹)_k = ∂J_k X + Xᵀ∂J_kᵀ − Xᵀ∂M_k X (X = M⁻¹Jᵀ). With H = Λx G Λx = U Vᵀ:
    term_J[k] = ⟨∂J_k, (H + Hᵀ) Xᵀ⟩ and ⟨∂M_k, X H Xᵀ⟩ = Σ_c (X U)_cᵀ ∂M_k (X V)_c.
    """
    eye = np.eye(6)
    S_f, S_m = eye[perm[n_m:]], eye[perm[:n_m]]
    left, right = _objective_sides(objective, Lambda_inv, P, A_inv, S_f, S_m, perm, n_m)
    U = Lambda @ left.T  # (6, n_f)
    V = Lambda @ ((weight * P) @ right.T).T  # (6, n_f)
    X = M_inv @ J.T
    H = U @ V.T
    n = J.shape[1]
    term_J = dJ.reshape(n, 6 * n) @ ((H + H.T) @ X.T).reshape(6 * n)
    return term_J, X @ U, X @ V


@njit(cache=True)
def gradient_contraction_fused(objective, J, M_inv, Lambda, Lambda_inv, P, A_inv, perm, n_m, weight):
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
    Pr = _matmul_bt(weight * P, right)  # (n_f, 6) = (weight ∘ P) rightᵀ
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
