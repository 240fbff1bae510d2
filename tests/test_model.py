"""The Dynamics snapshot: structural identities of [T 2-5] and ∂Λx/∂q against finite differences."""

from __future__ import annotations

import numpy as np

from control.model import RobotModel
from tests.conftest import random_configurations


def test_analytic_dLambda_matches_central_differences(robot):
    model = RobotModel(robot.model)
    for q in random_configurations(robot, 5, seed=1):
        analytic = model.dLambda_dq(model.compute(q, np.zeros(7)))
        numeric = model.dLambda_dq_fd(q, eps=1e-6)
        rel = np.max(np.abs(analytic - numeric)) / np.max(np.abs(numeric))
        assert rel < 1e-5, rel


def test_kinematic_hessian_layout_matches_finite_differences(robot):
    """Guards the Pinocchio 4.1 LOCAL_WORLD_ALIGNED Hessian layout workaround."""
    model = RobotModel(robot.model)
    q = random_configurations(robot, 1, seed=2)[0]
    dJ = model.tcp_jacobian_derivative(q)
    eps = 1e-6
    for k in range(7):
        e = np.zeros(7)
        e[k] = eps
        fd = (model.tcp_jacobian(q + e) - model.tcp_jacobian(q - e)) / (2 * eps)
        np.testing.assert_allclose(dJ[k], fd, atol=1e-8)


def test_dJ_dq_matches_time_derivative_of_tcp_velocity(robot):
    """J̇q̇ equals d/dt (J q̇) along a constant-velocity path (finite difference in time)."""
    model = RobotModel(robot.model)
    q = random_configurations(robot, 1, seed=3)[0]
    dq = np.linspace(-0.5, 0.5, 7)
    dt = 1e-6
    v_plus = model.tcp_jacobian(q + dq * dt) @ dq
    v_minus = model.tcp_jacobian(q - dq * dt) @ dq
    np.testing.assert_allclose(model.compute(q, dq).dJ_dq, (v_plus - v_minus) / (2 * dt), atol=1e-6)


def test_snapshot_identities(robot):
    model = RobotModel(robot.model)
    for q in random_configurations(robot, 5, seed=4):
        d = model.compute(q, np.full(7, 0.2))
        assert not d.near_singular
        np.testing.assert_allclose(d.Lambda, d.Lambda.T, atol=1e-9)
        assert np.linalg.eigvalsh(d.Lambda).min() > 0
        np.testing.assert_allclose(d.Lambda @ d.Lambda_inv, np.eye(6), atol=1e-8)
        np.testing.assert_allclose(d.M @ d.M_inv, np.eye(7), atol=1e-10)
        scale = np.abs(d.J).max()
        assert np.abs(d.J @ d.N).max() < 1e-10 * scale  # J N = 0
        assert np.abs(d.N @ d.J_bar).max() < 1e-10  # N J̄ = 0
        np.testing.assert_allclose(d.N @ d.N, d.N, atol=1e-10)  # idempotent
        # Λn = (N M⁻¹ Nᵀ)#: the four Moore-Penrose conditions
        S = d.N @ d.M_inv @ d.N.T
        P = d.Lambda_n
        np.testing.assert_allclose(S @ P @ S, S, atol=1e-9 * np.abs(S).max())
        np.testing.assert_allclose(P @ S @ P, P, atol=1e-6 * np.abs(P).max())
        np.testing.assert_allclose(P, P.T, atol=1e-8 * np.abs(P).max())
        assert np.linalg.matrix_rank(S, tol=1e-9 * np.abs(S).max()) == 1  # one redundant DOF


def test_singular_posture_is_flagged_not_crashing(rizon):
    model = RobotModel(rizon.model)
    d = model.compute(np.zeros(7), np.zeros(7))  # arm stretched straight up: wrist singular
    assert d.near_singular
    assert np.all(np.isfinite(d.Lambda)) and np.all(np.isfinite(d.N))
    assert np.abs(d.Lambda).max() < 1e7
