"""The twin arm: a second session in lockstep with another nullspace objective."""

from __future__ import annotations

import numpy as np
import pytest

from app.core.commands import DragCommand, Reset, SetParam, SetTwin, StepOnce, SwitchSession
from app.live.loop import SimLoop
from app.live.ui.snapshot import capture


@pytest.fixture
def polish():
    lp = SimLoop("polish", capture=capture)  # with the scene snapshot, so frames carry the twin's poses
    lp.start(running=False)
    yield lp
    lp.stop()


def _frame_with_twin(loop: SimLoop):
    """The first published frame that shows the twin (frames follow commands within ~1/30 s)."""
    seq = 0
    for _ in range(100):
        frame = loop.wait_frame(seq, timeout=1.0)
        if frame is not None:
            if frame.status.twin:
                return frame
            seq = frame.seq
    raise AssertionError("no frame showed the twin")


def test_a_twin_with_the_same_objective_repeats_the_main_arm_step_for_step(polish):
    polish.submit(StepOnce(50))
    polish.submit(SetTwin("a"))  # the polish controller runs W_a: the twin must be the same run
    polish.submit(StepOnce(400))
    status = polish.sync()
    assert status.twin == "a" and status.steps == 400  # switching the twin on restarted the scenario
    main, twin = polish.session, polish.twin
    assert twin is not None
    assert twin.session.world.time == main.world.time
    np.testing.assert_array_equal(twin.session.world.q, main.world.q)
    np.testing.assert_array_equal(twin.session.world.dq, main.world.dq)
    cols = polish.log.window(0.4, polish.dt)
    np.testing.assert_array_equal(twin.force_error_at(cols["t"]), cols["Fd_z"] - cols["F_z"])


def test_a_twin_with_another_objective_takes_another_posture_and_shares_the_settings(polish):
    polish.submit(SetParam("contact", "mu", 1.0))
    polish.submit(SetTwin("j"))
    polish.submit(StepOnce(2000))
    polish.sync()
    main, twin = polish.session, polish.twin
    assert twin is not None and twin.session.executor.nullspace.objective == "j"
    assert main.executor.nullspace.objective == "a"
    assert twin.session.environment.contact.mu == main.environment.contact.mu == 1.0
    # same TCP task, different elbow: W_a lets the elbow move, W_j holds the start posture
    assert np.linalg.norm(twin.session.dyn.tcp_position_world - main.dyn.tcp_position_world) < 2e-3
    assert np.max(np.abs(twin.session.world.q - main.world.q)) > 0.02
    frame = _frame_with_twin(polish)
    assert frame.status.twin == "j" and frame.scene.twin_objective == "j"
    assert frame.scene.twin_link_positions.shape == frame.scene.link_positions.shape


def test_the_drag_pulls_only_the_main_arm_and_reset_restarts_both(polish):
    polish.submit(SetTwin("d"))
    polish.submit(StepOnce(100))
    polish.sync()
    p = polish.session.world.data.xpos[polish.session.world.model.body("link4").id].copy()
    polish.submit(DragCommand("grab", client_id=1, body_name="link4", point_world=tuple(p)))
    polish.submit(DragCommand("move", client_id=1, target_world=tuple(p + np.array([0.0, 0.15, 0.0]))))
    polish.submit(StepOnce(300))
    polish.sync()
    twin = polish.twin
    assert twin is not None and polish.session.drag.active and not twin.session.drag.active
    polish.submit(Reset())
    status = polish.sync()
    assert status.t == 0.0 and twin.session.world.time == 0.0 and polish.twin is twin


def test_a_twin_needs_an_executor_with_an_objective(polish):
    polish.submit(SetTwin("z"))
    polish.sync()
    assert polish.twin is None and "objective" in polish.notice_log[-1].body
    polish.submit(SetTwin("f"))
    polish.sync()
    assert polish.twin is not None
    polish.submit(SwitchSession(executor="compliance-qp"))
    polish.sync()
    assert polish.twin is None and polish.notice_log[-1].title == "Twin arm off"
    polish.submit(SwitchSession(executor="projection"))
    polish.submit(SetTwin("f"))
    polish.submit(SwitchSession(robot="gen3"))  # a new session brings a new twin with the same objective
    status = polish.sync()
    assert status.robot == "gen3" and polish.twin is not None and polish.twin.session.robot.name == "gen3"
    polish.submit(SetTwin(None))
    assert polish.sync().twin == ""


def test_the_export_carries_the_twins_columns_beside_the_main_ones(polish):
    polish.submit(SetTwin("j"))
    polish.submit(StepOnce(500))
    polish.sync()
    export = polish.export(0.3)
    cols = export["columns"]
    assert export["twin_objective"] == "j"
    assert len(cols["t"]) == 300 and len(cols["twin_q_1"]) == 300
    assert not np.any(np.isnan(cols["twin_q_1"]))  # lockstep: every main row has a twin row
    twin = polish.twin
    assert twin is not None
    assert twin.session.last is not None and cols["twin_q_4"][-1] == twin.session.last.q[3]
    assert np.max(np.abs(cols["twin_q_4"] - cols["q_4"])) > 0.0  # W_j's elbow is not W_a's
    np.testing.assert_allclose(cols["twin_Fd_z"] - cols["twin_F_z"], twin.force_error_at(cols["t"]))


def test_the_twins_link_poses_are_copies_of_its_bodies():
    """The frame's twin arm: each link's position and orientation are the twin world's body origin and
    quaternion at the capture, and stay so while the twin steps on (copies, not views into MjData)."""
    from app.live.lab import Lab

    lab = Lab("polish")
    lab.apply(SetTwin("j"))
    lab.advance(20)
    twin = lab.twin
    assert twin is not None
    names = tuple(lab.session.robot.link_names)
    positions, wxyz = twin.link_poses(names)
    data, model = twin.session.world.data, twin.session.world.model
    expected = np.array([data.xpos[model.body(n).id] for n in names])
    np.testing.assert_array_equal(positions, expected)
    np.testing.assert_array_equal(wxyz, [data.xquat[model.body(n).id] for n in names])
    lab.advance(50)
    np.testing.assert_array_equal(positions, expected)
    assert not np.array_equal(twin.link_poses(names)[0], expected)


def test_a_twin_that_raises_stops_alone_with_its_own_reason_and_the_main_arm_goes_on(monkeypatch):
    """A twin exception (injected into its step) stops the twin with the exception as its reason;
    the main arm runs every step asked, is not halted, and says nothing of a divergence."""
    from app.live.lab import Lab

    lab = Lab("polish")
    lab.apply(SetTwin("j"))
    assert lab.twin is not None
    twin_session = lab.twin.session
    real_step, calls = twin_session.step, []

    def failing_step():
        calls.append(1)
        if len(calls) == 30:
            raise RuntimeError("injected twin failure")
        return real_step()

    monkeypatch.setattr(twin_session, "step", failing_step)
    result = lab.advance(100)
    assert result.stop == "done" and result.steps == 100 and not lab.halted
    (twin_result,) = result.lockstep
    assert twin_result.stop == "error" and twin_result.steps == 29 and "injected twin failure" in twin_result.reason
    assert lab.twin is None and len(calls) == 30
    notice = lab.notice_log[-1]
    assert notice.title == "Twin arm off" and "injected twin failure" in notice.body
    assert lab.advance(10).steps == 10 and lab.session.steps == 110


def test_a_lockstep_session_that_diverges_stops_there_and_the_main_run_goes_on():
    """Session.run with a lockstep member whose state turns NaN: that member's result says diverged
    at its step; the main run completes."""
    from app.core.session import Lockstep, Session

    main, other = Session("free"), Session("free")
    seen: list[float] = []

    def poison(rec) -> None:
        seen.append(rec.t)
        if len(seen) == 5:
            other.world.data.qvel[0] = np.nan

    result = main.run(steps=20, lockstep=(Lockstep(other, poison),))
    assert result.stop == "done" and result.steps == 20 and main.steps == 20
    (r,) = result.lockstep
    assert r.stop == "diverged" and r.steps == 5 and other.steps == 5 and "diverged" in r.reason


def test_a_twin_is_built_off_the_loop_thread_when_switched_on_and_on_a_switch(polish, monkeypatch):
    """SetTwin's twin, and the twin a preset or robot switch brings, are built in the builder's thread
    (`app.live.switch_builder`), never on the loop thread that steps the arm."""
    import threading

    from app.core.twin import Twin
    from app.live.switch_builder import THREAD_NAME

    built_in: list[str] = []
    init = Twin.__init__

    def recording_init(self, *args, **kwargs):
        built_in.append(threading.current_thread().name)
        init(self, *args, **kwargs)

    monkeypatch.setattr(Twin, "__init__", recording_init)
    polish.submit(SetTwin("j"))
    polish.sync()
    polish.submit(SwitchSession(robot="gen3"))
    status = polish.sync()
    assert status.twin == "j" and polish.twin is not None and polish.twin.session.robot.name == "gen3"
    assert len(built_in) == 2 and all(name.startswith(THREAD_NAME) for name in built_in), built_in


def test_restore_defaults_keeps_the_twin_and_sends_it_back_to_its_defaults_too(polish):
    """RestoreDefaults builds no new twin: the twin's own settings go back to the defaults with the main
    arm's, its objective stays, and with the main arm's objective it repeats it step for step again."""
    from app.core.commands import RestoreDefaults

    polish.submit(SetTwin("a"))
    polish.submit(SetParam("contact", "mu", 1.0))
    polish.submit(StepOnce(100))
    polish.sync()
    twin = polish.twin
    assert twin is not None and twin.session.environment.contact.mu == 1.0
    polish.submit(RestoreDefaults())
    polish.submit(StepOnce(300))
    polish.sync()
    assert polish.twin is twin and twin.session.executor.nullspace.objective == "a"
    assert twin.session.environment.contact.mu == polish.session.environment.contact.mu != 1.0
    assert twin.session.world.time == polish.session.world.time
    np.testing.assert_array_equal(twin.session.world.q, polish.session.world.q)
