"""Layers drawn on an experiment's maps from its own model, not from the sweep's runs.

Polish: along the start-swivel axis, the W_a basins of the self-motion loop at the start pose
(`polish_report.scan_at_start`, DESIGN §8): a solid line at each feasible local minimum of W_a
(where the gradient flow of [T15] ends), a dashed line at each ridge between two minima (the
basin border) and grey where the loop leaves the joint limits.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from app.sweep.grid import Axis

SWIVEL_AXES = ("swivel", "hold_swivel")


@lru_cache(maxsize=1)
def wa_basins() -> dict:
    """W_a minima and ridges (deg) and infeasible swivel bands along the loop at the start pose."""
    from app.experiments.polish_report import scan_at_start

    data = scan_at_start()["data"]
    psi, w, feas = data["swivel_deg"], data["W_a"], data["feasible"]
    n = len(psi)
    minima, ridges = [], []
    for i in range(n):
        a, b = w[i - 1], w[(i + 1) % n]
        if feas[i] and w[i] < a and w[i] < b:
            minima.append(float(psi[i]))
        if feas[i] and feas[i - 1] and feas[(i + 1) % n] and w[i] > a and w[i] > b:
            ridges.append(float(psi[i]))
    step = float(np.median(np.diff(psi))) if n > 1 else 0.0
    infeasible = [(float(p) - step / 2, float(p) + step / 2) for p, ok in zip(psi, feas, strict=True) if not ok]
    return {"minima": minima, "ridges": ridges, "infeasible": infeasible}


def polish_overlay(ax, axes: list[Axis], records: list[dict]) -> None:
    """W_a basins on a map whose x axis is a swivel angle (nothing otherwise)."""
    x_axis = axes[0]
    if x_axis.name not in SWIVEL_AXES or len(x_axis) < 2:
        return
    values = np.asarray(x_axis.values, dtype=float)
    index = np.arange(len(values), dtype=float)

    def to_x(deg: float) -> float | None:
        if not values[0] <= deg <= values[-1]:
            return None
        return float(np.interp(deg, values, index))

    basins = wa_basins()
    for lo, hi in basins["infeasible"]:
        a, b = to_x(max(lo, values[0])), to_x(min(hi, values[-1]))
        if a is not None and b is not None:
            ax.axvspan(a, b, color="0.5", alpha=0.25, lw=0)
    for k, deg in enumerate(basins["minima"]):
        x = to_x(deg)
        if x is not None:
            ax.axvline(x, color="white", lw=1.6, label="W_a minimum (basin)" if k == 0 else None)
    for k, deg in enumerate(basins["ridges"]):
        x = to_x(deg)
        if x is not None:
            ax.axvline(x, color="white", lw=1.2, ls="--", label="W_a ridge (basin border)" if k == 0 else None)
    if basins["minima"] or basins["ridges"]:
        ax.legend(fontsize=6, loc="upper right", framealpha=0.6)


def polish_notes(axes: list[Axis], records: list[dict]) -> str:
    """What the overlay shows, with its numbers, and where the runs ended along the loop."""
    basins = wa_basins()
    fmt = ", ".join
    text = (
        "<p>Self-motion loop at the polish start pose (swivel scan, 2° steps): W_a has feasible local minima "
        f"at {fmt(f'{d:+.0f}°' for d in basins['minima']) or 'none'} (solid lines: the basins the W_a flow "
        f"ends in) and ridges at {fmt(f'{d:+.0f}°' for d in basins['ridges']) or 'none'} (dashed: basin "
        "borders); grey: outside the joint limits. The linearised margin's predicted boundary and the "
        "planned path are not drawn (not available in this version).</p>"
    )
    ended = [
        r["metrics"].get("converged_swivel_deg")
        for r in records
        if r.get("status") == "ok" and r.get("metrics") and r["metrics"].get("converged_swivel_deg") is not None
    ]
    if ended and basins["minima"]:
        mins = np.asarray(basins["minima"])
        nearest = [float(mins[np.argmin(np.abs((mins - e + 180.0) % 360.0 - 180.0))]) for e in ended]
        counts = {m: nearest.count(m) for m in basins["minima"]}
        text += (
            "<p>Where the runs' postures were when the trajectory started (nearest W_a minimum): "
            + fmt(f"{m:+.0f}°: {c} run(s)" for m, c in counts.items())
            + ".</p>"
        )
    return text
