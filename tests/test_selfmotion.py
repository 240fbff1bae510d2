"""Self-motion preview: the scan predicts where the gradient flow settles; the app shows it."""

from __future__ import annotations

import time

import numpy as np
import pytest

from app.live.server import start_app
from app.live.ui.panels.nullspace import NullspacePanel
from app.live.ui.selfmotion import AS_CONTROLLER, link_poses, preview_objective, scan_preview
from app.scenarios import get_scenario
from app.sim.world import World
from control import coupling as c
from control.model import RobotModel
from tests.conftest import browser_update


def _nullspace_descent(model: RobotModel, q: np.ndarray, objective: str, step_rad: float = 0.01) -> np.ndarray:
    """Steepest descent of W in the nullspace of J with fixed-length joint steps, pulled back onto
    the TCP pose, until W stops falling (an independent stand-in for the flow of [T15])."""
    pose = model.frame_pose(q, "tcp")
    sub = c.POLISH_SUBSPACES
    W_prev = np.inf
    for _ in range(2000):
        dyn = model.compute(q, np.zeros(7))
        W, grad = c.objective_gradient(objective, dyn, sub, model)
        if W >= W_prev:
            break
        W_prev = W
        J = dyn.J
        direction = -(grad - J.T @ np.linalg.solve(J @ J.T, J @ grad))  # −(I − J⁺J)∇W
        q = c.project_to_pose(model, q + step_rad * direction / np.linalg.norm(direction), *_pose(pose))
    return q


def _pose(pose) -> tuple[np.ndarray, np.ndarray]:
    return pose.translation, pose.rotation


@pytest.mark.parametrize("objective", ["f", "a", "d"])
def test_scan_predicts_where_the_gradient_flow_settles(rizon, objective):
    model = RobotModel(rizon.model)
    q0 = get_scenario("polish").initial_q(rizon)
    preview = scan_preview(model, rizon, q0, c.POLISH_SUBSPACES, objective)
    assert preview.feasible[0] and preview.feasible[preview.flow]
    assert preview.W[preview.flow] < preview.W[0]
    q_end = _nullspace_descent(model, q0, objective)
    settled = np.rad2deg(c.swivel_angle(model, q_end) - c.swivel_angle(model, q0))
    predicted = preview.swivel_deg[preview.flow] - preview.swivel_deg[0]
    wrapped = (settled - predicted + 180.0) % 360.0 - 180.0
    assert abs(wrapped) < 4.0, (settled, predicted)  # the scan samples the loop every ≤ 3°


def test_best_posture_is_the_smallest_W_inside_the_limits(rizon):
    model = RobotModel(rizon.model)
    q0 = get_scenario("polish").initial_q(rizon)
    p = scan_preview(model, rizon, q0, c.POLISH_SUBSPACES, "a")
    assert p.best is not None and p.feasible[p.best]
    assert p.W[p.best] == pytest.approx(np.min(p.W[p.feasible]))
    assert p.W[p.best] <= p.W[p.flow]
    tcp0 = model.frame_pose(q0, "tcp")
    tcp_best = model.frame_pose(p.q[p.best], "tcp")
    assert np.linalg.norm(tcp_best.translation - tcp0.translation) < 1e-6  # same TCP pose, other elbow
    assert preview_objective(AS_CONTROLLER, "j") == "a" and preview_objective(AS_CONTROLLER, "d") == "d"


def test_ghost_link_poses_match_the_simulated_bodies(rizon):
    model = RobotModel(rizon.model)
    q = get_scenario("polish").initial_q(rizon)
    world = World(rizon)
    world.reset(q)
    ids = [world.model.body(name).id for name in rizon.link_names]
    positions, wxyz = link_poses(model, rizon, q)
    np.testing.assert_allclose(positions, world.data.xpos[ids], atol=1e-12)
    np.testing.assert_allclose(np.abs(np.sum(wxyz * world.data.xquat[ids], axis=1)), 1.0, atol=1e-12)


def test_the_app_draws_the_ghost_at_the_flow_target_and_hides_it_when_off():
    app = start_app(port=0, scenario="polish", running=False)
    try:
        panel = next(p for p in app.panels if isinstance(p, NullspacePanel))
        preview = panel.preview
        assert not preview.ghost_visible
        browser_update(preview.enabled, True)
        assert preview.wait_scans(1, timeout=30.0)
        assert preview._in_process  # the scan ran in the scan process, not on the server's interpreter
        deadline = time.monotonic() + 5.0
        while not preview.ghost_visible and time.monotonic() < deadline:
            time.sleep(0.02)
        assert preview.ghost_visible
        latest = preview.latest
        assert latest is not None and latest.objective == "a"  # the polish controller runs W_a
        assert "flow settles" in preview.text.content
        x = np.asarray(preview.plot.data[0])
        assert len(x) == len(latest.W) > 50
        browser_update(preview.enabled, False)
        deadline = time.monotonic() + 5.0
        while preview.ghost_visible and time.monotonic() < deadline:
            time.sleep(0.02)
        assert not preview.ghost_visible
    finally:
        app.stop()
    assert not preview._thread.is_alive()


def test_scan_in_the_worker_process_equals_the_scan_here(rizon):
    """The picklable entry point of the scan process gives the same preview as a scan in-process."""
    import pickle

    from app.live.ui.selfmotion_worker import scan_in_worker

    q0 = rizon.postures.get("polish_start", rizon.home)
    model = RobotModel(rizon.model)
    here = scan_preview(model, rizon, q0, c.POLISH_SUBSPACES, "a")
    args = (str(rizon.urdf_path), rizon.model, rizon.q_lower, rizon.q_upper, q0, c.POLISH_SUBSPACES.force_axes, "a")
    there = pickle.loads(pickle.dumps(scan_in_worker(*pickle.loads(pickle.dumps(args)))))
    np.testing.assert_array_equal(there.W, here.W)
    np.testing.assert_array_equal(there.q, here.q)
    assert (there.flow, there.best) == (here.flow, here.best)


def test_the_scan_process_runs_at_a_lower_priority_than_the_server():
    """The scan process is spawned SCAN_NICENESS steps nicer than the server (capped at 19), so on a
    busy machine the 1 kHz loop and the browser get the cores first."""
    import os

    from app.live.ui.selfmotion import scan_worker
    from app.live.ui.selfmotion_worker import SCAN_NICENESS

    worker = scan_worker()
    try:
        niceness = worker.call(os.nice, 0, timeout=60.0)
    finally:
        worker.stop()
    assert niceness == min(os.nice(0) + SCAN_NICENESS, 19) and SCAN_NICENESS == 10


def test_the_ghost_follows_the_planned_posture_while_a_plan_runs(server):
    """With the preview on and the first ghost choice, each frame of a planned case poses the ghost
    at the planned posture of that frame (to 1e-12); another choice leaves it to the scan."""
    from types import SimpleNamespace

    import robots
    from app.live.ui.selfmotion import GHOST_CHOICES, SelfMotionPreview

    robot = robots.load("rizon4s")
    preview = SelfMotionPreview(server)
    preview.stop()  # no scans: only what the frames say
    preview.set_enabled(True, ghost_at=GHOST_CHOICES[0])
    q0 = get_scenario("polish").initial_q(robot)

    def frame(planned: np.ndarray | None) -> SimpleNamespace:
        scene = SimpleNamespace(
            q=q0, near_singular=False, subspaces=c.POLISH_SUBSPACES, objective="j", planned_q=planned
        )
        signals = {"swivel_plan_deg": 10.0} if planned is not None else {}
        return SimpleNamespace(scene=scene, status=SimpleNamespace(signals=signals), robot=robot)

    for k in range(3):
        planned = q0 + 0.05 * (k + 1) * np.array([1.0, -1.0, 1.0, 0.5, -0.5, 0.3, 0.0])
        preview.feed(frame(planned))
        assert preview.ghost_visible and preview.ghost_q is not None
        np.testing.assert_allclose(preview.ghost_q, planned, atol=1e-12)
    drawn = preview.ghost_q
    preview.set_enabled(True, ghost_at=GHOST_CHOICES[1])
    preview.feed(frame(q0 + 0.3))
    np.testing.assert_array_equal(preview.ghost_q, drawn)  # "best inside the limits": not the plan


def test_the_scene_carries_the_planned_posture_only_while_a_plan_runs():
    from types import SimpleNamespace

    from app.live.ui.snapshot import _planned_posture

    q = np.arange(7.0)
    step = lambda sig: SimpleNamespace(target=SimpleNamespace(q_posture=q), signals=sig)  # noqa: E731
    np.testing.assert_array_equal(_planned_posture(step({"swivel_plan_deg": 12.0})), q)
    assert _planned_posture(step({"swivel_plan_deg": float("nan")})) is None
    assert _planned_posture(step({})) is None
    assert _planned_posture(None) is None


def test_in_the_planned_case_the_scene_and_the_ghost_follow_the_sessions_plan(server):
    """The polish case "planned W_a": during the transfer the snapshot's planned posture is the one the
    nullspace tracks (the step's q_posture, exactly) and the ghost stands on it; the flow case has none."""
    from types import SimpleNamespace

    from app.core.session import Session
    from app.core.variants import make_variant
    from app.live.ui.selfmotion import GHOST_CHOICES, SelfMotionPreview
    from app.live.ui.snapshot import capture

    planned = Session(make_variant("polish", "planned W_a"), robot="rizon4s", executor="projection")
    flow = Session("polish", robot="rizon4s", executor="projection")
    preview = SelfMotionPreview(server)
    preview.stop()  # no scans: only what the frames say
    preview.set_enabled(True, ghost_at=GHOST_CHOICES[0])
    drawn = []
    for _ in range(3):
        planned.run(steps=500)
        flow.run(steps=500)
        snap = capture(planned)
        assert snap.planned_q is not None and capture(flow).planned_q is None
        np.testing.assert_array_equal(snap.planned_q, planned.last.target.q_posture)
        status = SimpleNamespace(signals=dict(planned.last.signals))
        preview.feed(SimpleNamespace(scene=snap, status=status, robot=planned.robot))
        np.testing.assert_allclose(preview.ghost_q, snap.planned_q, atol=1e-12)
        drawn.append(preview.ghost_q.copy())
    assert np.max(np.abs(drawn[-1] - drawn[0])) > 1e-3  # the ghost moves with the plan's transfer


def test_the_preview_takes_W_in_the_controllers_units(rizon):
    """The preview scans W in the units the controller's nullspace group sets: L_c = 1 m is the SI
    scan; L_c = 0.1 m moves W_d's flow end further from the elbow-up start (its translational
    columns weigh more), by more than 30° here."""
    from types import SimpleNamespace

    from app.live.ui.selfmotion import _units_of
    from control.gains import NullspaceGains

    model = RobotModel(rizon.model)
    q0 = get_scenario("polish").initial_q(rizon)
    frame = SimpleNamespace(settings=SimpleNamespace(groups={"nullspace": NullspaceGains(unit_length_m=0.1)}))
    np.testing.assert_array_equal(_units_of(frame), c.task_scale(0.1))
    assert _units_of(SimpleNamespace(settings=SimpleNamespace(groups={}))) is None
    si = scan_preview(model, rizon, q0, c.POLISH_SUBSPACES, "d")
    metre = scan_preview(model, rizon, q0, c.POLISH_SUBSPACES, "d", c.task_scale(1.0))
    np.testing.assert_allclose(metre.W, si.W, rtol=1e-12)
    short = scan_preview(model, rizon, q0, c.POLISH_SUBSPACES, "d", _units_of(frame))
    assert np.all(short.W < si.W)
    wrap = lambda deg: abs((deg + 180.0) % 360.0 - 180.0)  # noqa: E731
    assert wrap(short.swivel_deg[short.flow]) > wrap(si.swivel_deg[si.flow]) + 30.0
