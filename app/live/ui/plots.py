"""Live plots (viser uPlot) in their own dockable panel, beside the control panel.

Force error along the force axis (the twin's dashed when a twin runs); the force loop's decay
margin a contact preset publishes (signals "margin_headroom_np", "margin_rate"): the stroke headroom
h (< 0 where a disturbance at the noise floor reaches F̂ within the stroke) with the decay rate σ
beside it (< 0 where a mode grows); W_f, W_a, W_d (Fig. 8 of [T]) in three small single-axis plots;
the (q, q̇) phase of one joint with its velocity limits,
the plot's x range being the joint's position range (Fig. 2–4 of [C]); joint torques as a share of
their limits; the real-time factor. A window of 10, 30 or 60 s of simulated time, a Freeze switch
that holds the picture (the history keeps filling), vertical markers where the scenario's phase
changes (polish segments S1…S6, a payload release) and the readouts docs/web-app.md quotes: force-error
STD per polish segment (main and twin), peak joint torque and overshoot in the limit drop. Each chart's
*Signals* fold chooses the series it draws (`app.live.ui.signals`); the choice outlives preset switches.

Every y range is fixed per signal and widens in 1-2-5 steps when the data leave it; x is the time
before now, so neither axis depends on uPlot's auto-ranging (which a series that is all NaN — the
twin's error with no twin — turns into a blank plot). The data come from the loop's `PlotData`
(the last 10 s, ≈ 50 samples per second); `SignalHistory` keeps the last 60 s of them here. The
peak-torque and per-segment STD readouts use the loop's running figures over every 1 ms step instead.
"""

from __future__ import annotations

import math
import threading
import time
import traceback
from dataclasses import dataclass
from typing import Any

import numpy as np
import viser
import viser.uplot as uplot

from app.live.loop import PlotData
from app.live.ui.signals import SignalChoice, masked, series_shown, signal_specs
from app.scenarios import SCENARIOS, Scenario, get_scenario, metrics
from app.scenarios.stroke_outcomes import HEADROOM_BAND_NP

COLORS = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2")
MARKER_COLOR = "#7a7a7a"
TWIN_COLOR = "#ff9f1c"  # the twin arm, here and in the 3D scene
COUPLING_TITLE = "Coupling W_f, W_a, W_d [T22]"
FORCE_TITLE = "Force error F̂_z − F_z"
NO_SETPOINT_TITLE = "F̂_z − F_z: no force setpoint here, so this is minus the F/T reading"
NEUTRAL_FORCE_TITLE = "F̂_z − F_z"  # before a run has shown whether it has a force setpoint
NO_SETPOINT_AFTER_S = 0.1  # a run is said to have no force setpoint once this long has passed without one
WINDOWS = {"10 s": 10.0, "30 s": 30.0, "60 s": 60.0}
HISTORY_S = 60.0
MAX_POINTS = 600  # per series sent to the browser, whatever the window
FORCE_RANGE_N = 10.0  # ± N before any widening
TORQUE_RANGE_PCT = 110.0
RTF_RANGE = 1.2
RATE_RANGE_PER_S = 10.0  # ± of the margin plot (headroom in Np, σ in 1/s) before any widening
RATE_ASPECT = 2.2  # width / height of the margin plot: tall enough for its ticks to stand apart
RATE_TICKS = 2  # about two tick intervals on its y axis (−max, 0): no crowding in a short plot
RATE_TITLE = (
    f"Stroke headroom h (Np; a prediction only outside the dashed ±{HEADROOM_BAND_NP:g} band: below it the tool is "
    "predicted to lift off within the stroke) and σ (1/s)"
)
W_SERIES = (("W_f", "1/kg²", COLORS[0]), ("W_a", "kg²", COLORS[1]), ("W_d", "1", COLORS[2]))
LEGEND = {"live": False}  # labels only: no "--" / "NaN" values beside them
DEFLECTION_RANGE_MM = 10.0
X_LABEL = "t − now (s)"
Y_LABELS = {
    "force": "F̂ − F (N)",
    "torque": "τ / τmax (%)",
    "rtf": "× real time",
    "deflection": "deflection (mm)",
    "rate": "h (Np) · σ (1/s)",
    **{name: f"{name} ({unit})" for name, unit, _ in W_SERIES},
}
LIMIT_COLOR, DS_COLOR, DI_COLOR = "#555555", "#d62728", "#ff9f1c"
PREVIOUS_COLOR = "rgba(90, 90, 90, 0.35)"  # the run before this one, faint, for A/B
PHASE_MARGIN = 0.06  # the phase plot's x range reaches this share of the joint's range beyond each limit
# zoomed on the nearer limit, the phase plot shows from this many d_i before it to this many d_s beyond: the
# last degrees where the damper acts, d_s several times wider than in the whole range
PHASE_ZOOM_DI = 1.25
PHASE_ZOOM_DS = 1.5
# The charts, each in its own folder of the Plots tab; a preset shows its lesson's charts first (its
# `Scenario.plot_layout`) and the others only with "Show all plots".
CHARTS = ("force", "coupling", "torque", "phase", "deflection", "rtf")
CHART_TITLES = {
    "force": "Force error",
    "coupling": "Coupling W",
    "torque": "Torques",
    "phase": "Joint phase",
    "deflection": "Deflection",
    "rtf": "Real-time factor",
}
NEW_RUN = "*A new run: its plots start at t = 0.*"
STATUS_ORDER = 0.45  # the app's status line: after the Window, Freeze and Replay controls, before the readouts
RESEND_AFTER_CONNECT_S = (2.0, 6.0, 15.0)  # a new page's charts get their axes again after these seconds
RESEND_AFTER_SHOW_S = (1.0, 4.0)
MIN_PREVIOUS_SAMPLES = 50  # a run this long (≈ 1 s of plot samples) is kept as the previous run


def nice_ceiling(value: float, floor: float) -> float:
    """The smallest of floor·{1, 2, 5}·10^k that is ≥ value (floor itself for small values)."""
    if not math.isfinite(value) or value <= floor:
        return floor
    k = math.floor(math.log10(value / floor))
    for base in (1.0, 2.0, 5.0, 10.0):
        candidate = floor * base * 10.0**k
        if candidate >= value * (1 - 1e-12):
            return candidate
    return floor * 10.0 ** (k + 1)


def tick_step(span: float, ticks: int = 4) -> float:
    """A 1-2-5 step that cuts `span` into about `ticks` intervals."""
    if not math.isfinite(span) or span <= 0:
        return 1.0
    raw = span / ticks
    k = math.floor(math.log10(raw))
    for base in (1.0, 2.0, 5.0, 10.0):
        if base * 10.0**k >= raw * (1 - 1e-9):
            return base * 10.0**k
    return 10.0 ** (k + 1)


def tick_text(value: float, step: float) -> str:
    """A tick as the browser writes it (uPlot's default: the locale's number format, thousands grouped,
    at most three decimals, no trailing zeros), for sizing the axis."""
    decimals = min(3, max(0, -math.floor(math.log10(step)))) if step < 1 else 0
    text = f"{value:,.{decimals}f}"
    if "." in text:
        text = text.rstrip("0").rstrip(".")
    return "0" if text in ("-0", "") else text


def y_axis(label: str, lo: float, hi: float, ticks: int = 4) -> uplot.Axis:
    """A y axis with its label (with the unit) and explicit ticks inside (lo, hi), none at the top edge
    (where it would hide under the title), and as wide as its longest tick needs (uPlot's default width
    clipped "10,000" to "0,000"); `ticks`: about how many intervals (fewer for a short plot)."""
    step = tick_step(hi - lo, ticks)
    first = math.ceil(lo / step - 1e-9) * step
    splits = [first + i * step for i in range(int((hi - first) / step + 1e-9) + 1)]
    splits = [0.0 if abs(v) < 1e-9 * step else v for v in splits if v < hi - 0.04 * (hi - lo)]
    width = 16 + 7 * max((len(tick_text(v, step)) for v in splits), default=1)
    axis = {"label": label, "labelSize": 18, "splits": tuple(splits), "size": width}
    return axis  # type: ignore[return-value]


def x_axis(label: str = X_LABEL) -> uplot.Axis:
    """The x axis with its label."""
    return {"label": label, "labelSize": 16}


class SignalHistory:
    """The last `seconds` of plot samples, by column, grown from overlapping `PlotData` windows.

    Rows newer than the newest kept one are appended; a window that ends earlier than the history
    (a reset, a new session) starts the history again."""

    def __init__(self, seconds: float = HISTORY_S):
        self.seconds = seconds
        self.columns: dict[str, np.ndarray] = {}

    @property
    def t(self) -> np.ndarray:
        return self.columns.get("t", np.zeros(0))

    def clear(self) -> None:
        """Forget every sample."""
        self.columns = {}

    def add(self, columns: dict[str, np.ndarray]) -> None:
        """Take in a window of samples (column "t" increasing)."""
        t = columns.get("t")
        if t is None or len(t) == 0:
            return
        old = self.t
        if len(old) and t[-1] < old[-1] - 1e-9:
            self.clear()
            old = self.t
        new = t > old[-1] + 1e-9 if len(old) else np.ones(len(t), dtype=bool)
        if not np.any(new):
            return
        n_old = len(old)
        merged: dict[str, np.ndarray] = {}
        for key in set(self.columns) | set(columns):
            before = self.columns.get(key, np.full(n_old, np.nan))
            after = columns[key][new] if key in columns else np.full(int(new.sum()), np.nan)
            merged[key] = np.concatenate([before, after])
        keep = merged["t"] >= merged["t"][-1] - self.seconds
        self.columns = {k: v[keep] for k, v in merged.items()}

    def window(self, seconds: float) -> dict[str, np.ndarray]:
        """The samples of the last `seconds` (views)."""
        t = self.t
        if len(t) == 0:
            return {}
        start = int(np.searchsorted(t, t[-1] - seconds))
        return {k: v[start:] for k, v in self.columns.items()}


@dataclass(frozen=True)
class Marker:
    """A phase change worth a vertical line: simulated time and a short name."""

    t: float
    label: str


def phase_markers(columns: dict[str, np.ndarray], segments: int) -> list[Marker]:
    """Where the scenario's phase changes in these samples: the strokes S1…S`segments` of a preset
    that has them (`Scenario.segments`, signal "segment") and their end, the mass drop's release
    (signal "mass_released" going to 1), a payload release (signal "payload_attached" going to 0),
    the compliance preset's pushes (signals "push_tcp", "push_elbow" going to 1)."""
    t = columns.get("t", np.zeros(0))
    out: list[Marker] = []
    seg = columns.get("segment")
    if seg is not None and len(seg) == len(t):
        idx = np.flatnonzero(np.diff(np.nan_to_num(seg, nan=-1.0)) != 0) + 1
        for i in idx:
            k = seg[i]
            if np.isfinite(k) and 1 <= k <= segments:
                out.append(Marker(float(t[i]), f"S{int(k)}"))
            elif np.isfinite(k) and k > segments:
                out.append(Marker(float(t[i]), "end"))
    released = columns.get("mass_released")
    if released is not None and len(released) == len(t):
        idx = np.flatnonzero((released[:-1] < 0.5) & (released[1:] > 0.5)) + 1
        out.extend(Marker(float(t[i]), "drop") for i in idx)
    attached = columns.get("payload_attached")
    if attached is not None and len(attached) == len(t):
        idx = np.flatnonzero((attached[:-1] > 0.5) & (attached[1:] < 0.5)) + 1
        out.extend(Marker(float(t[i]), "release") for i in idx)
    for where, text in (("tcp", "TCP push"), ("elbow", "elbow push")):
        push = columns.get(f"push_{where}")
        if push is not None and len(push) == len(t):
            idx = np.flatnonzero((np.nan_to_num(push[:-1]) < 0.5) & (push[1:] > 0.5)) + 1
            out.extend(Marker(float(t[i]), text) for i in idx)
    return sorted(out, key=lambda m: m.t)


def segment_std(columns: dict[str, np.ndarray], key: str, segments: int) -> dict[int, float]:
    """STD of column `key` over each stroke 1…`segments` present (segment index → N; `metrics.segment_std`)."""
    seg, values = columns.get("segment"), columns.get(key)
    if seg is None or values is None:
        return {}
    return metrics.segment_std(seg, values, range(1, segments + 1))


def force_error(columns: dict[str, np.ndarray]) -> np.ndarray:
    """F̂_z − F_z: the executor's own force error if it reports one, else from the logged wrenches."""
    err = columns.get("force_error_n")
    if err is None or not np.any(np.isfinite(err)):
        err = columns["Fd_z"] - columns["F_z"]
    return err


def _series(label: str, color: str, **extra: Any) -> uplot.Series:
    out: dict[str, Any] = {"label": label, "stroke": color, "width": 1.5, "spanGaps": True}
    out.update(extra)
    return out  # type: ignore[return-value]


def _marker_series() -> uplot.Series:
    return {"label": "phase", "stroke": MARKER_COLOR, "width": 1, "dash": (2.0, 3.0), "spanGaps": False}  # type: ignore[typeddict-item]


def _empty(n: int) -> tuple[np.ndarray, ...]:
    return tuple(np.zeros(2) for _ in range(n))


def _stride(n: int) -> int:
    return max(1, math.ceil(n / MAX_POINTS))


def _with_markers(
    x: np.ndarray,
    ys: list[np.ndarray],
    markers: list[Marker],
    now: float,
    lo: float,
    hi: float,
    after: list[np.ndarray] | None = None,
) -> tuple[np.ndarray, ...]:
    """(x, *ys, marker series, *after): three extra rows per marker at its time, a vertical line from lo
    up to hi and back in the marker series (uPlot joins across NaN, so the marker line runs along the
    bottom edge between two markers), NaN in the other series (their lines join across those rows)."""
    after = after or []
    xm = [m.t - now for m in markers if m.t - now >= x[0]] if len(x) else []
    if not xm:
        return (x, *ys, np.full(len(x), np.nan), *after)
    mx = np.repeat(np.array(xm), 3)
    my = np.tile([lo, hi, lo], len(xm))
    all_x = np.concatenate([x, mx])
    order = np.argsort(all_x, kind="stable")
    pad = np.full(len(mx), np.nan)
    out = [all_x[order]]
    out += [np.concatenate([y, pad])[order] for y in ys]
    out.append(np.concatenate([np.full(len(x), np.nan), my])[order])
    out += [np.concatenate([y, pad])[order] for y in after]
    return tuple(out)


class Plots:
    """The Plots panel (docked left of the 3D view) and its charts; see the module docstring."""

    def __init__(self, server: viser.ViserServer, n_joints: int = 7, order: float | None = None):
        self.n = n_joints
        gui = server.gui
        self.history = SignalHistory()
        self.monitor = SignalHistory()
        self.readouts: dict[str, float] = {}  # the numbers the readout line shows (tests read them)
        self.markers: list[Marker] = []
        self._ranges: dict[str, tuple[float, float]] = {}
        self._twin_shown: bool | None = None
        self._phase_range: tuple[float | int | None, ...] | None = None
        self._window_s = WINDOWS["10 s"]
        self._last: PlotData | None = None
        self._timers: list[threading.Timer] = []  # pending `resend_axes` (`stop` cancels them)
        self._stopped = False
        self._session: object = None
        self._blank = False  # the charts show a new run's empty axes
        self._settings: Any = None
        self._focus_joint: int | None = None  # the joint the preset is about (readouts)
        self.layout: tuple[str, ...] = Scenario.plot_layout
        self.segments = 0  # the strokes of the preset plotted (`Scenario.segments`)
        self.panel = gui.add_panel(order=order)
        self.replay_t: float | None = None  # while replaying: the instant the plots end at
        self.previous: dict[str, np.ndarray] | None = None  # the run before, drawn faint until cleared
        self.signals = SignalChoice(signal_specs(n_joints))  # which series each chart draws
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
            self.folders = {name: gui.add_folder(CHART_TITLES[name], order=1.0 + i) for i, name in enumerate(CHARTS)}
            with self.folders["force"]:
                self.force = gui.add_uplot(
                    _empty(5),
                    (
                        {"label": X_LABEL},
                        _series("F̂ − F (N)", COLORS[3]),
                        _series("twin arm (N)", TWIN_COLOR, dash=(5.0, 3.0), show=False),
                        _marker_series(),
                        _series("previous run (N)", PREVIOUS_COLOR, width=1),
                    ),
                    title=FORCE_TITLE,
                    scales=self._scales("force", (-FORCE_RANGE_N, FORCE_RANGE_N)),
                    axes=(x_axis(), y_axis(Y_LABELS["force"], -FORCE_RANGE_N, FORCE_RANGE_N)),
                    legend=LEGEND,  # type: ignore[arg-type]
                    aspect=2.0,
                    padding=(24, 12, 0, 0),
                )
                self.sensor_note = gui.add_markdown("")
                band = f"{HEADROOM_BAND_NP:g}"
                self.rate = gui.add_uplot(
                    _empty(7),
                    (
                        {"label": X_LABEL},
                        _series("h (Np)", COLORS[6]),
                        _series("σ (1/s)", COLORS[5], width=1),
                        _series("0", "#888888", width=1, dash=(1.0, 3.0)),
                        _series(f"h +{band}: keeps contact above", COLORS[6], width=1, dash=(4.0, 4.0)),
                        _series(f"h −{band}: lifts off below", COLORS[6], width=1, dash=(4.0, 4.0)),
                        _marker_series(),
                    ),
                    title=RATE_TITLE,
                    scales=self._scales("rate", (-RATE_RANGE_PER_S, RATE_RANGE_PER_S)),
                    axes=(x_axis(), y_axis(Y_LABELS["rate"], -RATE_RANGE_PER_S, RATE_RANGE_PER_S, RATE_TICKS)),
                    legend=LEGEND,  # type: ignore[arg-type]
                    aspect=RATE_ASPECT,
                    padding=(24, 12, 0, 0),
                )
            with self.folders["coupling"]:
                self.coupling = gui.add_markdown(f"**{COUPLING_TITLE}**")
                self.w_plots = {
                    name: gui.add_uplot(
                        _empty(3),
                        ({"label": X_LABEL}, _series(f"{name} ({unit})", color), _marker_series()),
                        scales=self._scales(name, (0.0, 1.0)),
                        axes=(x_axis(""), y_axis(Y_LABELS[name], 0.0, 1.0)),
                        legend=LEGEND,  # type: ignore[arg-type]
                        aspect=2.6,
                        padding=(10, 12, 0, 0),
                    )
                    for name, unit, color in W_SERIES
                }
            with self.folders["torque"]:
                self.torque = gui.add_uplot(
                    _empty(self.n + 4),
                    (
                        {"label": X_LABEL},
                        *(_series(f"τ{i + 1}", COLORS[i % len(COLORS)], width=1) for i in range(self.n)),
                        _series("+limit", "#888888", width=1, dash=(4.0, 4.0)),
                        _series("−limit", "#888888", width=1, dash=(4.0, 4.0)),
                        _marker_series(),
                    ),
                    title="Torques / limits (%)",
                    scales=self._scales("torque", (-TORQUE_RANGE_PCT, TORQUE_RANGE_PCT)),
                    axes=(x_axis(), y_axis(Y_LABELS["torque"], -TORQUE_RANGE_PCT, TORQUE_RANGE_PCT)),
                    legend=LEGEND,  # type: ignore[arg-type]
                    aspect=2.0,
                    padding=(24, 12, 0, 0),
                )
            with self.folders["phase"]:
                self.joint: Any = gui.add_dropdown(
                    "Phase plot joint", tuple(str(i + 1) for i in range(n_joints)), initial_value="4"
                )
                self.phase_zoom: Any = gui.add_checkbox(
                    "Zoom on the limit",
                    False,
                    hint="Show the last degrees before the joint's nearer limit: the limit, d_s and d_i apart",
                )
                self.phase_zoom.on_update(lambda _: self._phase_zoom_changed())
                self.phase = gui.add_uplot(
                    _empty(7),
                    (
                        {"label": "q (rad)", "sorted": 0},
                        _series("q̇ (rad/s)", COLORS[4], points={"show": False}, spanGaps=False),
                        _series("±q̇max", "#888888", width=1, dash=(4.0, 4.0)),
                        _series("−q̇max", "#888888", width=1, dash=(4.0, 4.0)),
                        _series("limit", LIMIT_COLOR, width=2, spanGaps=False),
                        _series("d_s", DS_COLOR, width=1, dash=(3.0, 3.0), spanGaps=False),
                        _series("d_i", DI_COLOR, width=1, dash=(6.0, 3.0), spanGaps=False),
                    ),
                    title="Joint phase (q, q̇)",
                    scales={"x": {"time": False, "auto": False, "range": (-1.0, 1.0)}},
                    axes=(x_axis("q (rad)"), y_axis("q̇ (rad/s)", -1.0, 1.0)),
                    legend=LEGEND,  # type: ignore[arg-type]
                    aspect=1.5,
                    padding=(24, 12, 0, 0),
                )
            with self.folders["deflection"]:
                self.deflection = gui.add_uplot(
                    _empty(5),
                    (
                        {"label": X_LABEL},
                        _series("TCP (mm)", COLORS[0]),
                        _series("elbow (mm)", COLORS[2]),
                        _marker_series(),
                        _series("TCP, previous run (mm)", PREVIOUS_COLOR, width=1),
                    ),
                    title="Deflection from the start pose (mm)",
                    scales=self._scales("deflection", (0.0, DEFLECTION_RANGE_MM)),
                    axes=(x_axis(), y_axis(Y_LABELS["deflection"], 0.0, DEFLECTION_RANGE_MM)),
                    legend=LEGEND,  # type: ignore[arg-type]
                    aspect=2.0,
                    padding=(24, 12, 0, 0),
                )
            with self.folders["rtf"]:
                self.rtf = gui.add_uplot(
                    _empty(2),
                    ({"label": X_LABEL}, _series("real-time factor", COLORS[5])),
                    title="Real-time factor",
                    scales=self._scales("rtf", (0.0, RTF_RANGE)),
                    axes=(x_axis(), y_axis(Y_LABELS["rtf"], 0.0, RTF_RANGE)),
                    legend=LEGEND,  # type: ignore[arg-type]
                    aspect=3.0,
                    padding=(24, 12, 0, 0),
                )
            for chart in self.signals.specs:
                with self.folders[chart]:
                    self._add_signal_boxes(gui, chart)
        self.panel.dock_left()
        self.panel.set_width(400)
        self.window.on_update(lambda _: self._on_window())
        self.freeze.on_update(lambda _: self._redraw())
        self.joint.on_update(lambda _: self._redraw())
        self.show_all.on_update(lambda _: self.arrange(None))
        self.arrange(None)
        server.on_client_connect(lambda _: self._resend_later(*RESEND_AFTER_CONNECT_S))

    # ---- signals --------------------------------------------------------------------------------
    def _add_signal_boxes(self, gui: Any, chart: str) -> None:
        """The chart's Signals fold: one checkbox per series it may draw."""
        with gui.add_folder("Signals", order=100.0, expand_by_default=False):
            for key, label in self.signals.specs[chart]:
                box = gui.add_checkbox(label, self.signals.shown(chart, key), hint=f"Draw {label} in this plot")
                box.on_update(lambda event, c=chart, k=key: self._on_signal_box(c, k, event.target.value))
                self.signal_boxes[(chart, key)] = box

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

    def apply_signals(self) -> None:
        """Show or hide each chart's series (and the σ and W plots) as the choice says; a frozen picture
        changes too (hidden series are not drawn whatever data they hold)."""
        shown = self.signals.shown
        self._show_series(
            self.force,
            {
                1: shown("force", "error"),
                2: shown("force", "twin") and bool(self._twin_shown),
                4: shown("force", "previous"),
            },
        )
        if self.rate.visible != shown("force", "rate"):
            self.rate.visible = shown("force", "rate")
        for name, handle in self.w_plots.items():
            if handle.visible != shown("coupling", name):
                handle.visible = shown("coupling", name)
        flags = {i + 1: shown("torque", f"tau_{i + 1}") for i in range(self.n)}
        flags |= {self.n + 1: shown("torque", "limits"), self.n + 2: shown("torque", "limits")}
        self._show_series(self.torque, flags)
        speed, zones = shown("phase", "speed_limits"), shown("phase", "zones")
        self._show_series(self.phase, {2: speed, 3: speed, 4: zones, 5: zones, 6: zones})
        self._show_series(
            self.deflection,
            {1: shown("deflection", "tcp"), 2: shown("deflection", "elbow"), 4: shown("deflection", "previous")},
        )

    @staticmethod
    def _show_series(handle: Any, flags: dict[int, bool]) -> None:
        series = series_shown(tuple(handle.series), flags)
        if series is not None:
            handle.series = series

    # ---- layout ---------------------------------------------------------------------------------
    def arrange(self, scenario: str | None) -> None:
        """Put the preset's charts first (its lesson's metric on top) and show the others only with
        "Show all plots"; None keeps the preset and applies the switch."""
        if scenario is not None:
            self.layout = get_scenario(scenario).plot_layout if scenario in SCENARIOS else Scenario.plot_layout
        show_all = bool(self.show_all.value)
        rest = [c for c in CHARTS if c not in self.layout]
        changed = False
        for i, name in enumerate((*self.layout, *rest)):
            folder = self.folders[name]
            order = 1.0 + i
            visible = show_all or name in self.layout
            if folder.order != order:
                folder.order = order
            if folder.visible != visible:
                folder.visible = visible
                if visible:
                    changed = True
        if changed or scenario is not None:  # shown charts, or a new preset's first frames
            self._resend_later(*RESEND_AFTER_SHOW_S)

    # ---- ranges ---------------------------------------------------------------------------------
    def _scales(self, key: str, y: tuple[float, float]) -> dict[str, uplot.Scale]:
        self._ranges[key] = y
        return {
            "x": {"time": False, "auto": False, "range": (-self._window_s, 0.0)},
            "y": {"auto": False, "range": y},
        }

    def _set_range(self, key: str, handle: Any, y: tuple[float, float], force: bool = False) -> None:
        """Give a plot a new y range and its ticks (a new range rebuilds the chart in the browser: only
        on change)."""
        if force or self._ranges.get(key) != y:
            handle.scales = self._scales(key, y)
            x_label = "" if key.startswith("W_") else X_LABEL  # three small plots: one x label is enough
            handle.axes = (x_axis(x_label), y_axis(Y_LABELS[key], *y, RATE_TICKS if key == "rate" else 4))

    def _on_window(self) -> None:
        value = WINDOWS.get(str(self.window.value))
        if value is None or value == self._window_s:
            return
        self._window_s = value
        for key, handle in self._handles().items():
            self._set_range(key, handle, self._ranges[key], force=True)
        self._redraw()

    def _handles(self) -> dict[str, Any]:
        return {
            "force": self.force,
            "rate": self.rate,
            "torque": self.torque,
            "rtf": self.rtf,
            "deflection": self.deflection,
            **self.w_plots,
        }

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
            self._update(plot, session, settings)

    def _update(self, plot: PlotData, session: object, settings: Any) -> None:
        if session != self._session:
            self._session = session
            old = self.history.columns
            if len(old.get("t", ())) >= MIN_PREVIOUS_SAMPLES:
                self.previous = {k: v.copy() for k, v in old.items()}
                if "Fd_z" in old:
                    self.previous["force_error"] = force_error(old).copy()
            self.replay_t = None
            if self.force.title != NEUTRAL_FORCE_TITLE:  # the old run's setpoint says nothing of the new one's
                self.force.title = NEUTRAL_FORCE_TITLE
            self.history.clear()
            self.monitor.clear()
            self.markers = []
            self.readouts = {}
            self._blank = False
        self._last = plot
        if settings is not None and settings is not self._settings:
            self._settings = settings
            self._show_sensor_note(settings)
        self.history.add(plot.columns)
        self.monitor.add(plot.monitor)
        self._redraw()

    def _show_sensor_note(self, settings: Any) -> None:
        """Under the force plot: whether the F/T model's sinusoid and noise are in the reading."""
        sensor = getattr(settings, "groups", {}).get("sensor")
        text = ""
        if sensor is not None and getattr(sensor, "noise", False):
            amp, hz = float(sensor.sine_amplitude_n), float(sensor.sine_hz)
            text = (
                f"*Sensor model on: a {hz:g} Hz, ±{amp:g} N sinusoid and noise ({float(sensor.force_noise_var):g} N²) "
                "are in the F/T reading — not the arm's motion (Tune → Sensor noise off removes them).*"
            )
        elif sensor is not None:
            text = "*Sensor model off: the F/T reading is the ideal filtered force.*"
        if self.sensor_note.content != text:
            self.sensor_note.content = text

    def _clear_charts(self) -> None:
        """A new run with no samples yet: empty charts (their axes stay) and no readouts of the old run."""
        if self._blank:
            return
        self._blank = True
        nan2 = np.full(2, np.nan)
        x = np.array([-self._window_s, 0.0])
        self.force.data = (x, nan2, nan2, nan2, nan2)
        self.torque.data = (x, *([nan2] * (self.n + 3)))
        self.deflection.data = (x, nan2, nan2, nan2, nan2)
        self.rtf.data = (x, nan2)
        self.rate.data = (x, nan2, nan2, nan2, nan2, nan2, nan2)
        for handle in self.w_plots.values():
            handle.data = (x, nan2, nan2)
        self.phase.data = (np.array([-1.0, 1.0]), *([nan2] * 6))
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

    def _window(self, history: SignalHistory, replay_t: float | None) -> dict[str, np.ndarray]:
        """The shown window of a history: up to now, or while replaying (`replay_t`, read once per
        redraw: Replay may clear it from another thread meanwhile) up to that instant."""
        if replay_t is None:
            return history.window(self._window_s)
        t = history.t
        end = int(np.searchsorted(t, replay_t, side="right"))
        start = int(np.searchsorted(t, replay_t - self._window_s))
        return {k: v[start:end] for k, v in history.columns.items()}

    def _previous_at(self, key: str, t: np.ndarray) -> np.ndarray:
        """The previous run's signal `key` at the simulated times t (NaN where it has none)."""
        prev = self.previous
        if prev is None or key not in prev or "t" not in prev or not len(t):
            return np.full(len(t), np.nan)
        pt, pv = prev["t"], prev[key]
        ok = np.isfinite(pv)
        if np.count_nonzero(ok) < 2:
            return np.full(len(t), np.nan)
        out = np.interp(t, pt[ok], pv[ok])
        out[(t < pt[ok][0]) | (t > pt[ok][-1])] = np.nan
        return out

    def _redraw(self) -> None:
        with self._redraw_lock:
            self._redraw_now()

    def _redraw_now(self) -> None:
        plot = self._last
        if plot is None:
            return
        replay_t = self.replay_t  # once per redraw: every chart of this redraw shows the same instant
        c = self._window(self.history, replay_t)
        t = c.get("t", np.zeros(0))
        if len(t) < 2 or "Fd_z" not in c:
            if not self.freeze.value:
                self._clear_charts()
            return
        self._blank = False
        self.segments = plot.segments
        self.markers = phase_markers(self.history.columns, plot.segments)
        self._update_readouts(plot)
        if self.freeze.value:
            return
        now = float(t[-1])
        s = slice(None, None, _stride(len(t)))
        x = t[s] - now
        self._draw_force(c, s, x, now)
        self._draw_rate(c, s, x, now)
        self._draw_torque(plot, c, s, x, now)
        self._draw_deflection(c, s, x, now)
        self._update_phase(plot, c)
        m = self._window(self.monitor, replay_t)
        mt = m.get("t", np.zeros(0))
        if len(mt) >= 2:
            ms = slice(None, None, _stride(len(mt)))
            mx = mt[ms] - now
            singular = not np.any(np.isfinite(m["W_a"][-5:]))
            title = COUPLING_TITLE + (": not shown near a singularity" if singular else "")
            if self.coupling.content != f"**{title}**":
                self.coupling.content = f"**{title}**"
            for name, handle in self.w_plots.items():
                w = m[name][ms]
                top = float(np.nanmax(w)) if np.any(np.isfinite(w)) else 0.0
                floor = 10.0 ** math.floor(math.log10(top)) if top > 0 else 1.0
                hi = nice_ceiling(1.1 * top, floor)
                self._set_range(name, handle, (0.0, hi))
                handle.data = _with_markers(mx, [w], self.markers, now, 0.0, hi)
            rtf = m["rtf"][ms]
            top = float(np.nanmax(rtf)) if np.any(np.isfinite(rtf)) else 0.0
            hi = nice_ceiling(1.1 * top, RTF_RANGE) if top > RTF_RANGE else RTF_RANGE
            self._set_range("rtf", self.rtf, (0.0, hi))
            self.rtf.data = (mx, rtf)

    def _draw_force(self, c: dict[str, np.ndarray], s: slice, x: np.ndarray, now: float) -> None:
        err = force_error(c)
        twin = c.get("twin_force_error_n")
        has_twin = twin is not None and bool(np.any(np.isfinite(twin)))
        if has_twin != self._twin_shown:
            self._twin_shown = has_twin
            self.apply_signals()
        shown = self.signals.shown
        err = masked(err, shown("force", "error"))
        if twin is not None:
            twin = masked(twin, shown("force", "twin"))
        values = np.abs(err[np.isfinite(err)])
        if has_twin and twin is not None:
            values = np.concatenate([values, np.abs(twin[np.isfinite(twin)])])
        top = float(values.max()) if values.size else 0.0
        hi = nice_ceiling(1.1 * top, FORCE_RANGE_N)
        self._set_range("force", self.force, (-hi, hi))
        twin_y = twin[s] if has_twin and twin is not None else np.zeros(len(x))
        prev = masked(self._previous_at("force_error", c["t"][s]), shown("force", "previous"))
        self.force.data = _with_markers(x, [err[s], twin_y], self.markers, now, -hi, hi, after=[prev])
        t = c["t"][np.isfinite(c["t"])]
        span = float(t[-1] - t[0]) if t.size else 0.0
        if np.any(c["Fd_z"] != 0.0):
            title = FORCE_TITLE
        else:  # a run paused at its start has not shown its setpoint yet: say nothing about it
            title = NO_SETPOINT_TITLE if span >= NO_SETPOINT_AFTER_S else NEUTRAL_FORCE_TITLE
        if self.force.title != title:
            self.force.title = title

    def _draw_rate(self, c: dict[str, np.ndarray], s: slice, x: np.ndarray, now: float) -> None:
        """The polish preset's live margin: the stroke headroom h (signal "margin_headroom_np", from the
        σ samples of the current stroke) and σ (signal "margin_rate", every 0.1 s of simulated time from
        the logged step's posture); all NaN elsewhere."""
        nan = np.full(len(c["t"]), np.nan)
        rate = c.get("margin_rate", nan)
        headroom = c.get("margin_headroom_np", nan)
        both = np.concatenate([rate, headroom])
        values = np.abs(both[np.isfinite(both)])
        hi = nice_ceiling(1.1 * float(values.max()), RATE_RANGE_PER_S) if values.size else RATE_RANGE_PER_S
        self._set_range("rate", self.rate, (-hi, hi))
        # only the sign outside the band is a prediction; drawn where the preset has a headroom
        band = np.full(len(x), HEADROOM_BAND_NP if np.any(np.isfinite(headroom)) else np.nan)
        self.rate.data = _with_markers(
            x, [headroom[s], rate[s], np.zeros(len(x)), band, -band], self.markers, now, -hi, hi
        )

    def _draw_torque(self, plot: PlotData, c: dict[str, np.ndarray], s: slice, x: np.ndarray, now: float) -> None:
        ratio = [
            masked(100.0 * c[f"tau_{i + 1}"][s] / plot.tau_max[i], self.signals.shown("torque", f"tau_{i + 1}"))
            for i in range(self.n)
        ]
        finite = [np.abs(r[np.isfinite(r)]) for r in ratio]
        top = max((float(r.max()) for r in finite if r.size), default=0.0)
        hi = nice_ceiling(1.05 * top, TORQUE_RANGE_PCT) if top > TORQUE_RANGE_PCT else TORQUE_RANGE_PCT
        self._set_range("torque", self.torque, (-hi, hi))
        ones = np.full(len(x), 100.0)
        self.torque.data = _with_markers(x, [*ratio, ones, -ones], self.markers, now, -hi, hi)

    def _draw_deflection(self, c: dict[str, np.ndarray], s: slice, x: np.ndarray, now: float) -> None:
        """TCP and elbow distance from their start (signals "tcp_dev_mm", "elbow_dev_mm"), when logged."""
        if "tcp_dev_mm" not in c:
            return
        shown = self.signals.shown
        tcp = masked(c["tcp_dev_mm"][s], shown("deflection", "tcp"))
        elbow = c["elbow_dev_mm"][s] if "elbow_dev_mm" in c else np.full(len(x), np.nan)
        elbow = masked(elbow, shown("deflection", "elbow"))
        both = np.concatenate([tcp[np.isfinite(tcp)], elbow[np.isfinite(elbow)]])
        top = float(both.max()) if both.size else 0.0
        hi = nice_ceiling(1.1 * top, DEFLECTION_RANGE_MM) if top > 0 else DEFLECTION_RANGE_MM
        if top > 0 and top < 0.5 * DEFLECTION_RANGE_MM:  # small deflections get a finer range
            hi = nice_ceiling(1.1 * top, 10.0 ** math.floor(math.log10(top)))
        self._set_range("deflection", self.deflection, (0.0, hi))
        prev = masked(self._previous_at("tcp_dev_mm", c["t"][s]), shown("deflection", "previous"))
        self.deflection.data = _with_markers(x, [tcp, elbow], self.markers, now, 0.0, hi, after=[prev])

    def _update_readouts(self, plot: PlotData) -> None:
        """The readouts docs/web-app.md quotes, from the whole history (not just the window shown)."""
        c = self.history.columns
        out: dict[str, float] = {}
        lines: list[str] = []
        if "segment" in c and np.any(np.isfinite(c["segment"])):
            # every 1 ms step since the reset when the loop counted them, else the plotted samples
            main = (
                plot.segment_std if plot.segment_std is not None else _std_by_segment(c, force_error(c), plot.segments)
            )
            twin: dict[int, float] = {}
            if plot.twin_segment_std is not None:
                twin = plot.twin_segment_std
            elif "twin_force_error_n" in c:  # on the twin's own segments (its zig-zag may run at other times)
                twin_seg = c["twin_segment"] if "twin_segment" in c else c["segment"]
                twin = segment_std({"segment": twin_seg, "v": c["twin_force_error_n"]}, "v", plot.segments)
            for k, v in main.items():
                out[f"force_error_std_S{k}"] = v
            for k, v in twin.items():
                out[f"twin_force_error_std_S{k}"] = v
            if main:
                head = " · ".join(f"S{k} {v:.1f}" for k, v in main.items())
                lines.append(f"Force-error STD (N, over every step of each stroke since the reset): {head}")
                if twin:
                    lines.append("twin: " + " · ".join(f"S{k} {v:.1f}" for k, v in twin.items()))
        joint = self._focus_joint
        if "payload_attached" in c and joint is not None:
            # from every 1 ms step since the reset (the loop's step log), not from the plotted samples
            tau = plot.peak_abs_tau[joint] if plot.peak_abs_tau is not None else np.nan
            # the deepest point toward the limit the joint falls to (the Gen3's upper one, the Panda's lower
            # one), in a coordinate s·q that grows toward that limit
            s = -1.0 if plot.fall_direction < 0 else 1.0
            deepest = plot.low_q if s < 0 else plot.peak_q
            q_deep = s * float(deepest[joint]) if deepest is not None else np.nan
            if np.isfinite(tau):
                peak = float(tau)
                out["peak_torque_nm"] = peak
                hi, lo = float(plot.q_upper[joint]), float(plot.q_lower[joint])
                limit = s * (lo if s < 0 else hi)
                d_s = self._damper_fraction("safety_fraction", 0.01) * (hi - lo) if np.isfinite(hi - lo) else math.nan
                over = q_deep - (limit - d_s) if np.isfinite(q_deep) and math.isfinite(d_s) else math.nan
                if math.isfinite(over):
                    out["overshoot_beyond_ds_rad"] = over
                text = f"Joint {joint + 1}: peak |τ| {peak:.1f} N m"
                if math.isfinite(over):
                    text += f" · beyond d_s {max(over, 0.0) * 1e3:.1f} mrad"
                lines.append(text)
        d = plot.deflection or {}
        if "peak_deflection_mm" in d:
            out.update(d)
            lines.append(
                f"TCP after the drop (every step since the release): peak {d['peak_deflection_mm']:.1f} mm · "
                f"back within {1e3 * metrics.STABLE_BAND_M:g} mm for good {d['stabilization_time_s']:.2f} s after "
                f"it · residual (mean of the last {metrics.RESIDUAL_WINDOW_S:g} s) {d['residual_error_mm']:.2f} mm"
            )
        for push in ("tcp", "elbow"):
            if f"{push}_push_tcp_mm" in d:
                out[f"{push}_push_tcp_mm"] = d[f"{push}_push_tcp_mm"]
                out[f"{push}_push_elbow_mm"] = d[f"{push}_push_elbow_mm"]
                lines.append(
                    f"Push at the {'TCP' if push == 'tcp' else 'elbow'} (peak over the push and the "
                    f"{metrics.PUSH_AFTER_S:g} s after it): TCP moved {d[f'{push}_push_tcp_mm']:.1f} mm, "
                    f"elbow {d[f'{push}_push_elbow_mm']:.1f} mm"
                )
        if lines and plot.run:  # the figures name the run they were measured on
            lines.insert(0, f"*Run:* {plot.run}")
        if self.markers:
            lines.append("Markers: " + " · ".join(f"{m.label} {m.t:.1f} s" for m in self.markers[-8:]))
        self.readouts = out
        text = "  \n".join(lines)
        if self.readout.content != text:
            self.readout.content = text

    def _damper_fraction(self, field: str, default: float) -> float:
        """A field of the damper group in force (d_s, d_i as shares of the range), or `default`."""
        damper = getattr(self._settings, "groups", {}).get("damper") if self._settings is not None else None
        value = getattr(damper, field, None)
        return float(value) if value is not None else default

    def _update_phase(self, plot: PlotData, c: dict[str, np.ndarray]) -> None:
        """The phase portrait of the chosen joint from the redraw's window `c`."""
        j = int(self.joint.value) - 1
        q, dq = c[f"q_{j + 1}"], c[f"dq_{j + 1}"]
        s = slice(None, None, _stride(len(q)))
        q, dq = q[s], dq[s]
        lo, hi = float(plot.q_lower[j]), float(plot.q_upper[j])
        limited = np.isfinite(lo) and np.isfinite(hi) and hi - lo <= 4 * np.pi
        if not limited:  # endless joint: follow the data
            lo, hi = float(np.nanmin(q)) - 0.1, float(np.nanmax(q)) + 0.1
        vlim = float(plot.dq_max[j])
        top = 1.15 * vlim
        pad = PHASE_MARGIN * (hi - lo)  # the stop is inside the plot, not on its edge
        d_s = self._damper_fraction("safety_fraction", math.nan) * (hi - lo) if limited else math.nan
        d_i = self._damper_fraction("influence_fraction", math.nan) * (hi - lo) if limited else math.nan
        x_range = (lo - pad, hi + pad)
        zoom = None  # the limit zoomed on (its sign: +1 upper, −1 lower)
        finite_q = q[np.isfinite(q)]
        if self.phase_zoom.value and limited and math.isfinite(d_s) and math.isfinite(d_i) and finite_q.size:
            zoom = 1 if float(finite_q[-1]) >= 0.5 * (lo + hi) else -1
            limit = hi if zoom > 0 else lo
            near, beyond = limit - zoom * PHASE_ZOOM_DI * d_i, limit + zoom * PHASE_ZOOM_DS * d_s
            x_range = (min(near, beyond), max(near, beyond))
        # NaN-free (NaN != NaN would send the chart's options again at every redraw, rebuilding it)
        key = (*(v if math.isfinite(v) else None for v in (lo, hi, vlim, d_s, d_i)), j, zoom)
        if self._phase_range != key:
            self._phase_range = key
            self.phase.scales = {
                "x": {"time": False, "auto": False, "range": x_range},
                "y": {"auto": False, "range": (-top, top)},
            }
            self.phase.axes = (x_axis("q (rad)"), y_axis("q̇ (rad/s)", -top, top))
            zones = " · d_s dotted red, d_i dashed orange" if math.isfinite(d_s) else ""
            where = (
                f", zoomed on the {'upper' if zoom > 0 else 'lower'} limit {hi if zoom > 0 else lo:.2f} rad"
                if zoom is not None
                else f": limits [{lo:.2f}, {hi:.2f}] rad"
            )
            self.phase.title = f"Joint {j + 1} phase (q, q̇){where}{zones}"
        # rows after the trajectory: two carry the velocity limits across the whole width, then for each
        # of limit, d_s and d_i its two vertical lines, joined far above the plot (uPlot joins across NaN,
        # so the join runs outside the drawn range instead)
        xs = [*q, *x_range]
        ys: list[list[float]] = [[math.nan] * len(xs) for _ in range(6)]  # series 1…6
        ys[0][: len(q)] = dq.tolist()
        ys[1][len(q) :] = [vlim, vlim]
        ys[2][len(q) :] = [-vlim, -vlim]
        lines: dict[int, tuple[float, float]] = {4: (lo, hi)} if limited else {}  # series → its two q
        if math.isfinite(d_s):
            lines |= {5: (lo + d_s, hi - d_s), 6: (lo + d_i, hi - d_i)}
        far = 3.0 * top
        for series, (left, right) in lines.items():
            for xv, y in ((left, -top), (left, far), (right, far), (right, -top)):
                xs.append(xv)
                for k in range(6):
                    ys[k].append(y if k == series - 1 else math.nan)
        self.phase.data = (np.array(xs), *(np.array(y) for y in ys))

    def _phase_zoom_changed(self) -> None:
        """The zoom switched: draw the phase plot again (its range follows the switch)."""
        with self._redraw_lock:
            self._redraw()

    def resend_axes(self) -> None:
        """Send every chart's scales and axes again: a chart the page built before its panel had its
        size draws no ticks until its options change (viser 1.1.1 with uPlot)."""
        for key, handle in self._handles().items():
            self._set_range(key, handle, self._ranges[key], force=True)
        scales, axes = self.phase.scales, self.phase.axes
        if scales is not None:
            self.phase.scales = dict(scales)
        if axes is not None:
            self.phase.axes = tuple(axes)

    def _resend_later(self, *delays_s: float) -> None:
        """`resend_axes` after each delay (a page just connected, or charts were just shown)."""
        self._timers = [t for t in self._timers if t.is_alive()]
        for delay in delays_s:
            if self._stopped:
                return
            timer = threading.Timer(delay, self._safe_resend)
            timer.daemon = True
            self._timers.append(timer)
            timer.start()

    def redraw_wait_s(self) -> float:
        """Seconds a redraw asked for now (a checkbox's handler) waits for the one under way (the
        publisher's frame) before it can start; a probe for `torquelab bench --serve`."""
        t0 = time.perf_counter()
        with self._redraw_lock:
            return time.perf_counter() - t0

    def stop(self) -> None:
        """No chart is sent anything from now on: the pending resends are cancelled (the server is
        about to stop; a resend after it queued messages on a closed server, with a warning)."""
        self._stopped = True
        for timer in self._timers:
            timer.cancel()

    def _safe_resend(self) -> None:
        if self._stopped:
            return
        try:
            self.resend_axes()
        except Exception:  # a chart being rebuilt meanwhile: the next resend fixes it
            traceback.print_exc()


def _std_by_segment(columns: dict[str, np.ndarray], values: np.ndarray, segments: int) -> dict[int, float]:
    return segment_std({"segment": columns["segment"], "v": values}, "v", segments)
