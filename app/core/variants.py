"""Scenario variants: the cases a preset can run in (mass drop: position / residual / fusion;
compliance: stiff / nullspace / full; limit drop: position / velocity limit).

A scenario class lists its cases in `cases` and takes its case as one constructor argument named
by `case_arg` (the one it runs in is `chosen_case`); `variant_of` names the argument, the choices
and the current one, and `make_variant` builds the scenario for a choice. Scenarios without cases
have no variants.
"""

from __future__ import annotations

from typing import NamedTuple

from app.scenarios import Scenario, get_scenario


class Variant(NamedTuple):
    """The constructor argument that picks a case, its choices and the current choice."""

    param: str
    options: tuple[str, ...]
    current: str


def variant_of(scenario: Scenario) -> Variant | None:
    """The cases of a scenario instance, or None."""
    if not scenario.cases:
        return None
    return Variant(scenario.case_arg, tuple(scenario.cases), scenario.chosen_case)


def make_variant(name: str, choice: str) -> Scenario:
    """A fresh scenario `name` in case `choice`; ValueError if it has no such case."""
    base = get_scenario(name)
    variant = variant_of(base)
    if variant is None or choice not in variant.options:
        options = ", ".join(variant.options) if variant else "none"
        raise ValueError(f"scenario {name!r} has no case {choice!r} (cases: {options})")
    return type(base)(**{variant.param: choice})  # type: ignore[call-arg]
