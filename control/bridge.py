"""The bridge between the two papers (DESIGN §3): [T]'s motion/force law as a task of [C]'s QP.

[T]'s shaped task dynamics Λ̂x ẍ = u + F^e [T7–9] can be written in the form of [C]'s task row
[C9] with the task reference ë* = Λ̂x⁻¹u and Γ_x = Λ̂x⁻¹Λx, because J q̈_e = J M⁻¹ Jᵀ F^e = Λx⁻¹F^e:
    J q̈ + J̇ q̇ = Λ̂x⁻¹u + Γ_x J q̈_e = Λ̂x⁻¹(u + F^e).
This is the same dynamics in [C]'s notation, not a [C] compliance. [C]'s Γ is diagonal with
entries in 0…1, one per task axis. Γ_x is a full 6×6 matrix and is not symmetric: it couples the
axes (a push along a motion axis shows up on a force axis, the decoupling of [T9]). Its symmetric
part can be indefinite: at the polish start its eigenvalues run from about −0.8 to 2.8, so along
some directions the arm gives more than the natural response (> 1) and along others it pushes
back (< 0). `gamma_x_matrix` and `gamma_x_summary` give the matrix and those two numbers (the
real eigenvalues of ½(Γ_x + Γ_xᵀ), the size of ½(Γ_x − Γ_xᵀ)); the app shows them live while
the projection executor runs. With shaping off (Λ̂x = Λx) Γ_x = I, [C]'s full compliance.
[T]'s nullspace QP [T15–17] drives [C]'s posture task: q̈*₀ = K_n^d (q̂̇n − q̇) [T13].

What must agree (DESIGN §8): the task-space acceleration, always; the whole torque only when the
posture term is M-weighted (its minimiser under J q̈ = b is q̈*₀ + J̄(b − J q̈*₀), the dynamically
consistent split of [T14]) and both executors use the same q̂̇n (then N q̈*₀ = K_n (q̂̇n − N q̇),
which is [T13]'s M⁻¹NᵀF_n for a scalar K_n, since q̂̇n ∈ null(J) = range(N)). With a real
estimate (fusion [C26]) instead of the sensed wrench, the task accelerations differ by
Γ_x J M⁻¹ (τ̂_e − JᵀF^e) (tests/test_bridge.py).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from control.compliance_qp import ComplianceQPExecutor, PostureTask, TaskRows
from control.coupling import Subspaces, partially_decoupled_inertia
from control.executor import ControlInputs, StepView, TaskTarget
from control.gains import ComplianceQPSettings, EstimatorGains, PostureTaskGains, SolverParams
from control.model import Dynamics
from control.motion_force import ProjectionExecutor


class GammaXSummary(NamedTuple):
    """Γ_x in two numbers a reader can check: is it a compliance (symmetric, eigenvalues in 0…1)?"""

    sym_eigenvalues: np.ndarray  # (6,) real eigenvalues of ½(Γ_x + Γ_xᵀ), ascending
    skew_norm: float  # spectral norm of ½(Γ_x − Γ_xᵀ); 0 for a symmetric Γ_x


def gamma_x_matrix(Lambda: np.ndarray, sub: Subspaces, shaping: bool = True) -> np.ndarray:
    """Γ_x = Λ̂x⁻¹Λx (6×6, task order) for the subspaces `sub` [T9]; the identity without shaping."""
    if not shaping:
        return np.eye(6)
    return np.linalg.solve(partially_decoupled_inertia(Lambda, sub), Lambda)


def gamma_x_summary(gamma_x: np.ndarray) -> GammaXSummary:
    """Real eigenvalues of Γ_x's symmetric part and the size of its skew part."""
    g = np.asarray(gamma_x, dtype=float)
    sym = 0.5 * (g + g.T)
    skew = 0.5 * (g - g.T)
    return GammaXSummary(np.linalg.eigvalsh(sym), float(np.linalg.norm(skew, 2)))


class ShapedMotionForceTask:
    """[T]'s motion/force law as one 6-D [C] task row: ë* = Λ̂x⁻¹u, Γ_x = Λ̂x⁻¹Λx.

    Γ_x is the full, non-symmetric matrix of the module docstring, not a [C] compliance: the row
    reproduces [T]'s shaped dynamics in [C]'s form.

    The [T] law (a `ProjectionExecutor`) is run on the same snapshot and F/T reading to get u,
    its force integral and its nullspace QP; the task then reads
    Λ̂x⁻¹u = Λx⁻¹(F_x + F^e) − Λ̂x⁻¹F^e from its wrench F_x = Λx Λ̂x⁻¹(u + F^e) − F^e [T7].
    With a posture task attached, it hands [T]'s q̂̇n to it as the velocity reference.
    """

    dim = 6

    def __init__(self, law: ProjectionExecutor, weight: float = 1e4, strict: bool = False):
        if not weight > 0:
            raise ValueError(f"weight must be positive, got {weight!r}")
        self.law = law
        self.weight = float(weight)
        self.strict = strict
        self.posture: PostureTask | None = None
        self._inputs: ControlInputs | None = None
        self.reference_acc = np.zeros(6)
        self.Lambda_hat = np.eye(6)

    def reset(self, dyn: Dynamics, target: TaskTarget) -> None:
        """Reset the [T] law's integrator and posture."""
        self.law.reset(dyn, target)

    def prepare(self, dyn: Dynamics, inputs: ControlInputs) -> None:
        """Run the [T] law on this step's snapshot and reading (called before `rows`)."""
        self._inputs = inputs
        self.law.step(dyn, inputs)
        F_e = np.asarray(inputs.wrench_tcp, dtype=float)
        self.Lambda_hat = partially_decoupled_inertia(dyn.Lambda, self.law.sub)  # [T9]
        self.Lambda_hat_inv = np.linalg.inv(self.Lambda_hat)
        # Λ̂x⁻¹u from [T7]: F_x = Λx Λ̂x⁻¹ u + (Λx Λ̂x⁻¹ − I) F^e
        self.reference_acc = dyn.Lambda_inv @ (self.law.last_wrench + F_e) - self.Lambda_hat_inv @ F_e
        if self.posture is not None and self.law.last_qp is not None:
            self.posture.dq_ref = self.law.last_qp.x.copy()

    def set_qp_backend(self, backend: str) -> None:
        """The [T] law's nullspace QP follows the executor's QP backend."""
        self.law.set_params("solver", SolverParams(qp_backend=backend))

    def view(self) -> StepView:
        """The [T] law's view of this step (objective, W, split, coupling terms, its nullspace QP)."""
        return self.law.view()

    def rows(self, dyn: Dynamics, target: TaskTarget, ddq_e: np.ndarray) -> TaskRows:
        """J q̈ = Λ̂x⁻¹u + Γ_x J q̈_e − J̇ q̇ with Γ_x = Λ̂x⁻¹Λx (the form of [C9], full Γ_x)."""
        gamma_x = self.Lambda_hat_inv @ dyn.Lambda
        b = self.reference_acc + gamma_x @ (dyn.J @ ddq_e) - dyn.dJ_dq
        return TaskRows(dyn.J, b, self.weight, None)


def make_bridge_executor(
    robot,
    law: ProjectionExecutor,
    metric: str = "inertia",
    strict: bool = False,
    estimator: EstimatorGains | None = None,
    settings: ComplianceQPSettings | None = None,
    dt: float = 1e-3,
) -> ComplianceQPExecutor:
    """The [C] QP executor running [T]'s motion/force law and nullspace reference.

    Posture task: q̈*₀ = K_n^d (q̂̇n − q̇), K_n^d from the law's gains (must be one value for all
    joints), weight 1, `metric` "inertia" (dynamically consistent) or "identity" ([C9]).
    The task weight is 1e4 (1e4 : 1 as in [C]'s setup), or equality rows when `strict`.
    """
    kn = np.asarray(law.gains.nullspace_kd, dtype=float)
    if not np.allclose(kn, kn[0]):
        raise ValueError("the bridge needs one K_n^d for all joints (a scalar commutes with N)")
    task = ShapedMotionForceTask(law, strict=strict)
    ex = ComplianceQPExecutor.for_robot(
        robot,
        tasks=[task],
        posture=PostureTaskGains(stiffness=0.0, damping=float(kn[0]), weight=1.0, metric=metric),
        estimator=estimator or EstimatorGains(source="fusion"),
        settings=settings,
        dt=dt,
    )
    task.posture = ex.posture
    return ex
