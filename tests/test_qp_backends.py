"""The dense and the OSQP backend give the same solution on problems both executors build.

Tolerances (stated once): the dense (DAQP active-set) solution is exact up to ~1e-10; OSQP, the
reference, is run tight (eps 1e-9 / 1e-10, polishing, 20 000 iterations). Agreement is asserted as
max |x_dense − x_osqp| ≤ AGREE_ABS + AGREE_REL · max|x|. For the 7-joint nullspace QP the exact
optimum is also known in closed form (J has a one-dimensional kernel z: x = t z, t clipped to the
interval the box allows) and the dense backend is checked against it to 1e-9; there OSQP's ADMM
stalls on a few feasible problems (max iter, even at 20 000 iterations, where the old OSQP path of
the executor fell back too): those are counted and must stay under 10 %.

The dense backend's fast path (the unconstrained optimum −P⁻¹q when it is feasible, no DAQP
call: `control.kernels.dense_qp`) is held to DAQP's own solve of the same problem (`daqp.solve`, fresh)
to FAST_REL · max|x| and to OSQP as above, with and without active constraints, and along
sequences that switch between the fast path and DAQP's warm-started solve.
"""

from __future__ import annotations

import itertools

import daqp
import numpy as np

from control import coupling as c
from control import qp
from control.compliance_qp import AccelerationQP, ComplianceQPExecutor, PoseTask
from control.executor import ControlInputs, TaskTarget
from control.gains import ComplianceQPSettings, EstimatorGains, NullspaceGains, PoseTaskGains
from control.model import RobotModel
from control.nullspace import NullspaceQP, damper_bounds
from tests.conftest import random_configurations

AGREE_ABS = 1e-6
AGREE_REL = 1e-6
FAST_REL = 1e-9  # dense backend (fast path or warm-started DAQP) vs a fresh DAQP solve
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
        if exact is None:  # no x in the kernel meets the box: both relax it to the same least violation
            n_infeasible += 1
            assert a.fallback and b.fallback and a.status.startswith("relaxed"), (a.status, b.status)
            assert float(np.max(np.abs(a.x - b.x))) <= AGREE_ABS + AGREE_REL * float(np.max(np.abs(a.x)))
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
        fused=False,  # every step's QP goes through `ex.qp.solve` (the fused step may solve it itself)
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


def _fresh_daqp(P, q, A, l, u, lb, ub, n_eq=0):
    """DAQP's solve of the problem from scratch (no workspace kept), its x and exit flag."""
    sense = np.zeros(len(lb) + len(l), dtype=np.int32)
    sense[len(sense) - n_eq :] = 5
    x, _, flag, _ = daqp.solve(P, q, A, np.r_[ub, u], np.r_[lb, l], sense)
    return x, flag


def _convex_problem(rng, n, m, active):
    """Strictly convex, unconstrained optimum feasible (active False) or cut off by one bound or
    row (active True)."""
    G = rng.normal(size=(n, n))
    P = G @ G.T + 0.1 * np.eye(n)
    x_unc = rng.normal(size=n)
    A = rng.normal(size=(m, n))
    lb, ub = x_unc - rng.uniform(0.1, 1.0, n), x_unc + rng.uniform(0.1, 1.0, n)
    Ax = A @ x_unc
    l, u = Ax - rng.uniform(0.5, 2.0, m), Ax + rng.uniform(0.5, 2.0, m)
    if active:  # a cut small next to the other margins, so the problem stays feasible
        k = int(rng.integers(n + m))
        if k < n:
            ub[k], lb[k] = x_unc[k] - 0.1, x_unc[k] - 2.0
        else:
            l[k - n], u[k - n] = Ax[k - n] + 0.1, Ax[k - n] + 2.0
    return P, -P @ x_unc, A, l, u, lb, ub


def test_dense_fast_path_is_the_optimum_daqp_and_osqp_find():
    """Without an active constraint the dense backend returns −P⁻¹q without DAQP (iterations 0);
    with one it calls DAQP; either way x is DAQP's fresh solution (FAST_REL) and OSQP's (AGREE)."""
    rng = np.random.default_rng(31)
    tight = qp.QPSettings(eps=1e-10, polish=True, max_iter=20000)
    for k in range(60):
        n, m = (7, 7) if k % 2 else (6, 10)
        active = k % 3 == 0
        prob = _convex_problem(rng, n, m, active)
        res = qp.make_qp("dense", n, m).solve(*prob)
        ref, flag = _fresh_daqp(*prob)
        osqp_res = qp.make_qp("osqp", n, m, settings=tight).solve(*prob)
        assert res.status == qp.SOLVED and flag == 1 and osqp_res.solved
        assert (res.iterations == 0) != active
        scale = float(np.max(np.abs(ref)))
        assert float(np.max(np.abs(res.x - ref))) <= FAST_REL * scale
        assert float(np.max(np.abs(res.x - osqp_res.x))) <= AGREE_ABS + AGREE_REL * scale


def test_dense_warm_start_after_fast_path_solves_the_current_data():
    """A sequence switching between the fast path and DAQP (warm-started from the empty working
    set the fast path leaves, with the data the fast-path solves loaded since) gives DAQP's fresh
    solution at every step, also when P and A are passed as None (unchanged since the last call)."""
    rng = np.random.default_rng(32)
    n, m = 7, 7
    solver = qp.make_qp("dense", n, m)
    P = A = np.eye(n)
    paths = []
    for k in range(80):
        P_new, q, A_new, l, u, lb, ub = _convex_problem(rng, n, m, active=rng.random() < 0.5)
        keep = k % 5 == 4  # the same P and A as the step before: passed as None
        if not keep:
            P, A = P_new, A_new
            x_unc = -np.linalg.solve(P, q)
        else:  # bounds around the old P's unconstrained optimum, one of them cut on odd k
            x_unc = -np.linalg.solve(P, q)
            lb, ub = x_unc - 1.0, x_unc + 1.0
            l, u = A @ x_unc - 1.0, A @ x_unc + 1.0
            if k % 2:
                ub[0], lb[0] = x_unc[0] - 0.2, x_unc[0] - 2.0
        res = solver.solve(None if keep else P, q, None if keep else A, l, u, lb, ub)
        ref, flag = _fresh_daqp(P, q, A, l, u, lb, ub)
        assert res.status == qp.SOLVED and flag == 1
        assert float(np.max(np.abs(res.x - ref))) <= FAST_REL * float(np.max(np.abs(ref))), k
        paths.append(res.iterations == 0)
    switches = sum(a != b for a, b in itertools.pairwise(paths))
    assert 10 <= sum(paths) <= 70 and switches >= 20


def test_dense_backend_with_equality_rows_leaves_them_to_daqp():
    """Equality rows: no fast path (DAQP's equality-constrained solve), same x as DAQP fresh, the
    rows held (the unconstrained optimum, which meets every inequality, misses them by 0.05)."""
    rng = np.random.default_rng(33)
    n, m, n_eq = 7, 9, 2
    solver = qp.make_qp("dense", n, m, n_eq=n_eq)
    for _ in range(20):
        P, q, A, l, u, lb, ub = _convex_problem(rng, n, m, active=False)
        l[m - n_eq :] = u[m - n_eq :] = A[m - n_eq :] @ np.linalg.solve(P, -q) + 0.05
        res = solver.solve(P, q, A, l, u, lb, ub)
        ref, flag = _fresh_daqp(P, q, A, l, u, lb, ub, n_eq)
        assert res.status == qp.SOLVED and flag == 1 and res.iterations > 0
        np.testing.assert_allclose(A[m - n_eq :] @ res.x, l[m - n_eq :], rtol=0, atol=1e-9)
        assert float(np.max(np.abs(res.x - ref))) <= FAST_REL * float(np.max(np.abs(ref)))
