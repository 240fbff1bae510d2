"""Sweep names → typed parameter fields: what `--grid NAME=…` may vary, typed and validated.

Each `Knob` maps a sweep name (and its aliases) to the (group, field) of a parameter the GUI
also sets, parses the command-line text to the field's type and validates it with the group's
own dataclass before anything runs. A name that is not a knob, or a value its group refuses,
is a `SweepError` with a one-line message.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from app.sweep.grid import Axis, SweepError

TRUE = ("1", "true", "on", "yes")
FALSE = ("0", "false", "off", "no")


@dataclass(frozen=True)
class Knob:
    """One sweepable parameter: its sweep name, the (group, field) it sets, its type and help.

    kind: "float", "int", "bool" or a tuple of allowed words.
    """

    name: str
    group: str
    field: str
    kind: str | tuple[str, ...]
    help: str
    aliases: tuple[str, ...] = ()

    def parse(self, text: str):
        """Command-line text → a value of this knob's type (SweepError if it is not one)."""
        text = str(text).strip()
        if isinstance(self.kind, tuple):
            if text not in self.kind:
                raise SweepError(f"{self.name}={text}: choose from {', '.join(self.kind)}")
            return text
        if self.kind == "bool":
            low = text.lower()
            if low in TRUE:
                return True
            if low in FALSE:
                return False
            raise SweepError(f"{self.name}={text}: must be on/off (true/false, 1/0)")
        try:
            x = float(text)
        except ValueError:
            raise SweepError(f"{self.name}={text}: must be a number") from None
        if not math.isfinite(x):
            raise SweepError(f"{self.name}={text}: must be finite")
        if self.kind == "int":
            if x != round(x):
                raise SweepError(f"{self.name}={text}: must be a whole number")
            return round(x)
        return x


def _dataclass_check(cls: type, attr: str) -> Callable[[Any], object]:
    """A check that builds `cls(attr=value)`: the group's dataclass validates the value."""

    def check(value: Any) -> None:
        cls(**{attr: value})

    return check


def _range_check(lo: float, hi: float, unit: str = "") -> Callable[[Any], object]:
    def check(value: Any) -> None:
        if not lo <= float(value) <= hi:
            raise ValueError(f"must be {lo:g} to {hi:g}{unit}, got {value!r}")

    return check


def _positive(value: Any) -> None:
    if not float(value) > 0:
        raise ValueError(f"must be positive, got {value!r}")


def _non_negative(value: Any) -> None:
    if not float(value) >= 0:
        raise ValueError(f"must be non-negative, got {value!r}")


def _checks() -> dict[tuple[str, str], Callable[[Any], object]]:
    """(group, field) → validator, from the groups' own dataclasses and ranges."""
    from app.experiments.polish import PLAN_COST_OF
    from app.scenarios.limit_drop import LimitDropScenario
    from app.scenarios.mass_drop import MassDropParams, MassDropScenario
    from app.scenarios.polish import PolishScenario
    from app.sim.world import MAX_TORQUE_DELAY_MS
    from control.gains import (
        ComplianceQPSettings,
        DamperGains,
        EstimatorGains,
        MotionForceGains,
        NullspaceGains,
    )

    return {
        ("damper", "lambda_"): _dataclass_check(DamperGains, "lambda_"),
        ("damper", "M"): _dataclass_check(DamperGains, "M"),
        ("damper", "form"): _dataclass_check(DamperGains, "form"),
        ("estimator", "observer_gain"): _dataclass_check(EstimatorGains, "observer_gain"),
        ("compliance_qp", "feedback"): _dataclass_check(ComplianceQPSettings, "feedback"),
        ("world", "torque_delay_ms"): _range_check(0.0, MAX_TORQUE_DELAY_MS, " ms"),
        ("sensor", "cutoff_hz"): _non_negative,
        ("motion_force", "shaping"): _dataclass_check(MotionForceGains, "shaping"),
        ("nullspace", "objective"): lambda v: None if v in PLAN_COST_OF else NullspaceGains(objective=v),
        ("scenario.polish", "armature_scale"): lambda v: PolishScenario(armature_scale=float(v)),
        ("scenario.limit-drop", "limit"): lambda v: LimitDropScenario(str(v)),
        ("scenario.mass-drop", "mode"): lambda v: MassDropScenario(str(v)),
        ("scenario.mass-drop", "case"): lambda v: MassDropScenario(case=str(v)),
        ("mass_drop_rig", "payload_mass_error"): _dataclass_check(MassDropParams, "payload_mass_error"),
        ("mass_drop_rig", "rope_stiffness_n_per_m"): _dataclass_check(MassDropParams, "rope_stiffness_n_per_m"),
        ("mass_drop_rig", "drop_height_m"): _dataclass_check(MassDropParams, "drop_height_m"),
        ("scenario.mass-drop", "rope_stiffness_n_per_m"): lambda v: MassDropParams(rope_stiffness_n_per_m=float(v)),
        ("scenario.mass-drop", "drop_height_m"): lambda v: MassDropParams(drop_height_m=float(v)),
        ("scenario.mass-drop", "payload_mass_error"): lambda v: MassDropParams(payload_mass_error=float(v)),
        ("scenario.polish", "mu"): lambda v: PolishScenario(mu=float(v)),
        ("scenario.polish", "start_swivel_deg"): _range_check(-360.0, 360.0, "°"),
        ("scenario.polish", "hold_swivel_deg"): _range_check(-360.0, 360.0, "°"),
        ("scenario.polish", "converge_timeout_s"): lambda v: PolishScenario(converge_timeout_s=float(v)),
        ("scenario.polish", "sander"): lambda v: None,
        ("run", "duration_s"): _positive,
    }


_CHECKS: dict[tuple[str, str], Callable[[Any], object]] | None = None


def check_field(group: str, field: str, value: Any) -> None:
    """Validate one value of (group, field) with its group's rules; ValueError if refused."""
    global _CHECKS
    if _CHECKS is None:
        _CHECKS = _checks()
    check = _CHECKS.get((group, field))
    if check is None:
        raise ValueError(f"no parameter {group}.{field}")
    check(value)


def find(knobs: tuple[Knob, ...], name: str) -> Knob:
    """The knob called `name` (or one of its aliases); SweepError naming the choices otherwise."""
    for k in knobs:
        if name == k.name or name in k.aliases:
            return k
    raise SweepError(f"unknown parameter {name!r}; this experiment sweeps {', '.join(k.name for k in knobs)}")


def build_axes(knobs: tuple[Knob, ...], items: list[tuple[str, list[str]]]) -> list[Axis]:
    """Typed, validated axes from parsed grid items (canonical knob names; SweepError if refused)."""
    axes: list[Axis] = []
    seen: set[str] = set()
    for name, texts in items:
        knob = find(knobs, name)
        if knob.name in seen:
            raise SweepError(f"{knob.name} is given twice in --grid")
        seen.add(knob.name)
        values = []
        for text in texts:
            value = knob.parse(text)
            try:
                check_field(knob.group, knob.field, value)
            except (ValueError, TypeError) as exc:
                raise SweepError(f"{knob.name}={text}: {_one_line(exc)}") from None
            values.append(value)
        if len(set(values)) != len(values):
            raise SweepError(f"{knob.name}: a value is given twice")
        axes.append(Axis(knob.name, tuple(values)))
    return axes


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__
