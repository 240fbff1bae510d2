"""`control.qp` is the one door to every way a QP is solved, and no code reaches into another
object's private state (issue: "the one QP door leaks")."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from control import qp
from control.nullspace import NullspaceQP

ROOT = Path(__file__).resolve().parents[1]
QP_KERNELS = ("nullspace_line_qp_fused", "unconstrained_optimum_fused", "dense_qp_load_fused")
BACKEND_TYPES = re.compile(r"DenseBackend|OSQPBackend|backend\s*==\s*[\"'](dense|osqp)[\"']")
PRIVATE = re.compile(r"(?<![\w.])(?!self\b|cls\b|np\b|pin\b)([a-z_][a-z0-9_]*)\._[A-Za-z]\w*")
ALLOWED_PRIVATE = ("._replace", "._asdict", "._fields")


def _control_sources() -> dict[str, str]:
    return {
        str(p.relative_to(ROOT)): p.read_text()
        for p in (ROOT / "control").glob("*.py")
        if p.name not in ("qp.py", "__init__.py")
    }


def test_executors_solve_qps_only_through_control_qp():
    """Outside `control.qp` (and the compiled steps of `control.kernels`, which run what it decides),
    no module calls a QP kernel or tests a backend's type."""
    for path, text in _control_sources().items():
        for name in QP_KERNELS:
            assert not re.search(rf"\b{name}\(", text), (path, name)
        assert not BACKEND_TYPES.search(text), (path, BACKEND_TYPES.search(text))


def test_no_control_code_touches_another_objects_private_state():
    sources = _control_sources()
    sources["control/qp.py"] = (ROOT / "control" / "qp.py").read_text()
    for path, text in sources.items():
        for m in PRIVATE.finditer(text):
            line = text[: m.start()].count("\n") + 1
            assert any(m.group(0).endswith(a) for a in ALLOWED_PRIVATE), (path, line, m.group(0))


def test_the_line_closed_form_equals_the_active_set_solve_of_the_same_qp():
    """[T15-17] on random full-rank (6, 7) J: `qp.solve_line_qp` gives DAQP's optimum to 1e-9 and
    counts the active bounds as iterations; it applies to the dense backend and a 1-D kernel only."""
    assert qp.line_qp_applies("dense", 7, 6)
    assert not qp.line_qp_applies("osqp", 7, 6) and not qp.line_qp_applies("dense", 8, 6)
    rng = np.random.default_rng(4)
    general = NullspaceQP(7, backend="dense", closed_form=False)
    active = 0
    for _ in range(40):
        J = rng.standard_normal((6, 7))
        g = rng.standard_normal(7) * rng.choice([0.1, 3.0])
        lower, upper = -rng.uniform(0.2, 1.0, 7), rng.uniform(0.2, 1.0, 7)
        line = qp.solve_line_qp(J, g, lower, upper, "dense")
        assert line is not None and line.solved
        ref = general.solve(J, g, lower, upper)
        assert ref.solved
        np.testing.assert_allclose(line.x, ref.x, atol=1e-9)
        active += line.iterations
    assert active >= 5


def test_a_fast_path_taken_by_the_caller_leaves_the_dense_backend_as_its_own_would():
    """`take_fast_path` returns what `solve` returns for a feasible unconstrained optimum, and the
    next active-set solve agrees with a fresh backend's."""
    rng = np.random.default_rng(5)
    n, m = 7, 3
    G = rng.standard_normal((n, n))
    P = G @ G.T + np.eye(n)
    x0 = rng.standard_normal(n)
    q, A = -P @ x0, rng.standard_normal((m, n))
    box = (x0 - 1.0, x0 + 1.0)
    rows = (A @ x0 - 100.0, A @ x0 + 100.0)
    backend = qp.make_qp("dense", n, m)
    assert backend.fast_path and not qp.make_qp("osqp", n, m).fast_path
    solved = backend.solve(P, q, A, *rows, *box)
    taken = backend.take_fast_path(-np.linalg.solve(P, q), 1.0)
    assert solved.iterations == taken.iterations == 0 and taken.solved
    np.testing.assert_allclose(taken.x, solved.x, rtol=1e-9)
    tight = (box[0], x0 - 0.5)  # the optimum now has active bounds: DAQP decides
    fresh = qp.make_qp("dense", n, m).solve(P, q, A, *rows, *tight)
    again = backend.solve(P, q, A, *rows, *tight)
    assert again.solved and again.iterations > 0
    np.testing.assert_allclose(again.x, fresh.x, atol=1e-9)
