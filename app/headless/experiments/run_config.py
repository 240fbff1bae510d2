"""What a run was made with, recorded beside its data: the experiments' `--set GROUP.FIELD=VALUE`
session parameters, and each run's configuration as its session ran it (robot, control period,
armature, every parameter group). A report reads these instead of the modules' constants."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable
from typing import Any

import numpy as np

TRUE_WORDS = ("on", "true", "yes")
FALSE_WORDS = ("off", "false", "no")


def parse_settings(texts: Iterable[str] | None) -> list[tuple[str, str, Any]]:
    """`--set` texts "GROUP.FIELD=VALUE" as (group, field, value) for `Session.set_param`: on/off
    (true/false) a bool, a number a number, anything else the text; ValueError (one line) for a text
    that is not of that form. The session checks the name and the value when the run is built."""
    out: list[tuple[str, str, Any]] = []
    for text in texts or ():
        name, sep, raw = str(text).partition("=")
        group, dot, field = name.strip().partition(".")
        raw = raw.strip()
        if not (sep and dot and group and field and raw) or "." in field:
            raise ValueError(f"--set {text!r}: expected GROUP.FIELD=VALUE, e.g. sensor.cutoff_hz=10")
        value: Any = raw
        if raw.lower() in TRUE_WORDS or raw.lower() in FALSE_WORDS:
            value = raw.lower() in TRUE_WORDS
        else:
            try:
                value = int(raw)
            except ValueError:
                try:
                    value = float(raw)
                except ValueError:
                    value = raw
        out.append((group, field, value))
    return out


def apply_settings(session, settings: Iterable[tuple[str, str, Any]]) -> None:
    """Each (group, field, value) on the session through the parameter path (`Session.set_param`); a
    refused one raises ParamError naming it."""
    for group, field, value in settings:
        session.set_param(group, field, value)


def run_configuration(session) -> dict:
    """The configuration a run was made with, as its session ran it: robot, control period (s), the
    armature of the controller's model and of the simulated arm (kg m² per joint) and every
    parameter group by name (its fields)."""
    world = session.world
    return {
        "robot": session.robot.name,
        "timestep_s": float(world.model.opt.timestep),
        "armature_model_kg_m2": [float(x) for x in session.robot.armature],
        "armature_simulated_kg_m2": [float(x) for x in np.asarray(world.model.dof_armature)[world.dof_adr]],
        "params": {name: _plain(dataclasses.asdict(group)) for name, group in session.params().items()},
    }


def _plain(obj):
    """Tuples as lists and numpy numbers as Python ones (JSON-ready)."""
    if isinstance(obj, dict):
        return {k: _plain(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple | np.ndarray):
        return [_plain(v) for v in obj]
    if isinstance(obj, np.generic):
        return obj.item()
    return obj
