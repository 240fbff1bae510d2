"""A joint-space PD hold with gravity/Coriolis compensation: the simplest executor.

τ = h(q, q̇) + K_p (q_d − q) − K_d q̇. Used by scenarios that only need the arm held and as a
reference when the task-space executors are switched off.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from control.executor import ControlInputs, ControlOutput, StepView, TaskTarget
from control.model import Dynamics
from control.params import ParamGroup, expect, param


@dataclass(frozen=True)
class JointHoldGains(ParamGroup):
    """Joint stiffness and damping, one value for all joints."""

    title = "Joint hold"

    stiffness: float = param(
        400.0, label="K_p joint", unit="N m/rad", lo=0.0, hi=2000.0, step=10.0, help="joint stiffness"
    )
    damping: float = param(40.0, label="K_d joint", unit="N m s/rad", lo=0.0, hi=200.0, step=1.0, help="joint damping")


class JointHold:
    """Holds the posture given at reset (or the target's `q_posture`)."""

    name = "joint-hold"

    def __init__(self, gains: JointHoldGains | None = None):
        self.gains = gains or JointHoldGains()
        self.q_hold: np.ndarray | None = None

    def reset(self, dyn: Dynamics, target: TaskTarget) -> None:
        self.q_hold = dyn.q.copy() if target.q_posture is None else np.array(target.q_posture)

    def params(self) -> dict[str, Any]:
        """Its one group, "joint_hold"."""
        return {"joint_hold": self.gains}

    def set_params(self, name: str, group: Any) -> None:
        """Take new joint-hold gains (ParamError for another group)."""
        self.gains = expect(name, group, JointHoldGains if name == "joint_hold" else None)

    def step(self, dyn: Dynamics, inputs: ControlInputs) -> ControlOutput:
        q_d = inputs.target.q_posture if inputs.target.q_posture is not None else self.q_hold
        if q_d is None:
            q_d = dyn.q
        tau = dyn.h + self.gains.stiffness * (q_d - dyn.q) - self.gains.damping * dyn.dq
        return ControlOutput(tau=tau)

    def view(self) -> StepView:
        """Nothing beyond the torque: no objective, split, limit zone or QP."""
        return StepView(self.name)
