"""External-torque estimation [C25–26]: observer time constant, fusion bandwidth, sources."""

from __future__ import annotations

import numpy as np
import pytest

from app.sim.world import World
from control.compliance_qp import ComplianceQPExecutor
from control.estimation import ExternalTorqueEstimator, HighPass, MomentumObserver
from control.executor import ControlInputs, TaskTarget
from control.gains import EstimatorGains
from control.model import RobotModel

K_I = 40.0  # 1/s
FORCE = np.array([0.0, 15.0, -10.0])  # N, at the TCP
T_STEP = 0.1  # s


def _run(gen3, source: str, seconds: float = 0.3):
    """Gen3 held by the QP executor (Γ = 0, feedback on) while a constant force acts at the TCP
    from T_STEP on; returns times, estimates, true τ^e and an ideal F/T reading's joint torque."""
    world = World(gen3)
    model = RobotModel(gen3.model)
    ex = ComplianceQPExecutor.for_robot(gen3, estimator=EstimatorGains(source=source, observer_gain=K_I))
    dyn = model.compute(world.q, world.dq)
    target = TaskTarget(position=dyn.tcp_position_world, rotation=dyn.tcp_rotation_world, q_posture=dyn.q)
    ex.reset(dyn, target)
    ts, est, truth = [], [], []
    for _ in range(round(seconds / 1e-3)):
        dyn = model.compute(world.q, world.dq)
        wrench = np.zeros(6)
        if world.time >= T_STEP - 1e-9:
            world.apply_force(world.wrist_body, world.site_pose(world.tcp_site)[0], FORCE)
            wrench[:3] = FORCE  # ideal sensor, force at the TCP
        out = ex.step(dyn, ControlInputs(world.time, target, wrench, world.external_joint_torque()))
        ts.append(world.time)
        est.append(ex.tau_hat.copy())
        truth.append(world.external_joint_torque())
        world.step(out.tau)
    return np.array(ts), np.array(est), np.array(truth)


def test_momentum_observer_converges_with_time_constant_one_over_k_i(gen3):
    t, r, truth = _run(gen3, "residual")
    tau_e = truth[-1]
    j = int(np.argmax(np.abs(tau_e)))
    s = (t - T_STEP) * K_I  # at t the residual has integrated [t − δt, t]
    expected = tau_e[j] * (1 - np.exp(-np.clip(s, 0, None)))
    after = s > 0
    err = np.max(np.abs(r[after, j] - expected[after]))
    assert err < 0.01 * abs(tau_e[j]), f"residual deviates {err:.3f} N m from the first-order response"
    k = int(np.argmin(np.abs(s - 1.0)))  # one time constant: 63.2 %
    assert r[k, j] / tau_e[j] == pytest.approx(1 - np.exp(-1), abs=0.02)
    np.testing.assert_allclose(r[-1], tau_e, atol=0.01 * np.max(np.abs(tau_e)))
    assert np.all(np.abs(r[t < T_STEP]) < 1e-6)  # no external force: no residual


def test_fusion_tracks_a_step_faster_than_the_residual(gen3):
    t, r, truth = _run(gen3, "residual", 0.2)
    _, f, _ = _run(gen3, "fusion", 0.2)
    tau_e = truth[-1]
    k = int(np.searchsorted(t, T_STEP + 0.01))  # 10 ms after the step (0.4 time constants)
    err_r = np.linalg.norm(r[k] - tau_e) / np.linalg.norm(tau_e)
    err_f = np.linalg.norm(f[k] - tau_e) / np.linalg.norm(tau_e)
    assert err_r > 0.5  # residual: e^{-0.36} ≈ 70 % still missing
    assert err_f < 0.05
    assert err_f < err_r / 10


def test_oracle_source_passes_the_truth_and_says_so(gen3):
    est = ExternalTorqueEstimator(7, EstimatorGains(source="oracle"))
    model = RobotModel(gen3.model)
    dyn = model.compute(gen3.home, np.zeros(7))
    est.reset(dyn)
    truth = np.arange(7.0)
    np.testing.assert_array_equal(est.update(dyn, dyn.h, np.zeros(6), truth), truth)
    assert est.is_oracle
    none = ExternalTorqueEstimator(7, EstimatorGains(source="none"))
    none.reset(dyn)
    assert not np.any(none.update(dyn, dyn.h, np.ones(6), truth)) and not none.is_oracle


def test_high_pass_plus_matching_low_pass_is_identity():
    """[C26] complementarity: LP_K(x) + HP_K(x) = x for every input sequence."""
    rng = np.random.default_rng(1)
    hp = HighPass(3, 30.0, 1e-3)
    obs_like = np.zeros(3)
    a = np.exp(-30.0 * 1e-3)
    for _ in range(200):
        x = rng.normal(size=3)
        y = hp.update(x)
        obs_like = a * obs_like + (1 - a) * x if _ else x.copy()
        np.testing.assert_allclose(y + obs_like, x, atol=1e-12)


def test_bad_estimator_settings_are_rejected():
    with pytest.raises(ValueError, match="source"):
        EstimatorGains(source="psychic")
    with pytest.raises(ValueError, match="observer_gain"):
        EstimatorGains(observer_gain=0.0)
    with pytest.raises(ValueError):
        MomentumObserver(7, -1.0, 1e-3)
