"""The readout line of the Plots tab: the figures docs/web-app.md quotes, over every logged step since
the reset where the loop keeps them running (else over the history's samples): the force-error STD per
stroke of a preset with strokes (main arm and twin), the falling joint's peak torque and how far it went
beyond d_s, a preset's own readouts in its own words (`Scenario.readout_text`), the run they were
measured on and the latest phase markers.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from app.live.ui.plot_history import Marker, force_error, segment_std


def _stroke_std(plot: Any, c: dict[str, np.ndarray]) -> tuple[dict[int, float], dict[int, float]]:
    """Force-error STD per stroke of the main arm and of the twin (on the twin's own strokes)."""
    if plot.segment_std is not None:  # every 1 ms step since the reset when the loop counted them
        main = plot.segment_std
    else:  # else the plotted samples
        main = segment_std({"segment": c["segment"], "v": force_error(c)}, "v", plot.segments)
    twin: dict[int, float] = {}
    if plot.twin_segment_std is not None:
        twin = plot.twin_segment_std
    elif "twin_force_error_n" in c:  # its zig-zag may run at other times
        twin_seg = c["twin_segment"] if "twin_segment" in c else c["segment"]
        twin = segment_std({"segment": twin_seg, "v": c["twin_force_error_n"]}, "v", plot.segments)
    return main, twin


def _fall(plot: Any, joint: int, damper_fraction: Callable[[str, float], float]) -> tuple[dict[str, float], str]:
    """The falling joint's peak |τ| and its deepest point beyond d_s, toward the limit it falls to (the
    Gen3's upper one, the Panda's lower one), in a coordinate s·q that grows toward that limit."""
    tau = plot.peak_abs_tau[joint] if plot.peak_abs_tau is not None else np.nan
    if not np.isfinite(tau):
        return {}, ""
    s = -1.0 if plot.fall_direction < 0 else 1.0
    deepest = plot.low_q if s < 0 else plot.peak_q
    q_deep = s * float(deepest[joint]) if deepest is not None else np.nan
    out = {"peak_torque_nm": float(tau)}
    hi, lo = float(plot.q_upper[joint]), float(plot.q_lower[joint])
    limit = s * (lo if s < 0 else hi)
    d_s = damper_fraction("safety_fraction", 0.01) * (hi - lo) if np.isfinite(hi - lo) else math.nan
    over = q_deep - (limit - d_s) if np.isfinite(q_deep) and math.isfinite(d_s) else math.nan
    text = f"Joint {joint + 1}: peak |τ| {float(tau):.1f} N m"
    if math.isfinite(over):
        out["overshoot_beyond_ds_rad"] = over
        text += f" · beyond d_s {max(over, 0.0) * 1e3:.1f} mrad"
    return out, text


def readouts(
    plot: Any,
    c: dict[str, np.ndarray],
    joint: int | None,
    damper_fraction: Callable[[str, float], float],
    markers: list[Marker],
) -> tuple[dict[str, float], list[str]]:
    """(figures by name, lines of text) of `plot` (the loop's `PlotData`) and the history's columns `c`;
    `joint`: the joint the preset is about, `damper_fraction(field, default)`: d_s, d_i in force."""
    out: dict[str, float] = {}
    lines: list[str] = []
    if "segment" in c and np.any(np.isfinite(c["segment"])):
        main, twin = _stroke_std(plot, c)
        out |= {f"force_error_std_S{k}": v for k, v in main.items()}
        out |= {f"twin_force_error_std_S{k}": v for k, v in twin.items()}
        if main:
            head = " · ".join(f"S{k} {v:.1f}" for k, v in main.items())
            lines.append(f"Force-error STD (N, over every step of each stroke since the reset): {head}")
            if twin:
                lines.append("twin: " + " · ".join(f"S{k} {v:.1f}" for k, v in twin.items()))
    if plot.fall_direction and joint is not None:
        figures, text = _fall(plot, joint, damper_fraction)
        out |= figures
        lines += [text] if text else []
    if plot.deflection:
        out |= plot.deflection
        lines += list(plot.readout_text)
    if lines and plot.run:  # the figures name the run they were measured on
        lines.insert(0, f"*Run:* {plot.run}")
    if markers:
        lines.append("Markers: " + " · ".join(f"{m.label} {m.t:.1f} s" for m in markers[-8:]))
    return out, lines
