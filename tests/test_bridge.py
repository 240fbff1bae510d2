"""The bridge (DESIGN §3, §8): [T]'s motion/force law run by [C]'s QP executor.

Two statements, with no active constraint:
1. the task-space acceleration J q̈ + J̇ q̇ of both executors is Λ̂x⁻¹(u + F^e), always — whatever
   the posture metric;
2. the whole torques are equal only with the M-weighted posture term and the same nullspace
   reference q̂̇n; with the identity metric ([C9] as written) they differ.
Strict priority: the motion/force task as equality rows of the QP (OSQP tolerance 1e-10,
polished). The weighted 1e4 : 1 variant is checked too, with the residual it leaves.
"""

from __future__ import annotations

import numpy as np
import pytest

from control.bridge import make_bridge_executor
from control.executor import ControlInputs, TaskTarget
from control.gains import ComplianceQPSettings, EstimatorGains
from control.model import RobotModel
from control.motion_force import make_projection_executor

EXACT = ComplianceQPSettings(eps=1e-10, polish=True, max_iter=20000)
WRENCH = np.array([3.0, -2.0, 18.0, 0.2, -0.1, 0.05])  # F^e read at the TCP, N and N m


def _case(rizon, seed: int):
    rng = np.random.default_rng(seed)
    model = RobotModel(rizon.model)
    q = rizon.home + rng.uniform(-0.15, 0.15, 7)
    dq = rng.uniform(-0.2, 0.2, 7)
    dyn = model.compute(q, dq)
    target = TaskTarget(
        position=dyn.tcp_position_world + rng.uniform(-0.01, 0.01, 3),
        rotation=dyn.tcp_rotation_world,
        velocity=np.zeros(6),
        wrench=np.array([0.0, 0.0, 20.0, 0.0, 0.0, 0.0]),
        q_posture=rizon.home,
    )
    tau_e = dyn.J.T @ WRENCH  # the estimate both executors act on: τ̂_e = Jᵀ F^e of the same reading
    inputs = ControlInputs(t=0.0, target=target, wrench_tcp=WRENCH, tau_ext_oracle=tau_e)
    return model, dyn, target, inputs, tau_e


def _projection(rizon, model, dyn, target, inputs, tau_e):
    law = make_projection_executor(rizon, model)
    law.reset(dyn, target)
    tau = law.step(dyn, inputs).tau
    ddq = dyn.M_inv @ (tau + tau_e - dyn.h)  # the arm's response [T1] to τ and the external wrench
    return tau, ddq


def _qp(rizon, model, dyn, target, inputs, metric, strict, settings=EXACT):
    law = make_projection_executor(rizon, model)
    ex = make_bridge_executor(
        rizon, law, metric=metric, strict=strict, estimator=EstimatorGains(source="oracle"), settings=settings
    )
    ex.reset(dyn, target)
    out = ex.step(dyn, inputs)
    assert out.info["qp_relaxed"] == 0.0 and not out.fallback  # no constraint trouble
    bounds = ex.damper.bounds(dyn.q, dyn.dq)
    assert np.all(ex.ddq < bounds.upper - 1e-3) and np.all(ex.ddq > bounds.lower + 1e-3)  # none active
    assert np.all(np.abs(ex.tau_desired) < rizon.tau_max)
    return out.tau, ex.ddq, ex.tasks[0]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_task_space_acceleration_is_the_same_for_both_executors_whatever_the_posture_metric(rizon, seed):
    model, dyn, target, inputs, tau_e = _case(rizon, seed)
    _, ddq_t = _projection(rizon, model, dyn, target, inputs, tau_e)
    acc_t = dyn.J @ ddq_t + dyn.dJ_dq
    for metric in ("inertia", "identity"):
        _, ddq_c, task = _qp(rizon, model, dyn, target, inputs, metric, strict=True)
        acc_c = dyn.J @ ddq_c + dyn.dJ_dq
        shaped = task.Lambda_hat_inv @ (task.Lambda_hat @ task.reference_acc + WRENCH)  # Λ̂x⁻¹(u + F^e)
        np.testing.assert_allclose(acc_c, acc_t, rtol=0, atol=1e-6 * np.linalg.norm(acc_t))
        np.testing.assert_allclose(acc_t, shaped, rtol=0, atol=1e-9 * np.linalg.norm(acc_t))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_projection_and_qp_executors_agree_without_constraints(rizon, seed):
    model, dyn, target, inputs, tau_e = _case(rizon, seed)
    tau_t, _ = _projection(rizon, model, dyn, target, inputs, tau_e)
    tau_c, _, _ = _qp(rizon, model, dyn, target, inputs, "inertia", strict=True)
    rel = np.linalg.norm(tau_c - tau_t) / np.linalg.norm(tau_t)
    assert rel < 1e-6, f"relative torque difference {rel:.2e}"


def test_identity_weighted_posture_gives_other_torques(rizon):
    """[C9]'s ‖q̈ − q̈*₀‖² splits with J⁺, not J̄: q̈ = J⁺b + (I − J⁺J) q̈*₀ — the same task
    acceleration as [T], another torque."""
    model, dyn, target, inputs, tau_e = _case(rizon, 0)
    tau_t, _ = _projection(rizon, model, dyn, target, inputs, tau_e)
    tau_c, _, task = _qp(rizon, model, dyn, target, inputs, "identity", strict=True)
    J = dyn.J
    J_pinv = J.T @ np.linalg.inv(J @ J.T)
    b = task.Lambda_hat_inv @ (task.Lambda_hat @ task.reference_acc + WRENCH) - dyn.dJ_dq
    ddq0 = task.law.gains.nullspace_kd[0] * (task.law.last_qp.x - dyn.dq)
    ddq_pred = J_pinv @ b + (np.eye(7) - J_pinv @ J) @ ddq0
    tau_pred = dyn.M @ ddq_pred + dyn.h - tau_e
    scale = np.linalg.norm(tau_t)
    np.testing.assert_allclose(tau_c, tau_pred, rtol=0, atol=1e-6 * scale)
    assert np.linalg.norm(tau_c - tau_t) > 100 * 1e-6 * scale  # well outside the agreement tolerance


def test_weighted_priority_leaves_a_small_task_residual(rizon):
    """Weights 1e4 : 1 instead of equality rows: the task acceleration is met to 0.1 %."""
    model, dyn, target, inputs, tau_e = _case(rizon, 1)
    _, ddq_t = _projection(rizon, model, dyn, target, inputs, tau_e)
    acc_t = dyn.J @ ddq_t + dyn.dJ_dq
    _, ddq_c, _ = _qp(rizon, model, dyn, target, inputs, "inertia", strict=False)
    acc_c = dyn.J @ ddq_c + dyn.dJ_dq
    assert np.linalg.norm(acc_c - acc_t) / np.linalg.norm(acc_t) < 1e-3


def test_bridge_needs_one_nullspace_gain(rizon):
    from control.gains import MotionForceGains

    model = RobotModel(rizon.model)
    law = make_projection_executor(rizon, model, gains=MotionForceGains(nullspace_kd=(50, 50, 50, 50, 50, 50, 40)))
    with pytest.raises(ValueError, match="one K_n"):
        make_bridge_executor(rizon, law)
