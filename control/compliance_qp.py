"""The [C] QP executor: acceleration QP with explicit compliance, safety constraints and
inverse dynamics with external-torque compensation (Celerier et al.).

Decision variable q̈ (n). Objective [C9]:
    Σ_k w_k ‖J_k q̈ + J̇_k q̇ − ẍ°_k − ë*_k − Γ_k J_k q̈_e‖²  +  w₀ ‖q̈ − q̈*₀ − Γ₀ q̈_e‖²_W₀,
q̈_e = M⁻¹ τ̂_e, ë*_k = −K_d ė − K_p e [C3, C6], W₀ = I ([C9]) or M (dynamically consistent,
DESIGN §8). Each task is a small object that turns a `Dynamics` snapshot into rows (J, b, weight)
meaning "J q̈ ≈ b"; a task marked strict becomes equality rows instead.
Constraints: joint position/velocity dampers [C17–24] as bounds on q̈; torque limits [C10]
τ⁻ ≤ M q̈ + h − τ̂_e ≤ τ⁺. Torque [C8]: τ_d = M q̈ + C q̇ + g − τ̂_e. The feedback switch removes
τ̂_e from [C8] and [C10] (the paper's Fig. 4 case) while the compliance terms keep it.

The QP is set up once through `control.qp` (dense active-set backend by default, OSQP as the
reference) and updated in place every step (warm-started). If it has no solution (torque limits
and dampers cannot hold together) the damper bounds are softened with penalised slacks while the
torque limits — which the motors enforce anyway by saturation — stay hard (`AccelerationQP`; its
status says which damper gave way, `slack_reason`); if that fails too, the tasks' unconstrained
optimum clipped to the damper bounds is used. Both cases are flagged; nothing raises inside `step`.

`ComplianceQPExecutor._step_reference` states the step object by object; `step` runs the same
step with the pose task, the posture task, the dampers and the torque rows in one compiled call
(`control.kernels.cqp.cqp_problem_fused`), tested equal to the reference to 1e-9.
"""

from __future__ import annotations

import math
import time
from dataclasses import replace
from typing import Any, NamedTuple, Protocol

import numpy as np
import pinocchio as pin

from control import qp
from control.dampers import JointLimitDamper
from control.estimation import ExternalTorqueEstimator
from control.executor import ControlInputs, ControlOutput, StepView, TaskTarget
from control.gains import (
    ComplianceQPSettings,
    DamperGains,
    EstimatorGains,
    PoseTaskGains,
    PostureTaskGains,
    SolverParams,
    compliance_matrix,
)
from control.kernels.compliance import (
    add_task_rows_fused,
    inverse_dynamics_fused,
    pose_task_target_fused,
    posture_target_fused,
    torque_rows_fused,
)
from control.kernels.cqp import (
    cqp_problem_fused,
    cqp_workspace_dtype,
    pose_record_dtype,
    posture_record_dtype,
    settings_record_dtype,
)
from control.kernels.records import fill_record
from control.model import Dynamics
from control.params import expect


class TaskRows(NamedTuple):
    """A task's contribution: weight · ‖J q̈ − b‖²_metric (or J q̈ = b when strict)."""

    J: np.ndarray  # (m, n)
    b: np.ndarray  # (m,) desired J q̈, compliance term included
    weight: float
    metric: np.ndarray | None  # (m, m) weighting, None = identity


class Task(Protocol):
    """Anything that yields rows for the QP objective."""

    dim: int
    strict: bool

    def reset(self, dyn: Dynamics, target: TaskTarget) -> None:
        """Clear internal state (integrators) at (re)start."""

    def rows(self, dyn: Dynamics, target: TaskTarget, ddq_e: np.ndarray) -> TaskRows:
        """Rows at this step; ddq_e = M⁻¹ τ̂_e is the acceleration the external forces cause."""
        ...


def pose_error(dyn: Dynamics, target: TaskTarget) -> np.ndarray:
    """e = x − x° of the TCP pose [C3]: [p − p°; log(R R°ᵀ)] in world axes (6,)."""
    e = np.empty(6)
    e[:3] = dyn.tcp_position_world - target.position
    e[3:] = pin.log3(dyn.tcp_rotation_world @ target.rotation.T)
    return e


class PoseTask:
    """6-D TCP pose task with explicit compliance Γ_k [C3–6, C9]."""

    dim = 6

    def __init__(self, gains: PoseTaskGains | None = None, strict: bool = False):
        self.strict = strict
        self.configure(gains or PoseTaskGains())

    def configure(self, gains: PoseTaskGains) -> None:
        """New gains / Γ (validated by the dataclass)."""
        self.gains = gains
        # the fused step's record of this task (`kernels.cqp.pose_record_dtype`: w by name, K_p, K_d, Γ);
        # the attributes are views of it
        gamma = compliance_matrix(gains.compliance, 6)
        self._use_gamma = bool(gamma.any())
        rec = self.kernel_record = fill_record(
            pose_record_dtype(), (gains,), kp=np.broadcast_to(np.asarray(gains.stiffness, dtype=float), (6,)),
            kd=np.broadcast_to(np.asarray(gains.damping, dtype=float), (6,)), gamma=gamma, use_gamma=self._use_gamma,
        )  # fmt: skip
        self.kp, self.kd, self.gamma = rec["kp"][0], rec["kd"][0], rec["gamma"][0]

    def reset(self, dyn: Dynamics, target: TaskTarget) -> None:
        """No internal state."""

    def reference(self, dyn: Dynamics, target: TaskTarget) -> np.ndarray:
        """ë* = −K_d ė − K_p e [C3] (the feed-forward ẍ° is added in `rows`)."""
        e = pose_error(dyn, target)
        de = dyn.J @ dyn.dq - target.velocity
        return -self.kd * de - self.kp * e

    def rows(self, dyn: Dynamics, target: TaskTarget, ddq_e: np.ndarray) -> TaskRows:
        """`rows_reference` in one compiled call (`control.kernels.compliance.pose_task_target_fused`)."""
        b = pose_task_target_fused(dyn.record, target.record, self.kernel_record, ddq_e)
        return TaskRows(dyn.J, b, self.gains.weight, None)

    def rows_reference(self, dyn: Dynamics, target: TaskTarget, ddq_e: np.ndarray) -> TaskRows:
        """J q̈ = ẍ° + ë* + Γ J q̈_e − J̇ q̇ [C4, C9]."""
        b = target.acceleration + self.reference(dyn, target) - dyn.dJ_dq
        if self.gamma.any():
            b = b + self.gamma @ (dyn.J @ ddq_e)
        return TaskRows(dyn.J, b, self.gains.weight, None)


class PostureTask:
    """Joint posture task, task 0 of [C7, C9]: q̈ ≈ q̈*₀ + Γ₀ q̈_e, identity or M metric.

    q_ref is the target's `q_posture` (or the posture at reset); `dq_ref` may be set each step to
    track a nullspace velocity, e.g. [T]'s q̂̇n from the nullspace QP (DESIGN §3 bridge).
    """

    def __init__(self, n: int, gains: PostureTaskGains | None = None, dt: float = 1e-3):
        self.dim = n
        self.strict = False
        self.dt = float(dt)
        self.dq_ref: np.ndarray | None = None
        self.q_hold = np.zeros(n)
        self._eye = np.eye(n)
        self.configure(gains or PostureTaskGains())

    def configure(self, gains: PostureTaskGains) -> None:
        """New gains / Γ₀ / metric (validated by the dataclass)."""
        n = self.dim
        self.gains = gains
        # the fused step's record of this task (`kernels.cqp.posture_record_dtype`: w₀ by name, K_p, K_d,
        # K_i, Γ₀, δt, the metric); the attributes are views of it
        ki = np.broadcast_to(np.asarray(gains.integral, dtype=float), (n,))
        gamma = compliance_matrix(gains.compliance, n)
        self._use_ki, self._use_gamma = bool(ki.any()), bool(gamma.any())
        old = getattr(self, "integral", None)  # new gains keep the integral running
        rec = self.kernel_record = fill_record(
            posture_record_dtype(n), (gains,), kp=np.broadcast_to(np.asarray(gains.stiffness, dtype=float), (n,)),
            kd=np.broadcast_to(np.asarray(gains.damping, dtype=float), (n,)), ki=ki, gamma=gamma,
            use_ki=self._use_ki, use_gamma=self._use_gamma, dt=self.dt, inertia_metric=gains.metric == "inertia",
            integral=np.zeros(n) if old is None else old,
        )  # fmt: skip
        self.kp, self.kd, self.ki, self.gamma = rec["kp"][0], rec["kd"][0], rec["ki"][0], rec["gamma"][0]
        self.integral = rec["integral"][0]  # advanced in place by the rows and the fused step
        self._zeros = np.zeros(n)

    def reset(self, dyn: Dynamics, target: TaskTarget) -> None:
        """Hold the current posture unless the target gives one; clear the integral."""
        self.q_hold = dyn.q.copy() if target.q_posture is None else np.array(target.q_posture, dtype=float)
        self.integral[:] = 0.0

    def velocity_reference(self) -> np.ndarray:
        """q̇_ref of this step: `dq_ref` when set, else zeros (the array the compiled rows read)."""
        return self._zeros if self.dq_ref is None else self.dq_ref

    def reference(self, dyn: Dynamics, target: TaskTarget) -> np.ndarray:
        """q̈*₀ = −K_d (q̇ − q̇_ref) − K_p (q − q_ref) − K_i ∫(q − q_ref)."""
        q_ref = self.q_hold if target.q_posture is None else target.q_posture
        e = dyn.q - q_ref
        dq_ref = 0.0 if self.dq_ref is None else self.dq_ref
        if self.ki.any():
            self.integral += e * self.dt
        return -self.kd * (dyn.dq - dq_ref) - self.kp * e - self.ki * self.integral

    def rows(self, dyn: Dynamics, target: TaskTarget, ddq_e: np.ndarray) -> TaskRows:
        """`rows_reference` in one compiled call (`control.kernels.compliance.posture_target_fused`)."""
        q_ref = self.q_hold if target.q_posture is None else target.q_posture
        dq_ref = self.velocity_reference()
        b = posture_target_fused(dyn.record, q_ref, dq_ref, self.integral, self.kernel_record, ddq_e)
        metric = dyn.M if self.gains.metric == "inertia" else None
        return TaskRows(self._eye, b, self.gains.weight, metric)

    def rows_reference(self, dyn: Dynamics, target: TaskTarget, ddq_e: np.ndarray) -> TaskRows:
        """q̈ = q̈*₀ + Γ₀ q̈_e [C9]."""
        b = self.reference(dyn, target)
        if self.gamma.any():
            b = b + self.gamma @ ddq_e
        metric = dyn.M if self.gains.metric == "inertia" else None
        return TaskRows(self._eye, b, self.gains.weight, metric)


class AccelerationQP:
    """The acceleration QP over q̈ (`control.qp`): box = the dampers [C17–24], rows [M (torque
    limits [C10]); J_strict (equalities)].

    With OSQP, the iteration cap (default 400, ≈ 0.3 ms) may stop a slow solve — an active torque
    limit with the 1e4 : 1 task/posture weighting converges slowly — and its iterate is then used
    as an approximate optimum (status "max iter", τ_d clipped to the torque limits), so one slow
    solve cannot blow the 1 ms budget. If the QP has no solution (the dampers ask for more than
    the torque limits allow), a fallback problem keeps the torque limits [C10] hard — the motors
    cannot exceed them anyway — and softens the damper rows with slack variables s ≥ 0 penalised
    by `SLACK_WEIGHT` (relative to the task Hessian, so the problem stays well conditioned):
    l_d − s ≤ q̈ ≤ u_d + s. If that fails too, the tasks' unconstrained optimum clipped to the
    damper bounds is used. Both cases are flagged `fallback`.
    """

    SLACK_WEIGHT = 1e3  # times the largest diagonal entry of the task Hessian

    def __init__(self, n: int, n_strict: int, settings: ComplianceQPSettings, backend: str | None = None):
        self.n = n
        self.n_strict = n_strict
        self.backend = qp.check_backend(backend or qp.default_backend())
        qp_settings = qp.QPSettings(
            eps=settings.eps, max_iter=settings.max_iter, polish=settings.polish, check_termination=10
        )
        # primary: x = q̈, rows A = [M; J_strict]; the objective, rows and box are views of the step's
        # workspace record (`kernels.cqp.cqp_workspace_dtype`), which the fused step writes
        self.m = n + n_strict
        self.work = work = np.zeros(1, cqp_workspace_dtype(n, self.m))
        row = work[0]
        self.P, self.q, self.A, self.l, self.u = row["P"], row["qv"], row["A"], row["l"], row["u"]
        self.lb, self.ub = row["lb"], row["ub"]  # damper bounds on q̈
        self.l[:], self.u[:], self.lb[:], self.ub[:] = -qp.INF, qp.INF, -qp.INF, qp.INF
        # what the fused step reads and leaves there, by name (reading a view costs less than `row[name]`)
        self.q_ref, self.dq_ref = row["q_ref"], row["dq_ref"]
        self.x, self.tau, self.tau_cmd = row["x"], row["tau"], row["tau_cmd"]
        self.crossed, self.solved, self.saturated = work["crossed"], work["solved"], work["saturated"]
        self.primary = qp.make_qp(self.backend, n, self.m, n_eq=n_strict, settings=qp_settings)
        # fallback over [q̈; s]: rows [I −I] ≤ u_d, [I I] ≥ l_d, [M 0] torque, [J 0] strict; box s ≥ 0
        self.m2 = 3 * n + n_strict
        eye = np.eye(n)
        self.A2 = np.zeros((self.m2, 2 * n))
        self.A2[:n, :n], self.A2[:n, n:] = eye, -eye
        self.A2[n : 2 * n, :n], self.A2[n : 2 * n, n:] = eye, eye
        A2_pattern = self.A2 != 0
        A2_pattern[2 * n :, :n] = True
        P2_pattern = np.zeros((2 * n, 2 * n), dtype=bool)
        P2_pattern[:n, :n] = True
        P2_pattern[n:, n:] = np.eye(n, dtype=bool)
        self.fallback = qp.make_qp(
            self.backend,
            2 * n,
            self.m2,
            n_eq=n_strict,
            P_pattern=P2_pattern,
            A_pattern=A2_pattern,
            settings=qp_settings,
        )
        self.P2 = np.zeros((2 * n, 2 * n))
        self.q2 = np.zeros(2 * n)
        self.l2 = np.full(self.m2, -qp.INF)
        self.u2 = np.full(self.m2, qp.INF)
        self.lb2 = np.r_[np.full(n, -qp.INF), np.zeros(n)]
        self.ub2 = np.full(2 * n, qp.INF)
        self._last = np.zeros(n)

    @property
    def fast_path(self) -> bool:
        """The primary backend tries the unconstrained optimum first (`control.qp.QP.fast_path`)."""
        return self.primary.fast_path

    def take_unconstrained_optimum(self, x: np.ndarray, solve_us: float) -> qp.QPResult:
        """The result for x = −P⁻¹q that the caller found feasible with the dense backend's exact
        fast path (`kernels.dense_qp.unconstrained_optimum_fused`, the fused [C] step): what `solve` would
        return; the backend's next DAQP solve starts afresh (all data, empty working set)."""
        self._last = x
        return self.primary.take_fast_path(x, solve_us)

    def solve(self, P: np.ndarray, q: np.ndarray) -> qp.QPResult:
        """Solve with the current A, l, u, lb, ub; fall back as described in the class docstring."""
        n = self.n
        res = self.primary.solve(P, q, self.A, self.l, self.u, self.lb, self.ub)
        if res.solved or (res.status == qp.MAX_ITER and np.isfinite(res.x @ res.x)):
            self._last = res.x
            return res
        try:
            self.P2[:n, :n] = P
            self.P2[n:, n:] = self.SLACK_WEIGHT * max(float(np.max(np.diag(P))), 1.0) * np.eye(n)
            self.q2[:n] = q
            self.u2[:n] = self.ub  # q̈ − s ≤ u_d
            self.l2[n : 2 * n] = self.lb  # q̈ + s ≥ l_d
            self.A2[2 * n :, :n] = self.A
            self.l2[2 * n :] = self.l
            self.u2[2 * n :] = self.u
            res2 = self.fallback.solve(self.P2, self.q2, self.A2, self.l2, self.u2, self.lb2, self.ub2)
            if res2.solved:
                self._last = res2.x[:n].copy()
                return res2._replace(x=self._last, status=slack_reason(res2.x[n:]), fallback=True)
            status, it = res2.status, res2.iterations
        except (ValueError, ArithmeticError, np.linalg.LinAlgError) as exc:
            status, it = f"{qp.FAILED}: {exc}", 0
        # analytic fallback: unconstrained optimum clipped to the damper bounds
        try:
            x = np.linalg.solve(P + 1e-9 * np.eye(n), -q)
        except np.linalg.LinAlgError:
            x = self._last.copy()
        x = np.clip(x, self.lb, self.ub)
        if not np.all(np.isfinite(x)):
            x = np.zeros(n)
        return qp.QPResult(x, status, it, res.solve_us, self.backend, fallback=True)


def slack_reason(slack: np.ndarray) -> str:
    """The status of a step solved with softened dampers: the joint whose damper gave way most (its
    slack s, rad/s²; 1-based) and what the step does instead."""
    k = int(np.argmax(slack))
    return (
        f"{qp.RELAXED}: the torque limits cannot give joint {k + 1} the acceleration its limit damper asks "
        f"(short by {float(slack[k]):.3g} rad/s²: the drag overpowers the motors); the torque limits are "
        "kept and the dampers give way"
    )


class ComplianceQPExecutor:
    """[C] executor: estimation [C25–26] → QP [C9, C10, C17–24] → inverse dynamics [C8]."""

    name = "compliance-qp"

    def __init__(
        self,
        q_lower: np.ndarray,
        q_upper: np.ndarray,
        dq_max: np.ndarray,
        tau_max: np.ndarray,
        endless: np.ndarray,
        tasks: list | None = None,
        posture: PostureTaskGains | None = None,
        dampers: DamperGains | None = None,
        estimator: EstimatorGains | None = None,
        settings: ComplianceQPSettings | None = None,
        dt: float = 1e-3,
        qp_backend: str | None = None,
        fused: bool = True,
    ):
        self.n = n = len(q_lower)
        # everything between the estimate and the QP in one compiled call (`_step_fused`); with
        # fused=False, the same step object by object (`_step_reference`)
        self.fused = bool(fused)
        self.qp_backend = qp.check_backend(qp_backend or qp.default_backend())
        self.dt = float(dt)
        self.tau_max = np.asarray(tau_max, dtype=float).copy()
        self.tasks: list = [PoseTask()] if tasks is None else list(tasks)
        self.posture = PostureTask(n, posture, dt=dt)
        self.damper = JointLimitDamper(q_lower, q_upper, dq_max, endless, dampers, dt=dt)
        self.estimator = ExternalTorqueEstimator(n, estimator, dt=dt)
        self.settings = settings or ComplianceQPSettings()
        self._build_qp()
        self.tau_hat = np.zeros(n)
        self.tau_desired = np.zeros(n)  # τ_d of [C8] before the motors' saturation
        self._zeros = np.zeros(n)  # τ_fb without external-force feedback
        self._diag = np.diag_indices(n)
        self.ddq = np.zeros(n)
        self._pose_unused = PoseTask().kernel_record  # read only with a pose task (`pose_on`)
        self.last_qp: qp.QPResult | None = None
        self.last_info: dict[str, float] = {}

    @classmethod
    def for_robot(cls, robot, **kwargs) -> ComplianceQPExecutor:
        """Executor with the robot's joint, velocity and torque limits."""
        return cls(robot.q_lower, robot.q_upper, robot.dq_max, robot.tau_max, robot.endless, **kwargs)

    def set_tasks(self, tasks: list) -> None:
        """Replace the operational tasks (rebuilds the QP; not for use inside the loop)."""
        self.tasks = list(tasks)
        self._build_qp()

    def _build_qp(self) -> None:
        self.strict_tasks = [t for t in self.tasks if getattr(t, "strict", False)]
        self.soft_tasks = [t for t in self.tasks if not getattr(t, "strict", False)]
        # the fused step computes the first soft PoseTask's rows itself, the others' by `rows`
        self._fused_pose = next((t for t in self.soft_tasks if type(t) is PoseTask), None)
        self._other_soft_tasks = [t for t in self.soft_tasks if t is not self._fused_pose]
        self._prepared_tasks = [t for t in self.tasks if getattr(t, "prepare", None) is not None]
        self.qp = AccelerationQP(self.n, sum(t.dim for t in self.strict_tasks), self.settings, self.qp_backend)
        # the fused step may run the backend's exact fast path itself (the objective is final there)
        self._fast_qp = self.qp.fast_path and not self.strict_tasks and not self._other_soft_tasks
        self._cache_settings()

    def _cache_settings(self) -> None:
        """The fused step's settings record (`kernels.cqp.settings_record_dtype`): the settings by name,
        τ limits, whether the call has a pose task and may end the step on the fast path."""
        self._settings_record = fill_record(
            settings_record_dtype(self.n), (self.settings,), tau_max=self.tau_max, no_bound=qp.INF,
            pose_on=self._fused_pose is not None, fast_on=self._fast_qp,
        )  # fmt: skip

    # ---- Executor protocol --------------------------------------------------------------------
    def reset(self, dyn: Dynamics, target: TaskTarget) -> None:
        """Clear estimator, integrators and warm start; gravity compensation as the last torque."""
        for task in self.tasks:
            task.reset(dyn, target)
        self.posture.reset(dyn, target)
        self.estimator.reset(dyn)
        self.estimator.tau_prev[:] = np.clip(dyn.h, -self.tau_max, self.tau_max)
        self.tau_hat = np.zeros(self.n)
        self._build_qp()

    def params(self) -> dict[str, Any]:
        """Its groups: "pose_task" (the first TCP pose task, if any), "posture_task", "damper",
        "estimator", "compliance_qp" (switches and solver settings) and "solver" (the QP backend)."""
        out: dict[str, Any] = {}
        pose = self._pose_task()
        if pose is not None:
            out["pose_task"] = pose.gains
        out["posture_task"] = self.posture.gains
        out["damper"] = self.damper.gains
        out["estimator"] = self.estimator.gains
        out["compliance_qp"] = self.settings
        out["solver"] = SolverParams(qp_backend=self.qp_backend)
        return out

    def set_params(self, name: str, group: Any) -> None:
        """Hand a new validated group to its owner (ParamError for a group this executor lacks).
        New solver settings (eps, polish, max_iter) rebuild the QP."""
        pose = self._pose_task()
        if name == "pose_task" and pose is not None:
            pose.configure(expect(name, group, PoseTaskGains))
        elif name == "posture_task":
            self.posture.configure(expect(name, group, PostureTaskGains))
        elif name == "damper":
            self.damper.configure(expect(name, group, DamperGains))
        elif name == "estimator":
            self.estimator.configure(expect(name, group, EstimatorGains))
        elif name == "compliance_qp":
            new = expect(name, group, ComplianceQPSettings)
            old, self.settings = self.settings, new
            if (old.eps, old.polish, old.max_iter) != (new.eps, new.polish, new.max_iter):
                self._build_qp()
            self._cache_settings()
        elif name == "solver":
            backend = expect(name, group, SolverParams).qp_backend
            if backend != self.qp_backend:
                self.qp_backend = backend
                self._build_qp()
            for task in self.tasks:  # tasks with a QP of their own (the [T] bridge's nullspace QP)
                hook = getattr(task, "set_qp_backend", None)
                if callable(hook):
                    hook(backend)
        else:
            expect(name, group, None)

    def _pose_task(self) -> PoseTask | None:
        return next((t for t in self.tasks if isinstance(t, PoseTask)), None)

    def view(self) -> StepView:
        """The latest step's damper zone d_i and QP result; objective, W, split and P from the first
        task that offers a view (the [T] bridge task), else none."""
        base = StepView(self.name)
        for task in self.tasks:
            task_view = getattr(task, "view", None)  # an optional method of a task (Task protocol)
            if callable(task_view):
                base = replace(task_view(), executor=self.name)
                break
        return _qp_view(base, self.last_qp, self.qp_backend, self.damper.d_i)

    def step(self, dyn: Dynamics, inputs: ControlInputs) -> ControlOutput:
        """One control step; never raises on numerical trouble (flags a fallback instead)."""
        return self._step_fused(dyn, inputs) if self.fused else self._step_reference(dyn, inputs)

    def _step_fused(self, dyn: Dynamics, inputs: ControlInputs) -> ControlOutput:
        """`_step_reference` with the estimate (once observer and sensor filter have started, when
        no task prepares itself on the step's inputs), the pose task (the first soft `PoseTask`),
        the posture task, the dampers and the torque rows in one compiled call
        (`control.kernels.cqp.cqp_problem_fused`); other tasks add their rows as in the reference.
        With the dense backend and the objective final in that call (no other task), the call also
        runs the backend's exact fast path and, when it holds, τ_d [C8]: the backend is not called
        (`qp_solve_us` is then the whole call's time)."""
        target = inputs.target
        est = self.estimator
        wrench = inputs.wrench_tcp
        estimate_on = (
            est.observer.previous is not None and est.high_pass.lp is not None and wrench is not None
            and est.source_code >= 0.0 and not self._prepared_tasks
        )  # fmt: skip
        est.estimate_on[0] = estimate_on
        if estimate_on:  # the call computes the estimate into the estimator's record
            est.wrench[:] = wrench
        else:  # the estimate is given (the record's `tau_hat`, which `update` writes)
            self._estimate(dyn, inputs)
        pose, posture, aqp = self._fused_pose, self.posture, self.qp
        aqp.q_ref[:] = posture.q_hold if target.q_posture is None else target.q_posture
        aqp.dq_ref[:] = posture.velocity_reference()
        t0 = time.perf_counter()
        cqp_problem_fused(
            dyn.record, est.kernel_record, target.record, self._pose_unused if pose is None else pose.kernel_record,
            posture.kernel_record, self.damper.kernel_record, self._settings_record, aqp.work,
        )  # fmt: skip
        tau_hat = self.tau_hat = est.estimate
        crossed = bool(aqp.crossed[0])
        if aqp.solved[0]:  # the unconstrained optimum is feasible: the QP's solution, τ_d computed with it
            res = aqp.take_unconstrained_optimum(aqp.x.copy(), (time.perf_counter() - t0) * 1e6)
            return self._output(res, tau_hat, crossed, aqp.tau.copy(), aqp.tau_cmd.copy(), bool(aqp.saturated[0]))
        P, q = aqp.P, aqp.q
        if self._other_soft_tasks or self.strict_tasks:
            ddq_e = dyn.M_inv @ tau_hat
            self._add_task_rows(self._other_soft_tasks, dyn, target, ddq_e, P, q)
            self._strict_rows(dyn, target, ddq_e)
        return self._solve_and_torque(dyn, P, q, tau_hat, crossed)

    def _step_reference(self, dyn: Dynamics, inputs: ControlInputs) -> ControlOutput:
        """Estimation [C25–26], the QP's data [C9, C10, C17–24] task by task, the QP, [C8]."""
        tau_hat = self._estimate(dyn, inputs)
        P, q, crossed = self._problem_reference(dyn, inputs.target, tau_hat)
        return self._solve_and_torque(dyn, P, q, tau_hat, crossed)

    def _estimate(self, dyn: Dynamics, inputs: ControlInputs) -> np.ndarray:
        """τ̂_e of this step [C25–26]; then the tasks that need this step's inputs are prepared."""
        tau_hat = self.estimator.update(dyn, self.estimator.tau_prev, inputs.wrench_tcp, inputs.tau_ext_oracle)
        self.tau_hat = tau_hat
        for task in self.tasks:  # tasks that need this step's inputs (e.g. the [T] bridge)
            prepare = getattr(task, "prepare", None)
            if prepare is not None:
                prepare(dyn, inputs)
        return tau_hat

    def _add_task_rows(
        self, tasks, dyn: Dynamics, target: TaskTarget, ddq_e: np.ndarray, P: np.ndarray, q: np.ndarray
    ) -> None:
        """P += w JᵀWJ, q −= w JᵀWb for each task's rows [C9]."""
        for task in tasks:
            J, b, w, W = task.rows(dyn, target, ddq_e)
            if J is self.posture._eye and W is None:  # identity rows: no matrix products
                P[self._diag] += w
                q -= w * b
                continue
            if W is None:  # P += w JᵀJ, q −= w Jᵀb, compiled
                add_task_rows_fused(P, q, J, b, float(w))
                continue
            JtW = (J.T @ W) * w
            P += JtW @ J
            q -= JtW @ b

    def _strict_rows(self, dyn: Dynamics, target: TaskTarget, ddq_e: np.ndarray) -> None:
        """Strict tasks as equality rows below the torque rows."""
        aqp = self.qp
        row = self.n
        for task in self.strict_tasks:
            J, b, _, _ = task.rows(dyn, target, ddq_e)
            aqp.A[row : row + task.dim] = J
            aqp.l[row : row + task.dim] = b
            aqp.u[row : row + task.dim] = b
            row += task.dim

    def _problem_reference(self, dyn: Dynamics, target: TaskTarget, tau_hat: np.ndarray) -> tuple:
        """The QP's objective (P, q) [C9] and its rows and box in `self.qp` [C10, C17–24], task by
        task; returns (P, q, damper bounds crossed)."""
        n = self.n
        ddq_e = dyn.M_inv @ tau_hat  # q̈_e = M⁻¹ τ̂_e
        # objective [C9]: ½ q̈ᵀ P q̈ + qᵀ q̈
        P = np.zeros((n, n))
        q = np.zeros(n)
        self._add_task_rows((*self.soft_tasks, self.posture), dyn, target, ddq_e, P, q)
        self._strict_rows(dyn, target, ddq_e)
        aqp = self.qp
        # dampers [C17–24] as the box on q̈
        bounds = self.damper.bounds(dyn.q, dyn.dq)
        aqp.lb[:] = bounds.lower
        aqp.ub[:] = bounds.upper
        # torque limits [C10] on τ_d of [C8] (compiled: rows of A, l, u in place)
        tau_fb = tau_hat if self.settings.feedback else self._zeros
        torque_rows_fused(dyn.M, dyn.h, tau_fb, self.tau_max, aqp.A, aqp.l, aqp.u, self.settings.torque_limits, qp.INF)
        return P, q, bounds.crossed

    def _solve_and_torque(
        self, dyn: Dynamics, P: np.ndarray, q: np.ndarray, tau_hat: np.ndarray, crossed: bool
    ) -> ControlOutput:
        """The QP, then τ_d of [C8] and the step's output."""
        res = self.qp.solve(P, q)
        # [C8] τ_d = M q̈ + h − τ_fb; [C10] stays hard for approximate solutions too; the motors clip
        tau_fb = tau_hat if self.settings.feedback else self._zeros
        tau, tau_cmd, saturated = inverse_dynamics_fused(
            dyn.M, res.x, dyn.h, tau_fb, self.tau_max, (res.fallback or not res.solved) and self.settings.torque_limits
        )
        return self._output(res, tau_hat, crossed, tau, tau_cmd, saturated)

    def _output(
        self,
        res: qp.QPResult,
        tau_hat: np.ndarray,
        crossed: bool,
        tau: np.ndarray,
        tau_cmd: np.ndarray,
        saturated: bool,
    ) -> ControlOutput:
        """Keep the step's QP result, τ_d and command; the output with its signals."""
        self.ddq = res.x
        self.last_qp = res
        self.tau_desired = tau
        self.estimator.tau_prev[:] = tau_cmd
        info = {
            "qp_status": res.status_code,
            "qp_iterations": float(res.iterations),
            "qp_relaxed": float(res.fallback),
            "qp_solve_us": res.solve_us,
            "damper_crossed": float(crossed),
            "tau_saturated": float(saturated),
            "tau_ext_estimate_norm": math.sqrt(float(tau_hat @ tau_hat)),
            "tau_ext_is_oracle": float(self.estimator.is_oracle),
            "feedback": float(self.settings.feedback),
        }
        self.last_info = info
        return ControlOutput(tau=tau_cmd, fallback=res.fallback or crossed, info=info)


def _qp_view(view: StepView, res: qp.QPResult | None, backend: str, limit_zone: np.ndarray) -> StepView:
    return replace(
        view,
        limit_zone=limit_zone,
        qp_status=None if res is None else res.status,
        qp_backend=backend if res is None else res.backend,
        qp_fallback=False if res is None else res.fallback,
        qp_iterations=0 if res is None else res.iterations,
        qp_solve_us=0.0 if res is None else res.solve_us,
    )


def make_compliance_qp(robot, model=None, **kwargs) -> ComplianceQPExecutor:
    """The [C] executor for a robot description (TCP pose task + posture task by default)."""
    return ComplianceQPExecutor.for_robot(robot, **kwargs)
