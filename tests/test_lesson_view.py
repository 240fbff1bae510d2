"""The Plots panel arranged for a lesson step's run (app.live.ui.lesson_view), on a stand-in for the plots:
the step's charts on top and the Replay fold under them while its run is on, the preset's order after it,
and the run it compares with drawn as the previous run, aligned on the task's start."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from app.live.ui.lesson_view import LessonView, Trace, step_layout, task_start
from app.scenarios import get_scenario


class FakePlots:
    """What the view uses of `Plots`: its layout, arrange, history, previous run and redraw."""

    def __init__(self, scenario: str = "polish"):
        self.layout = get_scenario(scenario).plot_layout
        self.readout = SimpleNamespace(order=0.5)
        self.history = SimpleNamespace(columns={})
        self.previous: dict | None = None
        self.redraws = 0

    def arrange(self, scenario: str | None) -> None:
        if scenario is not None:
            self.layout = get_scenario(scenario).plot_layout

    def redraw(self) -> None:
        self.redraws += 1


def frame(scenario: str, restarts: int, window: dict | None = None) -> SimpleNamespace:
    """A frame of run `restarts` whose plot data are `window` (the last rows of the run)."""
    plot = SimpleNamespace(columns=window) if window is not None else None
    return SimpleNamespace(status=SimpleNamespace(scenario=scenario), restarts=restarts, plot=plot)


def polish_columns(t0: float, start: float, seconds: float = 20.0, dt: float = 0.02) -> dict[str, np.ndarray]:
    """A polish run's plotted columns from t0: settling (segment 0) until `start`, then strokes 1…6."""
    t = np.arange(t0, t0 + seconds, dt)
    segment = np.where(t < start, 0.0, 1.0 + np.floor((t - start) / 2.5))
    return {"t": t, "segment": segment, "force_error": np.sin(t), "tcp_dev_mm": t.copy()}


def test_a_steps_charts_come_first_then_the_presets_others():
    assert step_layout(("torque", "phase"), "limit-drop") == ("torque", "phase")
    assert step_layout(("force",), "polish") == ("force", "coupling", "torque")
    assert step_layout(("deflection", "torque"), "compliance") == ("deflection", "torque")


def test_the_step_order_and_the_replay_fold_hold_on_the_steps_run_and_end_at_the_next():
    plots = FakePlots("limit-drop")
    folder = SimpleNamespace(order=0.4)
    view = LessonView(plots, folder)
    view.show(3, ("torque", "phase"))
    view.follow(frame("limit-drop", 2))  # a frame of the run before the set-up: nothing yet
    assert plots.layout == ("phase", "torque") and folder.order == pytest.approx(0.4)
    view.follow(frame("limit-drop", 3))
    assert plots.layout == ("torque", "phase")  # under both charts (1, 2): the readout, then the Replay fold
    assert plots.readout.order == pytest.approx(2.5) and folder.order == pytest.approx(2.6)
    plots.arrange("limit-drop")  # a preset switch's frame arranges for the preset: the next frame puts it back
    view.follow(frame("limit-drop", 3))
    assert plots.layout == ("torque", "phase")
    view.follow(frame("limit-drop", 4))  # a Reset: the preset's order and the fold's place come back
    assert plots.layout == ("phase", "torque") and view.arranged is None
    assert plots.readout.order == pytest.approx(0.5) and folder.order == pytest.approx(0.4)


def test_the_compared_run_is_drawn_aligned_on_this_runs_first_stroke_once_it_is_known():
    """W_j's run (first stroke at 2.1 s) compared in a W_a run (first stroke at 55.7 s): nothing drawn while
    W_a settles (not even the plots' own previous run), then W_j's trace shifted by 53.6 s, so that its
    first stroke's first sample sits at 55.7 s; a person's Clear previous run ends the comparison."""
    plots = FakePlots()
    plots.previous = {"t": np.array([0.0, 1.0]), "force_error": np.zeros(2)}  # the plots' own previous run
    view = LessonView(plots)
    wj = polish_columns(0.0, 2.1)
    trace = Trace(wj, task_start(wj) or 0.0)
    assert trace.start == pytest.approx(2.1, abs=0.02)
    view.show(7, ("force",), trace)
    plots.history.columns = wj  # the plots have not seen the set-up's run yet: W_j's rows, started at 2.1 s
    view.follow(frame("polish", 7, polish_columns(0.0, 55.7, seconds=4.0)))  # W_a's first rows: settling
    assert plots.previous is None
    wa = polish_columns(0.0, 55.7, seconds=70.0)
    plots.history.columns = wa
    last_10_s = {k: v[wa["t"] >= 50.0] for k, v in wa.items()}  # a frame's window over W_a's first stroke
    view.follow(frame("polish", 7, last_10_s))
    drawn = plots.previous
    assert drawn is not None
    first = int(np.flatnonzero(drawn["segment"] >= 1)[0])
    assert drawn["t"][first] == pytest.approx(task_start(plots.history.columns), abs=1e-9)
    assert drawn["t"][0] - wj["t"][0] == pytest.approx(55.7 - trace.start, abs=0.02)
    np.testing.assert_array_equal(drawn["force_error"], wj["force_error"])
    plots.previous = {"t": np.zeros(2)}  # a frame of a set-up's run replaced it: drawn again
    view.follow(frame("polish", 7, last_10_s))
    assert plots.previous is drawn
    plots.previous = None  # Clear previous run
    view.follow(frame("polish", 7, last_10_s))
    view.follow(frame("polish", 7, last_10_s))
    assert plots.previous is None
    plots.previous = {"t": np.zeros(2)}  # after that, a run the person plays keeps the plots' own previous run
    view.follow(frame("polish", 7, last_10_s))
    assert plots.previous is not None and plots.previous is not drawn


def test_a_step_with_nothing_to_compare_with_shows_no_previous_run():
    """The first step of a lesson (no earlier step or run of it): the plots' previous run, an unrelated one,
    is not drawn while the step's run is on."""
    plots = FakePlots("compliance")
    plots.previous = {"t": np.arange(3.0), "tcp_dev_mm": np.ones(3)}
    view = LessonView(plots)
    view.show(2, ("deflection", "torque"))
    view.follow(frame("compliance", 2))
    assert plots.previous is None and plots.redraws == 1


def test_a_run_without_strokes_starts_its_task_at_the_reset():
    assert task_start({"t": np.arange(5.0)}) == 0.0
    assert task_start(polish_columns(0.0, 60.0, seconds=10.0)) is None  # still settling


def test_a_captured_trace_keeps_the_signals_the_plots_draw_of_a_previous_run_and_its_start():
    """A finished run's plots history (force and deflection columns among others) becomes a trace of t,
    segment, the force error F̂_z − F_z and the TCP deflection, with its first stroke's start."""
    plots = FakePlots()
    columns = polish_columns(0.0, 2.1)
    n = len(columns["t"])
    columns.update({"Fd_z": np.full(n, 20.0), "F_z": 20.0 + np.cos(columns["t"]), "q_1": np.zeros(n)})
    plots.history.columns = columns
    trace = LessonView(plots).capture()
    assert trace is not None and trace.start == pytest.approx(2.1, abs=0.02)
    assert sorted(trace.columns) == ["force_error", "segment", "t", "tcp_dev_mm"]
    np.testing.assert_allclose(trace.columns["force_error"], -np.cos(columns["t"]), atol=1e-12)
    plots.history.columns = polish_columns(0.0, 60.0, seconds=10.0)  # still settling: nothing to compare with
    assert LessonView(plots).capture() is None


def test_a_frame_window_past_the_start_takes_the_start_from_the_plots_history():
    """A page that missed the first stroke's start (every row of the frame's window after it) aligns on the
    plots' history of the run, which by then is this run's."""
    plots = FakePlots()
    view = LessonView(plots)
    wj = polish_columns(0.0, 2.1)
    view.show(3, ("force",), Trace(wj, 2.1))
    wa = polish_columns(0.0, 55.7, seconds=70.0)
    plots.history.columns = wa
    view.follow(frame("polish", 3, {k: v[wa["t"] >= 60.0] for k, v in wa.items()}))
    assert plots.previous is not None
    assert plots.previous["t"][0] == pytest.approx(55.7 - 2.1, abs=0.02)
