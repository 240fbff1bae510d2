"""The coupling blocks A, B, D [T6, T20], A⁻¹, D̂ [T9], P_f, P_a, P_d (Table I) and W [T22]."""

from __future__ import annotations

import numpy as np
from numba import njit

from control.kernels._linalg import _inverse, _matmul, _sqnorm


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
