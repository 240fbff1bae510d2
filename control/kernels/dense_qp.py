"""The dense QP backend's load and its exact fast path, each beside its reference.

Like `control.kernels` (same conventions: numba with `cache=True`, a `*_reference` function that
states the algebra readably, `tests/test_kernels.py` holding the fused version to it):

- `dense_qp_load_*`: what `control.qp.DenseBackend` does before DAQP — copy the data into the
  backend's one buffer, refuse NaN and crossed bounds — and its exact fast path: for a strictly
  convex problem without equality rows, the unconstrained minimiser x = −P⁻¹q (Cholesky) that
  meets every bound and row (to the primal tolerance, DAQP's own test of the same candidate) is
  the optimum (the KKT conditions hold with all multipliers zero), so DAQP is not needed.
- `cqp_problem_fused`: the [C] executor's estimate [C25-26] and QP data [C9, C10, C17-24] in one call
  of the `control.kernels` functions the executor's reference path calls one by one
  (`ComplianceQPExecutor._step_reference` is its statement; `tests/test_compliance_qp.py` holds
  the fused step to it).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from control.kernels.records import fill_record, record_dtype

# `dense_qp_load_*` outcomes
FAST_SOLVED = 0  # x holds the optimum (the unconstrained minimiser is feasible)


NEEDS_SOLVER = 1  # data loaded, hand it to DAQP


NON_FINITE_DATA = 2  # NaN (or inf outside the bounds) in the data


CROSSED_BOUNDS = 3  # a lower bound above its upper bound


PIVOT_FLOOR = 1e-12  # Cholesky pivots below this times P's largest diagonal entry: left to DAQP


def dense_qp_buffer(n: int, m: int) -> np.ndarray:
    """The one data buffer of an (n variables, m rows) problem: [P (n·n), A (m·n), q (n), lower
    (n + m: box, then rows), upper (n + m)] (`dense_qp_views` names the parts)."""
    return np.zeros(n * n + m * n + n + 2 * (n + m))


def dense_qp_views(data: np.ndarray, n: int, m: int) -> tuple:
    """(P, A, q, lower, upper) views into a `dense_qp_buffer`."""
    k = n + m
    P = data[: n * n].reshape(n, n)
    A = data[n * n : n * n + m * n].reshape(m, n)
    rest = data[n * n + m * n :]
    return P, A, rest[:n], rest[n : n + k], rest[n + k : n + 2 * k]


SETUP_DTYPE = record_dtype(
    (), (("n", np.int64), ("m", np.int64), ("n_eq", np.int64), ("no_bound", np.float64), ("tol", np.float64))
)  # `dense_qp_setup`


def dense_qp_setup(n: int, m: int, n_eq: int, no_bound: float, tol: float) -> np.ndarray:
    """The record of what a dense problem's load reads besides its data (`control.kernels.records`):
    n variables, m rows (the last n_eq of them equalities), the value standing for no bound and the
    fast path's primal tolerance, by name."""
    return fill_record(SETUP_DTYPE, (), n=n, m=m, n_eq=n_eq, no_bound=no_bound, tol=tol)


def dense_qp_load_reference(
    data: np.ndarray,
    setup: np.ndarray,
    P: np.ndarray | None,
    q: np.ndarray,
    A: np.ndarray | None,
    l: np.ndarray,
    u: np.ndarray,
    lb: np.ndarray,
    ub: np.ndarray,
    x: np.ndarray,
) -> int:
    """Load min ½xᵀPx + qᵀx s.t. lb ≤ x ≤ ub, l ≤ Ax ≤ u (last n_eq rows equalities; P, A None:
    unchanged) into `data` and try the fast path; returns one of the outcome codes above and, for
    FAST_SOLVED, the optimum in `x`.

    ±inf bounds become ±no_bound (only when the data's sum of squares is not finite, as the
    backend always did); NaN anywhere is NON_FINITE_DATA. The fast path needs no equality rows and
    P positive definite (every Cholesky pivot above PIVOT_FLOOR · max diag P); its candidate
    x = −P⁻¹q must be finite and meet lb − tol ≤ x ≤ ub + tol, l − tol ≤ Ax ≤ u + tol. The sizes,
    no_bound and tol are read from `setup` (`dense_qp_setup`)."""
    c = setup[0]
    n, m, n_eq, no_bound, tol = int(c["n"]), int(c["m"]), int(c["n_eq"]), float(c["no_bound"]), float(c["tol"])
    Pd, Ad, qd, lo, hi = dense_qp_views(data, n, m)
    if P is not None:
        Pd[:] = P
    if A is not None:
        Ad[:] = A
    qd[:] = q
    lo[:n], lo[n:], hi[:n], hi[n:] = lb, l, ub, u
    with np.errstate(over="ignore", invalid="ignore"):
        finite = math.isfinite(float(data @ data))
        if not finite:
            bounds = data[n * n + m * n + n :]
            np.clip(bounds, -no_bound, no_bound, out=bounds)
            finite = math.isfinite(float(data @ data))
    if not finite:
        return NON_FINITE_DATA
    if (lo > hi).any():
        return CROSSED_BOUNDS
    if n_eq > 0:
        return NEEDS_SOLVER
    try:
        L = np.linalg.cholesky(Pd)
    except np.linalg.LinAlgError:
        return NEEDS_SOLVER
    if not np.all(np.diag(L) ** 2 > PIVOT_FLOOR * max(float(np.max(np.diag(Pd))), 0.0)):
        return NEEDS_SOLVER
    cand = -np.linalg.solve(L.T, np.linalg.solve(L, qd))
    rows = Ad @ cand
    if not np.all(np.isfinite(cand)):
        return NEEDS_SOLVER
    if np.any(cand < lo[:n] - tol) or np.any(cand > hi[:n] + tol):
        return NEEDS_SOLVER
    if np.any(rows < lo[n:] - tol) or np.any(rows > hi[n:] + tol):
        return NEEDS_SOLVER
    x[:] = cand
    return FAST_SOLVED


@njit(cache=True)
def dense_qp_load_fused(data, setup, P, q, A, l, u, lb, ub, x):
    """`dense_qp_load_reference` in one compiled call (Cholesky and the triangular solves written
    out, on the P held in `data`)."""
    c = setup[0]
    n, m, n_eq, no_bound, tol = c.n, c.m, c.n_eq, c.no_bound, c.tol
    k = n + m
    off_A = n * n
    off_q = off_A + m * n
    off_lo = off_q + n
    off_hi = off_lo + k
    if P is not None:
        for i in range(n):
            for j in range(n):
                data[i * n + j] = P[i, j]
    if A is not None:
        for i in range(m):
            for j in range(n):
                data[off_A + i * n + j] = A[i, j]
    for i in range(n):
        data[off_q + i] = q[i]
        data[off_lo + i] = lb[i]
        data[off_hi + i] = ub[i]
    for i in range(m):
        data[off_lo + n + i] = l[i]
        data[off_hi + n + i] = u[i]
    s = 0.0
    for i in range(data.shape[0]):
        s += data[i] * data[i]
    if not math.isfinite(s):
        for i in range(off_lo, off_hi + k):
            if data[i] > no_bound:
                data[i] = no_bound
            elif data[i] < -no_bound:
                data[i] = -no_bound
        s = 0.0
        for i in range(data.shape[0]):
            s += data[i] * data[i]
        if not math.isfinite(s):
            return NON_FINITE_DATA
    for i in range(k):
        if data[off_lo + i] > data[off_hi + i]:
            return CROSSED_BOUNDS
    if n_eq > 0:
        return NEEDS_SOLVER
    P = data[:off_A].reshape((n, n))
    A = data[off_A:off_q].reshape((m, n))
    lower, upper = data[off_lo:off_hi], data[off_hi : off_hi + k]
    if unconstrained_optimum_fused(P, data[off_q:off_lo], A, lower[:n], lower[n:], upper[:n], upper[n:], tol, x):
        return FAST_SOLVED
    return NEEDS_SOLVER


@njit(cache=True)
def unconstrained_optimum_fused(P, q, A, lb, l, ub, u, tol, x):
    """The fast path of `dense_qp_load_fused`: x = −P⁻¹q by Cholesky (lower triangle of P read;
    every pivot above PIVOT_FLOOR · max diag P) written into `x` when it is finite and meets
    lb − tol ≤ x ≤ ub + tol and l − tol ≤ A x ≤ u + tol; returns whether it did. Data with NaN
    (or a crossed bound) is refused: it is the backend's to report."""
    n, m = P.shape[0], A.shape[0]
    for i in range(n):
        if not (math.isfinite(q[i]) and lb[i] <= ub[i]):
            return False
        for j in range(n):
            if not math.isfinite(P[i, j]):
                return False
    for r in range(m):
        if not l[r] <= u[r]:
            return False
        for j in range(n):
            if not math.isfinite(A[r, j]):
                return False
    L = np.zeros((n, n))
    max_diag = 0.0
    for i in range(n):
        max_diag = max(max_diag, P[i, i])
    floor = PIVOT_FLOOR * max_diag
    for j in range(n):
        d = P[j, j]
        for c in range(j):
            d -= L[j, c] * L[j, c]
        if not d > floor:
            return False
        L[j, j] = math.sqrt(d)
        for i in range(j + 1, n):
            v = P[i, j]
            for c in range(j):
                v -= L[i, c] * L[j, c]
            L[i, j] = v / L[j, j]
    # L y = −q, Lᵀ x = y
    y = np.empty(n)
    for i in range(n):
        v = -q[i]
        for c in range(i):
            v -= L[i, c] * y[c]
        y[i] = v / L[i, i]
    cand = np.empty(n)
    for i in range(n - 1, -1, -1):
        v = y[i]
        for c in range(i + 1, n):
            v -= L[c, i] * cand[c]
        v /= L[i, i]
        if not math.isfinite(v):
            return False
        if v < lb[i] - tol or v > ub[i] + tol:
            return False
        cand[i] = v
    for r in range(m):
        v = 0.0
        for j in range(n):
            v += A[r, j] * cand[j]
        if v < l[r] - tol or v > u[r] + tol:
            return False
    for i in range(n):
        x[i] = cand[i]
    return True


def unconstrained_optimum_reference(P, q, A, lb, l, ub, u, tol, x) -> bool:
    """`unconstrained_optimum_fused` in numpy: x = −P⁻¹q by Cholesky (lower triangle; every pivot
    above PIVOT_FLOOR · max diag P) into `x` when finite and within lb, ub and l ≤ A x ≤ u (to `tol`);
    NaN or a crossed bound refused."""
    if not (np.all(np.isfinite(P)) and np.all(np.isfinite(q)) and np.all(np.isfinite(A))):
        return False
    if not (np.all(lb <= ub) and np.all(l <= u)):
        return False
    try:
        L = np.linalg.cholesky(P)
    except np.linalg.LinAlgError:
        return False
    if not np.all(np.diag(L) ** 2 > PIVOT_FLOOR * max(float(np.max(np.diag(P))), 0.0)):
        return False
    cand = -np.linalg.solve(L.T, np.linalg.solve(L, q))
    if not np.all(np.isfinite(cand)) or np.any(cand < lb - tol) or np.any(cand > ub + tol):
        return False
    rows = A @ cand
    if np.any(rows < l - tol) or np.any(rows > u + tol):
        return False
    x[:] = cand
    return True
