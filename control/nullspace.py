"""Nullspace velocity QP [T15-17], plus first-order joint-limit dampers.

    min_x ½ xᵀx + k0 ∇Wᵀx   s.t.  J x = 0 [T16],  l ≤ x ≤ u [T17]

x is the goal nullspace velocity q̂̇n. The bounds l, u are the joint velocity limits (scaled)
tightened by a first-order velocity damper near each position limit (beyond the paper): with
d the distance to the lower limit, x ≥ −ξ (d − d_s)/(d_i − d_s) when d < d_i, and the mirror
bound at the upper limit. Endless joints get no damper.

The QP is set up once through `control.qp` (dense active-set backend by default, OSQP with a
fixed sparsity pattern as the reference) and updated in place each step (warm-started). For a
7-joint arm the kernel of J is a line, and the dense backend solves the QP in closed form on it
(`control.qp.LineQPFirst`: the same optimum, without a solver call); where that
does not apply (J rank deficient, no point of the line meets the box) the active-set solver
decides as for any other arm.

The QP has no solution by construction when a joint is inside its damper's safety distance d_s
(its bound excludes 0: it must move out) and no nullspace motion moves it out fast enough within
the other joints' bounds, as under a hard drag that pins the joint in its stop zone. The step then
takes the least-violation solution (`RelaxedNullspaceQP`): J x = 0 [T16] is softened with a
penalty ρ‖J x‖² while the bounds [T17], which protect the joints, stay hard; the status says which
joint and why (`relaxed_reason`). Only when that fails too, or the bounds are inconsistent, the
step falls back to the bounded minimum-norm solution: the gradient step projected on the kernel
of J, scaled into the bounds. Both are flagged `fallback`. It never raises.
"""

from __future__ import annotations

import math

import numpy as np

from control import qp
from control.gains import NullspaceGains

N_TASK = 6
RELAX_WEIGHT = 1e4  # ρ of the least-violation problem: ‖J x‖² weighs this much more than ½‖x‖²


# One QP solve: x is q̂̇n (rad/s); `fallback` when the QP failed or the bounds are inconsistent
# (then x is the bounded minimum-norm solution and status the reason).
NullspaceResult = qp.QPResult


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


def relaxed_reason(lower: np.ndarray, upper: np.ndarray) -> str:
    """The status of a relaxed step: the joints whose bounds exclude 0 (inside their safety distance,
    the damper asks them to move out) and what the step does instead; 1-based joint numbers."""
    pinned = [i + 1 for i in range(lower.size) if lower[i] > 0.0 or upper[i] < 0.0]
    joints = ", ".join(str(i) for i in pinned) or "?"
    which = "joint" if len(pinned) == 1 else "joints"
    return (
        f"{qp.RELAXED}: {which} {joints} in the limit's safety zone and no nullspace motion within the "
        f"speed limits moves {'it' if len(pinned) == 1 else 'them'} out; the arm keeps the tool's task "
        "and asks the nullspace for the nearest motion that does (J x = 0 softened, the limit bounds kept)"
    )


class RelaxedNullspaceQP:
    """The least-violation form of the [T15-17] QP when it has no feasible point:

        min_x ½ xᵀx + k0 ∇Wᵀx + ½ ρ ‖J x‖²   s.t.  l ≤ x ≤ u [T17]

    (P = I + ρ JᵀJ, ρ = `RELAX_WEIGHT`): the bounds stay hard and, among the points of the box, the
    one nearest the kernel of J (J x = 0 [T16]) in the ρ-weighted sense. Set up once (`control.qp`,
    one free dummy row: a box-only problem).
    """

    def __init__(self, n: int, backend: str, eps: float, max_iter: int):
        self.n = n
        self._qp = qp.make_qp(backend, n, 1, settings=qp.QPSettings(eps=eps, max_iter=max_iter))
        self._P = np.empty((n, n))
        self._eye = np.eye(n)
        self._A = np.zeros((1, n))
        self._lo, self._hi = np.full(1, -qp.INF), np.full(1, qp.INF)

    def solve(self, J: np.ndarray, gradient_step: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> qp.QPResult:
        """The relaxed optimum (status and x as the backend returned them)."""
        np.matmul(J.T, J, out=self._P)
        self._P *= RELAX_WEIGHT
        self._P += self._eye
        return self._qp.solve(self._P, gradient_step, self._A, self._lo, self._hi, lower, upper)


class NullspaceQP(qp.LineQPFirst):
    """The [T15-17] QP for an n-joint arm, set up once (`control.qp`) and updated every step.

    P = I [T15] stays; A = J with J x = 0 [T16] as equality rows; the bounds are the box [T17].
    """

    def __init__(
        self,
        n: int = 7,
        eps: float = 1e-7,
        max_iter: int = 400,
        backend: str | None = None,
        polish: bool = False,
        closed_form: bool = True,
    ):
        self.n = n
        self.backend = qp.check_backend(backend or qp.default_backend())
        # dense backend, 7 joints: the one-dimensional kernel's closed form first (module docstring)
        self.closed_form = bool(closed_form) and qp.line_qp_applies(self.backend, n, N_TASK)
        self._qp = qp.make_qp(
            self.backend,
            n,
            N_TASK,
            n_eq=N_TASK,
            P_pattern=np.eye(n, dtype=bool),
            settings=qp.QPSettings(eps=eps, max_iter=max_iter, polish=polish),
        )
        self._zero = np.zeros(N_TASK)
        self._relaxed = RelaxedNullspaceQP(n, self.backend, eps, max_iter)
        self.last: NullspaceResult | None = None

    def solve_general(
        self, J: np.ndarray, gradient_step: np.ndarray, lower: np.ndarray, upper: np.ndarray
    ) -> NullspaceResult:
        """Goal nullspace velocity for q = k0 ∇W (`gradient_step`), J x = 0 and l ≤ x ≤ u, by the
        backend (`solve`, from `qp.LineQPFirst`, tries the 7-joint closed form first)."""
        res = self._qp.solve(None, gradient_step, J, self._zero, self._zero, lower, upper)
        if res.solved:
            self.last = res
            return res
        # why not (checked only now, off the normal path): one dot product per array
        Jr = J.ravel()
        if not (math.isfinite(float(Jr @ Jr)) and math.isfinite(float(gradient_step @ gradient_step))):
            n = self.n
            return self._fallback(np.zeros((N_TASK, n)), np.zeros(n), lower, upper, "non-finite input", res)
        if np.any(np.isnan(lower)) or np.any(np.isnan(upper)) or np.any(lower > upper):
            return self._fallback(J, gradient_step, lower, upper, "inconsistent bounds", res)
        if res.status == qp.INFEASIBLE:  # no point meets J x = 0 and the bounds: the least violation
            soft = self._relaxed.solve(J, gradient_step, lower, upper)
            if soft.solved:
                why = relaxed_reason(lower, upper)
                it, us = res.iterations + soft.iterations, res.solve_us + soft.solve_us
                self.last = NullspaceResult(soft.x, why, it, us, self.backend, fallback=True)
                return self.last
        return self._fallback(J, gradient_step, lower, upper, res.status, res)

    def closed_form_result(self, x: np.ndarray, active: int) -> NullspaceResult:
        """The result of a closed-form solve done by the caller's compiled step (see `solve`):
        `active` bounds (0 or 1); its time is part of that call, so `solve_us` is NaN."""
        self.last = qp.line_qp_result(x, active, self.backend)
        return self.last

    def _fallback(
        self,
        J: np.ndarray,
        gradient_step: np.ndarray,
        lower: np.ndarray,
        upper: np.ndarray,
        why: str,
        res: NullspaceResult | None = None,
    ) -> NullspaceResult:
        x = min_norm_fallback(J, gradient_step, lower, upper) if np.any(J) else np.zeros(self.n)
        it, us = (0, 0.0) if res is None else (res.iterations, res.solve_us)
        self.last = NullspaceResult(x, why, it, us, self.backend, fallback=True)
        return self.last
