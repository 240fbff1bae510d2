"""Sweep names → what they set: a typed parameter (group, field) or an argument of the run.

A parameter knob names a field of one of the session's parameter groups (`control.params`, the
groups the GUI's panels set, e.g. ("damper", "lambda_")): its text is typed by the field's
metadata and validated by the group's dataclass (`control.params.replaced` on the experiment's
default groups). A run knob is an argument of the experiment's single-run function that is not
a session parameter (which limit joint 4 falls into, the simulated seconds, a held swivel...):
it carries its own type and check. Either way a refused value is a `SweepError` with a one-line
message before anything runs.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from app.headless.sweep.grid import Axis, SweepError

TRUE = ("1", "true", "on", "yes")
FALSE = ("0", "false", "off", "no")
RUN = "run"  # the group of run knobs


@dataclass(frozen=True)
class Knob:
    """One sweepable name.

    group, field: a session parameter group and its field, or RUN and the run argument's name;
    kind: for run knobs "float", "int", "bool" or a tuple of allowed words (parameter knobs take
    theirs from the field's metadata); check: a run knob's validator (raises ValueError).
    """

    name: str
    group: str
    field: str
    help: str = ""
    aliases: tuple[str, ...] = ()
    kind: str | tuple[str, ...] | None = None
    check: Callable[[Any], object] | None = None


def parse_text(name: str, kind: str | tuple[str, ...], text: str) -> Any:
    """Command-line text → a value of `kind` (SweepError if it is not one)."""
    text = str(text).strip()
    if isinstance(kind, tuple):
        if text not in kind:
            raise SweepError(f"{name}={text}: choose from {', '.join(kind)}")
        return text
    if kind == "bool":
        if text.lower() in TRUE:
            return True
        if text.lower() in FALSE:
            return False
        raise SweepError(f"{name}={text}: must be on/off (true/false, 1/0)")
    try:
        x = float(text)
    except ValueError:
        raise SweepError(f"{name}={text}: must be a number") from None
    if not math.isfinite(x):
        raise SweepError(f"{name}={text}: must be finite")
    if kind == "int":
        if x != round(x):
            raise SweepError(f"{name}={text}: must be a whole number")
        return round(x)
    return x


def _param_kind(group: object, field: str) -> str | tuple[str, ...]:
    from control.params import spec_of

    spec = spec_of(group, field)
    if spec.kind == "choice":
        return spec.choices
    if spec.kind in ("float", "int", "bool"):
        return spec.kind
    return "float"  # a vector field swept as one number for every element


def find(knobs: tuple[Knob, ...], name: str, any_param: bool = False) -> Knob:
    """The knob called `name` (or one of its aliases); with `any_param`, "GROUP.FIELD" names any field
    of the session's parameter groups (checked against them by `build_axes`); SweepError naming the
    choices otherwise."""
    for k in knobs:
        if name == k.name or name in k.aliases:
            return k
    if any_param and name.count(".") == 1 and all(name.split(".")):
        group, field = name.split(".")
        return Knob(name, group, field, "a session parameter (its group's metadata)")
    more = ", or GROUP.FIELD of any session parameter" if any_param else ""
    raise SweepError(f"unknown parameter {name!r}; this experiment sweeps {', '.join(k.name for k in knobs)}{more}")


def build_axes(
    knobs: tuple[Knob, ...],
    items: list[tuple[str, list[str]]],
    groups: Callable[[], dict[str, Any]] | None = None,
    any_param: bool = False,
) -> list[Axis]:
    """Typed, validated axes from parsed grid items (canonical knob names; SweepError if refused).

    groups: the experiment's default parameter groups by name (built only if a parameter knob is
    swept); any_param: "GROUP.FIELD" names any of their fields (`find`)."""
    from control.params import ParamError, replaced, spec_of

    axes: list[Axis] = []
    seen: set[str] = set()
    defaults: dict[str, Any] | None = None
    for name, texts in items:
        knob = find(knobs, name, any_param)
        if knob.name in seen:
            raise SweepError(f"{knob.name} is given twice in --grid")
        seen.add(knob.name)
        if knob.group == RUN:
            kind = knob.kind or "float"
        else:
            if defaults is None:
                defaults = groups() if groups is not None else {}
            if knob.group not in defaults:
                raise SweepError(f"{knob.name}: this experiment has no parameter group {knob.group!r}")
            try:
                spec_of(defaults[knob.group], knob.field)
            except ParamError as exc:
                raise SweepError(f"{knob.name}: {_one_line(exc)}") from None
            kind = _param_kind(defaults[knob.group], knob.field)
        values = []
        for text in texts:
            value = parse_text(knob.name, kind, text)
            try:
                if knob.group == RUN:
                    if knob.check is not None:
                        knob.check(value)
                else:
                    assert defaults is not None
                    replaced(defaults[knob.group], knob.field, value)
            except (ValueError, TypeError) as exc:
                raise SweepError(f"{knob.name}={text}: {_one_line(exc)}") from None
            values.append(value)
        if len(set(values)) != len(values):
            raise SweepError(f"{knob.name}: a value is given twice")
        axes.append(Axis(knob.name, tuple(values)))
    return axes


def positive(value: Any) -> None:
    """ValueError unless value > 0."""
    if not float(value) > 0:
        raise ValueError(f"must be positive, got {value!r}")


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__
