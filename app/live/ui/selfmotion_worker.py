"""The self-motion scan (DESIGN §8) as a function a separate process can run.

Imports only numpy, Pinocchio and `control`: the scan process `app.live.ui.selfmotion` starts (spawned,
`app.live.workers.Worker`) does not load the web server. A scan traces the self-motion loop through a posture
(`control.coupling.swivel_scan`, ~0.1 s of Python) and finds where the [T15] flow settles and the
best posture inside the joint limits.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from control.coupling import Subspaces, flow_minimum, swivel_scan
from control.model import RobotModel

_MODELS: dict[str, RobotModel] = {}  # in the scan process: one RobotModel per URDF
# the scan process runs this much nicer than the server: when every core is busy, the 1 kHz loop and
# the browser go first and a scan waits (it is due about once a second and nobody waits for it)
SCAN_NICENESS = 10


@dataclass(frozen=True)
class Preview:
    """One scan of the self-motion loop for one objective (angles in degrees)."""

    objective: str  # "f", "a" or "d"
    swivel_deg: np.ndarray  # (k,) unwrapped from the current posture's swivel, increasing
    W: np.ndarray  # (k,) the objective along the loop
    feasible: np.ndarray  # (k,) bool: every joint inside its position limits
    q: np.ndarray  # (k, 7) postures along the loop
    flow: int  # index where the gradient flow from index 0 (the current posture) settles
    best: int | None  # index of the smallest W inside the limits, None if no sample is inside

    @property
    def name(self) -> str:
        return f"W_{self.objective}"

    def summary(self) -> str:
        """One line in words: now, where the flow settles, the best feasible posture."""
        name, deg = self.name, self.swivel_deg
        text = f"Now {name} = {self.W[0]:.3g} at {_deg(deg[0])}; the flow settles at {_deg(deg[self.flow])} "
        text += f"({name} = {self.W[self.flow]:.3g})"
        if self.best is None:
            return text + "; no posture on the loop is inside all joint limits."
        if self.best == self.flow:
            return text + ", which is also the best posture inside the joint limits."
        best = f"{_deg(deg[self.best])} ({name} = {self.W[self.best]:.3g})"
        return text + f"; the best inside the joint limits is {best}."


def _deg(value: float) -> str:
    wrapped = (float(value) + 180.0) % 360.0 - 180.0
    return f"{wrapped:+.0f}°"


def scan_preview(
    model: RobotModel, robot, q: np.ndarray, sub: Subspaces, objective: str, scale: np.ndarray | None = None
) -> Preview:
    """Trace the self-motion loop through q and find the flow's end and the best feasible posture;
    W in the task coordinates of `scale` (`control.coupling.task_scale`, the controller's units)."""
    scan = swivel_scan(model, np.asarray(q, dtype=float), sub, robot.q_lower, robot.q_upper, scale=scale)
    values = {"f": scan.W_f, "a": scan.W_a, "d": scan.W_d}[objective]
    feasible = np.asarray(scan.within_limits, dtype=bool)
    flow = flow_minimum(values, feasible, start=0, closed=scan.closed)
    inside = np.flatnonzero(feasible)
    best = int(inside[np.argmin(values[inside])]) if inside.size else None
    return Preview(objective, np.rad2deg(scan.swivel_rad), values, feasible, scan.q, flow, best)


def scan_in_worker(
    key: str,
    model: pin.Model,
    q_lower: np.ndarray,
    q_upper: np.ndarray,
    q: np.ndarray,
    force_axes: tuple[int, ...],
    objective: str,
    scale: np.ndarray | None = None,
) -> Preview:
    """`scan_preview` from picklable arguments (run in the scan process); `key` names the robot
    (its URDF path) so its `RobotModel` is built once per process."""
    robot_model = _MODELS.get(key)
    if robot_model is None:
        _MODELS.clear()
        robot_model = _MODELS[key] = RobotModel(model)
    limits = _Limits(np.asarray(q_lower, dtype=float), np.asarray(q_upper, dtype=float))
    return scan_preview(robot_model, limits, q, Subspaces.from_force_axes(force_axes), objective, scale)


@dataclass(frozen=True)
class _Limits:
    """The part of a `RobotDescription` a scan reads."""

    q_lower: np.ndarray
    q_upper: np.ndarray
