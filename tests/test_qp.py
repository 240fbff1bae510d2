"""The one QP interface (control/qp.py): OSQP's internal vs public path, patterns, statuses."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import osqp
import pytest

from control import qp
from control.gains import SolverParams

ROOT = Path(__file__).resolve().parents[1]


def _random_problem(rng: np.random.Generator, n: int, m: int, n_eq: int):
    """A strictly convex problem with a feasible box and rows, some of them active at the optimum."""
    G = rng.normal(size=(n, n))
    P = G @ G.T + 0.1 * np.eye(n)
    q = rng.normal(size=n) * 5.0
    A = rng.normal(size=(m, n))
    x0 = rng.uniform(-0.5, 0.5, size=n)  # a feasible point
    lb, ub = x0 - rng.uniform(0.1, 1.0, n), x0 + rng.uniform(0.1, 1.0, n)
    Ax0 = A @ x0
    l, u = Ax0 - rng.uniform(0.05, 0.5, m), Ax0 + rng.uniform(0.05, 0.5, m)
    l[m - n_eq :] = u[m - n_eq :] = Ax0[m - n_eq :]
    return P, q, A, l, u, lb, ub


def test_osqp_version_is_one_the_internal_path_was_checked_on_and_pyproject_bounds_it():
    assert qp.osqp_internal_supported(), f"OSQP {osqp.__version__} lies outside {qp.OSQP_INTERNAL_VERSIONS}"
    text = (ROOT / "pyproject.toml").read_text()
    spec = re.search(r'"osqp>=([\d.]+),<([\d.]+)"', text)
    assert spec is not None, "pyproject must give osqp a lower and an upper bound"
    lo, hi = (tuple(int(p) for p in (*v.split("."), 0, 0)[:3]) for v in spec.groups())
    assert (lo, hi) == qp.OSQP_INTERNAL_VERSIONS
    assert not qp.osqp_internal_supported("1.2.0") and not qp.osqp_internal_supported("1.1.2")
    assert qp.osqp_internal_supported("1.1.3") and not qp.osqp_internal_supported("garbage")


@pytest.mark.parametrize(("n", "m", "n_eq"), [(7, 6, 6), (7, 7, 0), (7, 13, 6), (14, 21, 0)])
def test_osqp_internal_and_public_paths_give_the_same_solution(n, m, n_eq):
    """Same setup, same updates: the extension-object path and osqp.OSQP.update/solve agree."""
    rng = np.random.default_rng(n * 100 + m)
    settings = qp.QPSettings(eps=1e-8, max_iter=4000)
    inner = qp.make_qp("osqp", n, m, n_eq, settings=settings, osqp_internal=True)
    public = qp.make_qp("osqp", n, m, n_eq, settings=settings, osqp_internal=False)
    assert inner.internal and not public.internal  # type: ignore[attr-defined]
    active = 0
    for _ in range(30):  # a sequence, so the warm starts are compared too
        prob = _random_problem(rng, n, m, n_eq)
        a, b = inner.solve(*prob), public.solve(*prob)
        assert a.status == b.status == qp.SOLVED
        assert a.iterations == b.iterations
        np.testing.assert_allclose(a.x, b.x, rtol=0, atol=1e-12)
        lb, ub = prob[5], prob[6]
        active += int(np.any(np.isclose(a.x, lb, atol=1e-6) | np.isclose(a.x, ub, atol=1e-6)))
    assert active > 0  # bounds were active in some of them


def test_osqp_internal_path_is_refused_or_skipped_outside_the_checked_versions(monkeypatch):
    monkeypatch.setattr(qp, "OSQP_INTERNAL_VERSIONS", ((0, 0, 1), (0, 0, 2)))
    assert not qp.make_qp("osqp", 3, 1).internal  # type: ignore[attr-defined]
    with pytest.raises(ValueError, match="not checked"):
        qp.make_qp("osqp", 3, 1, osqp_internal=True)


@pytest.mark.parametrize("backend", qp.BACKENDS)
def test_pattern_keeps_zeros_so_updates_can_fill_them(backend):
    """Set up with A all zero, then filled in; KKT reference of min ½xᵀPx + qᵀx s.t. 1ᵀx = 1."""
    s = qp.QPSettings(eps=1e-10, max_iter=4000, polish=True)
    solver = qp.make_qp(backend, 3, 2, n_eq=1, settings=s)
    inf = np.full(3, np.inf)
    solver.solve(np.eye(3), np.zeros(3), np.zeros((2, 3)), np.array([-1.0, 0.0]), np.array([1.0, 0.0]), -inf, inf)
    A = np.array([[1.0, 0.0, 0.0], [1.0, 1.0, 1.0]])
    P = np.diag([2.0, 1.0, 1.0])
    P[0, 1] = P[1, 0] = 0.5
    res = solver.solve(P, np.array([-1.0, 0.0, 0.0]), A, np.array([-np.inf, 1.0]), np.array([np.inf, 1.0]), -inf, inf)
    assert res.solved and res.backend == backend and res.solve_us > 0
    K = np.block([[P, np.ones((3, 1))], [np.ones((1, 3)), np.zeros((1, 1))]])
    ref = np.linalg.solve(K, np.array([1.0, 0.0, 0.0, 1.0]))[:3]
    np.testing.assert_allclose(res.x, ref, atol=1e-7)


@pytest.mark.parametrize("backend", qp.BACKENDS)
def test_infeasible_and_garbage_give_a_status_not_an_exception(backend):
    solver = qp.make_qp(backend, 2, 1, n_eq=1, settings=qp.QPSettings(max_iter=4000))
    box = np.ones(2)
    # x1 + x2 = 5 with |x| ≤ 1: infeasible
    res = solver.solve(np.eye(2), np.zeros(2), np.ones((1, 2)), np.array([5.0]), np.array([5.0]), -box, box)
    assert not res.solved and res.status == qp.INFEASIBLE
    # lower above upper on a bound or a row
    res = solver.solve(np.eye(2), np.zeros(2), np.ones((1, 2)), np.zeros(1), np.zeros(1), box, -box)
    assert not res.solved and res.status == qp.INFEASIBLE
    res = solver.solve(np.eye(2), np.zeros(2), np.ones((1, 2)), np.ones(1), -np.ones(1), -box, box)
    assert not res.solved and res.status == qp.INFEASIBLE
    nan = np.full(2, np.nan)
    res = solver.solve(np.eye(2), nan, np.ones((1, 2)), np.zeros(1), np.zeros(1), -box, box)
    assert not res.solved
    # and it recovers on good data
    res = solver.solve(np.eye(2), np.array([-1.0, 0.0]), np.ones((1, 2)), np.zeros(1), np.zeros(1), -box, box)
    assert res.solved
    np.testing.assert_allclose(res.x, [0.5, -0.5], atol=1e-6)


def test_unknown_backend_is_refused_with_the_choices():
    with pytest.raises(ValueError, match="dense, osqp"):
        qp.make_qp("cvxpy", 2, 1)


def test_osqp_is_used_only_through_control_qp():
    """No other module imports OSQP or reaches into a solver's private `_solver`."""
    offenders = []
    for path in [*ROOT.glob("control/*.py"), *ROOT.glob("app/**/*.py")]:
        if path.name == "qp.py" and path.parent.name == "control":
            continue
        text = path.read_text()
        if re.search(r"^\s*(import osqp|from osqp)", text, re.M) or "._solver" in text:
            offenders.append(str(path.relative_to(ROOT)))
    assert offenders == []


def test_osqp_iteration_cap_is_reported_as_max_iter_with_its_iterate():
    rng = np.random.default_rng(3)
    solver = qp.make_qp("osqp", 7, 7, settings=qp.QPSettings(eps=1e-12, max_iter=5))
    res = solver.solve(*_random_problem(rng, 7, 7, 0))
    assert res.status == qp.MAX_ITER and not res.solved and np.all(np.isfinite(res.x))
    assert res.status_code == float(osqp.SolverStatus.OSQP_MAX_ITER_REACHED.value)


def test_backend_is_chosen_by_cli_environment_and_configure(monkeypatch, rizon, capsys):
    from app.cli import main
    from control.compliance_qp import ComplianceQPExecutor
    from control.model import RobotModel
    from control.motion_force import make_projection_executor

    monkeypatch.setenv(qp.BACKEND_ENV, "")  # restored afterwards, though main() writes os.environ itself
    assert qp.default_backend() == qp.DEFAULT_BACKEND == "dense"
    assert main(["bench", "--only", "qp_solve_compliance_osqp", "--repeats", "3", "--qp-backend", "osqp"]) == 0
    assert qp.default_backend() == "osqp"  # set for everything built afterwards (and worker processes)
    ex = ComplianceQPExecutor.for_robot(rizon)
    proj = make_projection_executor(rizon, RobotModel(rizon.model))
    assert ex.qp.primary.backend == proj.qp._qp.backend == "osqp"
    ex.set_params("solver", SolverParams(qp_backend="dense"))
    proj.set_params("solver", SolverParams(qp_backend="dense"))
    assert ex.qp.primary.backend == proj.qp._qp.backend == "dense"
    for bad in ("cvxpy", 1.0, None):
        with pytest.raises(ValueError, match="qp_backend must be one of dense, osqp"):
            SolverParams(qp_backend=bad)
    assert ex.qp_backend == proj.qp_backend == "dense"
    monkeypatch.setenv(qp.BACKEND_ENV, "nonsense")
    with pytest.raises(ValueError, match="nonsense"):
        qp.default_backend()
