"""The parameter groups of the app by name, and settings files (TOML) validated by the same code.

`GROUP_TYPES` names the dataclass of every group a session may have (`Session.params()`); the
panels read labels, ranges and help from it before any session has the group. A settings file is
one TOML table per group with the fields that differ from the defaults:

    [damper]
    lambda_ = 300.0
    [posture_task]
    compliance = [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0]

`save_settings(session)` writes the session's overrides (`Session.overrides()`), `load_settings`
applies a file through `Session.set_param` — every value validated by its dataclass — and returns
one line per refused entry (nothing else is lost: the accepted ones stay applied). The running app
goes through the loop instead: `settings_commands` turns a file into `SetParam` commands (checked
against the groups in force) that the loop applies and remembers like any other change.
"""

from __future__ import annotations

import math
import sys
from typing import Any

from app.core.commands import SetParam
from app.core.session import Session, TargetParams
from app.scenarios import SCENARIOS, get_scenario
from app.sim.contact import ContactParams
from app.sim.disturbances import SanderParams
from app.sim.drag import DragParams
from app.sim.sensor import SensorParams
from app.sim.world import WorldParams
from control.gains import (
    ComplianceQPSettings,
    DamperGains,
    EstimatorGains,
    MotionForceGains,
    NullspaceGains,
    PoseTaskGains,
    PostureTaskGains,
    SolverParams,
)
from control.joint_hold import JointHoldGains
from control.params import ParamError, ParamGroup, ParamSpec, replaced, spec_of

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

GROUP_TYPES: dict[str, type] = {
    "motion_force": MotionForceGains,
    "nullspace": NullspaceGains,
    "pose_task": PoseTaskGains,
    "posture_task": PostureTaskGains,
    "damper": DamperGains,
    "estimator": EstimatorGains,
    "compliance_qp": ComplianceQPSettings,
    "solver": SolverParams,
    "joint_hold": JointHoldGains,
    "contact": ContactParams,
    "sander": SanderParams,
    "sensor": SensorParams,
    "world": WorldParams,
    "drag": DragParams,
    "target": TargetParams,
}


def _preset_groups() -> dict[str, tuple[type, ...]]:
    """The groups the presets declare (`Scenario.groups`), by name: a preset's own "scenario" group is
    a different dataclass per preset that has one."""
    out: dict[str, tuple[type, ...]] = {}
    for name in SCENARIOS:
        for group, cls in get_scenario(name).groups.items():
            if cls not in out.get(group, ()):
                out[group] = (*out.get(group, ()), cls)
    return out


_PRESET_GROUPS = _preset_groups()
for _group, _types in _PRESET_GROUPS.items():
    if _group != "scenario":
        if len(_types) != 1 or GROUP_TYPES.get(_group, _types[0]) is not _types[0]:
            raise RuntimeError(f"the presets declare the group {_group!r} as {_types}: one dataclass a name")
        GROUP_TYPES[_group] = _types[0]
SCENARIO_TYPES: tuple[type, ...] = _PRESET_GROUPS.get("scenario", ())
if SCENARIO_TYPES:
    GROUP_TYPES["scenario"] = SCENARIO_TYPES[0]  # one class per preset: see SCENARIO_TYPES


def group_types(group: str) -> tuple[type, ...]:
    """The dataclasses a group of this name may be (several for "scenario"); () if unknown."""
    if group == "scenario":
        return SCENARIO_TYPES
    return (GROUP_TYPES[group],) if group in GROUP_TYPES else ()


def field_spec(group: str, field: str) -> ParamSpec:
    """The metadata of `group.field`; ParamError for an unknown group or field."""
    types = group_types(group)
    if not types:
        raise ParamError(f"unknown parameter group {group!r}")
    for cls in types:
        try:
            return spec_of(cls, field)
        except ParamError:
            continue
    raise ParamError(f"{group} has no parameter {field!r}")


# ---- TOML ---------------------------------------------------------------------------------------


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if not math.isfinite(value):  # never stored (the groups refuse it), but say so if it were
            raise ValueError(f"cannot write {value!r} to TOML")
        return repr(value)
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    raise ValueError(f"cannot write {type(value).__name__} to TOML")


def dumps(tables: dict[str, dict[str, Any]]) -> str:
    """A TOML document of tables of scalars / arrays (the only shapes parameters take)."""
    out = []
    for name, fields in tables.items():
        if not fields:
            continue
        out.append(f"[{name}]")
        out.extend(f"{key} = {_toml_value(value)}" for key, value in fields.items())
        out.append("")
    return "\n".join(out)


def save_settings(session: Session) -> str:
    """The session's parameter overrides as TOML text (defaults are left out)."""
    return "# torquelab settings: one table per parameter group\n" + dumps(session.overrides())


MAX_SETTINGS_BYTES = 64 * 1024  # a file of every parameter of every preset is a few kB


def parse_settings(text: str) -> tuple[list[tuple[str, str, Any]], list[str]]:
    """The (group, field, value) entries of a TOML settings text, in file order, and one line per
    entry that is not of that shape (a syntax error, or a text over MAX_SETTINGS_BYTES, gives no
    entries and one line). The size bound keeps a parse short wherever it runs: a megabyte of TOML
    takes a second of one core in Python, and the interpreter's lock with it."""
    size = len(text.encode("utf-8", "surrogatepass"))
    if size > MAX_SETTINGS_BYTES:
        return [], [
            f"not a TOML settings file: {size / 1024:,.0f} kB, and a settings file is at most "
            f"{MAX_SETTINGS_BYTES // 1024} kB (every parameter of a preset takes a few kB); nothing applied"
        ]
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        return [], [f"not a TOML settings file: {exc}"]
    entries: list[tuple[str, str, Any]] = []
    problems: list[str] = []
    for group, fields in doc.items():
        if not isinstance(fields, dict):
            problems.append(f"{group}: expected a [{group}] table of parameters, got a value")
            continue
        entries.extend((group, field, value) for field, value in fields.items())
    return entries, problems


def load_settings(session: Session, text: str) -> list[str]:
    """Apply a TOML settings text through `Session.set_param` (each value validated by its group);
    returns one line per refusal. The accepted values stay applied; "scenario" values take
    effect at the next reset."""
    entries, refused = parse_settings(text)
    for group, field, value in entries:
        try:
            session.set_param(group, field, value)
        except ParamError as exc:
            refused.append(str(exc))
        except Exception as exc:  # whatever an entry does, the others still apply
            refused.append(f"{group}.{field}: {type(exc).__name__}: {exc}")
    return refused


def settings_commands(groups: dict[str, ParamGroup], text: str) -> tuple[list[SetParam], list[str]]:
    """The `SetParam` commands of a TOML settings text that the given groups accept, checked in file
    order (so a rule across fields sees the earlier values), and one line per refused entry."""
    entries, refused = parse_settings(text)
    groups = dict(groups)
    commands = []
    for group, field, value in entries:
        if group not in groups:
            refused.append(f"this session has no parameter group {group!r}")
            continue
        try:
            groups[group] = replaced(groups[group], field, value)
        except ParamError as exc:
            refused.append(f"{group}.{exc}")
            continue
        except Exception as exc:  # whatever an entry does, the others still apply
            refused.append(f"{group}.{field}: {type(exc).__name__}: {exc}")
            continue
        commands.append(SetParam(group, field, value))
    return commands, refused
