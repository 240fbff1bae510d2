"""Live plots: titles say when a plot's quantity is not what its name promises."""

from __future__ import annotations

import numpy as np

from app.commands import StepOnce
from app.loop import SimLoop
from app.ui.plots import COUPLING_TITLE, FORCE_TITLE, NO_SETPOINT_TITLE, Plots
from app.ui.snapshot import capture


def _plot_data(scenario: str):
    loop = SimLoop(scenario, capture=capture)
    loop.start(running=False)
    try:
        loop.submit(StepOnce(300))
        loop.sync()
        frame = loop.wait_frame(0, timeout=10.0)
        deadline = 50
        while (frame is None or frame.plot is None or len(frame.plot.monitor["t"]) < 2) and deadline:
            loop.submit(StepOnce(100))
            loop.sync()
            frame = loop.wait_frame(frame.seq if frame else 0, timeout=5.0)
            deadline -= 1
        assert frame is not None and frame.plot is not None
        return frame.plot
    finally:
        loop.stop()


def test_force_plot_says_when_there_is_no_force_setpoint(server):
    plots = Plots(server)
    polish = _plot_data("polish")
    plots.update(polish)
    assert np.any(polish.columns["Fd_z"] != 0) and plots.force.title == FORCE_TITLE
    drop = _plot_data("limit-drop")
    plots.update(drop)
    assert np.all(drop.columns["Fd_z"] == 0) and plots.force.title == NO_SETPOINT_TITLE
    # the L-shape is near a singularity: W is not plotted there and the title says why
    assert np.all(np.isnan(drop.monitor["W_a"])) and plots.coupling.title != COUPLING_TITLE
    plots.update(polish)
    assert plots.coupling.title == COUPLING_TITLE and np.all(np.isfinite(polish.monitor["W_a"]))
