"""The phase chart: the (q, q̇) portrait of one joint with its velocity limits, its position limits and the
damper's d_s and d_i lines (Fig. 2–4 of [C]); x is the joint's position range, or zoomed on its nearer
limit: the last degrees where the damper acts."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from app.live.ui.plot_axes import COLORS, line, stride, x_axis, y_axis

LIMIT_COLOR, DS_COLOR, DI_COLOR = "#555555", "#d62728", "#ff9f1c"
PHASE_MARGIN = 0.06  # the phase plot's x range reaches this share of the joint's range beyond each limit
# zoomed on the nearer limit, the phase plot shows from this many d_i before it to this many d_s beyond: the
# last degrees where the damper acts, d_s several times wider than in the whole range
PHASE_ZOOM_DI = 1.25
PHASE_ZOOM_DS = 1.5
PHASE_SERIES = (
    line("q̇ (rad/s)", COLORS[4], points={"show": False}, spanGaps=False),
    line("±q̇max", "#888888", width=1, dash=(4.0, 4.0)),
    line("−q̇max", "#888888", width=1, dash=(4.0, 4.0)),
    line("limit", LIMIT_COLOR, width=2, spanGaps=False),
    line("d_s", DS_COLOR, width=1, dash=(3.0, 3.0), spanGaps=False),
    line("d_i", DI_COLOR, width=1, dash=(6.0, 3.0), spanGaps=False),
)


def damper_fraction(settings: Callable[[], Any], field: str, default: float) -> float:
    """A field of the damper group in force (`settings()`: d_s, d_i as shares of the range), or `default`."""
    now = settings()
    damper = getattr(now, "groups", {}).get("damper") if now is not None else None
    value = getattr(damper, field, None)
    return float(value) if value is not None else default


def phase_controls(p: Any, gui: Any) -> None:
    """The joint dropdown and the zoom switch above the phase plot (`p.joint`, `p.phase_zoom`): a change
    draws the plots again."""
    p.joint = gui.add_dropdown("Phase plot joint", tuple(str(i + 1) for i in range(p.n)), initial_value="4")
    p.phase_zoom = gui.add_checkbox(
        "Zoom on the limit",
        False,
        hint="Show the last degrees before the joint's nearer limit: the limit, d_s and d_i apart",
    )
    p.joint.on_update(lambda _: p.redraw())
    p.phase_zoom.on_update(lambda _: p.redraw())


def draw_phase(p: Any, w: Any) -> None:
    """The phase portrait of the chosen joint from the redraw's window (`chart_draws.Window`)."""
    plot, c = w.plot, w.c
    j = int(p.joint.value) - 1
    q, dq = c[f"q_{j + 1}"], c[f"dq_{j + 1}"]
    s = slice(None, None, stride(len(q)))
    q, dq = q[s], dq[s]
    lo, hi = float(plot.q_lower[j]), float(plot.q_upper[j])
    limited = np.isfinite(lo) and np.isfinite(hi) and hi - lo <= 4 * np.pi
    if not limited:  # endless joint: follow the data
        lo, hi = float(np.nanmin(q)) - 0.1, float(np.nanmax(q)) + 0.1
    vlim = float(plot.dq_max[j])
    top = 1.15 * vlim
    pad = PHASE_MARGIN * (hi - lo)  # the stop is inside the plot, not on its edge
    d_s = p.damper_fraction("safety_fraction", math.nan) * (hi - lo) if limited else math.nan
    d_i = p.damper_fraction("influence_fraction", math.nan) * (hi - lo) if limited else math.nan
    x_range = (lo - pad, hi + pad)
    zoom = None  # the limit zoomed on (its sign: +1 upper, −1 lower)
    finite_q = q[np.isfinite(q)]
    if p.phase_zoom.value and limited and math.isfinite(d_s) and math.isfinite(d_i) and finite_q.size:
        zoom = 1 if float(finite_q[-1]) >= 0.5 * (lo + hi) else -1
        limit = hi if zoom > 0 else lo
        near, beyond = limit - zoom * PHASE_ZOOM_DI * d_i, limit + zoom * PHASE_ZOOM_DS * d_s
        x_range = (min(near, beyond), max(near, beyond))
    phase = p.handles["phase"]
    # NaN-free (NaN != NaN would send the chart's options again at every redraw, rebuilding it)
    key = (*(v if math.isfinite(v) else None for v in (lo, hi, vlim, d_s, d_i)), j, zoom)
    if p.memo.get("phase_range") != key:
        p.memo["phase_range"] = key
        phase.scales = {
            "x": {"time": False, "auto": False, "range": x_range},
            "y": {"auto": False, "range": (-top, top)},
        }
        phase.axes = (x_axis("q (rad)"), y_axis("q̇ (rad/s)", -top, top))
        zones = " · d_s dotted red, d_i dashed orange" if math.isfinite(d_s) else ""
        where = (
            f", zoomed on the {'upper' if zoom > 0 else 'lower'} limit {hi if zoom > 0 else lo:.2f} rad"
            if zoom is not None
            else f": limits [{lo:.2f}, {hi:.2f}] rad"
        )
        phase.title = f"Joint {j + 1} phase (q, q̇){where}{zones}"
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
    phase.data = (np.array(xs), *(np.array(y) for y in ys))
