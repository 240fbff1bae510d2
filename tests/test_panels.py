"""Panels: knobs are generated from parameter metadata and send SetParam commands the loop applies."""

from __future__ import annotations

import json

import numpy as np
import pytest

from app.core.commands import SetParam
from app.core.export import to_csv, to_json
from app.core.params import group_types
from app.core.session import Session
from app.live.loop import SimLoop
from app.live.ui.panels import ALL_FIELDS
from app.live.ui.panels.base import knob
from app.live.ui.panels.more_gains import claimed_fields
from app.scenarios import SCENARIOS
from control.params import specs


def _qp_loop() -> SimLoop:
    loop = SimLoop("free", executor="compliance-qp", capture=lambda s: None)
    loop.start(running=False)
    return loop


def test_every_panel_name_has_metadata_and_a_labelled_input():
    for path in ALL_FIELDS:
        k = knob(path)  # raises for an unknown group or field
        assert k.label and k.kind in ("checkbox", "dropdown", "slider", "number")
        if k.kind == "slider":
            lo, hi = k.bounds
            assert lo is not None and hi is not None and lo < hi and 0 < k.step <= hi - lo
        if k.spec.tag:
            assert k.spec.tag in (k.hint or "")
    assert knob("scenario.rope_length_m").spec.unit == "m"  # the "scenario" group differs per preset
    assert knob("scenario.start_swivel_deg").spec.unit == "deg"
    with pytest.raises(ValueError, match=r"group\.field"):
        knob("lambda_")
    with pytest.raises(ValueError, match="no parameter"):
        knob("damper.lambda")
    with pytest.raises(ValueError, match="elements"):
        knob("damper.lambda_[0]")


@pytest.mark.parametrize("scenario", sorted(SCENARIOS))
def test_every_group_of_every_preset_is_registered_with_its_dataclass(scenario):
    for executor in ("joint-hold", "projection", "compliance-qp"):
        groups = Session(scenario, executor=executor).params()
        for name, group in groups.items():
            assert type(group) in group_types(name), name
            assert specs(group), name  # every group has fields with metadata


def test_knob_labels_ranges_and_commands_come_from_the_metadata():
    trans, rot = knob("motion_force.motion_kp[0:3]"), knob("motion_force.motion_kp[3:6]")
    assert trans.label == "K_m^p px–pz (N/m)" and rot.label == "K_m^p rx–rz (N m/rad)"
    assert trans.bounds == (0.0, 10000.0) and rot.bounds == (0.0, 1000.0)
    assert [c.index for c in rot.commands(100.0, 1)] == [3, 4, 5]
    assert all(c == SetParam("motion_force", "motion_kp", 100.0, c.index, 1) for c in rot.commands(100.0, 1))
    joint = knob("posture_task.compliance[3]")
    assert joint.label == "Γ₀ joint 4" and joint.bounds == (0.0, 1.2)
    assert joint.shown((0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6)) == pytest.approx(0.3)
    assert knob("posture_task.compliance").shown(np.eye(7).tolist()) == pytest.approx(1.0)
    objective = knob("nullspace.objective")
    assert objective.options == ("W_j", "W_f", "W_a", "W_d") and objective.shown("d") == "W_d"
    assert objective.commands("W_f", None) == [SetParam("nullspace", "objective", "f")]
    assert knob("world.torque_delay_ms").bounds == (0.0, 20.0)  # the range is written once, in WorldParams


def test_qp_knob_changes_reach_the_executor_through_the_loop():
    loop = _qp_loop()
    try:
        for path, value in (
            ("damper.lambda_", 500.0),
            ("damper.velocity_scale", 0.5),
            ("pose_task.compliance", 1.0),
            ("posture_task.compliance[3]", 1.0),
            ("compliance_qp.feedback", False),
            ("estimator.source", "residual"),
        ):
            for cmd in knob(path).commands(value, 1):
                loop.submit(cmd)
        loop.sync()
        assert not [n for n in loop.notice_log if n.level == "error"]
        ex = loop.session.executor
        assert ex.damper.gains.lambda_ == 500.0 and ex.damper.gains.velocity_scale == pytest.approx(0.5)
        assert ex.settings.feedback is False and ex.estimator.gains.source == "residual"
        np.testing.assert_allclose(np.diag(ex.posture.gamma), [0, 0, 0, 1, 0, 0, 0])
        np.testing.assert_allclose(ex.tasks[0].gamma, np.eye(6))
        shown = loop.settings.groups
        assert knob("posture_task.compliance[3]").shown(shown["posture_task"].compliance) == 1.0
    finally:
        loop.stop()


def test_two_element_updates_of_one_vector_within_one_frame_are_both_applied():
    """The lost-update bug: translation 1000 then rotation 100 before the loop publishes."""
    loop = SimLoop("polish", capture=lambda s: None)
    loop.start(running=False)
    try:
        loop.sync()
        version = loop.settings.version
        for cmd in (
            *knob("motion_force.motion_kp[0:3]").commands(1000.0, 1),
            *knob("motion_force.motion_kp[3:6]").commands(100.0, 1),
        ):
            loop.submit(cmd)
        loop.sync()
        assert loop.settings.version > version
        assert loop.session.executor.gains.motion_kp == (1000.0,) * 3 + (100.0,) * 3
    finally:
        loop.stop()
    qp = _qp_loop()
    try:
        qp.submit(SetParam("posture_task", "compliance", 0.2))
        qp.submit(SetParam("posture_task", "compliance", 0.5, 1))
        qp.submit(SetParam("posture_task", "compliance", 0.9, 4))
        qp.sync()
        assert qp.session.params()["posture_task"].compliance == (0.2, 0.5, 0.2, 0.2, 0.9, 0.2, 0.2)
    finally:
        qp.stop()


def test_more_gains_shows_exactly_the_fields_no_panel_claims():
    claimed = claimed_fields(ALL_FIELDS)
    assert "motion_force.motion_kp" in claimed and "posture_task.compliance" in claimed
    assert "nullspace.k0_d" in claimed and "damper.lambda_" in claimed
    assert "compliance_qp.eps" not in claimed and "joint_hold.stiffness" not in claimed


def test_export_writes_every_column_and_marks_missing_values():
    cols = {"t": np.array([0.0, 0.001, 0.002]), "W_a": np.array([np.nan, 1.5, 2.0])}
    lines = to_csv(cols).decode().splitlines()
    assert lines[0] == "t,W_a" and len(lines) == 4 and lines[1] == "0,"
    doc = json.loads(to_json({"columns": cols, "scenario": "free", "settings": {"drag": {"max_force_n": 150.0}}}))
    assert doc["columns"]["W_a"] == [None, 1.5, 2.0] and doc["scenario"] == "free"


def test_the_gamma0_line_lists_each_joints_value_and_says_when_the_slider_shows_their_mean():
    from app.live.ui.panels.compliance import gamma0_text

    mixed = gamma0_text(np.diag([1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]))  # Γ₀ of joint 1 only: mean 0.14
    assert "1.00 · 0.00 · 0.00 · 0.00 · 0.00 · 0.00 · 0.00" in mixed and "mean" in mixed and "0.14" not in mixed
    same = gamma0_text(np.full(7, 0.5))
    assert same.count("0.50") == 7 and "mean" not in same
    assert gamma0_text(None) == ""
    one = gamma0_text(1.0)  # one value for every joint: no "by joint 1…1"
    assert one == "**Γ₀:** 1.00 on every joint"


def test_the_nullspace_panel_shows_the_units_of_W_for_the_coupling_objectives_only():
    """L_c and m_c change W_f, W_a, W_d only: their knobs show with those objectives, not with W_j."""
    from types import SimpleNamespace

    from app.live.ui.panels.nullspace import FIELDS, UNIT_FIELDS, NullspacePanel
    from control.gains import NullspaceGains

    assert {f"nullspace.{f}" for f in UNIT_FIELDS} <= set(FIELDS)
    for objective, shown in (("j", False), ("f", True), ("a", True), ("d", True)):
        settings = SimpleNamespace(groups={"nullspace": NullspaceGains(objective=objective)})
        for field in UNIT_FIELDS:
            knob = SimpleNamespace(group="nullspace", field=field)
            assert NullspacePanel.wanted(None, knob, settings) is shown, (objective, field)  # type: ignore[arg-type]
