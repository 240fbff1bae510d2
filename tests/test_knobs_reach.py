"""Every parameter reaches the run: changing it changes τ, the world or the scenario within a few steps.

The test enumerates every field of every parameter group a session may have (`GROUP_TYPES` and the
presets' `SCENARIO_TYPES`), sets it to another valid value (its range's other end, twice or half its
default, another choice, the other boolean) on a fresh session of each preset and executor that has
the group, resets, and steps beside an unchanged session of the same seed: the field reaches the run
when the applied torque τ, the joint positions or the task target differ at some step. A field that
reaches none in any context fails, unless its metadata says why it is display-only
(`param(..., display_only="...")`). So a new field that nothing reads fails here.

Contexts (`_contexts`): every preset with every executor for `STEPS` steps (polish through its
contact at 1 s, mass drop through its release), and the conditions some fields act in only.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable, Iterator

import numpy as np
import pytest

import robots
from app.core.executors import EXECUTORS
from app.core.params import GROUP_TYPES, SCENARIO_TYPES
from app.core.session import Session
from app.scenarios import SCENARIOS
from control.params import ParamError, ParamGroup, ParamSpec, spec_of

STEPS = {"polish": 1300, "mass-drop": 1700, "limit-drop": 2500}  # contact at 1 s, release at 1.5 s
DEFAULT_STEPS = 300


def _drag(pull_m: float) -> Callable[[Session], None]:
    def grab(session: Session) -> None:
        """Grab the last link at its origin and pull it `pull_m` sideways."""
        world = session.world
        body = int(world.model.nbody - 1)
        point = world.data.xpos[body].copy()
        session.drag.grab(world, body, point)
        session.drag.move(point + np.array([0.0, pull_m, 0.0]))

    return grab


Preset = tuple[tuple[str, str, object], ...]
Context = tuple[str, str, Callable[[Session], None] | None, Preset, bool]  # …, start near a joint limit


@functools.cache
def _near_limit(robot: str = "rizon4s") -> np.ndarray:
    """The home posture with joints 2 and 4 2° inside their upper limits (the dampers' zone)."""
    desc = robots.load(robot)
    q = np.array(desc.home, dtype=float)
    for j in (1, 3):
        q[j] = desc.q_upper[j] - np.radians(2.0)
    return q


@functools.cache
def _contexts() -> tuple[Context, ...]:
    """Every preset with every executor, then the conditions some parameters act in only: a drag
    (small and saturating), a start near the joint limits (the dampers; the classic [C] form, where
    d_i acts), each nullspace objective (only its k0 acts), the OSQP backend (the [C] solver
    settings act on an iterative solver only), the force integral on, the sander on."""
    small, large = _drag(0.05), _drag(1.0)
    out: list[Context] = [(s, e, None, (), False) for s in SCENARIOS for e in EXECUTORS]
    out += [("free", e, small, (), False) for e in EXECUTORS] + [("free", e, large, (), False) for e in EXECUTORS]
    out += [("free", e, None, (), True) for e in EXECUTORS]
    out += [("free", "compliance-qp", None, (("damper", "form", "classic"),), True)]  # d_i acts in [C15-17] only
    out += [("polish", "projection", None, (("nullspace", "objective", o),), False) for o in ("j", "f", "a", "d")]
    out += [("free", "compliance-qp", large, (("solver", "qp_backend", "osqp"),), False)]
    out += [("polish", "compliance-qp", None, (("solver", "qp_backend", "osqp"),), False)]
    out += [("polish", "projection", None, (("motion_force", "force_ki", 20.0),), False)]
    out += [("polish", e, None, (("sander", "enabled", True),), False) for e in EXECUTORS]
    return tuple(out)


def _session(context: Context, change: tuple[str, str, object] | None = None) -> Session:
    """A fresh session of the context, its presets (and `change`) set, reset, the drag applied."""
    scenario, executor, setup, preset, near_limit = context
    session = Session(scenario, executor=executor, seed=0, q0=_near_limit() if near_limit else None)
    for group, name, value in (*preset, *((change,) if change else ())):
        session.set_param(group, name, value)
    session.reset()
    if setup is not None:
        setup(session)
    return session


def _signature(session: Session) -> np.ndarray:
    rec = session.step()
    t = rec.target
    posture = t.q_posture if t.q_posture is not None else np.zeros(0)
    return np.concatenate([rec.tau, rec.q, t.position, t.rotation.ravel(), t.velocity, t.wrench, posture])


@functools.cache
def _groups(context: Context) -> dict[str, ParamGroup]:
    """The context's groups as its session has them (the preset's own values, before any change)."""
    return Session(context[0], executor=context[1]).params()


@functools.cache
def _baseline(context: Context) -> np.ndarray:
    session = _session(context)
    return np.array([_signature(session) for _ in range(STEPS.get(context[0], DEFAULT_STEPS))])


def _candidates(spec: ParamSpec, default: object) -> Iterator[object]:
    """Other valid-looking values of a field, the most different first."""
    if spec.kind == "bool":
        yield not default
        return
    if spec.kind == "choice":
        yield from (c for c in spec.choices if c != default)
        return
    scalar = default if isinstance(default, (int, float)) else float(np.max(np.abs(np.asarray(default, float))))
    lo, hi = spec.element(spec.lo, 0), spec.element(spec.hi, 0)
    step = spec.element(spec.step, 0)
    values = [hi, lo, 2.0 * scalar, 0.5 * scalar, scalar + (step or 1.0), 0.5]
    for v in values:
        if v is None or v == scalar:
            continue
        yield round(v) if spec.kind == "int" else float(v)


def _fields() -> list[tuple[str, type, str]]:
    out = []
    for group, cls in [*GROUP_TYPES.items(), *(("scenario", c) for c in SCENARIO_TYPES)]:
        out += [(group, cls, f.name) for f in dataclasses.fields(cls)]
    return sorted(set(out), key=lambda x: (x[0], x[1].__name__, x[2]))


# group -> the contexts in which one of its fields reached the run: its other fields try them first
# (a group's fields often act in the same condition: the nullspace dampers near a limit, the [C] solver
# settings on OSQP). Only the order of the search depends on it, not what it finds.
_REACHED_IN: dict[str, list[Context]] = {}


def _reaches(group: str, cls: type, name: str) -> tuple[bool, list[str]]:
    tried = []
    learned = _REACHED_IN.setdefault(group, [])
    # where a sibling reached first, then the contexts made for a group (its presets, or the drag for
    # the drag's group): cheaper
    aimed = sorted(
        _contexts(),
        key=lambda c: (c not in learned, not (any(g == group for g, _, _ in c[3]) or (group == "drag" and c[2]))),
    )
    for context in aimed:
        current = _groups(context).get(group)
        if type(current) is not cls:  # the "scenario" group: this preset's dataclass only
            continue
        if any(g == group and f == name for g, f, _ in context[3]):
            continue
        base = _baseline(context)
        default = getattr(current, name)
        valid = 0
        for value in _candidates(spec_of(cls, name), default):
            try:
                session = _session(context, (group, name, value))
            except ParamError:
                continue
            tried.append(f"{context[0]}/{context[1]}{list(context[3]) or ''}={value!r}")
            for k in range(base.shape[0]):
                sig = _signature(session)
                if sig.shape != base[k].shape or not np.array_equal(sig, base[k], equal_nan=True):
                    if context not in learned:
                        learned.insert(0, context)
                    return True, tried
            valid += 1
            if valid == 2:  # two valid values per context (the range's ends first)
                break
    return False, tried


def test_the_baseline_is_deterministic():
    """Two sessions of one seed step alike (else a difference below would prove nothing)."""
    context: Context = ("polish", "projection", None, (), False)
    again = _session(context)
    np.testing.assert_array_equal(np.array([_signature(again) for _ in range(1300)]), _baseline(context))


@pytest.mark.parametrize(("group", "cls", "name"), _fields(), ids=lambda v: getattr(v, "__name__", v))
def test_every_parameter_reaches_tau_the_world_or_the_scenario(group, cls, name):
    spec = spec_of(cls, name)
    reached, tried = _reaches(group, cls, name)
    if spec.display_only:
        assert not reached, f"{group}.{name} is marked display-only ({spec.display_only}) but acts: {tried}"
        return
    assert reached, f"{group}.{name} changes nothing in any context (tried {tried}); mark it display_only= with why"
