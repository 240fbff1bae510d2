"""The dense and the OSQP backend give the same solution on problems both executors build.

Tolerances (stated once): the dense (DAQP active-set) solution is exact up to ~1e-10; OSQP, the
reference, is run tight (eps 1e-9 / 1e-10, polishing, 20 000 iterations). Agreement is asserted as
max |x_dense − x_osqp| ≤ AGREE_ABS + AGREE_REL · max|x|. For the 7-joint nullspace QP the exact
optimum is also known in closed form (J has a one-dimensional kernel z: x = t z, t clipped to the
interval the box allows) and the dense backend is checked against it to 1e-9; there OSQP's ADMM
stalls on a few feasible problems (max iter, even at 20 000 iterations, where the old OSQP path of
the executor fell back too): those are counted and must stay under 10 %.
"""

from __future__ import annotations

import numpy as np

from control import coupling as c
from control.compliance_qp import AccelerationQP, ComplianceQPExecutor, PoseTask
from control.executor import ControlInputs, TaskTarget
from control.gains import ComplianceQPSettings, EstimatorGains, NullspaceGains, PoseTaskGains
from control.model import RobotModel
from control.nullspace import NullspaceQP, damper_bounds
from tests.conftest import random_configurations

AGREE_ABS = 1e-6
AGREE_REL = 1e-6
TIGHT = ComplianceQPSettings(eps=1e-10, polish=True, max_iter=20000)


def _near_limits(robot, rng, count):
    """Joint positions with some joints inside the damper zones (d < d_i), a few inside d_s."""
    qs = []
    span = robot.q_upper - robot.q_lower
    for q in random_configurations(robot, count, seed=int(rng.integers(1000))):
        k = rng.choice(7, size=2, replace=False)
        side = rng.choice([-1.0, 1.0], size=2)
        d = rng.uniform(0.0, 0.25, size=2)
        q = q.copy()
        q[k] = np.where(side > 0, robot.q_upper[k] - d, robot.q_lower[k] + d)
        q = np.where(robot.endless, q, np.clip(q, robot.q_lower + 1e-4 * span, robot.q_upper - 1e-4 * span))
        qs.append(q)
    return qs


def _kernel_box_exact(J, g, lower, upper):
    """min ½‖x‖² + gᵀx, J x = 0, l ≤ x ≤ u for a 6×7 J of full rank: x = t z (None if infeasible)."""
    z = np.linalg.svd(J)[2][-1]
    with np.errstate(divide="ignore", invalid="ignore"):
        a, b = lower / z, upper / z
    small = np.abs(z) < 1e-12
    if np.any(small & ((lower > 0) | (upper < 0))):
        return None
    lo = np.max(np.where(small, -np.inf, np.where(z > 0, a, b)))
    hi = np.min(np.where(small, np.inf, np.where(z > 0, b, a)))
    if lo > hi:
        return None
    return z * min(max(-(g @ z) / (z @ z), lo), hi)


def test_nullspace_qp_backends_agree_with_each_other_and_the_exact_optimum(robot):
    model = RobotModel(robot.model)
    rng = np.random.default_rng(5)
    gains = NullspaceGains()
    dense = NullspaceQP(backend="dense")
    osqp = NullspaceQP(eps=1e-9, max_iter=20000, backend="osqp", polish=True)
    n_active = n_infeasible = n_solved = n_osqp_stalled = 0
    for q in [*_near_limits(robot, rng, 40), *random_configurations(robot, 20, seed=6)]:
        dyn = model.compute(q, np.zeros(7))
        objective = str(rng.choice(["a", "d", "f"]))
        _, grad = c.objective_gradient(objective, dyn, c.POLISH_SUBSPACES, model)
        step = rng.uniform(0.05, 20.0) * grad / np.linalg.norm(grad)  # some steps large enough to hit the box
        lower, upper = damper_bounds(q, robot.q_lower, robot.q_upper, 0.5 * robot.dq_max, robot.endless, gains)
        a, b = dense.solve(dyn.J, step, lower, upper), osqp.solve(dyn.J, step, lower, upper)
        exact = _kernel_box_exact(dyn.J, step, lower, upper)
        if exact is None:  # no x in the kernel meets the box: both report it and fall back alike
            n_infeasible += 1
            assert a.fallback and b.fallback
            np.testing.assert_allclose(a.x, b.x, atol=1e-12)
            continue
        n_solved += 1
        assert not a.fallback, a.status
        np.testing.assert_allclose(a.x, exact, rtol=0, atol=1e-9)
        if b.fallback:  # OSQP's ADMM stalls on a few of these (status "max iter", also at 20 000)
            assert b.status == "max iter"
            n_osqp_stalled += 1
            continue
        scale = AGREE_ABS + AGREE_REL * float(np.max(np.abs(exact)))
        assert float(np.max(np.abs(a.x - b.x))) <= scale
        active = np.isclose(exact, lower, atol=1e-9) | np.isclose(exact, upper, atol=1e-9)
        n_active += int(active.any())
    assert n_active >= 10 and n_solved >= 40  # bounds (velocity limits and dampers) active in many
    assert n_osqp_stalled <= 0.1 * n_solved


def test_nullspace_closed_form_equals_the_active_set_solver(robot):
    """The dense backend's closed form on the kernel line (7 joints) and DAQP's active-set solve of
    the same problems agree to 1e-9, active bounds and infeasible boxes (both fall back) included."""
    model = RobotModel(robot.model)
    rng = np.random.default_rng(7)
    gains = NullspaceGains()
    line, daqp = NullspaceQP(backend="dense"), NullspaceQP(backend="dense", closed_form=False)
    n_active = n_solved = 0
    for q in [*_near_limits(robot, rng, 40), *random_configurations(robot, 20, seed=8)]:
        dyn = model.compute(q, np.zeros(7))
        _, grad = c.objective_gradient(str(rng.choice(["a", "d", "f"])), dyn, c.POLISH_SUBSPACES, model)
        step = rng.uniform(0.05, 20.0) * grad / np.linalg.norm(grad)
        lower, upper = damper_bounds(q, robot.q_lower, robot.q_upper, 0.5 * robot.dq_max, robot.endless, gains)
        a, b = line.solve(dyn.J, step, lower, upper), daqp.solve(dyn.J, step, lower, upper)
        assert a.fallback == b.fallback and a.status == b.status
        np.testing.assert_allclose(a.x, b.x, rtol=0, atol=1e-9)
        n_solved += not a.fallback
        n_active += a.iterations if not a.fallback else 0
    assert n_solved >= 40 and n_active >= 10


def _compliance_problems(robot, rng, count, tau_scale):
    """(P, q, A, l, u, lb, ub) of the [C] QP at random states with large pose errors and velocities
    towards the limits (torque limits scaled by tau_scale so they bind)."""
    model = RobotModel(robot.model)
    ex = ComplianceQPExecutor.for_robot(
        robot,
        tasks=[PoseTask(PoseTaskGains(stiffness=400.0, damping=40.0))],
        estimator=EstimatorGains(source="oracle"),
        qp_backend="dense",
    )
    ex.tau_max = ex.tau_max * tau_scale
    captured = []
    solve = ex.qp.solve

    def capture(P, q):
        aqp = ex.qp
        captured.append((P.copy(), q.copy(), aqp.A.copy(), aqp.l.copy(), aqp.u.copy(), aqp.lb.copy(), aqp.ub.copy()))
        return solve(P, q)

    for q in _near_limits(robot, rng, count):
        dq = rng.normal(size=7) * 0.8
        dyn = model.compute(q, dq)
        offset = rng.normal(size=3) * 0.15
        target = TaskTarget(dyn.tcp_position_world + offset, dyn.tcp_rotation_world, q_posture=robot.home)
        ex.reset(dyn, target)  # rebuilds the QP
        solve = ex.qp.solve
        ex.qp.solve = capture  # type: ignore[method-assign]
        tau_ext = rng.normal(size=7) * 2.0
        ex.step(dyn, ControlInputs(0.0, target, np.zeros(6), tau_ext))
    return captured


def _solve_both(n, problem):
    P, q, A, l, u, lb, ub = problem
    out = {}
    for backend, settings in (("dense", ComplianceQPSettings()), ("osqp", TIGHT)):
        aqp = AccelerationQP(n, 0, settings, backend)
        aqp.A[:], aqp.l[:], aqp.u[:], aqp.lb[:], aqp.ub[:] = A, l, u, lb, ub
        out[backend] = aqp.solve(P, q)
    return out["dense"], out["osqp"]


def test_compliance_qp_backends_agree_with_torque_limits_and_dampers_active(robot):
    rng = np.random.default_rng(11)
    n = 7
    n_torque = n_damper = n_slack = 0
    for tau_scale in (1.0, 0.25):
        for problem in _compliance_problems(robot, rng, 25, tau_scale):
            a, b = _solve_both(n, problem)
            A, l, u, lb, ub = problem[2:]
            assert a.fallback == b.fallback, (a.status, b.status)
            scale = AGREE_ABS + AGREE_REL * float(np.max(np.abs(b.x)))
            assert float(np.max(np.abs(a.x - b.x))) <= scale, (a.status, b.status, np.max(np.abs(a.x - b.x)))
            if a.fallback:  # the slack problem: dampers softened, torque limits hard
                n_slack += 1
                continue
            tau_rows = A[:n] @ a.x
            n_torque += int(np.any(np.isclose(tau_rows, l[:n], atol=1e-6) | np.isclose(tau_rows, u[:n], atol=1e-6)))
            n_damper += int(np.any(np.isclose(a.x, lb, atol=1e-6) | np.isclose(a.x, ub, atol=1e-6)))
    assert n_torque >= 5 and n_damper >= 5, (n_torque, n_damper, n_slack)
