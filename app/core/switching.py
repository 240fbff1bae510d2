"""Switching a run: a new preset, case or robot (a new session carrying the person's changes it keeps),
or a new controller on the same session — functions over (session, changes) that the app's lab calls.

A switch is planned from the command and the session (`plan_switch`, at once), the new session is built
with the changes it carries (`build_switch`: the costly part, which the app's loop runs off its thread),
and the caller makes it its own. A new preset starts from its defaults but for the groups in
KEPT_ON_PRESET_SWITCH; a new case of the same preset keeps every value the person set on a field the
case does not own (one whose default the case changes), and resets those it owns; a robot switch
keeps every change the new session accepts.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from app.core.commands import SetParam, SwitchSession
from app.core.executors import EXECUTORS
from app.core.session import Session
from app.core.steplog import StepLog, session_log
from app.core.variants import make_variant
from app.scenarios import Scenario
from control.params import ParamGroup

KEPT_ON_PRESET_SWITCH = ("drag",)  # parameter groups a new preset keeps from the old one


@dataclass(frozen=True)
class SwitchPlan:
    """What a switch builds: the scenario (`spec`), the robot asked for ("" = the preset's default) and
    the executor (None = the preset's default); `case` is the case asked for (None: none), `same_preset`
    whether the preset stays (a case or robot switch)."""

    spec: str | Scenario
    robot_choice: str
    executor: str | None
    case: str | None
    new_preset: bool  # a preset was named (the robot may fall back to the preset's own)
    same_preset: bool

    @property
    def case_switch(self) -> bool:
        """A new case of the same preset."""
        return self.case is not None and self.same_preset


@dataclass
class BuiltSwitch:
    """A switch's new session with the changes it carries in force (`kept` asked for, `reset_by_case`
    those the case owns and reset), the robot choice it ran with and, when the asked robot could not
    run the preset, why (`robot_note`)."""

    plan: SwitchPlan
    session: Session
    robot_choice: str
    kept: list[SetParam]
    reset_by_case: list[SetParam]
    refused: list[int]  # positions in `kept` the new session refused
    robot_note: str = ""
    log: StepLog | None = None  # an empty step log for the session, when asked for (`build_switch`)
    twin: Any = None  # the twin arm (or the ValueError it met) built beside `session`, when one runs


def rebuilds(cmd: SwitchSession) -> bool:
    """True for a preset, case or robot switch (a new session), False for a controller switch alone."""
    return not (cmd.scenario is None and cmd.robot is None and cmd.variant is None)


def plan_switch(session: Session, robot_choice: str, cmd: SwitchSession) -> SwitchPlan | None:
    """The plan of a preset, case or robot switch of `session` (run on `robot_choice`); None for a
    controller switch alone (`switch_executor`). ValueError for a case the preset does not have."""
    if not rebuilds(cmd):
        return None
    name = cmd.scenario if cmd.scenario is not None else session.scenario.name
    # a new scenario brings its default executor unless one is asked for explicitly
    executor = (
        cmd.executor if cmd.executor is not None else (None if cmd.scenario is not None else session.executor_name)
    )
    if cmd.variant is not None:
        spec: str | Scenario = make_variant(name, cmd.variant)
    elif cmd.scenario is None:
        spec = session.preset  # same scenario object, same case (robot switch; its parameters are replayed)
    else:
        spec = name
    return SwitchPlan(
        spec=spec,
        robot_choice=robot_choice if cmd.robot is None else cmd.robot,
        executor=executor,
        case=cmd.variant,
        new_preset=cmd.scenario is not None,
        same_preset=cmd.scenario is None or cmd.scenario == session.scenario.name,
    )


def build_switch(
    plan: SwitchPlan,
    seed: int,
    changes: Sequence[SetParam],
    defaults: Mapping[str, ParamGroup],
    defer_work: bool = False,
    log_seconds: float = 0.0,
) -> BuiltSwitch:
    """The new session of `plan` with `seed` and the `changes` it carries (see the module docstring;
    `defaults` are the old session's own values). A preset the asked robot cannot run (a posture it
    lacks) runs on its default robot. With `defer_work`, WorkPending before anything is built when the
    preset needs a costly computation first (`Scenario.pending_work`). With `log_seconds`, an empty step
    log of that many seconds comes with it (allocating one takes tens of ms)."""
    note = ""
    robot_choice = plan.robot_choice
    try:
        new = Session(plan.spec, robot=robot_choice or None, executor=plan.executor, seed=seed, defer_work=defer_work)
    except ValueError as exc:
        if not plan.new_preset or not robot_choice:
            raise
        new = Session(plan.spec, robot=None, executor=plan.executor, seed=seed)
        note, robot_choice = f"{exc}. Using {new.robot.name}.", ""
    kept, reset = carried_changes(plan, defaults, new.params(), changes)
    refused = new.replay(kept)
    log = session_log(new, log_seconds) if log_seconds > 0 else None
    return BuiltSwitch(plan, new, robot_choice, kept, reset, refused, note, log)


def carried_changes(
    plan: SwitchPlan, before: Mapping[str, ParamGroup], after: Mapping[str, ParamGroup], changes: Sequence[SetParam]
) -> tuple[list[SetParam], list[SetParam]]:
    """(kept, reset by the case): the `changes` a switch carries to the new session (`before`, `after`:
    the two sessions' own parameter groups) and those a case switch resets to the case's value."""
    if plan.case_switch:
        owned = owned_fields(before, after)
        return [o for o in changes if (o.group, o.field) not in owned], [
            o for o in changes if (o.group, o.field) in owned
        ]
    if plan.new_preset or plan.case is not None:  # a new preset starts from its defaults
        return [o for o in changes if o.group in KEPT_ON_PRESET_SWITCH], []
    return list(changes), []


def case_switch_text(built: BuiltSwitch) -> str:
    """What a case switch kept and reset, in words ("" when there is nothing to say)."""
    in_force = built.session.changes
    refused = [o for o in built.kept if o not in in_force]  # the new session did not accept them
    parts = []
    if built.reset_by_case:
        names = sorted({f"{o.group}.{o.field}" for o in built.reset_by_case})
        parts.append(f"reset to the case's own value: {', '.join(names)}")
    if refused:
        parts.append(f"not in this case: {', '.join(sorted({f'{o.group}.{o.field}' for o in refused}))}")
    if in_force:
        parts.append(f"kept {len(in_force)} value(s) you set")
    return "; ".join(parts)


def switch_executor(session: Session, name: str) -> None:
    """Run `session` with the controller `name` from its next step (its changes re-applied); ValueError
    for an unknown one."""
    if name not in EXECUTORS:
        raise ValueError(f"unknown executor {name!r}; choose one of {', '.join(EXECUTORS)}")
    session.set_executor(name)


def owned_fields(before: Mapping[str, ParamGroup], after: Mapping[str, ParamGroup]) -> set[tuple[str, str]]:
    """(group, field) pairs a case owns: those whose default differs between two cases' parameter
    groups, and every field of a group only one of them has."""
    out: set[tuple[str, str]] = set()
    for name in set(before) | set(after):
        a, b = before.get(name), after.get(name)
        if a is None or b is None:
            out |= {(name, f) for f in (a or b).values()}  # type: ignore[union-attr]
            continue
        va, vb = a.values(), b.values()
        for f in set(va) | set(vb):
            if not same_value(va.get(f), vb.get(f)):
                out.add((name, f))
    return out


def same_value(a: Any, b: Any) -> bool:
    """Equal parameter values (arrays element-wise, None only with None)."""
    if a is None or b is None:
        return a is b
    try:
        return bool(np.array_equal(np.asarray(a), np.asarray(b)))
    except (TypeError, ValueError):
        return a == b
