"""The Session: deterministic stepping, drag spring, robust executor handling."""

from __future__ import annotations

import numpy as np
import pytest

from app.session import Session
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

        def configure(self, **changes):
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
