"""Small dense-algebra helpers the compiled kernels share (numba, `cache=True`): products into
caller buffers, symmetrisation, Cholesky and SPD inverse, Gauss-Jordan inverse, 3-vector cross
products and 3×3 products. Private to `control.kernels`: each is tested through the kernels that call it.
"""

from __future__ import annotations

import numpy as np
from numba import njit


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
def _np_max(a, b):
    """numpy.maximum of two floats (NaN if either is NaN)."""
    if a != a or b != b:
        return np.nan
    return a if a >= b else b
