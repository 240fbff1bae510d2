"""Coupling terms of [T]: Λ̂x [T9], [T10], Table I projections, W [T22] and gradients [T24-27]."""

from __future__ import annotations

import numpy as np
import pytest

from control import coupling as c
from control.model import RobotModel
from tests.conftest import random_configurations


def _w(model: RobotModel, q: np.ndarray, sub: c.Subspaces, objective: str, scale: np.ndarray | None = None) -> float:
    return c.coupling_values(c.terms_of(model.compute(q, np.zeros(7)), sub), scale, sub)[f"W_{objective}"]


@pytest.mark.parametrize("units", [(0.0, 1.0), (0.15, 2.5)], ids=["SI", "L_c=0.15m,m_c=2.5kg"])
@pytest.mark.parametrize("objective", ["f", "a", "d"])
def test_coupling_gradients_match_central_differences(robot, objective, units):
    model = RobotModel(robot.model)
    sub = c.POLISH_SUBSPACES
    scale = c.task_scale(*units)
    eps = 1e-6
    for q in random_configurations(robot, 3, seed=11):
        dyn = model.compute(q, np.zeros(7))
        W, grad = c.objective_gradient(objective, dyn, sub, model, scale=scale)
        assert W == pytest.approx(_w(model, q, sub, objective, scale), rel=1e-12)
        fd = np.empty(7)
        for k in range(7):
            e = np.zeros(7)
            e[k] = eps
            fd[k] = (_w(model, q + e, sub, objective, scale) - _w(model, q - e, sub, objective, scale)) / (2 * eps)
        rel = np.max(np.abs(grad - fd)) / np.max(np.abs(fd))
        assert rel < 1e-4, (objective, rel)


def test_gradients_for_a_two_axis_force_subspace(rizon):
    """The gradients hold for any split, e.g. force = (pz, rx)."""
    model = RobotModel(rizon.model)
    sub = c.Subspaces.from_force_axes(("pz", "rx"))
    q = random_configurations(rizon, 1, seed=12)[0]
    dyn = model.compute(q, np.zeros(7))
    for objective in "fad":
        _, grad = c.objective_gradient(objective, dyn, sub, model)
        e = np.zeros(7)
        e[3] = 1e-6
        fd = (_w(model, q + e, sub, objective) - _w(model, q - e, sub, objective)) / 2e-6
        assert grad[3] == pytest.approx(fd, rel=1e-4, abs=1e-8)


def test_partially_decoupled_inertia_has_the_structure_of_T9(robot):
    model = RobotModel(robot.model)
    for axes in [("pz",), ("px", "rz"), ("py", "pz", "rx")]:
        sub = c.Subspaces.from_force_axes(axes)
        q = random_configurations(robot, 1, seed=13)[0]
        L = model.compute(q, np.zeros(7)).Lambda
        Lh = c.partially_decoupled_inertia(L, sub)
        m, f = list(sub.motion_axes), list(sub.force_axes)
        A, B, D = L[np.ix_(m, m)], L[np.ix_(m, f)], L[np.ix_(f, f)]
        np.testing.assert_allclose(Lh[np.ix_(m, m)], A, rtol=1e-12)  # motion dynamics unchanged
        np.testing.assert_allclose(Lh[np.ix_(m, f)], B, rtol=1e-12)
        assert np.max(np.abs(Lh[np.ix_(f, m)])) == 0.0  # no force ← motion coupling
        np.testing.assert_allclose(Lh[np.ix_(f, f)], D - B.T @ np.linalg.solve(A, B), rtol=1e-9)
        # [T10]: I − Λ̂x Λx⁻¹ = [[0, 0], [BᵀA⁻¹, 0]]
        proj = np.eye(6) - Lh @ np.linalg.inv(L)
        np.testing.assert_allclose(proj, c.disturbance_projection(L, sub), atol=1e-9 * np.abs(proj).max())
        assert np.max(np.abs(proj[np.ix_(m, m + f)])) < 1e-9 * np.abs(proj).max()


def test_fast_block_identities_equal_explicit_inverses(robot):
    model = RobotModel(robot.model)
    sub = c.Subspaces.from_force_axes(("pz", "ry"))
    for q in random_configurations(robot, 3, seed=14):
        d = model.compute(q, np.zeros(7))
        fast = c.coupling_terms(d.Lambda, d.Lambda_inv, sub, exact_inverse=True)
        slow = c.coupling_terms(d.Lambda, d.Lambda_inv, sub, exact_inverse=False)
        for name in ("A_inv", "D_hat", "P_f", "P_a", "P_d"):
            a, b = getattr(fast, name), getattr(slow, name)
            np.testing.assert_allclose(a, b, atol=1e-7 * np.abs(b).max(), err_msg=name)


def test_principal_axes_sum_to_W_and_span_the_image_of_the_unit_sphere():
    rng = np.random.default_rng(0)
    P = rng.normal(size=(2, 5))
    sigma, V = c.principal_axes(P)
    assert sigma.sum() == pytest.approx(np.sum(P * P), rel=1e-12)  # [T22]
    # every y = P v with ‖v‖ = 1 lies inside the ellipsoid yᵀ(PPᵀ)⁻¹y ≤ 1, on it when v ∈ row space
    v = rng.normal(size=(200, 5))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    y = v @ P.T
    r = np.einsum("ij,jk,ik->i", y, np.linalg.inv(P @ P.T), y)
    assert np.all(r <= 1 + 1e-9)
    v_row = np.linalg.pinv(P) @ (V[:, 0] * np.sqrt(sigma[0]))
    assert np.linalg.norm(v_row) == pytest.approx(1.0, rel=1e-9)


def test_coupling_ellipse_is_flat_when_decoupled_and_tilted_by_P():
    sub = c.POLISH_SUBSPACES  # motion px py rx ry rz, force pz
    flat = c.coupling_ellipse(np.zeros((1, 5)), sub, points=32)
    assert flat.shape == (32, 3)
    np.testing.assert_allclose(np.hypot(flat[:, 0], flat[:, 1]), 1.0, rtol=1e-12)
    assert np.max(np.abs(flat[:, 2])) == 0.0
    P = np.array([[0.3, -0.1, 5.0, 5.0, 5.0]])  # rotational columns do not tilt the translational ellipse
    tilted = c.coupling_ellipse(P, sub, scale=2.0, points=32)
    np.testing.assert_allclose(tilted[:, 2], 2.0 * (0.3 * tilted[:, 0] - 0.1 * tilted[:, 1]), atol=1e-12)


def test_swivel_scan_stays_on_the_tcp_pose_and_closes_the_loop(rizon):
    model = RobotModel(rizon.model)
    q0 = random_configurations(rizon, 1, seed=15)[0]
    scan = c.swivel_scan(model, q0, c.POLISH_SUBSPACES, rizon.q_lower, rizon.q_upper, step_rad=np.deg2rad(6))
    assert scan.closed
    assert np.all(np.diff(scan.swivel_rad) > 0)
    p0 = model.frame_pose(q0, "tcp")
    for q in scan.q[:: max(1, len(scan.q) // 10)]:
        pose = model.frame_pose(q, "tcp")
        assert np.linalg.norm(pose.translation - p0.translation) < 1e-8
        assert np.linalg.norm(pose.rotation - p0.rotation) < 1e-8
    w_start = _w(model, q0, c.POLISH_SUBSPACES, "a")
    assert scan.W_a[0] == pytest.approx(w_start, rel=1e-9)
    assert scan.W_a.min() <= w_start


def test_move_to_swivel_reaches_the_angle_at_the_same_pose(rizon):
    model = RobotModel(rizon.model)
    q0 = random_configurations(rizon, 1, seed=16)[0]
    target = c.swivel_angle(model, q0) + 0.4
    q = c.move_to_swivel(model, q0, target)
    assert c.swivel_angle(model, q) == pytest.approx(target, abs=1e-5)
    assert np.linalg.norm(model.frame_pose(q, "tcp").translation - model.frame_pose(q0, "tcp").translation) < 1e-8


def test_bad_axes_and_objectives_raise_clear_errors():
    with pytest.raises(ValueError, match="unknown task axis"):
        c.Subspaces.from_force_axes(("pq",))
    with pytest.raises(ValueError, match="repeat"):
        c.Subspaces.from_force_axes(("pz", 2))
    with pytest.raises(ValueError, match="between 1 and 5"):
        c.Subspaces.from_force_axes(())
    with pytest.raises(ValueError, match="unknown coupling objective"):
        c.projection(c.coupling_terms(np.eye(6), np.eye(6), c.POLISH_SUBSPACES), "x")


def test_joint_limits_are_checked_modulo_two_pi():
    lo, up = np.full(2, -3.0), np.full(2, 3.0)
    q = np.array([2.0 * np.pi - 0.5, 3.5])  # ≡ −0.5 rad (inside); 3.5 ≡ −2.78 rad (inside)
    np.testing.assert_array_equal(c.within_limits_mod_2pi(q, lo, up), [True, True])
    q = np.array([3.2, -3.2])  # ≡ −3.08 / +3.08: outside ±3 either way
    np.testing.assert_array_equal(c.within_limits_mod_2pi(q, lo, up), [False, False])


@pytest.mark.parametrize("axes", [("pz",), ("pz", "rx"), ("px", "py", "rz")])
def test_direct_gradient_equals_the_dLambda_form(robot, axes):
    """The executor's gradient (one RNEA derivative per force axis) equals [T24-27] with ∂Λx/∂q."""
    model = RobotModel(robot.model)
    sub = c.Subspaces.from_force_axes(axes)
    for q in random_configurations(robot, 2, seed=17):
        dyn = model.compute(q, np.zeros(7))
        terms = c.terms_of(dyn, sub)
        dLambda = model.dLambda_dq(dyn)
        for objective in "fad":
            W1, g1 = c.coupling_gradient(terms, dyn.Lambda_inv, dLambda, sub, objective)
            W2, g2 = c.coupling_gradient_direct(model, dyn, terms, sub, objective)
            assert W2 == pytest.approx(W1, rel=1e-12)
            np.testing.assert_allclose(g2, g1, atol=1e-9 * np.abs(g1).max())


def test_flow_minimum_walks_downhill_and_stops_at_minima_and_limits():
    W = np.array([5.0, 4.0, 3.0, 3.5, 6.0, 7.0, 2.0, 1.0, 6.0])
    ok = np.ones(len(W), dtype=bool)
    assert c.flow_minimum(W, ok, start=0) == 2  # downhill to the right, stops at the local minimum
    assert c.flow_minimum(W, ok, start=5) == 7  # takes the steeper of its two downhill sides
    assert c.flow_minimum(W, ok, start=8) == 7
    # closed loop: from 0 the left neighbour (index 8, W = 6) is higher, so it still goes right
    ok_blocked = ok.copy()
    ok_blocked[2] = False
    assert c.flow_minimum(W, ok_blocked, start=0) == 1  # a joint limit stops the flow before it
    assert c.flow_minimum(np.array([2.0, 1.0, 3.0]), np.ones(3, bool), start=1) == 1  # already at a minimum
    assert c.flow_minimum(np.array([1.0, 2.0, 3.0]), np.ones(3, bool), start=2, closed=True) == 0
    assert c.flow_minimum(np.array([1.0, 2.0, 3.0]), np.ones(3, bool), start=2, closed=False) == 0
