"""The Plots panel arranged for a lesson step's run: the charts the step names on top, in its order,
and the readout line and the Replay fold under them, so that at 1600×1000 the step's plot (and for a
polish step the margin's headroom under the force error) is in view under the status line; and the
run it compares with drawn faint behind it (the plots' "previous run" trace).

`LessonView.show(restarts, charts)` starts the arrangement for the run with that restart count (the
run the step's set-up made). `follow(frame)`, called with every frame the Lessons panel sees, keeps it
while the frames are of that run (a preset switch arranges the plots for the preset: the step's order
comes back within one live period) and ends it at a later run (a Reset, a switch) or on `clear()`: the
preset's own order and the readout's and Replay fold's places come back.

The comparison: `capture()` takes the plots' history of the run shown (a step's, at its end) as a
`Trace`; `show(..., trace)` draws it as the previous run, shifted in time so that its task starts
where this run's does (a polish run's first stroke, "segment" 1: each objective settles for its own
time; from the reset otherwise), once this run's start is known. A person's *Clear previous run* ends it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from app.live.loop import Frame
from app.live.ui.plots import force_error
from app.scenarios import SCENARIOS, Chart, Scenario, get_scenario

TRACE_SIGNALS = ("tcp_dev_mm",)  # besides the force error: the plots' previous-run series (deflection)


def preset_layout(scenario: str) -> tuple[str, ...]:
    """The keys of the charts a preset shows on its own (`Scenario.plot_layout`), first on top."""
    layout = get_scenario(scenario).plot_layout if scenario in SCENARIOS else Scenario.plot_layout
    return tuple(c.key if isinstance(c, Chart) else c for c in layout)


def step_layout(charts: tuple[str, ...], scenario: str) -> tuple[str, ...]:
    """The step's charts first, in its order, then the preset's others."""
    return (*charts, *(c for c in preset_layout(scenario) if c not in charts))


def task_start(columns: dict[str, np.ndarray]) -> float | None:
    """When a run's task starts (s): a polish run's first stroke (the first row with signal "segment" ≥ 1;
    None while it settles), else the reset (0)."""
    segment, t = columns.get("segment"), columns.get("t")
    if segment is None:
        return 0.0
    started = np.flatnonzero(np.nan_to_num(segment) >= 1.0)
    return float(t[started[0]]) if t is not None and started.size else None


def onset_in_window(columns: dict[str, np.ndarray]) -> float | None:
    """The run's task start if a window of its rows (a frame's plot data) shows it: 0 for a run without
    strokes, the first row with "segment" ≥ 1 when a row before it has not started; None otherwise (no
    rows, still settling, or every row of the window after the start)."""
    segment, t = columns.get("segment"), columns.get("t")
    if t is None or not len(t):
        return None  # no rows of the run yet
    if segment is None:
        return 0.0
    started = np.flatnonzero(np.nan_to_num(segment) >= 1.0)
    return float(t[started[0]]) if started.size and started[0] > 0 else None


@dataclass(frozen=True)
class Trace:
    """A run's plotted signals (the plots' history columns, with "force_error") and its task's start."""

    columns: dict[str, np.ndarray]
    start: float


@dataclass(frozen=True)
class Arranged:
    """The run a lesson step arranged the plots for, the charts it named and the run it compares with."""

    restarts: int
    charts: tuple[str, ...]
    trace: Trace | None = None
    cleared: bool = False  # a person cleared the comparison: the plots' previous run is theirs again


class LessonView:
    """See the module docstring. `plots`: the app's `Plots`; `replay_folder`: the Replay fold (None: none)."""

    def __init__(self, plots: Any, replay_folder: Any = None):
        self.plots = plots
        self.replay_folder = replay_folder
        self.replay_order = getattr(replay_folder, "order", None)  # its place outside a lesson
        self.readout = getattr(plots, "readout", None)  # the plots' readout line (per-stroke STDs, peaks)
        self.readout_order = getattr(self.readout, "order", None)
        self.arranged: Arranged | None = None
        self._scenario = ""
        self._drawn: dict[str, np.ndarray] | None = None  # the shifted trace given to the plots

    def show(self, restarts: int, charts: tuple[str, ...], trace: Trace | None = None) -> None:
        """Arrange the plots for the run with restart count `restarts`, `charts` on top, `trace` faint."""
        self._drawn = None
        self.arranged = Arranged(restarts, charts, trace)

    def capture(self) -> Trace | None:
        """The plots' history of the run shown, as a trace to compare with: the signals the plots draw as
        the previous run (`TRACE_SIGNALS`) and "segment" (None: too short, or its task has not started)."""
        history = self.plots.history.columns
        start = task_start(history)
        if len(history.get("t", ())) < 2 or start is None:
            return None
        columns = {k: np.array(history[k], copy=True) for k in ("t", "segment", *TRACE_SIGNALS) if k in history}
        if "Fd_z" in history:
            columns["force_error"] = force_error(history).copy()
        return Trace(columns, start)

    def clear(self) -> None:
        """End the arrangement (the preset's own order comes back at the next frame)."""
        self.arranged = None

    def follow(self, frame: Frame) -> None:
        """Keep the step's arrangement on its run's frames; back to the preset's after it."""
        arranged, scenario = self.arranged, frame.status.scenario
        if arranged is not None and frame.restarts > arranged.restarts:
            self.arranged = arranged = None
        if arranged is None:
            self._restore(scenario)
            return
        if frame.restarts < arranged.restarts:
            return  # a frame of the run before the set-up: nothing to arrange yet
        self._scenario = scenario
        wanted = step_layout(arranged.charts, scenario)
        if tuple(self.plots.layout) != wanted:
            self.plots.layout = wanted
            self.plots.arrange(None)
        under = float(len(arranged.charts)) + 0.5  # under the step's charts (theirs: 1, 2, …)
        _place(self.readout, under)
        _place(self.replay_folder, under + 0.1)
        self._compare(arranged, frame.plot.columns if frame.plot is not None else {})

    def _compare(self, arranged: Arranged, window: dict[str, np.ndarray]) -> None:
        """The trace as the plots' previous run, aligned on this run's task start (nothing before it); a step
        with nothing to compare with shows no previous run (the plots' own would be an unrelated run)."""
        plots, drawn = self.plots, self._drawn
        if arranged.trace is None:
            if plots.previous is not None and not arranged.cleared:
                plots.previous = None
                plots.redraw()
            return
        if drawn is not None and plots.previous is None:  # a person cleared it
            self.arranged = Arranged(arranged.restarts, arranged.charts, cleared=True)
            return
        if drawn is None:
            # this run's start from the frame's own rows (the plots' history may still be the run before the
            # set-up's); once the frame's window is past the start, the history is this run's
            start = onset_in_window(window)
            if start is None and len(window.get("t", ())) and task_start(window) is not None:
                start = task_start(plots.history.columns)
            if start is None:  # still settling: no comparison yet (the plots' own previous run is not it)
                if plots.previous is not None:
                    plots.previous = None
                    plots.redraw()
                return
            trace = arranged.trace
            assert trace is not None
            shifted = dict(trace.columns)
            shifted["t"] = trace.columns["t"] + (start - trace.start)
            self._drawn = drawn = shifted
        if plots.previous is not drawn:  # set again after a frame of the set-up's runs replaced it
            plots.previous = drawn
            plots.redraw()

    def _restore(self, scenario: str) -> None:
        if self._scenario:  # arranged before: the preset's order once
            self._scenario = ""
            self.plots.arrange(scenario)
        _place(self.readout, self.readout_order)
        _place(self.replay_folder, self.replay_order)


def _place(handle: Any, order: float | None) -> None:
    """Move a GUI element of the Plots panel to `order` (sent only on a change)."""
    if handle is not None and order is not None and handle.order != order:
        handle.order = order
