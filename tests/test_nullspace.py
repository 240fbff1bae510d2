"""Nullspace velocity QP [T15-17] with dampers and fallback; gains validation."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from control import coupling as c
from control.gains import MotionForceGains, NullspaceGains
from control.model import RobotModel
from control.nullspace import NullspaceQP, damper_bounds, min_norm_fallback
from tests.conftest import random_configurations


def _kernel_projection(J: np.ndarray) -> np.ndarray:
    return np.eye(J.shape[1]) - np.linalg.pinv(J) @ J


def test_qp_solution_lies_in_the_kernel_of_J_and_inside_the_bounds(robot):
    model = RobotModel(robot.model)
    qp = NullspaceQP()
    gains = NullspaceGains(objective="a")
    for q in random_configurations(robot, 4, seed=21):
        dyn = model.compute(q, np.zeros(7))
        _, grad = c.objective_gradient("a", dyn, c.POLISH_SUBSPACES, model)
        lower, upper = damper_bounds(q, robot.q_lower, robot.q_upper, 0.5 * robot.dq_max, robot.endless, gains)
        step = 2.0 * grad / np.linalg.norm(grad)  # large enough that some bounds bind
        res = qp.solve(dyn.J, step, lower, upper)
        assert not res.fallback, res.status
        assert np.max(np.abs(dyn.J @ res.x)) < 1e-5 * np.linalg.norm(step)  # [T16]
        assert np.all(res.x >= lower - 1e-5) and np.all(res.x <= upper + 1e-5)  # [T17]


def test_qp_equals_the_projected_gradient_when_no_bound_is_active(rizon):
    model = RobotModel(rizon.model)
    q = random_configurations(rizon, 1, seed=22)[0]
    dyn = model.compute(q, np.zeros(7))
    g = np.linspace(-0.1, 0.1, 7)
    big = np.full(7, 10.0)
    res = NullspaceQP().solve(dyn.J, g, -big, big)
    expected = -_kernel_projection(dyn.J) @ g  # minimiser of ½xᵀx + gᵀx on J x = 0
    np.testing.assert_allclose(res.x, expected, atol=1e-6)


def test_dampers_tighten_bounds_near_position_limits(rizon):
    gains = NullspaceGains()
    lim = np.full(7, 1.0)
    q = (rizon.q_lower + rizon.q_upper) / 2
    q[1] = rizon.q_lower[1] + 0.5 * (gains.damper_influence + gains.damper_safety)  # inside d_i
    q[2] = rizon.q_lower[2] + 0.5 * gains.damper_safety  # inside d_s: pushed out
    q[3] = rizon.q_upper[3] - 0.5 * (gains.damper_influence + gains.damper_safety)
    lower, upper = damper_bounds(q, rizon.q_lower, rizon.q_upper, lim, rizon.endless, gains)
    assert lower[0] == -1.0 and upper[0] == 1.0  # far from the limits: velocity limit
    assert lower[1] == pytest.approx(-0.5 * gains.damper_speed)  # halfway between d_s and d_i
    assert lower[2] > 0.0  # moves away from the limit
    assert upper[3] == pytest.approx(0.5 * gains.damper_speed)
    assert np.all(lower <= upper)


def test_infeasible_or_invalid_input_falls_back_without_raising(rizon):
    model = RobotModel(rizon.model)
    q = random_configurations(rizon, 1, seed=23)[0]
    J = model.compute(q, np.zeros(7)).J
    qp = NullspaceQP()
    lower, upper = -np.ones(7), np.ones(7)
    lower[0], upper[0] = 0.5, -0.5  # inconsistent bounds
    res = qp.solve(J, np.ones(7), lower, upper)
    assert res.fallback and res.status == "inconsistent bounds"
    assert np.all(np.isfinite(res.x))
    # bounds that exclude zero on a joint J cannot move alone: OSQP reports infeasible -> fallback
    lower, upper = np.full(7, 0.2), np.full(7, 0.3)
    res = qp.solve(J, np.zeros(7), lower, upper)
    assert res.fallback
    assert np.all(res.x >= lower - 1e-12) and np.all(res.x <= upper + 1e-12)
    res = qp.solve(J, np.full(7, np.nan), -np.ones(7), np.ones(7))
    assert res.fallback and np.all(res.x == 0.0)
    # and the solver recovers on the next normal step
    res = qp.solve(J, np.linspace(-0.1, 0.1, 7), -np.ones(7), np.ones(7))
    assert not res.fallback


def test_min_norm_fallback_stays_in_kernel_when_bounds_contain_zero(rizon):
    model = RobotModel(rizon.model)
    J = model.compute(random_configurations(rizon, 1, seed=24)[0], np.zeros(7)).J
    x = min_norm_fallback(J, np.linspace(-5, 5, 7), -0.1 * np.ones(7), 0.1 * np.ones(7))
    assert np.max(np.abs(x)) <= 0.1 + 1e-12
    assert np.max(np.abs(J @ x)) < 1e-10


def test_integrating_the_W_a_qp_at_a_fixed_tcp_decreases_W_a_monotonically(rizon):
    """Gradient flow of [T15]: q ← q + Δt q̂̇, pulled back onto the TCP pose (second-order drift)."""
    model = RobotModel(rizon.model)
    sub = c.POLISH_SUBSPACES
    gains = NullspaceGains(objective="a")
    q = random_configurations(rizon, 1, seed=25)[0]
    pose = model.frame_pose(q, "tcp")
    qp = NullspaceQP()
    values = []
    for _ in range(60):
        dyn = model.compute(q, np.zeros(7))
        W, grad = c.objective_gradient("a", dyn, sub, model)
        values.append(W)
        lower, upper = damper_bounds(q, rizon.q_lower, rizon.q_upper, 0.5 * rizon.dq_max, rizon.endless, gains)
        x = qp.solve(dyn.J, gains.k0 * grad, lower, upper).x
        q = c.project_to_pose(model, q + 0.02 * x, pose.translation, pose.rotation, iters=5)
    values_arr = np.array(values)
    assert np.all(np.diff(values_arr) <= 1e-9 * values_arr[0])
    assert values_arr[-1] < 0.9 * values_arr[0]


@pytest.mark.parametrize(
    ("cls", "field", "value"),
    [
        (MotionForceGains, "force_kp", -0.5),
        (MotionForceGains, "force_kd", float("nan")),
        (MotionForceGains, "motion_kp", (4000, 4000, -1, 400, 400, 400)),
        (NullspaceGains, "k0_a", float("nan")),
        (NullspaceGains, "velocity_scale", 0.0),
        (NullspaceGains, "damper_speed", -1.0),
    ],
)
def test_bad_gains_raise_value_error_naming_the_field(cls, field, value):
    with pytest.raises(ValueError, match=field):
        dataclasses.replace(cls(), **{field: value})


def test_unknown_objective_is_rejected():
    with pytest.raises(ValueError, match="objective"):
        NullspaceGains(objective="z")
    assert NullspaceGains(objective="d").k0 == NullspaceGains().k0_d
