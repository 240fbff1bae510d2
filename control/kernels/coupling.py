"""The coupling blocks A, B, D [T6, T20], A⁻¹, D̂ [T9], P_f, P_a, P_d (Table I) and W [T22]."""

from __future__ import annotations

import numpy as np
from numba import njit

from control.kernels._linalg import _inverse, _matmul


def coupling_weights_reference(scale: np.ndarray, perm: np.ndarray, n_m: int) -> tuple:
    """(w_f, w_a, w_d), each (n_f, n_m): the weights that turn ‖P‖²_F [T22] into the norm of P in
    task coordinates scaled by `scale` (6,), task order.

    With Λ̃x = diag(s) Λx diag(s) (s = `scale`), the projections of Λ̃x are P̃_f = P_f / (s_f s_mᵀ),
    P̃_a = P_a ∘ s_f s_mᵀ and P̃_d = P_d ∘ s_f / s_mᵀ, so W̃ = Σ w ∘ P² with w the squares of those
    factors. All ones (s = 1) gives W as [T22]; the blocks A, B, D, D̂ themselves never change.
    """
    s_m, s_f = scale[perm[:n_m]], scale[perm[n_m:]]
    ratio = s_f[:, None] / s_m[None, :]
    prod = s_f[:, None] * s_m[None, :]
    return 1.0 / (prod * prod), prod * prod, ratio * ratio


def coupling_reference(
    Lambda: np.ndarray, Lambda_inv: np.ndarray, perm: np.ndarray, n_m: int, exact: bool, scale: np.ndarray
) -> tuple:
    """(A, B, D, A⁻¹, D̂, P_f, P_a, P_d, W_f, W_a, W_d) in (motion, force) order `perm` [T6].

    With `exact` (Λx⁻¹ is the inverse of Λx) the block-inverse identities avoid an inversion:
    with L = Λx⁻¹, D̂ = L_ff⁻¹, BᵀA⁻¹ = −D̂ L_fm and A⁻¹ = L_mm − L_mf D̂ L_fm.
    The W's are taken in task coordinates scaled by `scale` (6,) (`coupling_weights_reference`;
    ones: ‖P‖²_F as [T22]); the blocks and P's are the physical ones.
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
    weights = coupling_weights_reference(scale, perm, n_m)
    W = [float(np.sum(w * P * P)) for w, P in zip(weights, (P_f, P_a, P_d), strict=True)]  # [T22] W = ‖P‖²_F
    return A, B, D, A_inv, D_hat, P_f, P_a, P_d, W[0], W[1], W[2]


@njit(cache=True)
def coupling_weights_fused(scale, perm, n_m):
    """Compiled `coupling_weights_reference`."""
    nf = 6 - n_m
    w_f = np.empty((nf, n_m))
    w_a = np.empty((nf, n_m))
    w_d = np.empty((nf, n_m))
    for r in range(nf):
        for c in range(n_m):
            prod = scale[perm[n_m + r]] * scale[perm[c]]
            ratio = scale[perm[n_m + r]] / scale[perm[c]]
            w_f[r, c] = 1.0 / (prod * prod)
            w_a[r, c] = prod * prod
            w_d[r, c] = ratio * ratio
    return w_f, w_a, w_d


@njit(cache=True)
def coupling_fused(Lambda, Lambda_inv, perm, n_m, exact, scale):
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
    W_f = 0.0
    W_a = 0.0
    W_d = 0.0
    for r in range(nf):  # [T22] W = Σ w ∘ P², w as `coupling_weights_fused` (no arrays here)
        for c in range(k):
            prod = scale[perm[k + r]] * scale[perm[c]]
            ratio = scale[perm[k + r]] / scale[perm[c]]
            W_f += P_f[r, c] * P_f[r, c] / (prod * prod)
            W_a += prod * prod * P_a[r, c] * P_a[r, c]
            W_d += ratio * ratio * P_d[r, c] * P_d[r, c]
    return A, B, D, A_inv, D_hat, P_f, P_a, P_d, W_f, W_a, W_d
