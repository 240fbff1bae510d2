"""The [C] QP executor: explicit compliance Γ [C9], inverse dynamics [C8], QP plumbing."""

from __future__ import annotations

import numpy as np
import pytest

from app.sim.world import World
from control.compliance_qp import ComplianceQPExecutor, pose_error
from control.executor import ControlInputs, TaskTarget
from control.gains import ComplianceQPSettings, EstimatorGains, PoseTaskGains, PostureTaskGains, compliance_matrix
from control.model import RobotModel
from control.params import ParamError, replaced, with_values

KP = 100.0  # 1/s²
FORCE = np.array([0.0, 10.0, -5.0])  # N at the TCP


_CACHE: dict = {}


def _push(gen3, gamma_task, gamma_posture=0.0, seconds: float = 1.0):
    key = (gamma_task, gamma_posture, seconds)
    if key not in _CACHE:
        _CACHE[key] = _push_run(gen3, gamma_task, gamma_posture, seconds)
    return _CACHE[key]


def _push_run(gen3, gamma_task, gamma_posture, seconds):
    """Constant force at the TCP from t = 0.1 s; τ̂_e from the oracle (sim truth) so that only the
    controller is tested. Returns the final pose error and the snapshot at the end."""
    world = World(gen3)
    model = RobotModel(gen3.model)
    ex = ComplianceQPExecutor.for_robot(
        gen3,
        tasks=None,
        estimator=EstimatorGains(source="oracle"),
        posture=PostureTaskGains(stiffness=1.0, damping=2.0, compliance=gamma_posture),
    )
    ex.tasks[0].configure(PoseTaskGains(stiffness=KP, damping=2 * np.sqrt(KP), compliance=gamma_task))
    dyn = model.compute(world.q, world.dq)
    target = TaskTarget(position=dyn.tcp_position_world, rotation=dyn.tcp_rotation_world, q_posture=dyn.q)
    ex.reset(dyn, target)
    for _ in range(round(seconds / 1e-3)):
        dyn = model.compute(world.q, world.dq)
        if world.time >= 0.1:
            world.apply_force(world.wrist_body, world.site_pose(world.tcp_site)[0], FORCE)
        out = ex.step(dyn, ControlInputs(world.time, target, np.zeros(6), world.external_joint_torque()))
        assert out.info["tau_ext_is_oracle"] == 1.0
        world.step(out.tau)
    return pose_error(dyn, target), dyn


def test_gamma_zero_is_stiff_and_gamma_identity_is_the_predicted_impedance(gen3):
    e_stiff, _ = _push(gen3, 0.0)
    e_soft, dyn = _push(gen3, 1.0)
    wrench = np.concatenate([FORCE, np.zeros(3)])
    predicted = dyn.Lambda_inv @ wrench / KP  # [C9] with Γ = I: K_p e = J q̈_e = Λx⁻¹ F at rest
    assert np.linalg.norm(e_soft[:3]) > 5e-3  # it gives way by millimetres
    np.testing.assert_allclose(e_soft, predicted, atol=0.05 * np.linalg.norm(predicted))
    assert np.linalg.norm(e_stiff[:3]) < 0.01 * np.linalg.norm(predicted[:3])  # Γ = 0: stays put


def test_half_compliance_gives_half_the_deflection(gen3):
    e_half, _ = _push(gen3, 0.5)
    e_full, _ = _push(gen3, 1.0)
    assert np.linalg.norm(e_half[:3]) / np.linalg.norm(e_full[:3]) == pytest.approx(0.5, rel=0.05)


def test_compliance_accepts_scalar_diagonal_and_matrix_and_rejects_bad_values():
    np.testing.assert_array_equal(compliance_matrix(0.5, 3), 0.5 * np.eye(3))
    np.testing.assert_array_equal(compliance_matrix([1, 0, 2], 3), np.diag([1.0, 0.0, 2.0]))
    R = np.array([[np.cos(0.3), -np.sin(0.3)], [np.sin(0.3), np.cos(0.3)]])
    G = R @ np.diag([1.0, 0.2]) @ R.T
    np.testing.assert_allclose(compliance_matrix(G, 2), G)
    with pytest.raises(ValueError, match="positive semi-definite"):
        compliance_matrix(np.diag([1.0, -0.1]), 2)
    with pytest.raises(ValueError, match="symmetric"):
        compliance_matrix(np.array([[1.0, 0.5], [0.0, 1.0]]), 2)
    with pytest.raises(ValueError, match="shape"):
        compliance_matrix(np.ones(4), 3)
    with pytest.raises(ValueError, match="stiffness"):
        PoseTaskGains(stiffness=-1.0)
    with pytest.raises(ValueError, match="metric"):
        PostureTaskGains(metric="euclid")


def test_set_params_routes_each_group_and_refuses_unknown_ones(gen3):
    ex = ComplianceQPExecutor.for_robot(gen3)
    assert set(ex.params()) == {"pose_task", "posture_task", "damper", "estimator", "compliance_qp", "solver"}
    with pytest.raises(ParamError, match="no parameter group"):
        ex.set_params("wobble", ex.settings)
    with pytest.raises(ParamError, match="takes a DamperGains"):
        ex.set_params("damper", ex.settings)
    with pytest.raises(ParamError, match="lambda_"):
        replaced(ex.damper.gains, "lambda_", -3.0)
    ex.set_params("compliance_qp", replaced(ex.settings, "feedback", False))
    ex.set_params("estimator", replaced(ex.estimator.gains, "source", "residual"))
    ex.set_params("damper", with_values(ex.damper.gains, {"lambda_": 70.0, "M": 3.0}))
    ex.set_params("pose_task", replaced(ex.params()["pose_task"], "compliance", [1, 1, 1, 0, 0, 0]))
    assert not ex.settings.feedback and ex.estimator.gains.source == "residual"
    assert ex.damper.gains.lambda_ == 70.0 and ex.tasks[0].gamma[0, 0] == 1.0 and ex.tasks[0].gamma[3, 3] == 0.0


def test_inverse_dynamics_is_c8_with_and_without_feedback(gen3):
    model = RobotModel(gen3.model)
    q = gen3.home + 0.1
    dyn = model.compute(q, np.full(7, 0.2))
    target = TaskTarget(position=dyn.tcp_position_world + 0.01, rotation=dyn.tcp_rotation_world, q_posture=q)
    tau_e = np.array([1.0, -2.0, 0.5, 0.3, 0.0, 0.1, -0.2])
    for feedback in (True, False):
        ex = ComplianceQPExecutor.for_robot(
            gen3, estimator=EstimatorGains(source="oracle"), settings=ComplianceQPSettings(feedback=feedback)
        )
        ex.reset(dyn, target)
        out = ex.step(dyn, ControlInputs(0.0, target, np.zeros(6), tau_e))
        expected = dyn.M @ ex.ddq + dyn.h - (tau_e if feedback else 0.0)  # [C8]
        np.testing.assert_allclose(out.tau, expected, atol=1e-9)


def test_infeasible_constraints_never_raise_and_keep_torque_limits(gen3):
    """A joint at speed right at its limit: the damper asks for more than the torque allows."""
    model = RobotModel(gen3.model)
    q = gen3.home.copy()
    q[3] = gen3.q_upper[3] - 0.03
    dq = np.zeros(7)
    dq[3] = 1.3
    dyn = model.compute(q, dq)
    target = TaskTarget(position=dyn.tcp_position_world, rotation=dyn.tcp_rotation_world, q_posture=q)
    ex = ComplianceQPExecutor.for_robot(gen3)
    ex.reset(dyn, target)
    out = ex.step(dyn, ControlInputs(0.0, target, np.zeros(6)))
    assert out.fallback and out.info["qp_relaxed"] == 1.0
    assert np.all(np.isfinite(out.tau))
    assert np.all(np.abs(ex.tau_desired) <= gen3.tau_max * (1 + 1e-4))
    nan_dyn = model.compute(q, dq)
    nan_dyn.M[:] = np.nan
    out = ex.step(nan_dyn, ControlInputs(0.0, target, np.zeros(6)))  # garbage in: flagged, no raise
    assert out.fallback


# ---- the fused step (one compiled call before the QP) equals the step task by task ---------------
# swings through most of the joint ranges: (amplitude over the range, rate scale, torque-limit scale)
SWINGS = {
    "active": (0.45, 0.2, 1.0),  # torque limits and dampers bind on most steps
    "relaxed": (0.45, 1.5, 0.2),  # the QP has no solution: the slack problem on most steps
}


def _twin_executors(robot, case: str):
    """The same executor twice, fused and reference (`fused=False`), configured for `case`."""
    from control.bridge import make_bridge_executor
    from control.compliance_qp import PoseTask
    from control.gains import DamperGains
    from control.motion_force import make_projection_executor

    model = RobotModel(robot.model)
    pair = []
    for fused in (True, False):
        if case == "bridge":  # another soft task (the [T] law as a row), inertia metric posture
            ex = make_bridge_executor(robot, make_projection_executor(robot, model))
            ex.fused = fused
        else:
            kwargs: dict = {"fused": fused}
            if case == "everything":
                kwargs = {
                    **kwargs,
                    "tasks": [PoseTask(PoseTaskGains(stiffness=(300.0, 200, 100, 50, 40, 30), compliance=0.5))],
                    "posture": PostureTaskGains(integral=2.0, compliance=(0, 0.3, 0, 1, 0, 0, 0.5), metric="inertia"),
                    "dampers": DamperGains(form="classic"),
                    "estimator": EstimatorGains(source="residual"),
                    "settings": ComplianceQPSettings(feedback=False),
                }
            elif case == "osqp":  # no fast path in the fused call: every QP goes to the backend
                kwargs["qp_backend"] = "osqp"
            elif case == "oracle":  # the estimate from the executor's estimator, not the fused call
                kwargs["estimator"] = EstimatorGains(source="oracle")
            elif case == "no torque limits":
                kwargs["settings"] = ComplianceQPSettings(torque_limits=False)
            elif case == "strict":
                kwargs["tasks"] = [PoseTask(strict=True)]
            elif case in SWINGS:  # no estimate: the synthetic swing is not caused by the torques
                kwargs["estimator"] = EstimatorGains(source="none")
            ex = ComplianceQPExecutor.for_robot(robot, **kwargs)
        if case in SWINGS:
            ex.tau_max = ex.tau_max * SWINGS[case][2]
        pair.append(ex)
    return model, pair


@pytest.mark.parametrize(
    "case", ["default", "everything", "oracle", "osqp", "no torque limits", "strict", "active", "relaxed", "bridge"]
)
def test_fused_step_equals_the_reference_step(rizon, case):
    """Both executors see the same snapshots (a swing through the joint ranges, fast near the
    limits for "active") and readings; τ, q̈, τ_d, the posture integral and the step's signals agree
    to 1e-9 relative at every step; the QP outcome (status, fallback, crossed dampers) is the same."""
    model, (fused, ref) = _twin_executors(rizon, case)
    rng = np.random.default_rng(sum(map(ord, case)))
    span, mid = rizon.q_upper - rizon.q_lower, 0.5 * (rizon.q_upper + rizon.q_lower)
    amp_frac, rate_scale, _ = SWINGS.get(case, (0.01, 1.0, 1.0))
    amp = amp_frac * span
    phase, rate = rng.uniform(0, 6, 7), rng.uniform(0.5, 2.0, 7) * rate_scale
    center = mid if case in SWINGS else rizon.home
    dyn0 = model.compute(center + amp * np.sin(phase), amp * rate * np.cos(phase))
    targets = [
        TaskTarget(dyn0.tcp_position_world + np.array([0.005, 0, 0]), dyn0.tcp_rotation_world, q_posture=rizon.home),
        TaskTarget(dyn0.tcp_position_world, dyn0.tcp_rotation_world, velocity=np.ones(6) * 0.01),  # q_posture None
    ]
    for ex in (fused, ref):
        ex.reset(dyn0, targets[0])
    n_fast = n_daqp = n_relaxed = 0
    for k in range(300):
        t = 1e-3 * k
        q = center + amp * np.sin(rate * t + phase)
        dq = amp * rate * np.cos(rate * t + phase)
        dyn = model.compute(q, dq)
        target = targets[(k // 100) % 2]
        inputs = ControlInputs(t, target, rng.normal(size=6), rng.normal(size=7))
        a, b = fused.step(dyn, inputs), ref.step(dyn, inputs)
        scale = max(1.0, float(np.max(np.abs(b.tau))))
        assert float(np.max(np.abs(a.tau - b.tau))) <= 1e-9 * scale, (k, a.info, b.info)
        assert float(np.max(np.abs(fused.ddq - ref.ddq))) <= 1e-9 * max(1.0, float(np.max(np.abs(ref.ddq)))), k
        np.testing.assert_allclose(fused.tau_desired, ref.tau_desired, rtol=0, atol=1e-9 * scale)
        np.testing.assert_allclose(fused.posture.integral, ref.posture.integral, rtol=1e-9, atol=1e-12)
        assert a.fallback == b.fallback and a.info.keys() == b.info.keys()
        for key in a.info.keys() - {"qp_solve_us", "qp_iterations"}:
            assert a.info[key] == pytest.approx(b.info[key], rel=1e-9, abs=1e-9), (k, key)
        n_fast += a.info["qp_iterations"] == 0 and not a.fallback
        n_daqp += a.info["qp_iterations"] > 0
        n_relaxed += a.info["qp_relaxed"] > 0
    if case == "active":
        assert n_daqp >= 100 and n_fast >= 10, (n_fast, n_daqp)
    elif case == "relaxed":
        assert n_relaxed >= 100, n_relaxed
    elif case in ("strict", "osqp"):  # equality rows: always DAQP; OSQP iterates
        assert n_fast == 0
    else:
        assert n_fast >= 250, n_fast
