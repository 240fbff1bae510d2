"""The [T] projection executor: partially decoupled impedance motion/force control [T7-14]
with the nullspace velocity QP [T15-17] steering the posture towards low coupling [T22].

Per step, from one `Dynamics` snapshot and the F/T reading mapped to the TCP (F^e, the wrench
the environment exerts on the robot, world axes):

- u_m = A ẍ̂_m + K_m^d ė_m + K_m^p e_m [T11] (C_m = 0: Coriolis terms are compensated by μx),
  e_m from the position error and the SO(3) log of R̂ Rᵀ, K_m^d = 2ζ√(K_m^p A_ii);
- u_f = −F̂_f + K_f^p e_f − K_f^d ẋ_f + K_f^i ∫e_f [T12], e_f = F_f^e − F̂_f (C_f = 0),
  with the integral clamped (anti-windup);
- F_x = Λx Λ̂x⁻¹ u + (Λx Λ̂x⁻¹ − I) F^e + μx [T7] with Λ̂x of [T9]; since
  Λx Λ̂x⁻¹ = [[I, 0], [BᵀA⁻¹, I]] this is F_m = u_m, F_f = u_f + BᵀA⁻¹ (u_m + F_m^e);
- F_n = Λn K_n^d (q̂̇n − N q̇) + μn [T13] with q̂̇n from the QP;
- τ = Jᵀ F_x + Nᵀ F_n [T14], where μx = J̄ᵀh − Λx J̇q̇ and μn = h together give Jᵀμx + Nᵀμn
  = h − JᵀΛx J̇q̇ (full gravity/Coriolis compensation).
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np
import pinocchio as pin

from control import qp
from control.coupling import (
    CouplingTerms,
    Subspaces,
    coupling_gradient_direct,
    task_scale,
    terms_and_values,
)
from control.executor import ControlInputs, ControlOutput, StepView, TaskTarget
from control.gains import CONTROL_PERIOD_S, MotionForceGains, NullspaceGains, SolverParams
from control.kernels.chain import pack_chain
from control.kernels.gradients import OBJECTIVE_CODES
from control.kernels.law import (
    OBJECTIVE_J,
    damper_bounds_fused,
    joint_torque_fused,
    law_record,
    projection_step_dtype,
    projection_step_fused,
    task_wrench_fused,
)
from control.model import Dynamics, RobotModel
from control.nullspace import NullspaceQP, NullspaceResult
from control.params import ParamGroup, expect

_VALUES = ("W", "W_f", "W_a", "W_d", "coupled", "force_error")  # `projection_step_dtype`'s scalars, in order


class ProjectionExecutor:
    """Motion/force control with Λ̂x shaping [T7-14] and the coupling-objective nullspace QP."""

    name = "projection"

    def __init__(
        self,
        model: RobotModel,
        q_lower: np.ndarray,
        q_upper: np.ndarray,
        dq_max: np.ndarray,
        endless: np.ndarray | None = None,
        gains: MotionForceGains | None = None,
        nullspace: NullspaceGains | None = None,
        qp_backend: str | None = None,
        fused: bool = True,
    ):
        self.model = model
        # the law in one compiled call (`_step_fused`) on a serial revolute chain; else, or with
        # fused=False, the same law kernel by kernel (`_step_reference`)
        self.fused = bool(fused) and model.revolute_chain
        self._chain = pack_chain(model.chain) if self.fused else None
        self.n = model.nv
        # the fused step's record (`projection_step_dtype`: inputs, force integral, QP data, values) and
        # views of its fields, through which they are read and written (cheaper than `row[name]`)
        self._step = step = np.zeros(1, projection_step_dtype(self.n))
        row = step[0]
        self._F_e, self._q_d, self._integral = row["F_e"], row["q_d"], row["force_integral"]
        self._F, self._F_mu, self._grad, self._lower, self._upper = (
            row["F"], row["F_mu"], row["grad"], row["lower"], row["upper"]
        )  # fmt: skip
        self._x, self._tau = row["x"], row["tau"]
        # the law's six scalar values lie side by side in the record: one float64 view reads them at once
        offset = step.dtype.fields["W"][1]
        assert [step.dtype.fields[name][1] - offset for name in _VALUES] == [8 * i for i in range(len(_VALUES))]
        self._scalars = np.frombuffer(step, np.float64, len(_VALUES), offset)
        self._active = step["active"]
        self.q_lower = np.asarray(q_lower, dtype=float)
        self.q_upper = np.asarray(q_upper, dtype=float)
        self.dq_max = np.asarray(dq_max, dtype=float)
        self.endless = np.zeros(self.n, dtype=bool) if endless is None else np.asarray(endless, dtype=bool)
        self.gains = gains or MotionForceGains()
        self.sub = Subspaces.from_force_axes(self.gains.force_axis_names)
        self.nullspace = nullspace or NullspaceGains()
        self.qp_backend = qp.check_backend(qp_backend or qp.default_backend())
        self.qp = NullspaceQP(self.n, backend=self.qp_backend)
        self._cache_gains()
        self.q_posture: np.ndarray | None = None
        self._last_terms: CouplingTerms | None = None
        self._last_dyn: Dynamics | None = None  # the fused step's terms are computed for the view only
        self.last_qp: NullspaceResult | None = None
        self._last_W: dict[str, float] = {}
        self._last_sub: Subspaces = self.sub
        self._last_q: np.ndarray | None = None
        self._last_q_d: np.ndarray | None = None
        self.last_wrench = np.zeros(6)
        self._last_valid_wrench = np.zeros(6)

    # ---- Executor interface ---------------------------------------------------------------------
    def reset(self, dyn: Dynamics, target: TaskTarget) -> None:
        """Clear the force integral and the QP's warm start (a fresh solver, so a reset run repeats
        the first one exactly); the W_j posture is the target's q_posture or the current q."""
        self._integral[:] = 0.0
        self.qp = NullspaceQP(self.n, backend=self.qp_backend)
        self._last_valid_wrench = np.zeros(6)
        self.q_posture = dyn.q.copy() if target.q_posture is None else np.array(target.q_posture, dtype=float)

    def params(self) -> dict[str, ParamGroup]:
        """ "motion_force" (the law [T11–12], incl. the force axes), "nullspace" (the QP [T15–17]) and
        "solver" (its QP backend)."""
        return {
            "motion_force": self.gains,
            "nullspace": self.nullspace,
            "solver": SolverParams(qp_backend=self.qp_backend),
        }

    def set_params(self, name: str, group: Any) -> None:
        """Take a new validated group; new force axes restart the force integral; the QP is kept
        unless the backend changes."""
        if name == "motion_force":
            gains = expect(name, group, MotionForceGains)
            if gains.force_axes != self.gains.force_axes:
                self.sub = Subspaces.from_force_axes(gains.force_axis_names)
                self._integral[:] = 0.0
            self.gains = gains
        elif name == "nullspace":
            self.nullspace = expect(name, group, NullspaceGains)
        elif name == "solver":
            backend = expect(name, group, SolverParams).qp_backend
            if backend != self.qp_backend:  # a new QP (no warm start carries over)
                self.qp_backend = backend
                self.qp = NullspaceQP(self.n, backend=backend)
        else:
            expect(name, group, None)
        self._cache_gains()

    def step(self, dyn: Dynamics, inputs: ControlInputs) -> ControlOutput:
        """τ for this step [T14]; never raises.

        A non-finite F/T reading is replaced by the last valid one (flagged); on numerical trouble
        the step returns gravity/Coriolis compensation only, flagged as a fallback.
        """
        wrench = inputs.wrench_tcp
        if type(wrench) is not np.ndarray or wrench.dtype != np.float64:  # (a float array passes as it is)
            wrench = np.asarray(wrench, dtype=float)
            inputs = replace(inputs, wrench_tcp=wrench)
        sensor_invalid = not math.isfinite(float(wrench.dot(wrench)))  # NaN/inf anywhere (one dot product)
        if sensor_invalid:
            inputs = replace(inputs, wrench_tcp=self._last_valid_wrench.copy())
        else:
            self._last_valid_wrench = wrench.copy()
        try:
            out = self._step_fused(dyn, inputs) if self.fused else self._step_reference(dyn, inputs)
        except (ValueError, ArithmeticError, np.linalg.LinAlgError):
            return ControlOutput(tau=dyn.h.copy(), fallback=True, info={"executor_error": 1.0})
        if not math.isfinite(float(out.tau.dot(out.tau))):
            return ControlOutput(tau=dyn.h.copy(), fallback=True, info={**out.info, "executor_error": 1.0})
        if sensor_invalid:
            out.fallback = True
            out.info["sensor_invalid"] = 1.0
        return out

    @property
    def last_terms(self) -> CouplingTerms | None:
        """The latest step's coupling blocks and projections [T6, T9, T20, Table I]."""
        if self._last_terms is None and self._last_dyn is not None:
            self._last_terms = terms_and_values(self._last_dyn, self._last_sub)[0]
        return self._last_terms

    def view(self) -> StepView:
        """The latest step's objective, W values (W_j [T18] included), split, P_f/P_a/P_d, damper zone
        d_i and QP result."""
        terms, res, sub = self.last_terms, self.last_qp, self._last_sub
        W: dict[str, float] = {key: self._last_W[key] for key in ("W", "W_f", "W_a", "W_d") if key in self._last_W}
        if self._last_q is not None and self._last_q_d is not None:
            e = self._last_q - np.asarray(self._last_q_d, dtype=float)
            W["W_j"] = 0.5 * float(e @ e)  # [T18], at the step's q and posture
        return StepView(
            self.name,
            objective=self.nullspace.objective,
            W=W,
            force_axes=sub.force_axes,
            motion_axes=sub.motion_axes,
            P=None if terms is None else {"P_f": terms.P_f, "P_a": terms.P_a, "P_d": terms.P_d},
            limit_zone=np.full(self.n, self.nullspace.damper_influence),
            shaping=bool(self.gains.shaping),
            qp_status=None if res is None else res.status,
            qp_backend=self.qp_backend if res is None else res.backend,
            qp_fallback=False if res is None else res.fallback,
            qp_iterations=0 if res is None else res.iterations,
            qp_solve_us=0.0 if res is None else res.solve_us,
        )

    @property
    def force_integral(self) -> np.ndarray:
        """∫e_f of the force axes [T12] (n_f,): a view of the step record's `force_integral`."""
        return self._integral[: self.sub.n_f]

    # ---- the law --------------------------------------------------------------------------------
    def _cache_gains(self) -> None:
        g = self.gains
        kp = np.asarray(g.motion_kp)
        two_zeta_sqrt_kp = 2.0 * np.asarray(g.motion_zeta) * np.sqrt(kp)
        self._kn = np.broadcast_to(np.asarray(g.nullspace_kd, dtype=float), (self.n,)).copy()
        self._dq_limit = self.nullspace.velocity_scale * self.dq_max
        self._m = np.array(self.sub.motion_axes, dtype=np.int64)
        self._f = np.array(self.sub.force_axes, dtype=np.int64)
        self._kp_m = np.asarray(kp[self._m], dtype=float)
        self._kd_scale_m = np.asarray(two_zeta_sqrt_kp[self._m], dtype=float)
        self._zeros_f = np.zeros(self.sub.n_f)
        ns = self.nullspace
        self._objective_code = OBJECTIVE_J if ns.objective == "j" else OBJECTIVE_CODES[ns.objective]
        self._task_scale = task_scale(ns.unit_length_m, ns.unit_mass_kg)
        # what the law's kernels read that changes only here, by name (`law_record`)
        self._law = law_record(
            g, ns, objective=self._objective_code, k0=float(ns.k0), n_m=self.sub.n_m, perm=self.sub.perm,
            kp_m=self._kp_m, kd_scale_m=self._kd_scale_m, q_lower=self.q_lower, q_upper=self.q_upper,
            dq_limit=self._dq_limit, endless=self.endless, kn=self._kn, closed_form=self.qp.closed_form,
            task_scale=self._task_scale,
        )  # fmt: skip
        self._law_closed_form = self.qp.closed_form

    def _step_fused(self, dyn: Dynamics, inputs: ControlInputs) -> ControlOutput:
        """`_step_reference` in one compiled call (`projection_step_fused`: pose error, force integral,
        coupling blocks, k0 ∇W, task wrench, damper bounds, and where the 7-joint closed form applies
        the nullspace QP and the torque); otherwise the QP goes to the backend here."""
        sub, target = self.sub, inputs.target
        F_e = inputs.wrench_tcp
        self._last_terms, self._last_dyn, self._last_sub = None, dyn, sub
        q_d = target.q_posture if target.q_posture is not None else self.q_posture
        qp_ = self.qp
        if qp_.closed_form != self._law_closed_form:  # a new QP (a reset, a backend) says otherwise
            self._cache_gains()
        self._F_e[:] = F_e
        self._q_d[:] = dyn.q if q_d is None else q_d
        projection_step_fused(dyn.record, target.record, self._law, self._chain, self._step)
        self._last_q, self._last_q_d = dyn.q, q_d  # for W_j in the view
        self.last_wrench = self._F.copy()
        active = int(self._active[0])
        if active >= 0:  # solved in the call above: not timed apart from the law
            res = qp_.closed_form_result(self._x.copy(), active)
            tau = self._tau.copy()
        else:
            res = qp_.solve(dyn.J, self._grad, self._lower, self._upper)  # [T15-17]
            # [T13] nullspace velocity tracking, [T14] torque
            tau = joint_torque_fused(dyn.J, self._F_mu, dyn.N, dyn.Lambda_n, self._kn, res.x, dyn.dq, dyn.h)
        self.last_qp = res
        W_obj, W_f, W_a, W_d, coupled, force_error = self._scalars.tolist()
        return self._output(tau, res, force_error, W_obj, W_f, W_a, W_d, coupled)

    def _output(self, tau, res, force_error, W_obj, W_f, W_a, W_d, coupled) -> ControlOutput:
        info = {
            "W": W_obj,
            "W_f": W_f,
            "W_a": W_a,
            "W_d": W_d,
            "force_error_n": force_error,
            "qp_iterations": float(res.iterations),
            "qp_fallback": float(res.fallback),
            "nullspace_speed": math.sqrt(float(res.x.dot(res.x))),
            "coupled_accel": coupled,
        }
        self._last_W = info  # the view reads W, W_f, W_a, W_d from it
        return ControlOutput(tau=tau, fallback=res.fallback, info=info)

    def _step_reference(self, dyn: Dynamics, inputs: ControlInputs) -> ControlOutput:
        """The law kernel by kernel (any chain; the statement `_step_fused` is tested against)."""
        g, ns = self.gains, self.nullspace
        target = inputs.target
        F_e = inputs.wrench_tcp
        terms, (W_f, W_a, W_d) = terms_and_values(dyn, self.sub, self._task_scale)
        self._last_terms, self._last_dyn = terms, dyn
        self._last_sub = self.sub

        # task errors, world-aligned [px py pz rx ry rz]
        e = np.empty(6)
        e[:3] = target.position - dyn.tcp_position_world
        e[3:] = pin.log3(target.rotation @ dyn.tcp_rotation_world.T)

        # [T12] clamped force integral (anti-windup)
        F_hat = target.wrench[self._f]
        if g.force_ki > 0:
            integral = self.force_integral  # a view: advanced in place
            integral += (F_e[self._f] - F_hat) * CONTROL_PERIOD_S
            lim = g.force_integral_limit_n / g.force_ki
            np.clip(integral, -lim, lim, out=integral)
            u_f_extra = g.force_ki * integral
        else:
            u_f_extra = self._zeros_f

        # [T11] motion impedance, [T12] force law, [T7] with Λ̂x [T9]: F_m = u_m,
        # F_f = u_f + BᵀA⁻¹(u_m + F_m^e); F minus Λx J̇q̇ (μx without gravity: h is added in τ)
        F, F_mu, coupled = task_wrench_fused(
            dyn.record, target.record, e, terms.A, terms.P_d, terms.P_f, F_e, F_hat, u_f_extra, self._law
        )
        self.last_wrench = F

        # [T15-17] goal nullspace velocity
        q_d = target.q_posture if target.q_posture is not None else self.q_posture
        self._last_q, self._last_q_d = dyn.q, q_d  # for W_j in the view
        if ns.objective == "j":
            grad = dyn.q - (dyn.q if q_d is None else q_d)  # [T18]
            W_obj = 0.5 * float(grad @ grad)
        else:
            W_obj, grad = coupling_gradient_direct(  # [T24-27]
                self.model, dyn, terms, self.sub, ns.objective, self._task_scale
            )
        lower, upper = damper_bounds_fused(
            dyn.q, self.q_lower, self.q_upper, self._dq_limit, self.endless,
            float(ns.damper_influence), float(ns.damper_safety), float(ns.damper_speed),
        )  # fmt: skip  # compiled `damper_bounds`
        res = self.qp.solve(dyn.J, ns.k0 * grad, lower, upper)
        self.last_qp = res

        # [T13] nullspace velocity tracking, [T14] torque
        tau = joint_torque_fused(dyn.J, F_mu, dyn.N, dyn.Lambda_n, self._kn, res.x, dyn.dq, dyn.h)
        return self._output(tau, res, float(F_hat[0] - F_e[self._f[0]]), W_obj, W_f, W_a, W_d, coupled)


def make_projection_executor(robot, model: RobotModel, **kwargs) -> ProjectionExecutor:
    """Executor factory over a `RobotDescription` (limits from the robot)."""
    return ProjectionExecutor(model, robot.q_lower, robot.q_upper, robot.dq_max, robot.endless, **kwargs)
