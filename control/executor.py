"""The interface every controller ("executor") implements, and what it is given each step.

A controller sees only what a real robot gives it: the `Dynamics` snapshot of its own model at
the measured (q, q̇), the filtered F/T reading, the task target, and the time. Simulation truth
(`tau_ext_oracle`) is present only so an estimator set to "oracle" on purpose can use it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from control.model import Dynamics


@dataclass
class TaskTarget:
    """Desired TCP motion and contact force, world-aligned axes [px py pz rx ry rz]."""

    position: np.ndarray  # (3,) m
    rotation: np.ndarray  # (3, 3) world ← tcp
    velocity: np.ndarray = field(default_factory=lambda: np.zeros(6))  # (6,) twist
    acceleration: np.ndarray = field(default_factory=lambda: np.zeros(6))  # (6,)
    wrench: np.ndarray = field(default_factory=lambda: np.zeros(6))  # (6,) desired F^e (force on the robot)
    q_posture: np.ndarray | None = None  # (n,) desired joint posture for posture/nullspace tasks


@dataclass
class ControlInputs:
    """Everything besides the Dynamics snapshot that a controller may read in one step."""

    t: float  # s
    target: TaskTarget
    wrench_tcp: np.ndarray  # (6,) filtered F/T reading mapped to the TCP: F^e [f; m], world axes
    tau_ext_oracle: np.ndarray | None = None  # (n,) true external torque: only for source "oracle"


@dataclass
class ControlOutput:
    """A controller's result for one step."""

    tau: np.ndarray  # (n,) commanded joint torque, N m
    fallback: bool = False  # a QP failed and a fallback solution was used
    info: dict[str, float] = field(default_factory=dict)  # scalar signals for plots and logs


class Executor(Protocol):
    """A torque controller stepped at 1 kHz."""

    name: str

    def reset(self, dyn: Dynamics, target: TaskTarget) -> None:
        """Forget integrators and warm starts; called on (re)start with the initial state."""

    def step(self, dyn: Dynamics, inputs: ControlInputs) -> ControlOutput:
        """Compute the joint torques for this step. Must not raise on numerical trouble."""
        ...

    def configure(self, **changes: object) -> None:
        """Change tunables between steps; raise ValueError (naming the field) on invalid values."""
