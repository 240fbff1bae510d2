"""The identity of a run: which preset, case, robot and controller ran, with every parameter in force.

A lesson's claim and a readout are about one run. `RunIdentity` names it; `differences` says in words
what changed between two identities (a lesson step cancels itself with that line when the person
changed something after *Set up this step*); `describe` names a run and the parameters a claim rests on.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from app.core.params import field_spec
from app.core.switching import same_value

if TYPE_CHECKING:  # the frames name runs with this module: types only, no import cycle
    from app.core.settings import Settings
    from app.live.frames import LoopStatus


@dataclass(frozen=True)
class RunIdentity:
    """Preset, case ("" when it has none), robot, executor and every parameter in force
    ("group.field" → value, in name order)."""

    preset: str
    case: str
    robot: str
    executor: str
    values: tuple[tuple[str, Any], ...]

    def value(self, key: str) -> Any:
        """The value of "group.field" in this run (None when the run has no such parameter)."""
        return dict(self.values).get(key)


def identity_from(status: LoopStatus, settings: Settings) -> RunIdentity:
    """The identity of the run a loop status and the settings in force describe (a published frame's)."""
    return RunIdentity(status.scenario, status.variant, status.robot, status.executor, flat_values(settings.groups))


def flat_values(groups: Mapping[str, Any]) -> tuple[tuple[str, Any], ...]:
    """Every field of the parameter groups as ("group.field", value), sorted by name."""
    return tuple(
        sorted((f"{name}.{field}", value) for name, group in groups.items() for field, value in group.values().items())
    )


def _parts(key: str, value: Any) -> tuple[str, str, str]:
    """(name "λ (damper.lambda_)", the value as written, its unit with a leading space or "")."""
    group, _, field = key.partition(".")
    try:
        spec = field_spec(group, field)
        name, unit = spec.label or field, spec.unit
    except (KeyError, ValueError):
        name, unit = field, ""
    shown = "none" if value is None else f"{value:g}" if isinstance(value, float) else str(value)
    return f"{name} ({key})", shown, f" {unit}" if unit else ""


def value_text(key: str, value: Any) -> str:
    """A parameter as a person reads it: "λ (damper.lambda_) = 1000 1/s"."""
    name, shown, unit = _parts(key, value)
    return f"{name} = {shown}{unit}"


def differences(before: RunIdentity, after: RunIdentity) -> list[str]:
    """What differs from `before` to `after`, one phrase each ("the preset limit-drop → compliance",
    "λ (damper.lambda_) 100 → 1000 1/s"); [] for the same run."""
    out = [
        f"the {what} {a or 'none'} → {b or 'none'}"
        for what, a, b in (
            ("preset", before.preset, after.preset),
            ("case", before.case, after.case),
            ("robot", before.robot, after.robot),
            ("controller", before.executor, after.executor),
        )
        if a != b
    ]
    if before.preset != after.preset:
        return out  # another preset has other parameters: the preset says it
    old, new = dict(before.values), dict(after.values)
    for key in sorted(set(old) | set(new)):
        a, b = old.get(key), new.get(key)
        if not same_value(a, b):
            name, was, unit = _parts(key, a)
            now = _parts(key, b)[1]
            out.append(f"{name} {was} → {now}{unit}")
    return out


def describe(identity: RunIdentity, keys: Iterable[str] = ()) -> str:
    """The run in words: "limit-drop (case position) on gen3, compliance-qp; λ (damper.lambda_) = 100 1/s"
    with the parameters `keys` ("group.field") it rests on."""
    case = f" (case {identity.case})" if identity.case else ""
    text = f"{identity.preset}{case} on {identity.robot}, {identity.executor}"
    shown = [value_text(k, identity.value(k)) for k in keys if identity.value(k) is not None]
    return text + ("; " + ", ".join(shown) if shown else "")
