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


# ---- two independent implementations in closed loop, with the fused estimate [C26] -----------
def _closed_loop(rizon, seconds: float, force_world: np.ndarray):
    """The bridge executor with the fused estimate (K_I = 50 s⁻¹, ideal F/T reading) steers the
    simulated arm under a constant push at the TCP; a separate [T] projection executor (its own
    law, integrator and nullspace QP) is fed the same snapshot and reading each step. Yields per
    step (t, a_C, a_T, Γ_x J M⁻¹ (τ̂_e − JᵀF^e)): the bridge QP's task acceleration, the one the
    [T] torque gives with the sensed wrench as the true one, and what the estimate error explains."""
    from app.sim.world import World

    world = World(rizon)
    model = RobotModel(rizon.model)
    world.reset(rizon.home)
    dyn = model.compute(world.q, world.dq)
    target = TaskTarget(
        position=dyn.tcp_position_world.copy(),
        rotation=dyn.tcp_rotation_world.copy(),
        velocity=np.zeros(6),
        wrench=np.array([0.0, 0.0, float(force_world[2]), 0.0, 0.0, 0.0]),
        q_posture=rizon.home,
    )
    bridge = make_bridge_executor(
        rizon, make_projection_executor(rizon, model), strict=True, estimator=EstimatorGains(source="fusion"),
        settings=EXACT,
    )  # fmt: skip
    shadow = make_projection_executor(rizon, model)
    bridge.reset(dyn, target)
    shadow.reset(dyn, target)
    for _ in range(round(seconds / 1e-3)):
        dyn = model.compute(world.q, world.dq)
        p_tcp, _ = world.site_pose(world.tcp_site)
        world.apply_force(world.wrist_body, p_tcp, force_world)
        wrench = np.concatenate([force_world, np.zeros(3)])  # ideal sensor, already at the TCP
        inputs = ControlInputs(t=world.time, target=target, wrench_tcp=wrench, tau_ext_oracle=dyn.J.T @ wrench)
        out = bridge.step(dyn, inputs)
        tau_t = shadow.step(dyn, inputs).tau
        task = bridge.tasks[0]
        tau_e = dyn.J.T @ wrench
        a_c = dyn.J @ bridge.ddq + dyn.dJ_dq
        a_t = dyn.J @ (dyn.M_inv @ (tau_t + tau_e - dyn.h)) + dyn.dJ_dq
        gamma_x = task.Lambda_hat_inv @ dyn.Lambda
        explained = gamma_x @ (dyn.J @ (dyn.M_inv @ (bridge.estimator.estimate - tau_e)))
        yield world.time, a_c, a_t, explained
        world.step(out.tau)


def test_bridge_with_the_fused_estimate_agrees_with_the_projection_law_in_closed_loop(rizon):
    """Accepted residual, and why: the QP plans with τ̂_e (fusion) where [T] uses the sensed wrench,
    so a_C − a_T = Γ_x J M⁻¹ (τ̂_e − JᵀF^e) exactly (equality rows, OSQP at 1e-10: checked to
    1e-6 of the push's own acceleration |Λx⁻¹F^e|). The estimate error itself is the fusion's
    start-up transient (its high-pass starts on the first reading, so τ̂_e starts at the observer's
    r = 0 and closes the gap as e^(−K_I t)) plus the discretisation of r + s/(K_I + s)τ_s: after
    10/K_I = 0.2 s (e^−10 ≈ 5e-5) the two task accelerations must agree to 1e-3 of |Λx⁻¹F^e|."""
    force = np.array([4.0, -3.0, 15.0])
    worst_identity = 0.0
    early, late = [], []
    for t, a_c, a_t, explained in _closed_loop(rizon, 0.3, force):
        if t == 0.0:
            scale = float(np.linalg.norm(explained))  # |Λx⁻¹F^e|: τ̂_e = 0 at the start
        worst_identity = max(worst_identity, np.linalg.norm(a_c - a_t - explained) / scale)
        (late if t > 0.2 else early).append(np.linalg.norm(a_c - a_t) / scale)
    assert worst_identity < 1e-6
    assert max(late) < 1e-3
    assert early[0] == pytest.approx(1.0, abs=1e-6)  # the start: no estimate yet, the full push unexplained


def test_the_qp_own_pose_task_with_a_diagonal_compliance_cannot_give_the_shaped_response(rizon):
    """[C]'s own tasks take a diagonal Γ (per axis, 0…1), one for all wrenches. [T]'s response to
    F^e is Γ_x J q̈_e with the full Γ_x = Λ̂x⁻¹Λx. With shaping off Γ_x = I: the QP's pose task with
    Γ = I gives [T]'s response exactly. With shaping on, the best diagonal Γ over many wrenches
    (least squares per axis, clipped to 0…1) leaves more than 5 % of the response unexplained."""
    from control.bridge import gamma_x_matrix
    from control.coupling import POLISH_SUBSPACES

    _, dyn, _, _, _ = _case(rizon, 0)
    wrenches = np.random.default_rng(4).normal(size=(6, 200)) * np.array([[10.0], [10.0], [10.0], [1.0], [1.0], [1.0]])
    response = dyn.J @ (dyn.M_inv @ (dyn.J.T @ wrenches))  # J q̈_e = Λx⁻¹ F^e, one column per wrench
    # shaping off: Λ̂x = Λx
    np.testing.assert_allclose(gamma_x_matrix(dyn.Lambda, POLISH_SUBSPACES, shaping=False), np.eye(6), atol=1e-12)
    # shaping on: [T]'s response is Λ̂x⁻¹ F^e = Γ_x Λx⁻¹ F^e
    G = gamma_x_matrix(dyn.Lambda, POLISH_SUBSPACES)
    shaped = G @ response
    best = np.clip(np.sum(shaped * response, axis=1) / np.sum(response**2, axis=1), 0.0, 1.0)
    residual = np.linalg.norm(shaped - best[:, None] * response) / np.linalg.norm(shaped)
    off = np.linalg.norm(G - np.diag(np.diag(G))) / np.linalg.norm(G)
    assert off > 0.05 and residual > 0.05  # a full coupling matrix, not a per-axis factor in 0…1


def test_gamma_x_summary_reports_symmetric_eigenvalues_and_skew_size(rizon):
    from control.bridge import gamma_x_matrix, gamma_x_summary
    from control.coupling import POLISH_SUBSPACES

    _, dyn, _, _, _ = _case(rizon, 1)
    G = gamma_x_matrix(dyn.Lambda, POLISH_SUBSPACES)
    s = gamma_x_summary(G)
    sym = 0.5 * (G + G.T)
    np.testing.assert_allclose(np.sort(s.sym_eigenvalues), np.linalg.eigvalsh(sym), atol=1e-12)
    assert s.skew_norm == pytest.approx(np.linalg.norm(0.5 * (G - G.T), 2))
    assert s.skew_norm > 1e-3  # Γ_x is not symmetric at this posture


def test_the_app_shows_gamma_x_live_while_the_projection_executor_runs():
    from app.core.session import Session
    from app.live.ui.panels.compliance import gamma_x_text
    from app.live.ui.snapshot import capture
    from control.bridge import gamma_x_matrix, gamma_x_summary

    session = Session("free", robot="rizon4s", executor="projection")
    session.run(steps=5)
    snap = capture(session)
    expected = gamma_x_summary(gamma_x_matrix(session.dyn.Lambda, session.executor.sub))
    np.testing.assert_allclose(snap.gamma_x_sym_eigs, expected.sym_eigenvalues, atol=1e-12)
    assert snap.gamma_x_skew == pytest.approx(expected.skew_norm)
    text = gamma_x_text(snap.gamma_x_sym_eigs, snap.gamma_x_skew)
    assert f"{expected.sym_eigenvalues[0]:.2f} … {expected.sym_eigenvalues[-1]:.2f}" in text
    assert "not a [C] compliance" in text  # the free-drag pose couples its axes
    session.set_executor("compliance-qp")
    session.run(steps=2)
    assert capture(session).gamma_x_sym_eigs is None  # [C]'s own executor: no Γ_x to show
