"""Live plots (viser uPlot) in their own dockable panel, beside the control panel.

The charts are the rows of one table (`app.live.ui.charts`), each in its own folder of the Plots tab and
drawn by its own function (`app.live.ui.chart_draws`); a preset shows its lesson's charts first (its
`Scenario.plot_layout`, which may hold charts of its own) and the others only with "Show all plots". A
window of 10, 30 or 60 s of simulated time, a Freeze switch that holds the picture (the history keeps
filling), vertical markers where the scenario's phase changes (its strokes and `Scenario.phase_marks`)
and the readouts (`app.live.ui.plot_readouts`). Each chart's *Signals* fold chooses the series it draws
(`app.live.ui.signals`); the choice outlives preset switches.

The data come from the loop's `PlotData` (the last 10 s, ≈ 50 samples per second); `SignalHistory` keeps
the last 60 s of them here.
"""

from __future__ import annotations

import functools
import threading
import time
from typing import Any

import numpy as np
import viser

from app.live.frames import PEAK_SIGNALS
from app.live.loop import PlotData
from app.live.ui.chart_draws import NEUTRAL_FORCE_TITLE, Window, sensor_note
from app.live.ui.charts import ChartRow, PlotSpec, add_plot, add_signal_boxes, chart_table, plot_options, preset_row
from app.live.ui.phase_plot import damper_fraction
from app.live.ui.plot_axes import Later, peaks_kept, stride
from app.live.ui.plot_history import Marker, SignalHistory, force_error, phase_markers
from app.live.ui.plot_readouts import readouts
from app.live.ui.signals import SignalChoice, series_shown
from app.scenarios import SCENARIOS, Chart, Scenario, get_scenario

WINDOWS = {"10 s": 10.0, "30 s": 30.0, "60 s": 60.0}
NEW_RUN = "*A new run: its plots start at t = 0.*"
STATUS_ORDER = 0.45  # the app's status line: after the Window, Freeze and Replay controls, before the readouts
RESEND_AFTER_CONNECT_S = (2.0, 6.0, 15.0)  # a new page's charts get their axes again after these seconds
RESEND_AFTER_SHOW_S = (1.0, 4.0)
MIN_PREVIOUS_SAMPLES = 50  # a run this long (≈ 1 s of plot samples) is kept as the previous run


class Plots:
    """The Plots panel (docked left of the 3D view) and its charts; see the module docstring."""

    def __init__(self, server: viser.ViserServer, n_joints: int = 7, order: float | None = None):
        self.n = n_joints
        self.gui = gui = server.gui
        self.history, self.monitor = SignalHistory(), SignalHistory()
        self.readouts: dict[str, float] = {}  # the numbers the readout line shows (tests read them)
        self.markers: list[Marker] = []
        self.memo: dict[str, Any] = {}  # what draw functions keep between redraws
        self._ranges: dict[str, tuple[float, float]] = {}
        self._absent: set[tuple[str, str]] = {("force", "twin")}  # series with nothing to draw in this run
        self._window_s = WINDOWS["10 s"]
        self._last: PlotData | None = None
        self.resend = Later(self.resend_axes)  # the axes again after a page connects or charts are shown
        self._session: object = None
        self._blank = False  # the charts show a new run's empty axes
        self._settings: Any = None
        self.damper_fraction = functools.partial(damper_fraction, lambda: self._settings)  # (field, default)
        self._focus_joint: int | None = None  # the joint the preset is about (readouts)
        self.layout: tuple[str, ...] = tuple(c for c in Scenario.plot_layout if isinstance(c, str))
        self.rows: dict[str, ChartRow] = {}
        self.specs: dict[str, tuple[PlotSpec, ChartRow]] = {}  # plot key → its spec and chart
        self.handles: dict[str, Any] = {}  # plot key → its uPlot handle
        self.headings: dict[str, Any] = {}  # chart key → its heading, note, folder
        self.notes: dict[str, Any] = {}
        self.folders: dict[str, Any] = {}
        self.joint: Any = None  # the phase chart's joint and zoom (`phase_plot.phase_controls`)
        self.phase_zoom: Any = None
        self.panel = gui.add_panel(order=order)
        self.replay_t: float | None = None  # while replaying: the instant the plots end at
        self.previous: dict[str, np.ndarray] | None = None  # the run before, drawn faint until cleared
        table = chart_table(n_joints)
        self.signals = SignalChoice({row.key: row.choices for row in table if row.choices})
        # one redraw at a time: a checkbox's handler (viser's thread pool) and the publisher's frame both
        # redraw; unserialised, a frame that read the old choice could send its picture after the
        # handler's and be taken as the new one's (the chart then kept a series its box had hidden)
        self._redraw_lock = threading.RLock()
        self.signal_boxes: dict[tuple[str, str], Any] = {}  # (chart, series) → its checkbox
        self.panel_tab = self.panel.add_tab("Plots", icon=viser.Icon.CHART_LINE)
        with self.panel_tab:
            self.window: Any = gui.add_dropdown(
                "Window", tuple(WINDOWS), initial_value="10 s", hint="Simulated time shown, up to now", order=0.1
            )
            self.freeze: Any = gui.add_checkbox(
                "Freeze", False, hint="Hold the plots (the history keeps filling)", order=0.2
            )
            self.show_all: Any = gui.add_checkbox(
                "Show all plots", False, hint="Off: only the preset's own plots, its lesson's on top", order=0.3
            )
            self.readout = gui.add_markdown("", order=0.5)
        for row in table:
            self._add_chart(row)
        self.panel.dock_left()
        self.panel.set_width(400)
        self.window.on_update(lambda _: self._on_window())
        self.freeze.on_update(lambda _: self.redraw())
        self.show_all.on_update(lambda _: self.arrange(None))
        self.arrange(None)
        server.on_client_connect(lambda _: self.resend.after(*RESEND_AFTER_CONNECT_S))

    # ---- charts ---------------------------------------------------------------------------------
    def _add_chart(self, row: ChartRow) -> None:
        """The chart's folder: its inputs, heading, plots, note and Signals fold (a preset's chart: once)."""
        if row.key in self.rows:
            return
        gui = self.gui
        self.rows[row.key] = row
        with self.panel_tab:
            folder = self.folders[row.key] = gui.add_folder(row.title, order=1.0 + len(self.folders))
        with self.panel_tab, folder:
            if row.controls is not None:
                row.controls(self, gui)
            if row.heading:
                self.headings[row.key] = gui.add_markdown(row.heading)
            for spec in row.plots:
                self.specs[spec.key] = (spec, row)
                self.handles[spec.key] = add_plot(gui, spec, self._window_s)
                self._ranges[spec.key] = spec.y_range
            if row.note:
                self.notes[row.key] = gui.add_markdown("")
            if row.choices:
                self.signals.add(row.key, row.choices)
                self.signal_boxes |= add_signal_boxes(gui, row, self.signals.shown, self._on_signal_box)
        self.apply_signals()

    def set_range(self, key: str, y: tuple[float, float], force: bool = False) -> None:
        """Give a plot a new y range and its ticks (a new range rebuilds the chart in the browser: only
        on change)."""
        if force or self._ranges.get(key) != y:
            spec = self.specs[key][0]
            self._ranges[key] = y
            handle = self.handles[key]
            handle.scales, handle.axes = plot_options(spec, y, self._window_s)

    def _timed(self) -> list[str]:
        return [k for k, (spec, _) in self.specs.items() if spec.timed]

    # ---- signals --------------------------------------------------------------------------------
    def _on_signal_box(self, chart: str, key: str, value: object) -> None:
        with self._redraw_lock:
            if self.signals.set(chart, key, value):
                self.apply_signals()
                self._redraw()

    def choose_signals(self, chart: str, keys: Any) -> None:
        """Draw exactly the series `keys` of `chart` (ValueError, one line, for an unknown chart or series:
        then nothing changes); the checkboxes follow."""
        with self._redraw_lock:
            if self.signals.choose(chart, keys):
                for (c, k), box in self.signal_boxes.items():
                    if c == chart and box.value != self.signals.shown(c, k):
                        box.value = self.signals.shown(c, k)
                self.apply_signals()
                self._redraw()

    def present(self, chart: str, key: str) -> bool:
        """Whether this run has something to draw in series `key` of `chart` (the twin arm's: while one runs)."""
        return (chart, key) not in self._absent

    def set_present(self, chart: str, key: str, present: bool) -> None:
        """Say whether series `key` of `chart` has anything to draw; its legend entry follows."""
        if self.present(chart, key) != present:
            self._absent ^= {(chart, key)}
            self.apply_signals()

    def apply_signals(self) -> None:
        """Show or hide each plot and series as the choice says (a hidden series is not drawn whatever data
        it holds); a frozen picture changes too."""
        for key, (spec, row) in self.specs.items():
            handle = self.handles[key]
            if spec.shown_by and handle.visible != self.signals.shown(row.key, spec.shown_by):
                handle.visible = self.signals.shown(row.key, spec.shown_by)
            flags = {
                i + 1: self.signals.shown(row.key, s) and self.present(row.key, s)
                for i, s in enumerate(spec.signals)
                if s is not None
            }
            series = series_shown(tuple(handle.series), flags) if flags else None
            if series is not None:
                handle.series = series

    # ---- layout ---------------------------------------------------------------------------------
    def arrange(self, scenario: str | None) -> None:
        """Put the preset's charts first (its lesson's metric on top; a chart of its own is built the first
        time) and show the others only with "Show all plots"; None keeps the preset and applies the switch."""
        if scenario is not None:
            layout = get_scenario(scenario).plot_layout if scenario in SCENARIOS else Scenario.plot_layout
            for chart in layout:
                if isinstance(chart, Chart):
                    self._add_chart(preset_row(chart))
            self.layout = tuple(c.key if isinstance(c, Chart) else c for c in layout)
        show_all = bool(self.show_all.value)
        rest = [c for c in self.rows if c not in self.layout]
        changed = False
        for i, name in enumerate((*self.layout, *rest)):
            folder, order = self.folders[name], 1.0 + i
            visible = show_all or name in self.layout
            if folder.order != order:
                folder.order = order
            if folder.visible != visible:
                folder.visible = visible
                changed |= visible
        if changed or scenario is not None:  # shown charts, or a new preset's first frames
            self.resend.after(*RESEND_AFTER_SHOW_S)

    def _on_window(self) -> None:
        value = WINDOWS.get(str(self.window.value))
        if value is None or value == self._window_s:
            return
        self._window_s = value
        for key in self._timed():
            self.set_range(key, self._ranges[key], force=True)
        self._redraw()

    # ---- data -----------------------------------------------------------------------------------
    def focus(self, joint: int | None, scenario: str | None = None) -> None:
        """Show joint `joint` (0-based) in the phase plot and its readouts, e.g. the one a preset is
        about; None keeps the phase plot's joint and drops the readouts. With `scenario`, arrange the
        charts for that preset."""
        self._focus_joint = joint
        if joint is not None and 0 <= joint < self.n and self.joint.value != str(joint + 1):
            self.joint.value = str(joint + 1)
        if scenario is not None:
            zoom = joint is not None  # a preset about one joint is about it reaching its limit
            if self.phase_zoom.value != zoom:
                self.phase_zoom.value = zoom
            self.arrange(scenario)

    def update(self, plot: PlotData, session: object = None, settings: Any = None) -> None:
        """Take in new plot data and redraw unless frozen (one message per chart); a new `session`
        key (the loop's session id and restart count) starts the history again and blanks the charts
        and readouts of the old run. `settings` (the parameters in force) name the sensor model's
        disturbances under the force plot."""
        with self._redraw_lock:  # the history and the picture change together (see _redraw_lock)
            if session != self._session:
                self._new_run(session)
            self._last = plot
            if settings is not None and settings is not self._settings:
                self._settings = settings
                text = sensor_note(settings)
                if self.notes["force"].content != text:
                    self.notes["force"].content = text
            self.history.add(plot.columns)
            self.monitor.add(plot.monitor)
            self._redraw()

    def _new_run(self, session: object) -> None:
        """A new run: the old one's samples become the previous run (when long enough) and everything starts over."""
        self._session = session
        old = self.history.columns
        if len(old.get("t", ())) >= MIN_PREVIOUS_SAMPLES:
            self.previous = {k: v.copy() for k, v in old.items()}
            if "Fd_z" in old:
                self.previous["force_error"] = force_error(old).copy()
        self.replay_t = None
        if self.handles["force"].title != NEUTRAL_FORCE_TITLE:  # the old run's setpoint says nothing of the new one's
            self.handles["force"].title = NEUTRAL_FORCE_TITLE
        self.history.clear()
        self.monitor.clear()
        self.markers, self.readouts, self._blank = [], {}, False

    def _clear_charts(self) -> None:
        """A new run with no samples yet: empty charts (their axes stay) and no readouts of the old run."""
        if self._blank:
            return
        self._blank = True
        nan2 = np.full(2, np.nan)
        for key, (spec, _) in self.specs.items():
            x = np.array([-self._window_s, 0.0]) if spec.timed else np.array([-1.0, 1.0])
            self.handles[key].data = (x, *([nan2] * len(spec.series)))
        self.readouts = {}
        if self.readout.content != NEW_RUN:
            self.readout.content = NEW_RUN

    def clear_previous(self) -> None:
        """Forget the previous run's trace."""
        self.previous = None
        self.redraw()

    def redraw(self) -> None:
        """Draw again from the history (e.g. at a new replay instant)."""
        self._redraw()

    def _redraw(self) -> None:
        with self._redraw_lock:
            plot = self._last
            if plot is None:
                return
            replay_t = self.replay_t  # once per redraw: every chart of this redraw shows the same instant
            c = self.history.shown(self._window_s, replay_t)
            t = c.get("t", np.zeros(0))
            if len(t) < 2 or "Fd_z" not in c:
                if not self.freeze.value:
                    self._clear_charts()
                return
            self._blank = False
            self.markers = phase_markers(self.history.columns, plot.segments, plot.marks)
            self.readouts, lines = readouts(
                plot, self.history.columns, self._focus_joint, self.damper_fraction, self.markers
            )
            text = "  \n".join(lines)
            if self.readout.content != text:
                self.readout.content = text
            if self.freeze.value:
                return
            now = float(t[-1])
            every = stride(len(t))
            s, c = slice(None, None, every), peaks_kept(c, PEAK_SIGNALS, every)
            window = Window(plot, c, s, t[s] - now, now, self.monitor.shown(self._window_s, replay_t), self.markers)
            for row in self.rows.values():
                row.draw(self, window)

    def resend_axes(self) -> None:
        """Send every chart's scales and axes again: a chart the page built before its panel had its
        size draws no ticks until its options change (viser 1.1.1 with uPlot)."""
        for key in self._timed():
            self.set_range(key, self._ranges[key], force=True)
        phase = self.handles["phase"]
        scales, axes = phase.scales, phase.axes
        if scales is not None:
            phase.scales = dict(scales)
        if axes is not None:
            phase.axes = tuple(axes)

    def redraw_wait_s(self) -> float:
        """Seconds a redraw asked for now (a checkbox's handler) waits for the one under way (the
        publisher's frame) before it can start; a probe for `torquelab bench --serve`."""
        t0 = time.perf_counter()
        with self._redraw_lock:
            return time.perf_counter() - t0

    def stop(self) -> None:
        """No chart is sent anything from now on: the pending resends are cancelled (the server is
        about to stop; a resend after it queued messages on a closed server, with a warning)."""
        self.resend.stop()
