"""The interface every controller ("executor") implements, and what it is given each step.

A controller sees only what a real robot gives it: the `Dynamics` snapshot of its own model at
the measured (q, q̇), the filtered F/T reading, the task target, and the time. Simulation truth
(`tau_ext_oracle`) is present only so an estimator set to "oracle" on purpose can use it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Protocol

import numpy as np

from control.model import Dynamics
from control.params import ParamGroup

_ARRAY = np.ndarray
_F64 = np.dtype(np.float64)


def _plain(a: np.ndarray) -> bool:
    """C-contiguous and writeable (a read-only or strided array is another type to numba)."""
    flags = a.flags
    return bool(flags.c_contiguous and flags.writeable)


FINITE_LIMIT = 1e150  # |entries| a target may hold: its squared norm stays finite (the cheap check)


def float_array(owner: str, name: str, value: object, shape: tuple[int, ...] | None, finite: bool = True) -> np.ndarray:
    """`value` as a writeable C-contiguous float64 array of `shape` (None: any 1-D length), its entries
    finite and below `FINITE_LIMIT` in magnitude when `finite`: the one type the compiled kernels are
    compiled for. A value that is not one raises ValueError naming `owner.name`, in one line."""
    a = value
    if not (type(a) is np.ndarray and a.dtype == np.float64 and _plain(a)):
        try:
            a = np.array(value, dtype=np.float64)  # a copy: never a view of the caller's array
        except (TypeError, ValueError) as err:
            raise ValueError(f"{owner}.{name} must be an array of numbers, got {value!r:.60}") from err
    wrong = a.shape != shape if shape is not None else (a.ndim != 1 or a.shape[0] == 0)
    if wrong:
        want = "a non-empty vector" if shape is None else f"shape {shape}"
        raise ValueError(f"{owner}.{name} must have {want}, got shape {a.shape}")
    flat = a.reshape(-1)
    if finite and not math.isfinite(float(flat @ flat)):
        raise ValueError(f"{owner}.{name} must be finite (|x| < {FINITE_LIMIT:.0e}), got {a.tolist()}")
    return a


@dataclass
class TaskTarget:
    """Desired TCP motion and contact force, world-aligned axes [px py pz rx ry rz].

    Every field is coerced at construction to a float64 array of its shape with finite entries
    (`float_array`): a bad one is a ValueError here, never a recompilation or a type error inside
    a compiled step."""

    position: np.ndarray  # (3,) m
    rotation: np.ndarray  # (3, 3) world ← tcp
    velocity: np.ndarray = field(default_factory=lambda: np.zeros(6))  # (6,) twist
    acceleration: np.ndarray = field(default_factory=lambda: np.zeros(6))  # (6,)
    wrench: np.ndarray = field(default_factory=lambda: np.zeros(6))  # (6,) desired F^e (force on the robot)
    q_posture: np.ndarray | None = None  # (n,) desired joint posture for posture/nullspace tasks

    @classmethod
    def trusted(
        cls,
        position: np.ndarray,
        rotation: np.ndarray,
        velocity: np.ndarray,
        acceleration: np.ndarray,
        wrench: np.ndarray,
        q_posture: np.ndarray | None,
    ) -> TaskTarget:
        """A target from arrays its builder already holds as the checked type (float64, these shapes,
        finite, C-contiguous): no check here. For a builder that makes one target per control step from
        inputs it checked once, at its own construction (`app.scenarios.polish.PolishTarget`)."""
        target = object.__new__(cls)
        target.position, target.rotation, target.velocity = position, rotation, velocity
        target.acceleration, target.wrench, target.q_posture = acceleration, wrench, q_posture
        return target

    def __post_init__(self) -> None:
        p, R, v, a, w, qp = self.position, self.rotation, self.velocity, self.acceleration, self.wrench, self.q_posture
        # the per-step case first (float64 arrays of the right shape, not read-only: one combined
        # finiteness check); anything else takes `float_array`, field by field
        if (
            type(p) is _ARRAY and type(R) is _ARRAY and type(v) is _ARRAY and type(a) is _ARRAY and type(w) is _ARRAY
            and p.dtype is _F64 and R.dtype is _F64 and v.dtype is _F64 and a.dtype is _F64 and w.dtype is _F64
            and p.shape == (3,) and R.shape == (3, 3) and v.shape == (6,) and a.shape == (6,) and w.shape == (6,)
            and (qp is None or (type(qp) is _ARRAY and qp.dtype is _F64 and qp.ndim == 1 and qp.shape[0] > 0))
            and _plain(p) and _plain(R) and _plain(v) and _plain(a) and _plain(w) and (qp is None or _plain(qp))
        ):  # fmt: skip
            r = R.reshape(9)  # `dot` costs a third of `@` on these sizes
            s = float(p.dot(p)) + float(v.dot(v)) + float(a.dot(a)) + float(w.dot(w)) + float(r.dot(r))
            if qp is not None:
                s += float(qp.dot(qp))
            if math.isfinite(s):
                return
        self.position = float_array("TaskTarget", "position", self.position, (3,))
        self.rotation = float_array("TaskTarget", "rotation", self.rotation, (3, 3))
        self.velocity = float_array("TaskTarget", "velocity", self.velocity, (6,))
        self.acceleration = float_array("TaskTarget", "acceleration", self.acceleration, (6,))
        self.wrench = float_array("TaskTarget", "wrench", self.wrench, (6,))
        if self.q_posture is not None:
            self.q_posture = float_array("TaskTarget", "q_posture", self.q_posture, None)


@dataclass
class ControlInputs:
    """Everything besides the Dynamics snapshot that a controller may read in one step."""

    t: float  # s
    target: TaskTarget
    wrench_tcp: np.ndarray  # (6,) filtered F/T reading mapped to the TCP: F^e [f; m], world axes
    tau_ext_oracle: np.ndarray | None = None  # (n,) true external torque: only for source "oracle"

    @classmethod
    def trusted(
        cls, t: float, target: TaskTarget, wrench_tcp: np.ndarray, tau_ext_oracle: np.ndarray | None
    ) -> ControlInputs:
        """Inputs from arrays the caller made as the checked type (float64 C-contiguous vectors, the
        reading (6,)): no check here. For the session's step, whose reading comes from a compiled
        kernel and whose oracle torque is a fresh copy of the world's (`app.core.session.Session.step`)."""
        inputs = object.__new__(cls)
        inputs.t, inputs.target, inputs.wrench_tcp, inputs.tau_ext_oracle = t, target, wrench_tcp, tau_ext_oracle
        return inputs

    def __post_init__(self) -> None:
        """The reading as float64 (6,) (NaN kept: a faulty sensor is the executor's to survive)."""
        w, tau = self.wrench_tcp, self.tau_ext_oracle
        if w is not None and not (type(w) is _ARRAY and w.dtype is _F64 and w.shape == (6,) and _plain(w)):
            self.wrench_tcp = float_array("ControlInputs", "wrench_tcp", w, (6,), False)
        if tau is not None and not (type(tau) is _ARRAY and tau.dtype is _F64 and tau.ndim == 1 and _plain(tau)):
            self.tau_ext_oracle = float_array("ControlInputs", "tau_ext_oracle", tau, None, False)


@dataclass
class ControlOutput:
    """A controller's result for one step."""

    tau: np.ndarray  # (n,) commanded joint torque, N m
    fallback: bool = False  # a QP failed and a fallback solution was used
    # scalar signals for plots and logs: a new dict every step (the session adds the environment's)
    info: dict[str, float] = field(default_factory=dict)


def frozen_copy(array: object) -> np.ndarray:
    """A read-only float copy of an array (for a `StepView`)."""
    out = np.array(array, dtype=float)
    out.flags.writeable = False
    return out


@dataclass(frozen=True)
class StepView:
    """What an executor's latest step computed, for the UI to read (read-only copies).

    Built by `Executor.view()` when a frame is published, not every step. Fields an executor does
    not compute are None (or empty): the reader computes those itself, never reaches inside.
    """

    executor: str  # the executor's name
    objective: str | None = None  # nullspace objective [T15]: "j", "f", "a", "d"; None without one
    W: Mapping[str, float] = field(default_factory=dict)  # W_f, W_a, W_d [T22] and "W" (the objective's)
    force_axes: tuple[int, ...] | None = None  # the force/motion split the step used [T19]
    motion_axes: tuple[int, ...] | None = None
    P: Mapping[str, np.ndarray] | None = None  # "P_f", "P_a", "P_d" (n_f, n_m) of this step (Table I)
    limit_zone: np.ndarray | None = None  # (n,) rad: the joint-limit damper's influence distance d_i
    shaping: bool | None = None  # the step used Λ̂x [T9] (True) or Λx (False); None without a split
    qp_status: str | None = None  # `control.qp` status of the step's QP (or the fallback's reason)
    qp_backend: str | None = None  # "dense" or "osqp"
    qp_fallback: bool = False  # the QP's solution was replaced by a fallback
    qp_iterations: int = 0
    qp_solve_us: float = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "W", MappingProxyType(dict(self.W)))
        if self.P is not None:
            object.__setattr__(self, "P", MappingProxyType({k: frozen_copy(v) for k, v in self.P.items()}))
        if self.limit_zone is not None:
            object.__setattr__(self, "limit_zone", frozen_copy(self.limit_zone))


class Executor(Protocol):
    """A torque controller stepped at 1 kHz."""

    name: str

    def reset(self, dyn: Dynamics, target: TaskTarget) -> None:
        """Forget integrators and warm starts; called on (re)start with the initial state."""

    def step(self, dyn: Dynamics, inputs: ControlInputs) -> ControlOutput:
        """Compute the joint torques for this step. Must not raise on numerical trouble."""
        ...

    def params(self) -> dict[str, ParamGroup]:
        """Its parameter groups by name (frozen, validated; see `control.params`)."""
        ...

    def set_params(self, name: str, group: ParamGroup) -> None:
        """Take a new (already validated) group between two steps; ParamError for an unknown name."""

    def view(self) -> StepView:
        """What the latest step computed (copies), for the UI; called at the frame rate."""
        ...
