"""Panels: knobs read the values in force from every executor and write well-formed changes."""

from __future__ import annotations

import json

import numpy as np
import pytest

from app.commands import Configure
from app.export import to_csv, to_json
from app.loop import SimLoop
from app.scenarios import SCENARIOS
from app.session import Session
from app.ui.panels import ALL_KNOBS
from app.ui.panels.base import Knob, coerce, make_settings_reader
from app.ui.panels.compliance import JOINT_KNOBS
from app.ui.panels.compliance import KNOBS as COMPLIANCE
from app.ui.panels.motion_force import KNOBS as MOTION_FORCE
from app.ui.panels.safety import KNOBS as SAFETY

READER = make_settings_reader((*ALL_KNOBS, *JOINT_KNOBS))


def _knob(knobs, key: str, label_part: str = "") -> Knob:
    return next(k for k in knobs if k.key == key and label_part in k.label)


def _qp_session() -> Session:
    qp = pytest.importorskip("control.compliance_qp")
    s = Session("free")
    s.executor = qp.ComplianceQPExecutor.for_robot(s.robot)
    s.executor_name = "compliance-qp"
    s.executor.reset(s.dyn, s.target_fn(0.0))
    return s


@pytest.mark.skipif("polish" not in SCENARIOS, reason="polish scenario not registered")
def test_projection_executor_and_polish_settings_are_read():
    values = READER(Session("polish"))
    ex, env, sensor, target = values["executor"], values["environment"], values["sensor"], values["target"]
    assert ex["objective"] in ("j", "f", "a", "d") and f"k0_{ex['objective']}" in ex
    assert ex["force_kp"] >= 0 and len(ex["motion_kp"]) == 6 and ex["motion_kp_rot"] == ex["motion_kp"]
    assert 0 < ex["velocity_scale"] <= 1 and ex["damper_influence"] > ex["damper_safety"]
    assert env["mu"] == pytest.approx(0.25) and env["sander_enabled"] is False and env["sander_amplitude_n"] > 0
    assert sensor["force_noise_var"] == pytest.approx(5.0)
    assert target["force_setpoint_n"] == pytest.approx(20.0)
    assert "lambda_" not in ex  # the QP executor's knobs are hidden for this executor


def test_compliance_qp_executor_settings_are_read():
    values = READER(_qp_session())["executor"]
    assert values["lambda_"] == pytest.approx(100.0) and values["M"] == pytest.approx(2.0)
    assert values["form"] == "proposed" and values["source"] in ("none", "residual", "fusion", "oracle")
    assert values["feedback"] is True and values["torque_limits"] is True
    assert values["task_compliance"] == 0.0 and values["posture_compliance"] == 0.0
    assert 0 < values["safety_fraction"] < values["influence_fraction"]
    assert "objective" not in values


def test_qp_knob_changes_reach_the_executor_through_the_loop():
    loop = SimLoop("free", capture=lambda s: None, settings_reader=READER)
    loop.start(running=False)
    try:
        session = loop.call(lambda s: s)
        qp = _qp_session().executor
        loop.call(lambda s: setattr(s, "executor", qp))
        joint3 = JOINT_KNOBS[3]
        for knob, value in (
            (_knob(SAFETY, "lambda_"), 500.0),
            (_knob(SAFETY, "velocity_scale"), 50.0),
            (_knob(COMPLIANCE, "task_compliance"), 1.0),
            (joint3, 1.0),
            (_knob(COMPLIANCE, "feedback"), False),
        ):
            stored = loop.settings.values["executor"].get(knob.key)
            loop.submit(Configure("executor", knob.to_changes(coerce(knob, value), stored), client_id=1))
            loop.sync()
        assert not [n for n in loop.notice_log if n.level == "error"]
        assert session.executor.damper.gains.lambda_ == 500.0
        assert session.executor.damper.gains.velocity_scale == pytest.approx(0.5)
        assert session.executor.settings.feedback is False
        np.testing.assert_allclose(np.diag(qp.posture.gamma), [0, 0, 0, 1, 0, 0, 0])
        np.testing.assert_allclose(qp.tasks[0].gamma, np.eye(6))
        shown = loop.settings.values["executor"]
        assert _knob(SAFETY, "velocity_scale").display(shown["velocity_scale"]) == pytest.approx(50.0)
        assert joint3.display(shown["posture_compliance"]) == 1.0
    finally:
        loop.stop()


def test_vector_knobs_change_only_their_part():
    rot = _knob(MOTION_FORCE, "motion_kp_rot")
    stored = [4000.0, 4000.0, 4000.0, 400.0, 400.0, 400.0]
    assert rot.display(stored) == 400.0
    assert rot.to_changes(100.0, stored) == {"motion_kp": (4000.0, 4000.0, 4000.0, 100.0, 100.0, 100.0)}
    trans = _knob(MOTION_FORCE, "motion_kp", "translation")
    assert trans.to_changes(10.0, stored) == {"motion_kp": (10.0, 10.0, 10.0, 400.0, 400.0, 400.0)}
    assert JOINT_KNOBS[6].to_changes(0.5, 0.2) == {"posture_compliance": (0.2,) * 6 + (0.5,)}
    noise = _knob(MOTION_FORCE, "force_noise_var")
    assert noise.to_changes(False, 5.0) == {"force_noise_var": 0.0, "sine_amplitude_n": 0.0}
    axes = _knob(MOTION_FORCE, "force_axes")
    assert axes.display([0, 1, 2]) == "px py pz" and axes.to_changes("px py", [2]) == {"force_axes": ("px", "py")}


@pytest.mark.parametrize("value", ["abc", None, float("nan"), float("inf"), -1.0, 1e12, True, [1.0]])
def test_slider_values_outside_the_knob_are_refused(value):
    with pytest.raises(ValueError):
        coerce(_knob(SAFETY, "lambda_"), value)


def test_checkbox_and_dropdown_accept_only_their_kind():
    with pytest.raises(ValueError):
        coerce(_knob(COMPLIANCE, "feedback"), "yes")
    with pytest.raises(ValueError):
        coerce(_knob(SAFETY, "form"), "<script>")
    assert coerce(_knob(SAFETY, "form"), "classic") == "classic"


def test_export_writes_every_column_and_marks_missing_values():
    cols = {"t": np.array([0.0, 0.001, 0.002]), "W_a": np.array([np.nan, 1.5, 2.0])}
    lines = to_csv(cols).decode().splitlines()
    assert lines[0] == "t,W_a" and len(lines) == 4 and lines[1] == "0,"
    doc = json.loads(to_json({"columns": cols, "scenario": "free", "settings": {"drag": {"max_force_n": 150.0}}}))
    assert doc["columns"]["W_a"] == [None, 1.5, 2.0] and doc["scenario"] == "free"


def test_more_gains_lists_exactly_the_scalars_the_executor_accepts():
    s = Session("free")
    values = READER(s)
    assert set(values["meta"]["executor_scalars"]) == {"stiffness", "damping"}  # joint-hold
    qp_values = READER(_qp_session())
    scalars = set(qp_values["meta"]["executor_scalars"])
    assert {"feedback", "torque_limits"} <= scalars
    assert "eps" not in scalars and "dt" not in scalars  # present on the object, refused by configure()
