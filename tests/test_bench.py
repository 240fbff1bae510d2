"""`torquelab bench` entries carry a real-time factor; the placo peer's failure is a clear message."""

from __future__ import annotations

import sys

import pytest

from app.bench import BUDGET_US, placo_step, run_bench


def test_every_bench_entry_has_its_real_time_factor():
    report = run_bench(only=["mj_step", "dynamics_snapshot"], repeats=5)
    for entry in report["results"].values():
        assert entry["real_time_factor"] == pytest.approx(BUDGET_US / entry["median_us"], rel=1e-12)


def test_qp_solve_entries_run_on_the_problems_the_executors_built():
    report = run_bench(only=["qp_solve_compliance_dense", "qp_solve_nullspace_dense"], repeats=5)
    assert set(report["results"]) == {"qp_solve_compliance_dense", "qp_solve_nullspace_dense"}


def test_placo_peer_without_placo_says_why(rizon):
    """This venv has no placo (it pins another Pinocchio): the error names the failure."""
    try:
        import placo  # noqa: F401
    except ImportError:
        pass
    else:  # pragma: no cover - a venv with placo installed
        pytest.skip("placo is importable here")
    with pytest.raises(ValueError, match=r"placo run with .* failed: .*placo"):
        placo_step(sys.executable, rizon, steps=5)
