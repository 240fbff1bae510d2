"""A joint-space PD hold with gravity/Coriolis compensation: the simplest executor.

τ = h(q, q̇) + K_p (q_d − q) − K_d q̇. Used by scenarios that only need the arm held and as a
reference when the task-space executors are switched off.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from control.executor import ControlInputs, ControlOutput, StepView, TaskTarget
from control.gains import validate_non_negative
from control.model import Dynamics


@dataclass(frozen=True)
class JointHoldGains:
    """Joint stiffness (N m/rad) and damping (N m s/rad), one value for all joints."""

    stiffness: float = 400.0
    damping: float = 40.0

    def __post_init__(self) -> None:
        validate_non_negative(self)


class JointHold:
    """Holds the posture given at reset (or the target's `q_posture`)."""

    name = "joint-hold"

    def __init__(self, gains: JointHoldGains | None = None):
        self.gains = gains or JointHoldGains()
        self.q_hold: np.ndarray | None = None

    def reset(self, dyn: Dynamics, target: TaskTarget) -> None:
        self.q_hold = dyn.q.copy() if target.q_posture is None else np.array(target.q_posture)

    def configure(self, **changes: object) -> None:
        self.gains = replace(self.gains, **changes)  # type: ignore[arg-type]

    def step(self, dyn: Dynamics, inputs: ControlInputs) -> ControlOutput:
        q_d = inputs.target.q_posture if inputs.target.q_posture is not None else self.q_hold
        if q_d is None:
            q_d = dyn.q
        tau = dyn.h + self.gains.stiffness * (q_d - dyn.q) - self.gains.damping * dyn.dq
        return ControlOutput(tau=tau)

    def view(self) -> StepView:
        """Nothing beyond the torque: no objective, split, limit zone or QP."""
        return StepView(self.name)
