"""OSQP's polishing, done on its solution (`control.qp.polish_active_set`): exact and silent."""

from __future__ import annotations

import numpy as np
import pytest

from app.core.commands import SetParam
from app.live.lab import Lab
from control import qp


def _problems(rng: np.random.Generator, count: int, n: int = 7, m: int = 7):
    """Strictly convex problems whose optimum sits on some bounds and rows (and some on none)."""
    for i in range(count):
        G = rng.normal(size=(n, n))
        P = G @ G.T + 0.1 * np.eye(n)
        q = rng.normal(size=n) * (0.01 if i % 4 == 0 else 3.0)  # every 4th: the unconstrained optimum
        A = rng.normal(size=(m, n))
        yield P, q, A, np.full(m, -1.0), np.full(m, 1.0), np.full(n, -0.5), np.full(n, 0.5)


def test_polished_osqp_meets_the_exact_optimum_where_plain_osqp_stops_at_its_tolerance():
    rng = np.random.default_rng(4)
    settings = dict(eps=1e-4, max_iter=4000)
    dense = qp.make_qp("dense", 7, 7)
    plain = qp.make_qp("osqp", 7, 7, settings=qp.QPSettings(**settings))
    polished = qp.make_qp("osqp", 7, 7, settings=qp.QPSettings(polish=True, **settings))
    err_plain, err_polished, n_active = [], [], 0
    for problem in _problems(rng, 40):
        exact, a, b = dense.solve(*problem), plain.solve(*problem), polished.solve(*problem)
        assert exact.solved and a.solved and b.solved
        lo, hi = np.r_[problem[5], problem[3]], np.r_[problem[6], problem[4]]
        z = np.r_[exact.x, problem[2] @ exact.x]
        n_active += int(np.any(np.isclose(z, lo, atol=1e-9) | np.isclose(z, hi, atol=1e-9)))
        err_plain.append(float(np.max(np.abs(a.x - exact.x))))
        err_polished.append(float(np.max(np.abs(b.x - exact.x))))
    assert n_active >= 20
    assert np.median(err_polished) < 1e-9 < 1e-5 < np.median(err_plain), (np.median(err_polished), np.median(err_plain))
    assert max(err_polished) <= max(err_plain)  # a failed polish keeps OSQP's own answer


@pytest.mark.usefixtures("warm_kernels")
def test_steps_with_osqp_polishing_print_nothing(capfd):
    lab = Lab("compliance", executor="compliance-qp")
    lab.apply(SetParam("solver", "qp_backend", "osqp"))
    lab.apply(SetParam("compliance_qp", "polish", True))
    capfd.readouterr()
    lab.advance(300)  # before: 300 lines "Polishing not needed - no active set detected at optimal point"
    out, err = capfd.readouterr()
    assert lab.session.executor.last_qp.backend == "osqp" and lab.session.executor.qp.primary._polish
    assert out == "" and err == "", (out.splitlines()[:2], err.splitlines()[:2])
