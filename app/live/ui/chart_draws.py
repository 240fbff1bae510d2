"""How each chart of the table (`app.live.ui.charts`) is drawn from one redraw's `Window` of samples.

Force error along the force axis (the twin's dashed when a twin runs) and the force loop's decay margin a
contact preset publishes ("margin_headroom_np", "margin_rate": the stroke headroom h, < 0 where a
disturbance at the noise floor reaches F̂ within the stroke, and the decay rate σ, < 0 where a mode grows);
W_f, W_a, W_d (Fig. 8 of [T]) in three small plots; joint torques as a share of their limits; the TCP's and
the elbow's deflection; the real-time factor; a preset's own chart. A draw function sets its plots' ranges
(`Plots.set_range`) and data; a hidden series is sent as NaN (`masked`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from app.live.frames import PEAK_SIGNALS
from app.live.ui.plot_axes import COLORS, nice_ceiling, stride, with_markers
from app.live.ui.plot_history import Marker, force_error, previous_at
from app.live.ui.signals import masked
from app.scenarios.stroke_outcomes import HEADROOM_BAND_NP

COUPLING_TITLE = "Coupling W_f, W_a, W_d [T22]"
FORCE_TITLE = "Force error F̂_z − F_z"
NO_SETPOINT_TITLE = "F̂_z − F_z: no force setpoint here, so this is minus the F/T reading"
NEUTRAL_FORCE_TITLE = "F̂_z − F_z"  # before a run has shown whether it has a force setpoint
NO_SETPOINT_AFTER_S = 0.1  # a run is said to have no force setpoint once this long has passed without one
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
DEFLECTION_RANGE_MM = 10.0
DEFLECTION_MIN_MM = 0.01  # the smallest deflection range: below 10 µm the arm is at rest


@dataclass(frozen=True)
class Window:
    """One redraw's samples: the plot data `plot`, the history's shown window `c` sent every `s`-th row
    at times `x` before `now`, the monitor's window `m`, and the phase markers."""

    plot: Any
    c: dict[str, np.ndarray]
    s: slice
    x: np.ndarray
    now: float
    m: dict[str, np.ndarray]
    markers: list[Marker]


def _top(*values: np.ndarray) -> float:
    """The largest |value| among the finite ones (0 for none)."""
    finite = [np.abs(v[np.isfinite(v)]) for v in values]
    return max((float(f.max()) for f in finite if f.size), default=0.0)


def draw_force(p: Any, w: Window) -> None:
    """Force error (main, twin, previous run) and the margin plot below it."""
    c, s, x = w.c, w.s, w.x
    twin = c.get("twin_force_error_n")
    p.set_present("force", "twin", twin is not None and bool(np.any(np.isfinite(twin))))
    shown = p.signals.shown
    err = masked(force_error(c), shown("force", "error"))
    twin = masked(twin, shown("force", "twin")) if p.present("force", "twin") and twin is not None else None
    hi = nice_ceiling(1.1 * _top(err, *(() if twin is None else (twin,))), FORCE_RANGE_N)
    p.set_range("force", (-hi, hi))
    twin_y = twin[s] if twin is not None else np.zeros(len(x))
    prev = masked(previous_at(p.previous, "force_error", c["t"][s]), shown("force", "previous"))
    handle = p.handles["force"]
    handle.data = with_markers(x, [err[s], twin_y], w.markers, w.now, -hi, hi, after=[prev])
    t = c["t"][np.isfinite(c["t"])]
    span = float(t[-1] - t[0]) if t.size else 0.0
    if np.any(c["Fd_z"] != 0.0):
        title = FORCE_TITLE
    else:  # a run paused at its start has not shown its setpoint yet: say nothing about it
        title = NO_SETPOINT_TITLE if span >= NO_SETPOINT_AFTER_S else NEUTRAL_FORCE_TITLE
    if handle.title != title:
        handle.title = title
    _draw_rate(p, w)


def _draw_rate(p: Any, w: Window) -> None:
    """The live margin: the stroke headroom h (from the σ samples of the current stroke) and σ (every 0.1 s
    of simulated time from the logged step's posture); all NaN in a preset without them."""
    c, s, x = w.c, w.s, w.x
    nan = np.full(len(c["t"]), np.nan)
    rate, headroom = c.get("margin_rate", nan), c.get("margin_headroom_np", nan)
    top = _top(rate, headroom)
    hi = nice_ceiling(1.1 * top, RATE_RANGE_PER_S) if top > 0 else RATE_RANGE_PER_S
    p.set_range("rate", (-hi, hi))
    # only the sign outside the band is a prediction; drawn where the preset has a headroom
    band = np.full(len(x), HEADROOM_BAND_NP if np.any(np.isfinite(headroom)) else np.nan)
    p.handles["rate"].data = with_markers(
        x, [headroom[s], rate[s], np.zeros(len(x)), band, -band], w.markers, w.now, -hi, hi
    )


def draw_torque(p: Any, w: Window) -> None:
    """Each joint's torque as a share of its limit, with the ±100 % lines."""
    ratio = [
        masked(100.0 * w.c[f"tau_{i + 1}"][w.s] / w.plot.tau_max[i], p.signals.shown("torque", f"tau_{i + 1}"))
        for i in range(p.n)
    ]
    top = _top(*ratio)
    hi = nice_ceiling(1.05 * top, TORQUE_RANGE_PCT) if top > TORQUE_RANGE_PCT else TORQUE_RANGE_PCT
    p.set_range("torque", (-hi, hi))
    ones = np.full(len(w.x), 100.0)
    p.handles["torque"].data = with_markers(w.x, [*ratio, ones, -ones], w.markers, w.now, -hi, hi)


def deflection_range(top: float) -> tuple[float, float]:
    """(0, hi) for deflections up to `top` mm: the 10 mm range, widened in 1-2-5 steps, and for small ones
    a finer 1-2-5 range of their own decade, never below DEFLECTION_MIN_MM (ticks stay distinct)."""
    if not top > DEFLECTION_MIN_MM:
        return (0.0, DEFLECTION_MIN_MM)
    if top < 0.5 * DEFLECTION_RANGE_MM:
        return (0.0, nice_ceiling(1.1 * top, max(DEFLECTION_MIN_MM, 10.0 ** math.floor(math.log10(top)))))
    return (0.0, nice_ceiling(1.1 * top, DEFLECTION_RANGE_MM))


def draw_deflection(p: Any, w: Window) -> None:
    """TCP and elbow distance from their start (signals "tcp_dev_mm", "elbow_dev_mm"), when logged."""
    c, s = w.c, w.s
    tcp_key, elbow_key = PEAK_SIGNALS  # the log and the chart keep their peaks (`frames.PEAK_SIGNALS`)
    if tcp_key not in c:
        return
    shown = p.signals.shown
    tcp = masked(c[tcp_key][s], shown("deflection", "tcp"))
    elbow = c[elbow_key][s] if elbow_key in c else np.full(len(w.x), np.nan)
    elbow = masked(elbow, shown("deflection", "elbow"))
    lo, hi = deflection_range(_top(tcp, elbow))
    p.set_range("deflection", (lo, hi))
    prev = masked(previous_at(p.previous, tcp_key, c["t"][s]), shown("deflection", "previous"))
    p.handles["deflection"].data = with_markers(w.x, [tcp, elbow], w.markers, w.now, lo, hi, after=[prev])


def _monitor(w: Window) -> tuple[dict[str, np.ndarray], np.ndarray] | None:
    """The monitor's window sent every few samples and its times before now (None: too few samples)."""
    mt = w.m.get("t", np.zeros(0))
    if len(mt) < 2:
        return None
    ms = slice(None, None, stride(len(mt)))
    return {k: v[ms] for k, v in w.m.items()}, mt[ms] - w.now


def draw_coupling(p: Any, w: Window) -> None:
    """W_f, W_a, W_d from the monitor series, each on (0, a 1-2-5 ceiling of its own decade)."""
    monitor = _monitor(w)
    if monitor is None:
        return
    m, mx = monitor
    singular = not np.any(np.isfinite(w.m["W_a"][-5:]))
    heading = f"**{COUPLING_TITLE}{': not shown near a singularity' if singular else ''}**"
    if p.headings["coupling"].content != heading:
        p.headings["coupling"].content = heading
    for name, _, _ in W_SERIES:
        values = m[name]
        top = float(np.nanmax(values)) if np.any(np.isfinite(values)) else 0.0
        hi = nice_ceiling(1.1 * top, 10.0 ** math.floor(math.log10(top)) if top > 0 else 1.0)
        p.set_range(name, (0.0, hi))
        p.handles[name].data = with_markers(mx, [values], w.markers, w.now, 0.0, hi)


def draw_rtf(p: Any, w: Window) -> None:
    """The real-time factor from the monitor series."""
    monitor = _monitor(w)
    if monitor is None:
        return
    m, mx = monitor
    rtf = m["rtf"]
    top = float(np.nanmax(rtf)) if np.any(np.isfinite(rtf)) else 0.0
    p.set_range("rtf", (0.0, nice_ceiling(1.1 * top, RTF_RANGE) if top > RTF_RANGE else RTF_RANGE))
    p.handles["rtf"].data = (mx, rtf)


def draw_preset_chart(p: Any, w: Window, key: str, signals: tuple[str, ...], y_range: tuple[float, float]) -> None:
    """A preset's own chart `key` (`charts.preset_row`): its logged `signals`, on `y_range` widened in 1-2-5
    steps (symmetric about 0 when that range is)."""
    lo0, hi0 = y_range
    nan = np.full(len(w.x), np.nan)
    ys = [masked(w.c[k][w.s], p.signals.shown(key, k)) if k in w.c else nan for k in signals]
    top = _top(*ys)
    hi = nice_ceiling(1.1 * top, hi0) if top > hi0 else hi0
    lo = -hi if lo0 < 0 else lo0
    p.set_range(key, (lo, hi))
    p.handles[key].data = with_markers(w.x, ys, w.markers, w.now, lo, hi)


def sensor_note(settings: Any) -> str:
    """The line under the force plot: whether the F/T model's sinusoid and noise are in the reading."""
    sensor = getattr(settings, "groups", {}).get("sensor")
    if sensor is not None and getattr(sensor, "noise", False):
        amp, hz = float(sensor.sine_amplitude_n), float(sensor.sine_hz)
        return (
            f"*Sensor model on: a {hz:g} Hz, ±{amp:g} N sinusoid and noise ({float(sensor.force_noise_var):g} N²) "
            "are in the F/T reading — not the arm's motion (Tune → Sensor noise off removes them).*"
        )
    return "*Sensor model off: the F/T reading is the ideal filtered force.*" if sensor is not None else ""
