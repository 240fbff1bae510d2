"""The charts' axes and series options for viser's uPlot: 1-2-5 ranges, explicit ticks and their texts,
series styles, and the phase markers drawn into a chart's data.

Every y range is fixed per signal and widens in 1-2-5 steps when the data leave it (`nice_ceiling`);
x is the time before now, so neither axis depends on uPlot's auto-ranging. The ticks are sent with
their texts (`y_axis`): the page writes exactly those, with as many decimals as the step needs, so
ticks at any scale read as distinct numbers (uPlot's own format stops at three decimals).
"""

from __future__ import annotations

import math
import threading
import traceback
from collections.abc import Callable
from typing import Any

import numpy as np
import viser.uplot as uplot

from app.core.steplog import largest_magnitude
from app.live.ui.plot_history import Marker

COLORS = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2")
MARKER_COLOR = "#7a7a7a"
TWIN_COLOR = "#ff9f1c"  # the twin arm, here and in the 3D scene
PREVIOUS_COLOR = "rgba(90, 90, 90, 0.35)"  # the run before this one, faint, for A/B
X_LABEL = "t − now (s)"
LEGEND = {"live": False}  # labels only: no "--" / "NaN" values beside them
MAX_POINTS = 600  # per series sent to the browser, whatever the window
MAX_DECIMALS = 6  # a tick text has at most this many decimals


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
    """A tick's text: thousands grouped, as many decimals as `step` needs (at most MAX_DECIMALS), no
    trailing zeros; every multiple of `step` gets a text of its own."""
    decimals = min(MAX_DECIMALS, max(0, -math.floor(math.log10(step) + 1e-9))) if step < 1 else 0
    text = f"{value:,.{decimals}f}"
    if "." in text:
        text = text.rstrip("0").rstrip(".")
    return "0" if text in ("-0", "") else text


def y_axis(label: str, lo: float, hi: float, ticks: int = 4, top: bool = False) -> uplot.Axis:
    """A y axis with its label (with the unit), explicit ticks inside (lo, hi) and their texts, as wide as
    its longest tick needs (uPlot's default width clipped "10,000" to "0,000"); `ticks`: about how many
    intervals (fewer for a short plot); `top`: a tick at the top edge too (a chart without a title, where
    none would hide under it)."""
    step = tick_step(hi - lo, ticks)
    first = math.ceil(lo / step - 1e-9) * step
    splits = [first + i * step for i in range(int((hi - first) / step + 1e-9) + 1)]
    edge = hi + 1e-9 * step if top else hi - 0.04 * (hi - lo)
    splits = [0.0 if abs(v) < 1e-9 * step else v for v in splits if v < edge]
    texts = tuple(tick_text(v, step) for v in splits)
    width = 16 + 7 * max((len(t) for t in texts), default=1)
    axis = {"label": label, "labelSize": 18, "splits": tuple(splits), "values": texts, "size": width}
    return axis  # type: ignore[return-value]


def x_axis(label: str = X_LABEL) -> uplot.Axis:
    """The x axis with its label."""
    return {"label": label, "labelSize": 16}


def line(label: str, color: str, **extra: Any) -> uplot.Series:
    """A series drawn as a line joining across gaps."""
    out: dict[str, Any] = {"label": label, "stroke": color, "width": 1.5, "spanGaps": True}
    out.update(extra)
    return out  # type: ignore[return-value]


def marker_series() -> uplot.Series:
    """The dashed series that carries a chart's phase markers (`with_markers`)."""
    return {"label": "phase", "stroke": MARKER_COLOR, "width": 1, "dash": (2.0, 3.0), "spanGaps": False}  # type: ignore[typeddict-item]


def empty(n: int) -> tuple[np.ndarray, ...]:
    """Placeholder data of `n` columns."""
    return tuple(np.zeros(2) for _ in range(n))


def stride(n: int) -> int:
    """Every how many samples of `n` one is sent (at most MAX_POINTS)."""
    return max(1, math.ceil(n / MAX_POINTS))


def peaks_kept(columns: dict[str, np.ndarray], names: tuple[str, ...], every: int) -> dict[str, np.ndarray]:
    """`columns` with each of `names` changed so that its rows sent (every `every`-th from the first) hold
    the value of largest magnitude over the rows each stands for (itself up to the next one sent): a
    scope's peak detect, so a chart thinned for the browser still reaches the peak its readout states."""
    if every <= 1:
        return columns
    out = dict(columns)
    for name in names:
        values = columns.get(name)
        if values is None or len(values) == 0:
            continue
        sent = np.arange(0, len(values), every)
        span = np.minimum(sent[:, None] + np.arange(every)[None, :], len(values) - 1)
        kept = values.copy()
        kept[sent] = largest_magnitude(values[span])
        out[name] = kept
    return out


def with_markers(
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


class Later:
    """Calls `fn` after given delays on timer threads (a chart's axes sent again once the page has laid
    it out), until `stop`; a failing call prints its traceback and the next one tries again."""

    def __init__(self, fn: Callable[[], None]):
        self.fn = fn
        self._timers: list[threading.Timer] = []
        self._stopped = False

    def after(self, *delays_s: float) -> None:
        """`fn()` after each of `delays_s` seconds."""
        self._timers = [t for t in self._timers if t.is_alive()]
        for delay in delays_s:
            if self._stopped:
                return
            timer = threading.Timer(delay, self._call)
            timer.daemon = True
            self._timers.append(timer)
            timer.start()

    def stop(self) -> None:
        """Cancel every pending call; none is made from now on."""
        self._stopped = True
        for timer in self._timers:
            timer.cancel()

    def _call(self) -> None:
        if self._stopped:
            return
        try:
            self.fn()
        except Exception:  # a chart being rebuilt meanwhile: the next call fixes it
            traceback.print_exc()
