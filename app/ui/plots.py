"""Live plots (viser uPlot), refreshed at 10 Hz over the last 10 s of simulation.

Force error along the force axis; W_f, W_a, W_d (Fig. 8 of [T]); the (q, q̇) phase of one joint
with its velocity limits, the plot's x range being the joint's position range (Fig. 2–4 of [C]);
joint torques as a share of their limits; the real-time factor. The data come from the loop's
`PlotData`; nothing here touches the session.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import viser
import viser.uplot as uplot

from app.loop import PlotData

COLORS = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2")
LIMIT = {"stroke": "#888888", "width": 1, "dash": (4.0, 4.0)}
TIME_X: dict[str, uplot.Scale] = {"x": {"time": False}}
COUPLING_TITLE = "Coupling W_f, W_a, W_d [T22]"
TWIN_COLOR = "#ff9f1c"  # the twin arm, here and in the 3D scene
FORCE_TITLE = "Force error F̂_z − F_z"
NO_SETPOINT_TITLE = "F̂_z − F_z: no force setpoint here, so this is minus the F/T reading"


def _series(label: str, color: str, **extra: Any) -> uplot.Series:
    out: dict[str, Any] = {"label": label, "stroke": color, "width": 1.5}
    out.update(extra)
    return out  # type: ignore[return-value]


def _empty(n: int) -> tuple[np.ndarray, ...]:
    return tuple(np.zeros(2) for _ in range(n))


class Plots:
    """The Plots folder and its five charts."""

    def __init__(self, server: viser.ViserServer, n_joints: int = 7, order: float | None = None):
        self.n = n_joints
        gui = server.gui
        with gui.add_folder("Plots", order=order, expand_by_default=True):
            gui.add_markdown("Last 10 s of simulated time, refreshed 10 times a second.")
            self.force = gui.add_uplot(
                _empty(3),
                (
                    {"label": "t (s)"},
                    _series("F̂ − F (N)", COLORS[3]),
                    _series("twin arm (N)", TWIN_COLOR, dash=(5.0, 3.0)),
                ),
                title=FORCE_TITLE,
                scales=TIME_X,
                aspect=2.0,
            )
            self.coupling = gui.add_uplot(
                _empty(4),
                (
                    {"label": "t (s)"},
                    _series("W_f", COLORS[0], scale="wf"),
                    _series("W_a", COLORS[1]),
                    _series("W_d", COLORS[2], scale="wd"),
                ),
                title=COUPLING_TITLE,
                scales=TIME_X,
                axes=(
                    {},
                    {"scale": "y", "stroke": COLORS[1], "label": "W_a (kg²)"},
                    {"scale": "wf", "side": 1, "stroke": COLORS[0], "grid": {"show": False}, "label": "W_f (1/kg²)"},
                    {"scale": "wd", "side": 1, "stroke": COLORS[2], "grid": {"show": False}, "label": "W_d"},
                ),
                aspect=2.0,
            )
            self.joint: Any = gui.add_dropdown(
                "Phase plot joint", tuple(str(i + 1) for i in range(n_joints)), initial_value="4"
            )
            self.phase = gui.add_uplot(
                _empty(4),
                (
                    {"label": "q (rad)", "sorted": 0},
                    _series("q̇ (rad/s)", COLORS[4], points={"show": False}),
                    _series("+q̇max", "#888888", width=1, dash=(4.0, 4.0)),
                    _series("−q̇max", "#888888", width=1, dash=(4.0, 4.0)),
                ),
                title="Joint phase (q, q̇); x range = position limits",
                scales={"x": {"time": False, "auto": False, "range": (-1.0, 1.0)}},
                aspect=1.5,
            )
            self.torque = gui.add_uplot(
                _empty(self.n + 3),
                (
                    {"label": "t (s)"},
                    *(_series(f"τ{i + 1}", COLORS[i % len(COLORS)], width=1) for i in range(self.n)),
                    _series("+limit", "#888888", width=1, dash=(4.0, 4.0)),
                    _series("−limit", "#888888", width=1, dash=(4.0, 4.0)),
                ),
                title="Torques / limits (%)",
                scales=TIME_X,
                aspect=2.0,
            )
            self.rtf = gui.add_uplot(
                _empty(2),
                ({"label": "t (s)"}, _series("real-time factor", COLORS[5])),
                title="Real-time factor",
                scales={"x": {"time": False}, "y": {"auto": False, "range": (0.0, 1.2)}},
                aspect=3.0,
            )
        self._phase_range: tuple[float, float, float] | None = None

    def focus(self, joint: int | None) -> None:
        """Show joint `joint` (0-based) in the phase plot, e.g. the one a preset is about; None keeps it."""
        if joint is not None and 0 <= joint < self.n and self.joint.value != str(joint + 1):
            self.joint.value = str(joint + 1)

    def update(self, plot: PlotData) -> None:
        """Push new data to the charts (one message per chart)."""
        c = plot.columns
        t = c.get("t", np.zeros(0))
        if len(t) >= 2:
            err = c.get("force_error_n")
            if err is None or np.all(np.isnan(err)):
                err = c["Fd_z"] - c["F_z"]
            twin = c.get("twin_force_error_n")
            self.force.data = (t, err, twin if twin is not None else np.full(len(t), np.nan))
            title = FORCE_TITLE if np.any(c["Fd_z"] != 0.0) else NO_SETPOINT_TITLE
            if self.force.title != title:
                self.force.title = title
            ratio = [100.0 * c[f"tau_{i + 1}"] / plot.tau_max[i] for i in range(self.n)]
            ones = np.full_like(t, 100.0)
            self.torque.data = (t, *ratio, ones, -ones)
            self._update_phase(plot)
        m = plot.monitor
        if len(m.get("t", ())) >= 2:
            self.coupling.data = (m["t"], m["W_f"], m["W_a"], m["W_d"])
            self.rtf.data = (m["t"], m["rtf"])
            title = COUPLING_TITLE if np.isfinite(m["W_a"][-1]) else COUPLING_TITLE + ": not shown near a singularity"
            if self.coupling.title != title:
                self.coupling.title = title

    def _update_phase(self, plot: PlotData) -> None:
        j = int(self.joint.value) - 1
        q, dq = plot.columns[f"q_{j + 1}"], plot.columns[f"dq_{j + 1}"]
        lo, hi = float(plot.q_lower[j]), float(plot.q_upper[j])
        if not (np.isfinite(lo) and np.isfinite(hi)) or hi - lo > 4 * np.pi:  # endless joint: follow the data
            lo, hi = float(np.min(q)) - 0.1, float(np.max(q)) + 0.1
        vlim = float(plot.dq_max[j])
        key = (lo, hi, vlim)
        if self._phase_range != key:
            self._phase_range = key
            self.phase.scales = {
                "x": {"time": False, "auto": False, "range": (lo, hi)},
                "y": {"auto": False, "range": (-1.15 * vlim, 1.15 * vlim)},
            }
            self.phase.title = f"Joint {j + 1} phase (q, q̇); x range = limits [{lo:.2f}, {hi:.2f}] rad"
        # two extra points at the position limits carry the velocity-limit lines across the whole
        # width; the trajectory has no value there (NaN is not drawn)
        x = np.concatenate([q, [lo, hi]])
        traj = np.concatenate([dq, [np.nan, np.nan]])
        vmax = np.full_like(x, vlim)
        self.phase.data = (x, traj, vmax, -vmax)
