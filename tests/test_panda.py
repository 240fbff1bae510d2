"""The Franka Panda by name, from the optional example-robot-data package: published limits, the
sidecar's frames, the locked fingers, the model cross-check, and the one-line error without it."""

from __future__ import annotations

import importlib.metadata

import numpy as np
import pytest

import robots
from app.tools.check import cross_check
from control.model import RobotModel
from robots import external

pytestmark = pytest.mark.skipif(not external.installed("panda"), reason="needs the robots extra (example-robot-data)")

# Franka's published limits (FCI "Robot and interface specifications")
Q_LOWER = [-2.8973, -1.7628, -2.8973, -3.0718, -2.8973, -0.0175, -2.8973]
Q_UPPER = [2.8973, 1.7628, 2.8973, -0.0698, 2.8973, 3.7525, 2.8973]
DQ_MAX = [2.175, 2.175, 2.175, 2.175, 2.61, 2.61, 2.61]
TAU_MAX = [87, 87, 87, 87, 12, 12, 12]


@pytest.fixture(scope="module")
def panda():
    return robots.load("panda")


def test_panda_loads_by_name_with_its_published_limits(panda):
    assert "panda" in robots.available()
    assert panda.joint_names == tuple(f"panda_joint{i}" for i in range(1, 8))
    np.testing.assert_allclose(panda.q_lower, Q_LOWER)
    np.testing.assert_allclose(panda.q_upper, Q_UPPER)
    np.testing.assert_allclose(panda.dq_max, DQ_MAX)
    np.testing.assert_allclose(panda.tau_max, TAU_MAX)
    assert panda.locked == {"panda_finger_joint1": 0.0, "panda_finger_joint2": 0.0}
    assert {"panda_hand", "panda_leftfinger", "panda_rightfinger"} <= set(panda.link_names)
    assert panda.guessed == {}  # the sidecar gives armature, TCP and postures
    np.testing.assert_allclose(panda.armature, 0.1)


def test_panda_tcp_is_at_the_hand_tcp_frame_and_the_postures_are_inside_the_limits(panda):
    model = RobotModel(panda.model)
    q = panda.postures["ready"]
    tcp = model.frame_pose(q, "tcp")
    hand_tcp = model.frame_pose(q, "panda_hand_tcp")
    np.testing.assert_allclose(tcp.translation, hand_tcp.translation, atol=1e-12)
    np.testing.assert_allclose(tcp.rotation[:, 2], hand_tcp.rotation[:, 2], atol=1e-12)  # same tool axis
    for name, posture in panda.postures.items():
        assert np.all(posture >= panda.q_lower) and np.all(posture <= panda.q_upper), name


def test_panda_pinocchio_and_mujoco_agree(panda):
    rep = cross_check(panda, samples=50)
    assert max(rep["worst_relative_error"].values()) <= 1e-9, rep


def test_panda_without_the_extra_is_one_line_with_the_install_command(monkeypatch):
    def missing(name):
        raise importlib.metadata.PackageNotFoundError(name)

    monkeypatch.setattr(external.importlib.metadata, "distribution", missing)
    assert "panda" not in robots.available()
    with pytest.raises(robots.RobotLoadError) as exc:
        robots.load("panda")
    text = str(exc.value)
    assert "\n" not in text and "pip install 'torquelab[robots]'" in text


PRESETS = ("free", "polish", "compliance", "limit-drop", "mass-drop")
DRAG_N = 300.0  # the GUI's largest drag
# How far the Panda may sink into a stop under that drag. MuJoCo's stop (app.sim.world HARD_STOP_SOLREF,
# the shortest time constant it recommends) is a spring whose stiffness scales with the joint's
# effective inertia; 300 N at the TCP puts ~70 N m on the Panda's joint 6 (a 12 N m motor, light wrist
# links) and sinks it ~23 mrad into its stop, past the 20 mrad HARD_STOP_GIVE_RAD that holds on the
# shipped arms. 30 mrad (1.7°) bounds it with room for the executors' differences.
PANDA_STOP_GIVE_RAD = 0.03


def _drag_run(session, seconds: float, where: str | None, pull: tuple[float, float, float]):
    """Run `seconds` with a 300 N-capped drag at the TCP or the elbow (None: no drag); the worst
    excursion beyond a position limit (rad) and the run's result."""
    robot, w = session.robot, session.world
    if where is not None:
        body = w.wrist_body if where == "tcp" else int(w.model.jnt_bodyid[w.model.joint(robot.joint_names[3]).id])
        p0 = w.site_pose(w.tcp_site)[0] if where == "tcp" else w.data.xpos[body].copy()
        session.drag.grab(w, body, p0)
        session.drag.move(p0 + 2.0 * np.array(pull))
    worst = np.full(robot.nq, -np.inf)

    def track(rec):
        np.maximum(worst, np.maximum(rec.q - robot.q_upper, robot.q_lower - rec.q), out=worst)

    result = session.run(seconds, record=track)
    session.drag.release()
    return float(np.max(worst)), result


@pytest.mark.slow
@pytest.mark.parametrize("executor", ["projection", "compliance-qp"])
@pytest.mark.parametrize("scenario", PRESETS)
def test_every_preset_runs_ten_seconds_on_the_panda_with_a_300_newton_drag(scenario, executor):
    """10 simulated seconds: 2 s free, 3 s pulled 300 N at the TCP (−x), 1 s free, 3 s pulled 300 N
    down at the elbow, 1 s free; no divergence and no joint deeper into its mechanical stop than
    PANDA_STOP_GIVE_RAD."""
    from app.core.session import Session
    from app.sim.world import HARD_STOP_BEYOND_RAD

    session = Session(scenario, robot="panda", executor=executor)
    session.drag.set_params("drag", replace_drag(session.drag.params()["drag"], DRAG_N))
    worst = -np.inf
    for seconds, where, pull in (
        (2.0, None, (0, 0, 0)),
        (3.0, "tcp", (-1.0, 0.0, 0.0)),
        (1.0, None, (0, 0, 0)),
        (3.0, "elbow", (0.0, 0.0, -1.0)),
        (1.0, None, (0, 0, 0)),
    ):
        beyond, result = _drag_run(session, seconds, where, pull)
        assert not result.halted, (scenario, executor, where, result.reason)
        worst = max(worst, beyond)
    assert session.world.time == pytest.approx(10.0, abs=2e-3)
    print(f"{scenario} {executor}: worst {worst - HARD_STOP_BEYOND_RAD:+.4f} rad into a stop")
    assert worst <= HARD_STOP_BEYOND_RAD + PANDA_STOP_GIVE_RAD, worst


def replace_drag(group, force_n: float):
    from control.params import replaced

    return replaced(group, "max_force_n", force_n)


def test_a_urdf_without_sidecar_polishes_from_a_searched_start_and_the_page_says_what_was_guessed():
    """The Panda's URDF alone (no sidecar next to it): armature zero, TCP at the tip, the polish
    start found by the reach search inside the joint limits; the lab's notice and status say so."""
    from app.live.frames import make_status
    from app.live.lab import Lab
    from app.scenarios.polish import PolishScenario

    path = external.urdf_path("panda")
    r = robots.load(str(path))
    assert set(r.guessed) == {"armature", "tcp", "postures"} and np.all(r.armature == 0)
    lab = Lab("polish", robot=str(path))
    q0 = lab.session.world.q
    assert np.all(q0 >= r.q_lower) and np.all(q0 <= r.q_upper)
    p, R = PolishScenario().start_pose()
    tcp = RobotModel(lab.session.robot.model).frame_pose(q0, "tcp")
    np.testing.assert_allclose(tcp.translation, p, atol=1e-6)
    np.testing.assert_allclose(tcp.rotation, R, atol=1e-6)
    said = [n for n in lab.notice_log if n.title == "Guessed robot values"]
    assert len(said) == 1 and "armature" in said[0].body and "coupling" in said[0].body
    assert "guessed" in make_status(lab).robot
    result = lab.advance(1500)  # approach, contact and the first half second of settling
    assert not result.halted, result.reason


def test_the_page_draws_the_panda_with_its_meshes_at_the_simulated_poses_and_they_drag(server):
    """Every Panda link with a visual (fingers included, at their locked position) is a mesh of the
    real DAE (thousands of faces, the file's colour), posed at the simulated body; a drag on one
    becomes grab / move / release commands."""
    import asyncio
    import types

    from app.core.commands import DragCommand
    from app.core.session import Session
    from app.live.ui.scene import NEUTRAL, SceneView
    from app.live.ui.snapshot import capture
    from app.live.ui.visuals import VisualSettings

    session = Session("free", robot="panda")
    sent: list[DragCommand] = []
    view = SceneView(server, session.robot, sent.append, VisualSettings(limit_colors=False))
    try:
        visual_links = {f"panda_link{i}" for i in range(8)} | {"panda_hand", "panda_leftfinger", "panda_rightfinger"}
        assert set(view.meshes) == visual_links
        assert all(len(view._link_shapes[name].faces) > 500 for name in visual_links)
        snap = capture(session)
        with server.atomic():
            view.update(snap)
        i = snap.link_index("panda_leftfinger")
        assert np.allclose(view.frames["panda_leftfinger"].position, snap.link_positions[i])
        body = session.world.model.body("panda_leftfinger").id
        np.testing.assert_allclose(snap.link_positions[i], session.world.data.xpos[body], atol=1e-9)
        assert tuple(view.meshes["panda_link3"].color) != NEUTRAL  # the DAE's own colour
        cb = view._drag_callback("panda_link5")
        for phase in ("start", "update", "end"):
            event = types.SimpleNamespace(
                phase=phase, client_id=3, start_position=(0.1, 0, 0.5), end_position=(0.2, 0, 0.5)
            )
            asyncio.run(cb(event))
        assert [c.kind for c in sent] == ["grab", "move", "release"] and sent[0].body_name == "panda_link5"
    finally:
        view.remove()


@pytest.mark.slow
def test_a_smaller_arm_without_sidecar_gets_the_table_and_start_scaled_to_its_reach(tmp_path):
    """The Panda's URDF with every joint offset ×0.6 (a smaller arm) and no sidecar: the paper's
    table and start are out of its reach, so the polish is placed at the first scale it reaches
    (start and every zig-zag corner tool down inside the limits); the guessed values say so and the
    first 1.5 s run."""
    import re

    from app.core.session import Session
    from app.scenarios.polish_stroke import START_XY_M, TABLE_HEIGHT_M, segment_waypoints

    text = external.urdf_path("panda").read_text()

    def shrink(m: re.Match) -> str:
        return m.group(1) + 'xyz="' + " ".join(f"{0.6 * float(v):.6f}" for v in m.group(2).split()) + '"'

    small = re.sub(r'(<joint[^>]*>\s*(?:<[^>]*>\s*)*?<origin[^>]*?)xyz="([^"]*)"', shrink, text)
    path = tmp_path / "small_arm.urdf"
    path.write_text(small)
    share = external.urdf_path("panda").parents[4]  # the folder holding example-robot-data/
    session = Session("polish", robot=robots.robot_spec(path, package_paths=[str(share)]))
    sc, r = session.scenario, session.robot
    scale = sc.table_height / TABLE_HEIGHT_M
    assert scale < 1.0 and sc.start_xy == pytest.approx((START_XY_M[0] * scale, START_XY_M[1] * scale))
    assert "placement" in r.guessed and f"×{scale:g}" in r.guessed["placement"]
    q0 = session.world.q
    assert np.all(q0 >= r.q_lower) and np.all(q0 <= r.q_upper)
    tcp = RobotModel(r.model).frame_pose(q0, "tcp").translation
    np.testing.assert_allclose(tcp, [*sc.start_xy, sc.table_height + 0.002], atol=1e-6)
    assert len(segment_waypoints(sc.start_xy)) == 7
    result = session.run(1.5)
    assert not result.halted, result.reason
    assert session.last is not None and session.last.signals["contact_force_n"] > 5.0  # pressing on the table


def test_the_pandas_limit_drop_start_has_the_load_push_joint_4_into_its_lower_limit_all_the_way(panda):
    """The sidecar's start: the 1.25 kg load's torque on joint 4 points to the lower limit from the start
    to the limit (6.0 → 3.3 N m, like the Gen3's 5.9 → 3.2 toward its upper one); [C]'s literal
    L-shape (upper arm vertical) has it reverse before the limit."""
    from app.scenarios.drop_postures import fall_from
    from app.scenarios.limit_drop import PAYLOAD_KG, LimitDropScenario

    fall = LimitDropScenario().fall(panda)
    assert fall.direction == -1 and fall.limit == pytest.approx(Q_LOWER[3]) and fall.reaches_limit
    assert fall.torque[0] > 5.5 and fall.torque[-1] > 3.0  # N m
    gen3 = robots.load("gen3")
    g = LimitDropScenario().fall(gen3)
    assert g.direction == 1 and g.limit == pytest.approx(gen3.q_upper[3]) and g.reaches_limit
    literal = np.array([0.0, 0.0, np.pi / 2, -np.pi / 2, 0.0, np.pi / 2, 0.0])
    assert not fall_from(panda, RobotModel(panda.model), literal, PAYLOAD_KG, 3).reaches_limit


@pytest.fixture(scope="module")
def panda_drops():
    from app.headless.experiments.limit_drop import run_drop

    with pytest.MonkeyPatch.context() as mp:
        mp.setenv(robots.ROBOT_ENV, "panda")
        return {fb: run_drop("proposed", 100.0, 2.0, fb, "position", 3.0) for fb in (True, False)}


def test_on_the_panda_joint_4_falls_into_its_lower_limit_and_the_dampers_hold_it(panda, panda_drops):
    """λ = 100, M = 2, feedback on: joint 4 falls 1 rad, comes to rest within 2 d_s (60 mrad) of its
    lower limit, far inside the dampers' influence distance d_i (0.30 rad), and never enters d_s
    (0.1 mrad slack); without feedback it goes at least 2 mrad deeper and into d_s ([C] Fig. 4)."""
    on, off = panda_drops[True], panda_drops[False]
    span = Q_UPPER[3] - Q_LOWER[3]
    assert on["robot"] == "panda" and on["direction"] == -1 and on["q_limit"] == pytest.approx(Q_LOWER[3])
    assert on["d_s"] == pytest.approx(0.01 * span)
    assert on["stop"] == "until" and abs(on["trace_dq"][-1]) < 0.01  # at rest before the 3 s cap
    assert np.min(on["trace_q"]) - Q_LOWER[3] < 2 * on["d_s"] < 0.1 * span
    assert 0.0 < on["final_margin"] < 2 * on["d_s"]
    assert on["max_violation"] < 0.0 and on["overshoot_beyond_ds"] < 1e-4
    assert off["overshoot_beyond_ds"] > max(on["overshoot_beyond_ds"], 0.0) + 2e-3


def test_the_panda_without_its_sidecar_postures_drops_into_a_limit_and_starts_the_mass_drop(monkeypatch):
    """The Panda's URDF alone: the limit drop's start is searched and the dampers catch joint 4 at the
    limit it falls toward; the mass drop starts tool down in front of the shoulder."""
    from app.core.session import Session
    from app.scenarios.drop_postures import TOOL_DOWN, mass_drop_target
    from tests.test_robot_chains import _drops, assert_drop_reaches_and_holds

    path = str(external.urdf_path("panda"))
    session = Session("limit-drop", robot=path)
    fall = session.scenario.fall(session.robot)
    assert "limit_drop" in session.robot.guessed and fall.reaches_limit
    drops = _drops(monkeypatch, path)
    assert drops[True]["q_limit"] == pytest.approx(fall.limit)
    assert_drop_reaches_and_holds(drops[True], drops[False])
    md = Session("mass-drop", robot=path)
    assert "mass_drop" in md.robot.guessed
    np.testing.assert_allclose(md.dyn.tcp_position_world, mass_drop_target(md.robot), atol=1e-6)
    np.testing.assert_allclose(md.dyn.tcp_rotation_world, TOOL_DOWN, atol=1e-6)
