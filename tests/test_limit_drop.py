"""Joint-limit drop [C] §IV-B–C in closed loop: dampers with and without external-force feedback,
and torque limits [C10]."""

from __future__ import annotations

import numpy as np
import pytest

from app.core.session import Session
from app.headless.experiments.limit_drop import run_drop
from app.scenarios.limit_drop import FALLING_JOINT, LimitDropScenario
from app.scenarios.metrics import velocity_reversals
from control.compliance_qp import ComplianceQPExecutor

DURATION = 1.8  # s: the fall and the braking (λ = 100, M = 2) are over after about 1.3 s


@pytest.fixture(scope="module")
def drops():
    return {fb: run_drop("proposed", 100.0, 2.0, fb, "position", DURATION) for fb in (True, False)}


def test_with_feedback_joint_4_never_crosses_its_position_limit(drops):
    on = drops[True]
    assert on["direction"] == 1  # the Gen3 falls toward its upper limit
    assert np.max(on["trace_q"]) > on["q_limit"] - 0.1  # it did fall all the way to the limit
    assert on["max_violation"] < 0.0
    assert on["overshoot_beyond_ds"] < 1e-4  # stays out of the safety distance d_s (0.1 mrad slack)


def test_without_feedback_it_overshoots_more(drops):
    on, off = drops[True], drops[False]
    assert off["overshoot_beyond_ds"] > on["overshoot_beyond_ds"] + 5e-3  # at least 5 mrad further
    assert off["overshoot_beyond_ds"] > 0.0  # it enters d_s


def _braking_torques(torque_limits: bool) -> tuple[np.ndarray, float]:
    """Joint-4 τ_d over a hard drop (M = 1.5) with joint 4's torque limit lowered to 16 N m."""
    scenario = LimitDropScenario("position")
    q0 = scenario.initial_q(_gen3())
    q0[FALLING_JOINT] = 2.1  # start part-way down: the fall reaches the limit sooner
    session = Session(scenario, executor="compliance-qp", q0=q0)
    ex = session.executor
    assert isinstance(ex, ComplianceQPExecutor)
    session.set_param("damper", "lambda_", 100.0)
    session.set_param("damper", "M", 1.5)
    session.set_param("compliance_qp", "torque_limits", torque_limits)
    ex.tau_max[FALLING_JOINT] = 16.0  # holding the arm and the mass needs about 13 N m
    session.reset()
    taus = []
    for _ in range(round(1.0 / 1e-3)):
        session.step()
        taus.append(ex.tau_desired.copy())
        if not torque_limits and abs(taus[-1][FALLING_JOINT]) > 17.0:
            break  # enough to show the limit was needed
    return np.array(taus), 16.0


def test_with_torque_limits_tau_d_never_exceeds_them():
    taus, limit = _braking_torques(True)
    assert np.max(np.abs(taus[:, FALLING_JOINT])) <= limit * (1 + 1e-4)
    assert np.all(np.abs(taus) <= ComplianceQPExecutor.for_robot(_gen3()).tau_max * (1 + 1e-4))
    free, _ = _braking_torques(False)
    assert np.max(np.abs(free[:, FALLING_JOINT])) > limit + 1.0  # the limit was needed


def _gen3():
    import robots

    return robots.load("gen3")


def test_oscillation_count_counts_velocity_reversals():
    t = np.linspace(0, 1, 1000)
    assert velocity_reversals(np.exp(-5 * t)) == 0
    assert velocity_reversals(np.sin(2 * np.pi * 3 * t)) == 5
    assert velocity_reversals(0.01 * np.sin(2 * np.pi * 3 * t)) == 0  # inside the hysteresis band


def test_a_few_ms_of_torque_delay_make_a_high_lambda_ring_but_not_a_low_one():
    """With 5 ms of actuator latency the damper at λ = 500 chatters against the limit while
    λ = 100 still stops cleanly (the report's latency check; the app's Safety → Torque delay)."""
    low = run_drop("proposed", 100.0, 3.0, True, "position", DURATION, delay_steps=5)
    high = run_drop("proposed", 500.0, 3.0, True, "position", DURATION, delay_steps=5)
    assert low["torque_delay_ms"] == high["torque_delay_ms"] == pytest.approx(5.0)
    assert low["oscillations"] == 0 and low["max_violation"] < 0.0
    assert high["oscillations"] >= 10


@pytest.mark.slow
def test_velocity_limit_excess_is_the_observers_lag_and_fusion_removes_most_of_it():
    """Lowered velocity limit, feedback on: with the observer alone the excess shrinks as K_I grows
    (its lag is 1/K_I); fusion, whose sensor feels the payload's m(g − a), exceeds it far less at the
    default K_I. Each run ends once joint 4 is at rest."""
    slow = run_drop("proposed", 100.0, 2.0, True, "velocity", 6.0, 50.0, 0, "residual")
    fast = run_drop("proposed", 100.0, 2.0, True, "velocity", 6.0, 1000.0, 0, "residual")
    fused = run_drop("proposed", 100.0, 2.0, True, "velocity", 6.0, 50.0, 0, "fusion")
    lim = slow["dq_limit"]
    assert slow["max_violation"] > 0.02 * lim  # a visible excess with the slow observer alone
    assert fast["max_violation"] < 0.2 * slow["max_violation"]
    assert fused["max_violation"] < 0.2 * slow["max_violation"]
    for r in (slow, fast, fused):
        assert r["stop"] == "until" and abs(r["trace_dq"][-1]) < 0.01  # the curve ends at rest


def test_a_drop_runs_until_joint_4_has_stopped(drops):
    on = drops[True]
    assert on["stop"] == "until" and on["duration_s"] < DURATION
    assert abs(on["trace_dq"][-1]) < 0.01
