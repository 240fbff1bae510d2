"""Executors' read-only view of their latest step, and the scene reading it instead of internals."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from app.core.session import Session
from app.live.ui import snapshot
from control import coupling as c
from control.bridge import make_bridge_executor
from control.compliance_qp import ComplianceQPExecutor
from control.executor import ControlInputs, TaskTarget
from control.gains import NullspaceGains, SolverParams
from control.joint_hold import JointHold
from control.model import RobotModel
from control.motion_force import make_projection_executor
from tests.conftest import random_configurations

ROOT = Path(__file__).resolve().parents[1]


def _target(dyn):
    return TaskTarget(dyn.tcp_position_world.copy(), dyn.tcp_rotation_world.copy(), wrench=np.r_[0, 0, 20.0, 0, 0, 0])


def test_projection_view_equals_what_the_step_computed(rizon):
    model = RobotModel(rizon.model)
    ex = make_projection_executor(rizon, model, nullspace=NullspaceGains(objective="d"))
    q = random_configurations(rizon, 1, seed=3)[0]
    dyn = model.compute(q, np.full(7, 0.05))
    ex.reset(dyn, _target(dyn))
    out = ex.step(dyn, ControlInputs(0.0, _target(dyn), np.array([1.0, -2.0, 19.0, 0, 0, 0])))
    view = ex.view()
    assert view.executor == "projection" and view.objective == "d"
    for k in ("W", "W_f", "W_a", "W_d"):
        assert view.W[k] == out.info[k]
    terms = c.terms_of(dyn, c.POLISH_SUBSPACES)  # recomputed independently from the same snapshot
    for k in ("P_f", "P_a", "P_d"):
        np.testing.assert_allclose(view.P[k], getattr(terms, k), rtol=1e-12, atol=1e-15)
    assert view.W["W_d"] == pytest.approx(float(np.sum(terms.P_d**2)), rel=1e-12)
    assert view.force_axes == c.POLISH_SUBSPACES.force_axes and view.motion_axes == c.POLISH_SUBSPACES.motion_axes
    np.testing.assert_array_equal(view.limit_zone, np.full(7, ex.nullspace.damper_influence))
    assert view.shaping is ex.gains.shaping is True
    res = ex.last_qp
    assert (view.qp_status, view.qp_backend, view.qp_fallback) == (res.status, res.backend, res.fallback)
    assert view.qp_iterations == out.info["qp_iterations"] and view.qp_fallback == bool(out.info["qp_fallback"])
    # read-only copies: writing fails, and the next step does not change a view already taken
    with pytest.raises(ValueError):
        view.P["P_f"][0, 0] = 1.0
    with pytest.raises(TypeError):
        view.W["W_f"] = 0.0  # type: ignore[index]
    before = np.array(view.P["P_f"])
    dyn2 = model.compute(q + 0.1, np.zeros(7))
    ex.step(dyn2, ControlInputs(1e-3, _target(dyn), np.zeros(6)))
    np.testing.assert_array_equal(view.P["P_f"], before)
    assert not np.allclose(ex.view().P["P_f"], before)
    e = dyn2.q - ex.q_posture  # the target has no posture: the one held at reset [T18]
    assert ex.view().W["W_j"] == pytest.approx(0.5 * float(e @ e), rel=1e-12) and float(e @ e) > 0.05


def test_compliance_and_bridge_views_carry_damper_zone_qp_and_the_law(gen3):
    model = RobotModel(gen3.model)
    dyn = model.compute(gen3.home, np.zeros(7))
    ex = ComplianceQPExecutor.for_robot(gen3)
    ex.reset(dyn, _target(dyn))
    out = ex.step(dyn, ControlInputs(0.0, _target(dyn), np.zeros(6)))
    view = ex.view()
    assert view.objective is None and view.P is None and view.force_axes is None
    np.testing.assert_array_equal(view.limit_zone, ex.damper.d_i)
    assert view.qp_status == ex.last_qp.status and view.qp_backend == ex.qp_backend
    assert view.qp_iterations == out.info["qp_iterations"] and view.qp_solve_us == out.info["qp_solve_us"]
    assert view.qp_fallback == bool(out.info["qp_relaxed"])

    law = make_projection_executor(gen3, model, nullspace=NullspaceGains(objective="a"))
    bridge = make_bridge_executor(gen3, law)
    bridge.reset(dyn, _target(dyn))
    bridge.step(dyn, ControlInputs(0.0, _target(dyn), np.zeros(6)))
    bv, lv = bridge.view(), law.view()
    assert bv.executor == "compliance-qp" and bv.objective == "a" and bv.W == lv.W
    np.testing.assert_array_equal(bv.P["P_a"], lv.P["P_a"])
    assert bv.qp_status == bridge.last_qp.status  # its own acceleration QP, not the law's
    bridge.set_params("solver", SolverParams(qp_backend="osqp"))  # the law's nullspace QP follows
    assert bridge.qp.primary.backend == law.qp._qp.backend == "osqp"
    assert JointHold().view().P is None


def test_scene_takes_objective_split_coupling_and_zone_from_the_view(monkeypatch):
    s = Session("polish")
    s.set_param("nullspace", "objective", "a")
    for _ in range(5):
        s.step()
    view = s.executor.view()

    def no_recompute(*args, **kwargs):
        raise AssertionError("the scene recomputed coupling terms the step had")

    monkeypatch.setattr(snapshot, "coupling_terms", no_recompute)
    snap = snapshot.capture(s)
    assert snap.objective == view.objective == "a"
    assert snap.force_axes == view.force_axes
    for k in ("P_f", "P_a", "P_d"):
        np.testing.assert_array_equal(snap.P[k], view.P[k])
    assert snap.W == {k: view.W[k] for k in ("W_f", "W_a", "W_d")}
    np.testing.assert_array_equal(snap.limit_zone, view.limit_zone)
    assert snap.step is not None and snap.step.qp_backend == view.qp_backend


def test_snapshot_reads_the_executor_only_through_its_view():
    text = (ROOT / "app" / "live" / "ui" / "snapshot.py").read_text()
    assert not re.search(r"getattr\([^)]*executor", text)
    uses = re.findall(r"executor\.(\w+)", text)
    assert uses == ["view"], uses
