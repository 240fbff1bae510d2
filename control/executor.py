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

from control.kernels.records import TARGET_FIELDS, target_record_dtype
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


# each field of a task target and its shape (None: a non-empty vector); q_posture may be None
TARGET_SHAPES: dict[str, tuple[int, ...] | None] = {
    "position": (3,), "rotation": (3, 3), "velocity": (6,), "acceleration": (6,), "wrench": (6,), "q_posture": None,
}  # fmt: skip


def _checked_target_field(name: str, value: object) -> object:
    """A target field's value as the one type the kernels are compiled for (`float_array`); the
    per-step case (already that type, finite) passes with one finiteness check."""
    shape = TARGET_SHAPES[name]
    if value is None and name == "q_posture":
        return None
    a = value
    if (
        type(a) is _ARRAY and a.dtype is _F64 and _plain(a)
        and (a.shape == shape if shape is not None else (a.ndim == 1 and a.shape[0] > 0))
    ):  # fmt: skip
        flat = a.reshape(-1)
        if math.isfinite(float(flat.dot(flat))):
            return a
    return float_array("TaskTarget", name, value, shape)


@dataclass
class TaskTarget:
    """Desired TCP motion and contact force, world-aligned axes [px py pz rx ry rz].

    Every field is coerced to a float64 array of its shape with finite entries (`float_array`) when
    it is assigned, at construction and after it (`target.position = (0.4, 0, 0.3)` stores a float64
    array): a bad one is a ValueError naming the field at the assignment, never a recompilation or a
    type error inside a compiled step. A name that is not a field is an AttributeError.

    The five arrays live in one record (`record`, `control.kernels.records.target_record_dtype`),
    which the kernels read by field name; `target.position` is a view of it (an edit in place is seen
    by the next step). An assignment stores a copy of the value in a new record, so an array read
    from the target before keeps its values. `q_posture` is not in the record."""

    position: np.ndarray  # (3,) m
    rotation: np.ndarray  # (3, 3) world ← tcp
    velocity: np.ndarray = field(default_factory=lambda: np.zeros(6))  # (6,) twist
    acceleration: np.ndarray = field(default_factory=lambda: np.zeros(6))  # (6,)
    wrench: np.ndarray = field(default_factory=lambda: np.zeros(6))  # (6,) desired F^e (force on the robot)
    q_posture: np.ndarray | None = None  # (n,) desired joint posture for posture/nullspace tasks

    @classmethod
    def of_record(
        cls,
        record: np.ndarray,
        q_posture: np.ndarray | None,
        fields: dict[str, np.ndarray] | None = None,
        at: int = 0,
    ) -> TaskTarget:
        """A target on a record its builder filled (`target_record_dtype`, finite entries), e.g. one
        taken from `records.RecordBlocks` with its block's `fields` and index `at`, and a posture of
        the checked type: no check here, and the arrays' views are made when first read. For a builder
        that makes one target per control step from inputs it checked once, at its own construction
        (`app.scenarios.polish_plan.PolishTarget`)."""
        target = object.__new__(cls)
        d = target.__dict__
        d["_record"], d["_fields"], d["_at"], d["q_posture"] = record, fields, at, q_posture
        return target

    def __getattr__(self, name: str) -> np.ndarray:
        """An array of a target made by `of_record`, on its first read: the view of its record's field."""
        d = self.__dict__
        if name not in _RECORD_FIELDS or "_record" not in d:
            raise AttributeError(f"TaskTarget has no attribute {name!r}")
        fields = d["_fields"]
        view = d[name] = d["_record"][0][name] if fields is None else fields[name][d["_at"]]
        return view

    @property
    def record(self) -> np.ndarray:
        """The one-element record of the five arrays (`target_record_dtype`), as the kernels read it."""
        return self.__dict__["_record"]

    def __getstate__(self) -> dict:
        d = self.__dict__
        return {"_record": d["_record"].copy(), "q_posture": d["q_posture"]}  # not the block it came from

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(_record=state["_record"], _fields=None, _at=0, q_posture=state["q_posture"])

    def __setattr__(self, name: str, value: object) -> None:
        if name not in TARGET_SHAPES:
            raise AttributeError(f"TaskTarget has no field {name!r} (its fields: {', '.join(TARGET_SHAPES)})")
        checked = _checked_target_field(name, value)
        d = self.__dict__
        if name == "q_posture":
            d[name] = checked
            return
        old = d.get("_record")
        record = np.zeros(1, target_record_dtype()) if old is None else old.copy()
        row = record[0]
        row[name] = checked
        for f in _RECORD_FIELDS:
            d[f] = row[f]
        d["_record"], d["_fields"] = record, None


_RECORD_FIELDS = tuple(name for name, _ in TARGET_FIELDS)


def _checked_input(name: str, value: object) -> object:
    """A `ControlInputs` field as the type the executors and kernels take (see `ControlInputs`)."""
    if name == "t":
        if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
            raise ValueError(f"ControlInputs.t must be a number of seconds, got {value!r:.60}")
        return float(value)
    if name == "target":
        if not isinstance(value, TaskTarget):
            raise ValueError(f"ControlInputs.target must be a TaskTarget, got {type(value).__name__}")
        return value
    if value is None:
        return None
    if name == "wrench_tcp":  # NaN kept: a faulty sensor is the executor's to survive
        if type(value) is _ARRAY and value.dtype is _F64 and value.shape == (6,) and _plain(value):
            return value
        return float_array("ControlInputs", "wrench_tcp", value, (6,), False)
    if name == "tau_ext_oracle":
        if type(value) is _ARRAY and value.dtype is _F64 and value.ndim == 1 and _plain(value):
            return value
        return float_array("ControlInputs", "tau_ext_oracle", value, None, False)
    raise AttributeError(f"ControlInputs has no field {name!r} (its fields: t, target, wrench_tcp, tau_ext_oracle)")


@dataclass
class ControlInputs:
    """Everything besides the Dynamics snapshot that a controller may read in one step.

    Each field is checked as it is assigned (at construction and after): t a number (stored as
    float), the target a `TaskTarget`, the reading float64 (6,) and the oracle torque a float64
    vector (NaN kept), converted when they are numbers of another type; anything else is a ValueError
    naming the field."""

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
        d = inputs.__dict__
        d["t"], d["target"], d["wrench_tcp"], d["tau_ext_oracle"] = t, target, wrench_tcp, tau_ext_oracle
        return inputs

    def __setattr__(self, name: str, value: object) -> None:
        self.__dict__[name] = _checked_input(name, value)


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
