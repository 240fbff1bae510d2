"""Parameters as data: coercion and validation in the dataclass, one path from a name to the owner."""

from __future__ import annotations

import math

import numpy as np
import pytest

from app.core.params import GROUP_TYPES, SCENARIO_TYPES, dumps, load_settings, parse_settings, save_settings
from app.core.session import Session
from control.gains import MotionForceGains, NullspaceGains, PoseTaskGains, PostureTaskGains
from control.params import ParamError, replaced, specs


def test_numeric_text_none_and_booleans_are_refused_for_a_number():
    g = MotionForceGains()
    for bad in ("5", "abc", None, True, b"5", {"x": 1}):
        with pytest.raises(ParamError, match="force_ki"):
            replaced(g, "force_ki", bad)
    assert replaced(g, "force_ki", 5).force_ki == 5.0 and isinstance(replaced(g, "force_ki", 5).force_ki, float)
    assert replaced(g, "force_ki", np.float32(2.5)).force_ki == 2.5


def test_non_finite_and_out_of_range_numbers_are_refused_with_the_range():
    g = NullspaceGains()
    for bad in (math.nan, math.inf, -math.inf, 1e300, -1.0):
        with pytest.raises(ParamError, match=r"between 0 and 1"):
            replaced(g, "k0_a", bad)
    with pytest.raises(ParamError, match=r"between 0\.25 and 4"):
        Session("free").set_param("world", "armature_scale", 1e6)


def test_a_list_for_a_scalar_and_wrong_shapes_for_a_vector_are_refused():
    g = MotionForceGains()
    with pytest.raises(ParamError, match="one number"):
        replaced(g, "force_ki", [1, 2])
    with pytest.raises(ParamError, match="needs 6 numbers"):
        replaced(g, "motion_kp", [1.0, 2.0])
    with pytest.raises(ParamError, match=r"motion_kp\[0\]"):
        replaced(g, "motion_kp", [[1.0] * 6] + [1.0] * 5)  # a nested list
    with pytest.raises(ParamError, match=r"motion_kp\[3\] must be between 0 and 1000"):
        replaced(g, "motion_kp", [5000.0] * 6)  # translation ≤ 10000 N/m but rotation ≤ 1000 N m/rad
    # a single number applies to every element of a vector
    assert replaced(g, "motion_zeta", 1.0).motion_zeta == (1.0,) * 6


def test_an_index_promotes_a_scalar_stiffness_to_its_vector():
    g = PoseTaskGains(stiffness=100.0)
    h = replaced(g, "stiffness", 50.0, index=2)
    assert h.stiffness == (100.0, 100.0, 50.0, 100.0, 100.0, 100.0)
    assert g.stiffness == 100.0  # the old group is untouched
    posture = replaced(PostureTaskGains(compliance=0.2), "compliance", 1.0, index=6)
    assert posture.compliance == (0.2,) * 6 + (1.0,)


def test_an_index_on_a_matrix_a_scalar_field_or_out_of_range_is_refused():
    full = PostureTaskGains(compliance=np.eye(7).tolist())
    assert isinstance(full.compliance[0], tuple)
    with pytest.raises(ParamError, match="full 7×7 matrix"):
        replaced(full, "compliance", 0.5, index=1)
    with pytest.raises(ParamError, match="single value"):
        replaced(MotionForceGains(), "force_kp", 0.5, index=0)
    with pytest.raises(ParamError, match="elements 0 … 5"):
        replaced(MotionForceGains(), "motion_kp", 1.0, index=6)
    with pytest.raises(ParamError, match="whole number"):
        replaced(MotionForceGains(), "motion_kp", 1.0, index=True)
    with pytest.raises(ParamError, match="one number"):
        replaced(MotionForceGains(), "motion_kp", [1.0, 2.0], index=1)


def test_gamma_matrices_must_be_symmetric_with_eigenvalues_in_range():
    G = np.eye(6) * 0.5
    G[0, 1] = G[1, 0] = 0.1
    assert np.allclose(PoseTaskGains(compliance=G.tolist()).compliance, G)
    G[0, 1] = 0.3
    with pytest.raises(ParamError, match="symmetric"):
        PoseTaskGains(compliance=G.tolist())
    with pytest.raises(ParamError, match="eigenvalues"):
        PoseTaskGains(compliance=(np.eye(6) * 2.0).tolist())


def test_rules_across_fields_refuse_and_keep_the_old_group():
    g = NullspaceGains()
    with pytest.raises(ParamError, match="damper_safety"):
        replaced(g, "damper_safety", 0.3)  # d_s must stay below d_i = 0.25
    assert g.damper_safety == 0.03


def test_session_set_param_names_group_and_field_and_changes_nothing_on_refusal():
    s = Session("polish")
    before = s.params()
    with pytest.raises(ParamError, match=r"^contact\.mu must be between 0 and 1\.5"):
        s.set_param("contact", "mu", 1e6)
    with pytest.raises(ParamError, match="no parameter group 'damper'"):
        s.set_param("damper", "lambda_", 10.0)
    assert s.params() == before
    s.set_param("contact", "mu", 1.0)
    s.set_param("target", "force_setpoint_n", 30.0)
    s.reset()  # environment and target are rebuilt: the overrides come back
    assert s.environment.contact.mu == 1.0 and s.target_fn.wrench[2] == 30.0
    assert s.overrides() == {"contact": {"mu": 1.0}, "target": {"force_setpoint_n": 30.0}}
    s.restore_defaults()
    assert s.environment.contact.mu == 0.25 and s.target_fn.wrench[2] == 20.0 and s.overrides() == {}


def test_the_start_swivel_is_a_scenario_parameter_used_at_reset_and_not_shared():
    s = Session("polish")
    q0 = s.world.q.copy()
    s.set_param("scenario", "start_swivel_deg", 30.0)
    s.reset()
    assert np.max(np.abs(s.world.q - q0)) > 0.05
    assert Session("polish").params()["scenario"].start_swivel_deg == 0.0  # the preset itself is untouched


def test_every_field_of_every_group_has_sane_metadata():
    for name, cls in [*GROUP_TYPES.items(), *(("scenario", c) for c in SCENARIO_TYPES)]:
        default = cls()
        for field, spec in specs(cls).items():
            assert spec.label, f"{name}.{field}"
            if spec.kind in ("float", "int"):
                assert spec.lo is not None and spec.hi is not None, f"{name}.{field} needs a range"
            if spec.kind == "choice":
                assert getattr(default, field) in spec.choices


def test_settings_round_trip_through_toml_and_refusals_are_listed():
    s = Session("polish")
    s.set_param("motion_force", "motion_kp", 1000.0, index=1)
    s.set_param("sander", "enabled", True)
    s.set_param("nullspace", "objective", "d")
    text = save_settings(s)
    t = Session("polish")
    assert load_settings(t, text) == []
    assert t.params() == s.params()
    refused = load_settings(t, '[contact]\nmu = "5"\n[nowhere]\nx = 1\nsize = 3\n[drag]\nmax_force_n = 1e300\n')
    assert len(refused) == 4 and "contact.mu" in refused[0] and "drag.max_force_n" in refused[3]
    assert "no parameter group 'nowhere'" in refused[1]
    assert t.params() == s.params()
    entries, problems = parse_settings("x = 1\n[a]\nb = [1, 2]")
    assert entries == [("a", "b", [1, 2])] and problems and "expected a [x] table" in problems[0]
    assert parse_settings("not toml [")[1][0].startswith("not a TOML settings file")
    assert dumps({"g": {"m": [[1.0, 0.0], [0.0, 1.0]], "s": 'a"b', "on": False}}) == (
        '[g]\nm = [[1.0, 0.0], [0.0, 1.0]]\ns = "a\\"b"\non = false\n'
    )


def test_a_settings_file_reaches_the_running_loop_in_order_and_refusals_are_listed():
    from app.live.loop import SimLoop
    from app.live.settings_io import load_settings_text, save_settings_text

    loop = SimLoop("polish", capture=lambda s: None)
    loop.start(running=False)
    try:
        text = (
            "[nullspace]\ndamper_influence = 0.5\ndamper_safety = 0.4\nk0_a = 9.0\n"
            "[contact]\nmu = 1.0\n[damper]\nM = 3\n"
        )
        refused = load_settings_text(loop, text)
        # d_s = 0.4 is accepted because d_i = 0.5 came first in the file; k0_a is out of range
        assert len(refused) == 2 and "nullspace.k0_a" in refused[0] and "'damper'" in refused[1]
        ns = loop.session.params()["nullspace"]
        assert (ns.damper_influence, ns.damper_safety, loop.session.environment.contact.mu) == (0.5, 0.4, 1.0)
        assert [(o.group, o.field) for o in loop.lab.overrides] == [
            ("nullspace", "damper_influence"),
            ("nullspace", "damper_safety"),
            ("contact", "mu"),
        ]
        saved = save_settings_text(loop)
        assert "damper_safety = 0.4" in saved and "mu = 1.0" in saved
    finally:
        loop.stop()


def test_serve_refuses_an_unreadable_or_malformed_settings_file_in_one_line(tmp_path, capsys):
    from app.cli import main

    bad = tmp_path / "bad.toml"
    bad.write_text("[damper\nlambda_ = 3")
    for path in (str(tmp_path / "missing.toml"), str(bad)):
        assert main(["serve", "--port", "0", "--settings", path]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and path in err[0], err


def test_restore_defaults_returns_every_parameter_of_the_preset_and_forgets_the_overrides():
    from app.core.commands import RestoreDefaults, SetParam
    from app.live.lab import Lab

    lab = Lab("limit-drop")
    defaults = lab.session.params()
    for cmd in (
        SetParam("damper", "lambda_", 300.0),
        SetParam("posture_task", "compliance", 1.0, 3),
        SetParam("world", "torque_delay_ms", 4.0),
        SetParam("drag", "max_force_n", 50.0),
        SetParam("solver", "qp_backend", "osqp"),
    ):
        lab.apply(cmd)
    lab.advance(20)
    assert len(lab.overrides) == 5 and lab.session.params() != defaults
    lab.apply(RestoreDefaults())
    assert lab.overrides == [] and lab.session.overrides() == {}
    assert lab.session.params() == defaults and lab.session.steps == 0
    assert lab.session.world.torque_delay_steps == 0 and lab.session.drag.max_force_n == 150.0
