"""The Session: deterministic stepping, drag spring, robust executor handling."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from app.core.session import Session
from control.executor import ControlOutput


def test_reset_reproduces_the_same_trajectory_step_for_step():
    s = Session("free")
    s.drag.grab(s.world, s.world.wrist_body, s.world.site_pose(s.world.tcp_site)[0])
    s.drag.move(s.world.site_pose(s.world.tcp_site)[0] + np.array([0.0, 0.1, 0.0]))
    first = [s.step().q.copy() for _ in range(200)]
    s.reset()
    assert not s.drag.active  # reset releases the drag
    s.drag.grab(s.world, s.world.wrist_body, s.world.site_pose(s.world.tcp_site)[0])
    s.drag.move(s.world.site_pose(s.world.tcp_site)[0] + np.array([0.0, 0.1, 0.0]))
    second = [s.step().q.copy() for _ in range(200)]
    np.testing.assert_array_equal(np.array(first), np.array(second))


def test_drag_pulls_the_grabbed_point_toward_the_target_and_is_clamped():
    s = Session("free")
    p0 = s.world.site_pose(s.world.tcp_site)[0]
    s.drag.max_force_n = 40.0
    s.drag.grab(s.world, s.world.wrist_body, p0)
    s.drag.move(p0 + np.array([0.0, 0.0, -0.5]))  # far away: the force saturates
    forces = []
    for _ in range(300):
        s.step()
        assert s.drag.state is not None
        forces.append(np.linalg.norm(s.drag.state.force_world))
    assert max(forces) <= 40.0 + 1e-9
    assert max(forces) > 39.0
    assert s.world.site_pose(s.world.tcp_site)[0][2] < p0[2] - 0.01  # moved down
    s.drag.release()
    s.step()
    assert s.last is not None and s.last.signals["drag_force_n"] == 0.0


def test_executor_nan_output_falls_back_to_gravity_compensation():
    s = Session("free")

    class Broken:
        name = "broken"

        def reset(self, dyn, target):
            pass

        def params(self):
            return {}

        def set_params(self, name, group):
            pass

        def step(self, dyn, inputs):
            return ControlOutput(tau=np.full(7, np.nan))

    s.executor = Broken()
    rec = s.step()
    assert rec.fallback and np.all(np.isfinite(rec.tau))
    assert not s.diverged()


@pytest.mark.parametrize("scenario", ["polish", "limit-drop"])
def test_reset_repeats_a_qp_run_exactly(scenario):
    """The QPs' warm starts are cleared on reset: the run after a Reset is the first run again."""
    fresh = Session(scenario)
    reset = Session(scenario)
    reset.run(0.05)
    reset.reset()
    for _ in range(300):
        fresh.step()
        reset.step()
    np.testing.assert_array_equal(reset.world.q, fresh.world.q)


def test_run_records_every_step_and_stops_on_until_divergence_or_an_error():
    s = Session("free")
    seen: list[float] = []
    result = s.run(0.05, record=lambda rec: seen.append(rec.t))
    assert (result.steps, result.stop, result.halted) == (50, "done", False)
    assert len(seen) == 50 and seen[-1] == pytest.approx(0.049)
    result = s.run(steps=100, until=lambda rec: rec.t >= 0.0595)
    assert result.stop == "until" and result.steps == 11 and result.t == pytest.approx(0.061)  # rec.t: step start

    s.world.data.qvel[2] = np.nan  # the first step after this is the last
    result = s.run(1.0)
    assert result.stop == "diverged" and result.halted and result.steps == 1 and "diverged" in result.reason

    s = Session("free")

    calls = []

    def boom(rec):
        calls.append(rec)
        if len(calls) == 10:
            raise TypeError("bad gain")

    result = s.run(steps=100, record=boom)
    assert result.stop == "error" and result.steps == 10 and isinstance(result.error, TypeError)
    assert "TypeError: bad gain" in result.reason


def test_a_state_mujoco_had_to_reset_counts_as_divergence():
    s = Session("free")
    assert not s.diverged()
    s.world.data.warning[int(mujoco.mjtWarning.mjWARN_BADQACC)].number = 1
    assert s.diverged()
    s.reset()
    assert not s.diverged()


def test_a_headless_run_logs_the_deflection_signals_the_live_app_publishes_for_the_same_run():
    """The compliance preset's deflection signals ("tcp_dev_mm", "elbow_dev_mm": the TCP's and the
    elbow's distance from the t = 0 pose) are the session's own: a headless run (Session.run into a
    StepLog) carries them, and the web app's loop running the same preset and seed for the same steps
    publishes the same numbers, in its export (every step) and in its plot data (decimated by peak),
    within 1e-9 mm (the same steps in the same order)."""
    from app.core.commands import StepOnce
    from app.core.steplog import StepLog
    from app.live.loop import SimLoop

    steps = 3000  # both pushes: the TCP at 0.5…1.0 s, the elbow at 2.0…2.5 s
    s = Session("compliance")
    log = StepLog(s.robot.nq, capacity=steps, segments=0)
    assert not s.run(steps=steps, record=log.append).halted
    headless = log.window(steps * 1e-3, 1e-3)
    assert len(headless["t"]) == steps
    assert headless["tcp_dev_mm"].max() > 0.1 and headless["elbow_dev_mm"].max() > 0.1  # both pushes moved them

    lp = SimLoop("compliance", capture=lambda s: None)
    lp.start(running=False)
    try:
        lp.submit(StepOnce(steps))
        assert lp.sync(timeout=120).steps == steps
        live = lp.export(steps * 1e-3)["columns"]
        frame = lp.wait_frame(0, timeout=10)
        while frame is not None and frame.status.steps < steps:
            frame = lp.wait_frame(frame.seq, timeout=10)
    finally:
        lp.stop()
    assert frame is not None and frame.plot is not None
    for name in ("tcp_dev_mm", "elbow_dev_mm"):
        np.testing.assert_allclose(live[name], headless[name], rtol=0, atol=1e-9)
        assert float(np.nanmax(frame.plot.columns[name])) == pytest.approx(headless[name].max(), abs=1e-9)
