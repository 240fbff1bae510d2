"""Parameters as data: frozen dataclass groups whose fields carry their own metadata.

A tunable is declared once, as a field of a frozen dataclass that derives from `ParamGroup`:

    lambda_: float = param(100.0, label="λ", unit="1/s", lo=1.0, hi=1000.0, step=1.0,
                           help="damper gain", tag="[C24]")

The metadata (label, unit, range, step, one-line help, paper tag, choices, size, kind) drives
validation, the generated GUI panels and the settings file, so a range is written in one place.
Constructing a group (or `replaced(group, field, value, index)`) coerces and validates every field
before anything is stored: text (also numeric text such as "5"), None, booleans for numbers,
non-finite or out-of-range numbers, wrong lengths and nested lists are refused with a one-line
`ParamError` naming the field and what it accepts. A refused value leaves the old group as it was.

Kinds (`kind=`):
- "float", "int", "bool", "choice" (a str among `choices`);
- "vector": exactly `size` numbers (a single number is accepted and applies to every element);
- "scalar_or_vector": one number or `size` numbers (e.g. a stiffness per axis);
- "gamma": a compliance Γ [C9] — one number, `size` diagonal values or a symmetric `size`×`size`
  matrix whose eigenvalues lie in [lo, hi].
`replaced(..., index=i)` changes one element of a vector; on a scalar_or_vector or gamma field a
scalar (or Γ's diagonal) is first promoted to its vector; on a full Γ matrix an index is refused.

Pure Python + numpy: `control/` never imports the app, MuJoCo or viser.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

KINDS = ("float", "int", "bool", "choice", "vector", "scalar_or_vector", "gamma")
Bound = float | tuple[float, ...]


class ParamError(ValueError):
    """A value a parameter refuses; the message is one line naming the field and what it accepts."""


@dataclass(frozen=True)
class ParamSpec:
    """The metadata of one parameter field (see the module docstring)."""

    kind: str
    label: str
    unit: str | tuple[str, ...] = ""
    lo: Bound | None = None
    hi: Bound | None = None
    step: Bound | None = None
    help: str = ""
    tag: str = ""
    choices: tuple[str, ...] = ()
    size: int | None = None
    axes: tuple[str, ...] = ()  # element names of a vector ("px", "joint 1"...)
    choice_labels: tuple[str, ...] = ()  # what a dropdown shows for each choice (default: the choice)
    # why the field reaches neither τ, the world nor the scenario (shown, logged or read by tools
    # only); empty for every field that acts: `tests/test_knobs_reach.py` holds each to it
    display_only: str = ""

    def element(self, which: Bound | None, i: int) -> float | None:
        """A per-element bound/step (tuples give one per element)."""
        if which is None:
            return None
        return float(which[i]) if isinstance(which, tuple) else float(which)

    def element_unit(self, i: int) -> str:
        """Unit of element i."""
        return self.unit[i] if isinstance(self.unit, tuple) else self.unit

    def axis_name(self, i: int) -> str:
        """Name of element i ("joint 3" when the metadata gives none)."""
        return self.axes[i] if i < len(self.axes) else f"[{i}]"

    def range_text(self, i: int = 0) -> str:
        """'between lo and hi' for messages."""
        lo, hi = self.element(self.lo, i), self.element(self.hi, i)
        unit = f" {self.element_unit(i)}" if self.element_unit(i) else ""
        if lo is not None and hi is not None:
            return f"between {lo:g} and {hi:g}{unit}"
        if lo is not None:
            return f"at least {lo:g}{unit}"
        if hi is not None:
            return f"at most {hi:g}{unit}"
        return "a finite number"


def param(
    default: Any,
    *,
    label: str,
    unit: str | tuple[str, ...] = "",
    lo: Bound | None = None,
    hi: Bound | None = None,
    step: Bound | None = None,
    help: str = "",
    tag: str = "",
    choices: Sequence[str] | None = None,
    size: int | None = None,
    kind: str | None = None,
    axes: Sequence[str] = (),
    choice_labels: Sequence[str] = (),
    display_only: str = "",
) -> Any:
    """A dataclass field with parameter metadata; `kind` is inferred from the default when omitted
    (bool → "bool", int → "int", float → "float", str with choices → "choice", tuple → "vector")."""
    if kind is None:
        if isinstance(default, bool):
            kind = "bool"
        elif isinstance(default, int):
            kind = "int"
        elif isinstance(default, float):
            kind = "float"
        elif isinstance(default, str):
            kind = "choice"
        elif isinstance(default, tuple):
            kind = "vector"
        else:
            raise TypeError(f"cannot infer the kind of a parameter with default {default!r}")
    if kind not in KINDS:
        raise ValueError(f"unknown parameter kind {kind!r}")
    if kind in ("vector", "scalar_or_vector", "gamma"):
        if size is None:
            if not isinstance(default, tuple):
                raise ValueError(f"{label}: a {kind} parameter needs size=")
            size = len(default)
    spec = ParamSpec(
        kind=kind,
        label=label,
        unit=unit,
        lo=lo,
        hi=hi,
        step=step,
        help=help,
        tag=tag,
        choices=tuple(choices or ()),
        size=size,
        axes=tuple(axes),
        choice_labels=tuple(choice_labels),
        display_only=display_only,
    )
    if spec.choice_labels and len(spec.choice_labels) != len(spec.choices):
        raise ValueError(f"{label}: one choice label per choice")
    return dataclasses.field(default=default, metadata={"param": spec})


def spec_of(group: type | object, name: str) -> ParamSpec:
    """The metadata of field `name` of a group (class or instance); ParamError if it has none."""
    for f in dataclasses.fields(group):  # type: ignore[arg-type]
        if f.name == name and "param" in f.metadata:
            return f.metadata["param"]
    label = group.__name__ if isinstance(group, type) else type(group).__name__
    raise ParamError(f"{label} has no parameter {name!r}")


def specs(group: type | object) -> dict[str, ParamSpec]:
    """Field name → metadata, in declaration order."""
    return {f.name: f.metadata["param"] for f in dataclasses.fields(group) if "param" in f.metadata}  # type: ignore[arg-type]


class ParamGroup:
    """Base of a frozen parameter dataclass: `__post_init__` coerces and validates every field from
    its metadata, then calls `check()` for rules across fields (raise ParamError there)."""

    title: ClassVar[str] = ""

    def __post_init__(self) -> None:
        for name, spec in specs(self).items():
            object.__setattr__(self, name, coerce(spec, name, getattr(self, name)))
        self.check()

    def check(self) -> None:
        """Rules across fields (e.g. d_s < d_i); the default has none."""

    def values(self) -> dict[str, Any]:
        """Field name → current value (plain Python: floats, bools, str, tuples)."""
        return {name: getattr(self, name) for name in specs(self)}


# ---- coercion -------------------------------------------------------------------------------------


def _number(spec: ParamSpec, name: str, value: Any, i: int = 0, where: str = "") -> float:
    """One finite number in range (bools, text, None, sequences refused)."""
    label = f"{name}{where}"
    if isinstance(value, (bool, np.bool_)) or isinstance(value, (str, bytes)) or value is None:
        raise ParamError(f"{label} must be a number {spec.range_text(i)}, got {value!r}")
    if isinstance(value, np.ndarray) and value.ndim == 0:
        value = value.item()
    if not isinstance(value, (int, float, np.integer, np.floating)):
        raise ParamError(f"{label} must be a number {spec.range_text(i)}, got {_short(value)}")
    try:
        x = float(value)
    except OverflowError:  # an integer beyond any float (10**400)
        raise ParamError(f"{label} must be a number {spec.range_text(i)}, got an integer too large") from None
    if not math.isfinite(x):
        raise ParamError(f"{label} must be a finite number {spec.range_text(i)}, got {value!r}")
    lo, hi = spec.element(spec.lo, i), spec.element(spec.hi, i)
    if (lo is not None and x < lo) or (hi is not None and x > hi):
        raise ParamError(f"{label} must be {spec.range_text(i)}, got {x:g}")
    return x


def _is_sequence(value: Any) -> bool:
    return isinstance(value, (list, tuple, np.ndarray)) and not (isinstance(value, np.ndarray) and value.ndim == 0)


def _vector(spec: ParamSpec, name: str, value: Any) -> tuple[float, ...]:
    n = int(spec.size or 0)
    if not _is_sequence(value):
        x = _number(spec, name, value)  # one number for every element
        return tuple(_number(spec, name, x, i) for i in range(n))
    items = list(value)
    if len(items) != n:
        raise ParamError(f"{name} needs {n} numbers, got {len(items)}")
    return tuple(_number(spec, name, v, i, f"[{i}]") for i, v in enumerate(items))


def _gamma(spec: ParamSpec, name: str, value: Any) -> float | tuple:
    n = int(spec.size or 0)
    if not _is_sequence(value):
        return _number(spec, name, value)
    items = list(value)
    if items and all(_is_sequence(row) for row in items):
        if len(items) != n or any(len(row) != n for row in items):
            raise ParamError(f"{name} must be one number, {n} values or a {n}×{n} matrix")
        rows = tuple(tuple(_finite(spec, name, v) for v in row) for row in items)
        G = np.array(rows)
        if not np.allclose(G, G.T, atol=1e-12):
            raise ParamError(f"{name} must be symmetric")
        eig = np.linalg.eigvalsh(G)
        lo, hi = spec.element(spec.lo, 0), spec.element(spec.hi, 0)
        if (lo is not None and eig[0] < lo - 1e-12) or (hi is not None and eig[-1] > hi + 1e-12):
            raise ParamError(f"{name}: the eigenvalues must be {spec.range_text()}, got {eig[0]:g} … {eig[-1]:g}")
        return rows
    if len(items) != n:
        raise ParamError(f"{name} must be one number, {n} values or a {n}×{n} matrix, got {len(items)} values")
    return tuple(_number(spec, name, v, i, f"[{i}]") for i, v in enumerate(items))


def _finite(spec: ParamSpec, name: str, value: Any) -> float:
    """A finite number (matrix entries: range applies to the eigenvalues)."""
    bare = dataclasses.replace(spec, lo=None, hi=None)
    return _number(bare, name, value)


def _short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def coerce(spec: ParamSpec, name: str, value: Any) -> Any:
    """The value as stored (float, int, bool, str, tuple, tuple of tuples); ParamError otherwise."""
    kind = spec.kind
    if kind == "bool":
        if isinstance(value, (bool, np.bool_)):
            return bool(value)
        raise ParamError(f"{name} must be true or false, got {_short(value)}")
    if kind == "choice":
        if isinstance(value, str) and value in spec.choices:
            return value
        raise ParamError(f"{name} must be one of {', '.join(spec.choices)}, got {_short(value)}")
    if kind == "float":
        if _is_sequence(value):
            raise ParamError(f"{name} must be one number {spec.range_text()}, got a list")
        return _number(spec, name, value)
    if kind == "int":
        if _is_sequence(value):
            raise ParamError(f"{name} must be one whole number {spec.range_text()}, got a list")
        x = _number(spec, name, value)
        if not float(x).is_integer():
            raise ParamError(f"{name} must be a whole number, got {x:g}")
        return int(x)
    if kind == "vector":
        return _vector(spec, name, value)
    if kind == "scalar_or_vector":
        if not _is_sequence(value):
            return _number(spec, name, value)
        return _vector(spec, name, value)
    if kind == "gamma":
        return _gamma(spec, name, value)
    raise ParamError(f"{name}: unknown kind {kind!r}")  # pragma: no cover - param() checks kinds


def as_array(value: Any, n: int) -> np.ndarray:
    """A stored scalar / vector value as an (n,) float array."""
    arr = np.asarray(value, dtype=float)
    return np.full(n, float(arr)) if arr.ndim == 0 else arr.copy()


def replaced(group: Any, name: str, value: Any, index: int | None = None) -> Any:
    """A new validated group with field `name` set to `value` (or element `index` of it).

    ParamError (the group unchanged) for an unknown field, a refused value, an index on a scalar
    field or a full Γ matrix, or an index out of range.
    """
    spec = spec_of(group, name)
    if index is not None:
        if isinstance(index, (bool, np.bool_)) or not isinstance(index, (int, np.integer)):
            raise ParamError(f"{name}: the element index must be a whole number, got {index!r}")
        if spec.kind not in ("vector", "scalar_or_vector", "gamma"):
            raise ParamError(f"{name} is a single value: it has no elements to index")
        n = int(spec.size or 0)
        if not 0 <= int(index) < n:
            raise ParamError(f"{name} has elements 0 … {n - 1}, got index {index}")
        current = getattr(group, name)
        if spec.kind == "gamma" and _is_sequence(current) and _is_sequence(current[0]):
            raise ParamError(f"{name} is a full {n}×{n} matrix: set it whole, not one element")
        if _is_sequence(value):
            raise ParamError(f"{name}[{index}] must be one number, got a list")
        element = _number(spec, name, value, int(index), f"[{index}]")
        vec = list(as_array(current, n))
        vec[int(index)] = element
        value = tuple(vec)
    try:
        return dataclasses.replace(group, **{name: value})
    except ParamError:
        raise
    except (TypeError, ValueError) as exc:  # pragma: no cover - a check() raising a plain ValueError
        raise ParamError(str(exc)) from None


def with_values(group: Any, changes: Mapping[str, Any]) -> Any:
    """A new validated group with several fields changed at once (ParamError on any refusal)."""
    for name in changes:
        spec_of(group, name)
    try:
        return dataclasses.replace(group, **dict(changes))
    except ParamError:
        raise
    except (TypeError, ValueError) as exc:  # pragma: no cover
        raise ParamError(str(exc)) from None


def expect(name: str, group: Any, cls: type | None) -> Any:
    """`group` if it is a `cls`; ParamError naming the group otherwise (None: no such group)."""
    if cls is None:
        raise ParamError(f"no parameter group {name!r} here")
    if not isinstance(group, cls):
        raise ParamError(f"parameter group {name!r} takes a {cls.__name__}, got {type(group).__name__}")
    return group
