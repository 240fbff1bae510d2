"""Nullspace velocity QP [T15-17] with OSQP, plus first-order joint-limit dampers.

    min_x ½ xᵀx + k0 ∇Wᵀx   s.t.  J x = 0 [T16],  l ≤ x ≤ u [T17]

x is the goal nullspace velocity q̂̇n. The bounds l, u are the joint velocity limits (scaled)
tightened by a first-order velocity damper near each position limit (beyond the paper): with
d the distance to the lower limit, x ≥ −ξ (d − d_s)/(d_i − d_s) when d < d_i, and the mirror
bound at the upper limit. Endless joints get no damper.

The OSQP problem is set up once with a fixed sparsity pattern (P = I, A = [J; I] dense in the
J rows) and updated in place each step (warm-started). When OSQP does not return a solution or
the bounds are inconsistent, the step falls back to the bounded minimum-norm solution: the
gradient step projected on the kernel of J, scaled into the bounds. It never raises.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import osqp
import scipy.sparse as sp

from control.gains import NullspaceGains

N_TASK = 6
_SOLVED = (1, 2)  # OSQP_SOLVED, OSQP_SOLVED_INACCURATE


class NullspaceResult(NamedTuple):
    """One QP solve."""

    dq_goal: np.ndarray  # (n,) q̂̇n, rad/s
    fallback: bool  # OSQP failed / bounds inconsistent: bounded minimum-norm solution used
    status: str  # OSQP status text or the fallback reason
    iterations: int


def damper_bounds(
    q: np.ndarray,
    q_lower: np.ndarray,
    q_upper: np.ndarray,
    dq_limit: np.ndarray,
    endless: np.ndarray,
    gains: NullspaceGains,
) -> tuple[np.ndarray, np.ndarray]:
    """Velocity bounds (l, u): ±dq_limit tightened by first-order dampers near position limits.

    Inside d_s the bound changes sign (the damper pushes the joint back out); l ≤ u always holds
    because the two limits are far further apart than 2 d_i on every real joint.
    """
    span = gains.damper_influence - gains.damper_safety
    slope = gains.damper_speed / span
    d_low = q - q_lower
    d_up = q_upper - q
    # the damper bound only inside the influence distance (and never on endless joints)
    lo_damper = np.where((d_low < gains.damper_influence) & ~endless, -slope * (d_low - gains.damper_safety), -np.inf)
    up_damper = np.where((d_up < gains.damper_influence) & ~endless, slope * (d_up - gains.damper_safety), np.inf)
    return np.maximum(-dq_limit, lo_damper), np.minimum(dq_limit, up_damper)


def min_norm_fallback(J: np.ndarray, gradient_step: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """Bounded minimum-norm solution: −(I − J⁺J) k0∇W scaled uniformly into [l, u].

    When 0 lies inside the bounds the uniform scaling keeps J x = 0; otherwise the result is
    clipped (J x = 0 is then given up for the bounds, which protect the joints).
    """
    JJt = J @ J.T
    try:
        x = -(gradient_step - J.T @ np.linalg.solve(JJt, J @ gradient_step))
    except np.linalg.LinAlgError:
        x = np.zeros_like(gradient_step)
    if not np.all(np.isfinite(x)):
        x = np.zeros_like(gradient_step)
    if np.all(lower <= 0.0) and np.all(upper >= 0.0):
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio_u = np.where(x > 0, upper / x, np.inf)
            ratio_l = np.where(x < 0, lower / x, np.inf)
        s = min(1.0, float(np.min(ratio_u)), float(np.min(ratio_l)))
        return x * max(s, 0.0)
    return np.clip(x, lower, upper)


class NullspaceQP:
    """The [T15-17] QP for an n-joint arm, built once and updated in place every step."""

    def __init__(self, n: int = 7, eps: float = 1e-7, max_iter: int = 400):
        self.n = n
        m = N_TASK + n
        # A = [J; I] in CSC: column j holds rows 0..5 (J[:, j]) then row 6 + j (the identity).
        indptr = np.arange(0, (N_TASK + 1) * n + 1, N_TASK + 1)
        indices = np.concatenate([np.r_[np.arange(N_TASK), N_TASK + j] for j in range(n)])
        self._A_data = np.zeros((N_TASK + 1, n))
        self._A_data[N_TASK] = 1.0
        A = sp.csc_matrix((self._A_data.ravel(order="F"), indices, indptr), shape=(m, n))
        P = sp.identity(n, format="csc")  # Q = I [T15]
        self._l = np.zeros(m)
        self._u = np.zeros(m)
        self._solver = osqp.OSQP()
        self._solver.setup(
            P=P,
            q=np.zeros(n),
            A=A,
            l=self._l,
            u=self._u,
            verbose=False,
            warm_starting=True,
            polishing=False,
            eps_abs=eps,
            eps_rel=eps,
            max_iter=max_iter,
        )
        self.last: NullspaceResult | None = None
        ext = getattr(self._solver, "_solver", None)
        needed = ("update_data_vec", "update_data_mat", "solve", "info", "solution")
        self._ext = ext if ext is not None and all(hasattr(ext, a) for a in needed) else None

    def solve(self, J: np.ndarray, gradient_step: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> NullspaceResult:
        """Goal nullspace velocity for q = k0 ∇W (`gradient_step`), J x = 0 and l ≤ x ≤ u."""
        n = self.n
        # one dot product per array: NaN/inf anywhere makes it non-finite (cheaper than isfinite)
        Jr = J.ravel()
        if not (math.isfinite(float(Jr @ Jr)) and math.isfinite(float(gradient_step @ gradient_step))):
            return self._fallback(np.zeros((N_TASK, n)), np.zeros(n), lower, upper, "non-finite input")
        if not (math.isfinite(float(lower @ lower)) and math.isfinite(float(upper @ upper))) or np.any(lower > upper):
            return self._fallback(J, gradient_step, lower, upper, "inconsistent bounds")
        self._A_data[:N_TASK] = J
        self._l[N_TASK:] = lower
        self._u[N_TASK:] = upper
        Ax = self._A_data.ravel(order="F")
        try:
            if self._ext is not None:  # the extension object directly: skips ~20 µs of wrapper
                ext = self._ext
                ext.update_data_vec(q=gradient_step, l=self._l, u=self._u)
                ext.update_data_mat(P_x=None, P_i=None, A_x=Ax, A_i=None)
                ext.solve()
                info = ext.info
                status, status_val, iters = str(info.status), int(info.status_val), int(info.iter)
                x = np.array(ext.solution.x, dtype=float)
            else:  # pragma: no cover - public API path for other OSQP builds
                self._solver.update(q=gradient_step, l=self._l, u=self._u, Ax=Ax)
                res = self._solver.solve(raise_error=False)
                status, status_val, iters = str(res.info.status), int(res.info.status_val), int(res.info.iter)
                x = np.array(res.x, dtype=float) if res.x is not None else np.full(n, np.nan)
        except (ValueError, RuntimeError, TypeError) as exc:  # pragma: no cover - defensive
            return self._fallback(J, gradient_step, lower, upper, f"osqp error: {exc}")
        if status_val not in _SOLVED or not math.isfinite(float(x @ x)):
            return self._fallback(J, gradient_step, lower, upper, status)
        self.last = NullspaceResult(x, False, status, iters)
        return self.last

    def _fallback(
        self, J: np.ndarray, gradient_step: np.ndarray, lower: np.ndarray, upper: np.ndarray, why: str
    ) -> NullspaceResult:
        x = min_norm_fallback(J, gradient_step, lower, upper) if np.any(J) else np.zeros(self.n)
        self.last = NullspaceResult(x, True, why, 0)
        return self.last
