"""Loader: shipped numbers, frames, sidecar validation, foreign URDFs."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

import robots
from control.model import RobotModel


def test_rizon_limits_and_tool(rizon):
    np.testing.assert_allclose(rizon.q_lower[[3, 5]], [-1.9548, -1.4835])
    np.testing.assert_allclose(rizon.q_upper[[3, 5]], [2.7751, 4.6251])
    np.testing.assert_allclose(rizon.tau_max, [123, 123, 64, 64, 39, 39, 39])
    model = RobotModel(rizon.model)
    flange = model.frame_pose(rizon.home, "flange")
    tcp = model.frame_pose(rizon.home, "tcp")
    # the TCP is 0.10 m along the flange z axis
    np.testing.assert_allclose(flange.actInv(tcp.translation), [0, 0, 0.10], atol=1e-12)
    assert np.all(rizon.armature > 0)
    np.testing.assert_allclose(rizon.model.armature, rizon.armature)


def test_gen3_endless_joints_and_home(gen3):
    assert list(gen3.endless) == [True, False, True, False, True, False, True]
    np.testing.assert_allclose(gen3.home, [0, 0.2618, 3.1416, -2.2689, 0, 0.9599, 1.5708])
    assert gen3.model.nq == 7


def test_total_mass_matches_published_link_masses(rizon, gen3):
    def arm_mass(r):
        return sum(i.mass for i in r.model.inertias[1:])

    assert arm_mass(rizon) == pytest.approx(3.6 + 2.7 + 2.4 + 2.4 + 2.3 + 2.2 + 1.4)
    assert arm_mass(gen3) == pytest.approx(1.3773 + 2 * 1.1636 + 0.9302 + 2 * 0.6781 + 0.5)


def test_foreign_urdf_without_sidecar_loads_with_defaults(tmp_path):
    path = tmp_path / "arm.urdf"
    path.write_text((robots.ROBOTS_DIR / "rizon4s.urdf").read_text())
    r = robots.load(str(path))
    assert r.flange_frame == "flange"
    assert np.all(r.armature == 0)
    assert r.model.existFrame("tcp")
    assert isinstance(r.tcp_in_flange, pin.SE3)


def test_sidecar_naming_a_missing_frame_is_refused(tmp_path):
    path = tmp_path / "arm.urdf"
    path.write_text((robots.ROBOTS_DIR / "rizon4s.urdf").read_text())
    (tmp_path / "arm.toml").write_text('flange_frame = "tool0"\n')
    with pytest.raises(robots.RobotLoadError, match="no frame 'tool0'"):
        robots.load(str(path))


def test_the_robot_list_names_a_urdf_by_its_robot_name_and_tells_apart_those_that_collide(tmp_path):
    """A URDF's label is its `<robot name>` (the file stem when it has none); one that a shipped robot
    or an earlier URDF already holds gets its chain options, else its file name, then its folder and
    file, in brackets; every label maps back to its spec."""
    from app.live.ui.panels.scenario import robot_labels
    from tests import urdf_fixtures as fx

    arm = fx.write(tmp_path / "lab" / "gripper_arm.urdf", fx.gripper_arm())
    same = fx.write(tmp_path / "other" / "gripper_arm.urdf", fx.gripper_arm())
    renamed = fx.write(tmp_path / "lab" / "my_arm.urdf", fx.gripper_arm())
    panda = fx.write(tmp_path / "lab" / "franka.urdf", fx.robot("panda", fx.arm("a", "world_base")))
    nameless = fx.write(tmp_path / "lab" / "bare.urdf", fx.gripper_arm().replace(' name="gripper_arm"', "", 1))
    tipped = robots.robot_spec(arm, tip="a_link7")
    twin = fx.write(tmp_path / "more" / "other" / "gripper_arm.urdf", fx.gripper_arm())
    specs = [str(arm), str(same), str(renamed), str(panda), str(nameless), tipped, str(twin)]
    labels = robot_labels(specs, taken=("scenario default", "rizon4s", "gen3", "panda"))
    assert labels["gripper_arm"] == str(arm)
    assert labels["gripper_arm (gripper_arm.urdf)"] == str(same)
    assert labels["gripper_arm (my_arm.urdf)"] == str(renamed)
    assert labels["panda (franka.urdf)"] == str(panda)
    assert labels["bare"] == str(nameless)
    assert labels["gripper_arm (other/gripper_arm.urdf)"] == str(twin)  # file name taken: folder and file
    assert labels["gripper_arm (tip=a_link7)"] == tipped  # the same file as the first: its chain option
    assert len(set(labels.values())) == len(specs)


def test_the_page_lists_a_urdf_arm_by_its_short_name_keeps_the_path_in_the_hint_and_switches_to_it(tmp_path):
    """`serve --urdf PATH`: the Robot dropdown offers "gripper_arm", not the path; its hint holds the
    path; the dropdown shows that label for the arm in force, and choosing it switches to the spec."""
    import types

    from app.live.server import start_app
    from app.live.ui.panels.scenario import DEFAULT_ROBOT, ScenarioPanel
    from tests import urdf_fixtures as fx
    from tests.conftest import free_port

    spec = str(fx.write(tmp_path / "gripper_arm.urdf", fx.gripper_arm()))
    app = start_app("127.0.0.1", free_port(), "free", spec, running=False)
    try:
        panel = next(p for p in app.panels if isinstance(p, ScenarioPanel))
        assert "gripper_arm" in panel.robot.options and spec not in panel.robot.options
        assert f"gripper_arm: {spec}" in (panel.robot.hint or "")
        frame = app.loop.wait_frame(0, timeout=10.0)
        assert frame is not None
        panel.live(frame)
        assert panel.robot.value == "gripper_arm"

        def choose(label: str) -> None:
            panel._on_robot(types.SimpleNamespace(client_id=1, target=types.SimpleNamespace(value=label)))
            app.loop.sync()

        choose(DEFAULT_ROBOT)
        assert app.loop.robot_choice == "" and app.loop.session.robot.name == "rizon4s"
        choose("gripper_arm")
        assert app.loop.robot_choice == spec and app.loop.session.robot.name == "gripper_arm"
    finally:
        app.stop()


def test_the_warm_up_runs_a_preset_the_chosen_arm_lacks_a_posture_for_on_the_presets_own_arm(monkeypatch):
    """`serve --robot rizon4s`: the Rizon's sidecar has no limit-drop posture, so the warm-up runs that
    preset on the Gen3 (as a switch in the page does) and says so, instead of stopping the start."""
    from app.core import executors
    from app.live import warmup

    monkeypatch.setattr(executors, "EXECUTORS", {"joint-hold": executors.EXECUTORS["joint-hold"]})
    monkeypatch.setattr("app.scenarios.SCENARIOS", {"limit-drop": "limit_drop"})
    monkeypatch.setattr(warmup, "WARM_STEPS", 5)
    monkeypatch.setattr(warmup, "DRAG_STEPS", 5)
    lines: list[str] = []
    assert warmup.warm_presets("rizon4s", lines.append) == 1
    assert any("on its own arm" in ln and "l_shape" in ln for ln in lines)
