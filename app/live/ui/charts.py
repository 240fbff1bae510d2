"""The charts of the Plots tab as one table: a row per chart (its folder), each with its uPlot plots, the
series one may choose in its *Signals* fold and the function that draws it (`app.live.ui.chart_draws`).

A new signal is one row here (or one series in a row) and at most one draw function; a preset brings a
chart of its own as a `Chart` in its `Scenario.plot_layout`, drawn by `draw_preset_chart` (`preset_row`).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import viser.uplot as uplot

from app.live.ui import chart_draws as draws
from app.live.ui.phase_plot import PHASE_SERIES, draw_phase, phase_controls
from app.live.ui.plot_axes import (
    COLORS,
    LEGEND,
    PREVIOUS_COLOR,
    TWIN_COLOR,
    X_LABEL,
    empty,
    line,
    marker_series,
    x_axis,
    y_axis,
)
from app.scenarios import Chart
from app.scenarios.stroke_outcomes import HEADROOM_BAND_NP

Draw = Callable[[Any, Any], None]  # (the Plots, the redraw's `draws.Window`)


@dataclass(frozen=True)
class PlotSpec:
    """One uPlot of a chart: its series after the x column, the signal choice (`signals`, per series: the
    chart's choosable key that draws it, None for none) and its y axis before any widening."""

    key: str  # its y range's name, unique over the page
    series: tuple[uplot.Series, ...]
    y_label: str
    y_range: tuple[float, float]
    signals: tuple[str | None, ...] = ()
    title: str = ""
    aspect: float = 2.0
    padding: tuple[float, float, float, float] = (24, 12, 0, 0)
    ticks: int = 4  # about how many tick intervals
    top_tick: bool = False  # a tick at the top edge (a plot without a title)
    x_label: str = X_LABEL
    shown_by: str = ""  # the chart's choosable key that shows the whole plot ("": always shown)
    timed: bool = True  # x is the time before now (the phase plot's is q)


@dataclass(frozen=True)
class ChartRow:
    """A chart of the Plots tab: its folder `title`, its plots, what its Signals fold offers, how it is drawn."""

    key: str
    title: str
    plots: tuple[PlotSpec, ...]
    draw: Draw
    choices: tuple[tuple[str, str], ...] = ()  # (key, label) the Signals fold offers
    heading: str = ""  # markdown above the plots
    note: bool = False  # a markdown line under the plots (the sensor model's)
    controls: Callable[[Any, Any], None] | None = None  # (Plots, gui): inputs above the plots


def chart_table(n_joints: int) -> tuple[ChartRow, ...]:
    """The page's own charts in their default order."""
    band = f"{HEADROOM_BAND_NP:g}"
    torque = tuple(line(f"τ{i + 1}", COLORS[i % len(COLORS)], width=1) for i in range(n_joints))
    limit = line("+limit", "#888888", width=1, dash=(4.0, 4.0))
    return (
        ChartRow(
            "force",
            "Force error",
            (
                PlotSpec(
                    "force",
                    (
                        line("F̂ − F (N)", COLORS[3]),
                        line("twin arm (N)", TWIN_COLOR, dash=(5.0, 3.0), show=False),
                        marker_series(),
                        line("previous run (N)", PREVIOUS_COLOR, width=1),
                    ),
                    "F̂ − F (N)",
                    (-draws.FORCE_RANGE_N, draws.FORCE_RANGE_N),
                    signals=("error", "twin", None, "previous"),
                    title=draws.FORCE_TITLE,
                ),
                PlotSpec(
                    "rate",
                    (
                        line("h (Np)", COLORS[6]),
                        line("σ (1/s)", COLORS[5], width=1),
                        line("0", "#888888", width=1, dash=(1.0, 3.0)),
                        line(f"h +{band}: keeps contact above", COLORS[6], width=1, dash=(4.0, 4.0)),
                        line(f"h −{band}: lifts off below", COLORS[6], width=1, dash=(4.0, 4.0)),
                        marker_series(),
                    ),
                    "h (Np) · σ (1/s)",
                    (-draws.RATE_RANGE_PER_S, draws.RATE_RANGE_PER_S),
                    title=draws.RATE_TITLE,
                    aspect=draws.RATE_ASPECT,
                    ticks=draws.RATE_TICKS,
                    shown_by="rate",
                ),
            ),
            draws.draw_force,
            (("error", "F̂ − F"), ("twin", "twin arm"), ("previous", "previous run"), ("rate", "margin plot (h, σ)")),
            note=True,
        ),
        ChartRow(
            "coupling",
            "Coupling W",
            tuple(
                PlotSpec(
                    name,
                    (line(f"{name} ({unit})", color), marker_series()),
                    f"{name} ({unit})",
                    (0.0, 1.0),
                    aspect=2.6,
                    padding=(10, 12, 0, 0),
                    top_tick=True,
                    x_label="",  # three small plots: one x label is enough
                    shown_by=name,
                )
                for name, unit, color in draws.W_SERIES
            ),
            draws.draw_coupling,
            tuple((name, name) for name, _, _ in draws.W_SERIES),
            heading=f"**{draws.COUPLING_TITLE}**",
        ),
        ChartRow(
            "torque",
            "Torques",
            (
                PlotSpec(
                    "torque",
                    (*torque, limit, {**limit, "label": "−limit"}, marker_series()),
                    "τ / τmax (%)",
                    (-draws.TORQUE_RANGE_PCT, draws.TORQUE_RANGE_PCT),
                    signals=(*(f"tau_{i + 1}" for i in range(n_joints)), "limits", "limits", None),
                    title="Torques / limits (%)",
                ),
            ),
            draws.draw_torque,
            (*((f"tau_{i + 1}", f"τ{i + 1}") for i in range(n_joints)), ("limits", "±limit")),
        ),
        ChartRow(
            "phase",
            "Joint phase",
            (
                PlotSpec(
                    "phase",
                    PHASE_SERIES,
                    "q̇ (rad/s)",
                    (-1.0, 1.0),
                    signals=(None, "speed_limits", "speed_limits", "zones", "zones", "zones"),
                    title="Joint phase (q, q̇)",
                    aspect=1.5,
                    x_label="q (rad)",
                    timed=False,
                ),
            ),
            draw_phase,
            (("speed_limits", "±q̇max"), ("zones", "limit, d_s, d_i")),
            controls=phase_controls,
        ),
        ChartRow(
            "deflection",
            "Deflection",
            (
                PlotSpec(
                    "deflection",
                    (
                        line("TCP (mm)", COLORS[0]),
                        line("elbow (mm)", COLORS[2]),
                        marker_series(),
                        line("TCP, previous run (mm)", PREVIOUS_COLOR, width=1),
                    ),
                    "deflection (mm)",
                    (0.0, draws.DEFLECTION_RANGE_MM),
                    signals=("tcp", "elbow", None, "previous"),
                    title="Deflection from the start pose (mm)",
                ),
            ),
            draws.draw_deflection,
            (("tcp", "TCP"), ("elbow", "elbow"), ("previous", "previous run")),
        ),
        ChartRow(
            "rtf",
            "Real-time factor",
            (
                PlotSpec(
                    "rtf",
                    (line("real-time factor", COLORS[5]),),
                    "× real time",
                    (0.0, draws.RTF_RANGE),
                    title="Real-time factor",
                    aspect=3.0,
                ),
            ),
            draws.draw_rtf,
        ),
    )


def preset_row(chart: Chart) -> ChartRow:
    """The row of a chart a preset brings (`app.scenarios.Chart`): its signals against time, each choosable."""
    keys = tuple(signal for signal, _ in chart.series)
    return ChartRow(
        chart.key,
        chart.title,
        (
            PlotSpec(
                chart.key,
                (*(line(label, COLORS[i % len(COLORS)]) for i, (_, label) in enumerate(chart.series)), marker_series()),
                chart.y_label,
                chart.y_range,
                signals=(*keys, None),
                title=chart.title,
            ),
        ),
        functools.partial(draws.draw_preset_chart, key=chart.key, signals=keys, y_range=chart.y_range),
        tuple(chart.series),
    )


def signal_specs(n_joints: int) -> dict[str, tuple[tuple[str, str], ...]]:
    """The choosable series of each chart of the page's own (charts with one series have none)."""
    return {row.key: row.choices for row in chart_table(n_joints) if row.choices}


def plot_options(spec: PlotSpec, y: tuple[float, float], window_s: float) -> tuple[dict, tuple[uplot.Axis, ...]]:
    """(scales, axes) of a plot on the y range `y`, its x the last `window_s` seconds (the phase plot's: q)."""
    x = (-window_s, 0.0) if spec.timed else (-1.0, 1.0)
    scales = {"x": {"time": False, "auto": False, "range": x}, "y": {"auto": False, "range": y}}
    return scales, (x_axis(spec.x_label), y_axis(spec.y_label, *y, spec.ticks, top=spec.top_tick))


def add_plot(gui: Any, spec: PlotSpec, window_s: float) -> Any:
    """The uPlot of `spec` in the current folder of `gui`, empty, on its y range before any widening."""
    x_column = {"label": X_LABEL} if spec.timed else {"label": spec.x_label, "sorted": 0}
    scales, axes = plot_options(spec, spec.y_range, window_s)
    return gui.add_uplot(
        empty(len(spec.series) + 1),
        (x_column, *spec.series),
        title=spec.title or None,
        scales=scales,
        axes=axes,
        legend=LEGEND,
        aspect=spec.aspect,
        padding=spec.padding,
    )


def add_signal_boxes(
    gui: Any, row: ChartRow, shown: Callable[[str, str], bool], changed: Callable[[str, str, object], None]
) -> dict[tuple[str, str], Any]:
    """The chart's Signals fold: a checkbox per series it offers, ticked as `shown` says, calling
    `changed(chart, series, value)`; (chart, series) → its checkbox."""
    boxes = {}
    with gui.add_folder("Signals", order=100.0, expand_by_default=False):
        for key, label in row.choices:
            box = gui.add_checkbox(label, shown(row.key, key), hint=f"Draw {label} in this plot")
            box.on_update(lambda event, c=row.key, k=key: changed(c, k, event.target.value))
            boxes[(row.key, key)] = box
    return boxes
