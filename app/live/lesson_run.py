"""A lesson step bound to the run its set-up made.

*Set up this step* builds a run (preset, case, robot, parameters); the step's claim is about that run
only. `bind` takes the run's identity once the set-up is applied; `cancel_line` says, in one line,
what changed since (the preset, case, robot, controller or a parameter — also one changed and set
back, which the lab's edit count shows), or None while the run is still the step's; `finish` measures
the run and returns the claim, which names the run it was measured on, or the cancellation line.
"""

from __future__ import annotations

from dataclasses import dataclass

from app.core.commands import SetParam
from app.live.frames import make_status
from app.live.lab import Lab
from app.live.lessons import Memo, Obs, Step, measure
from app.live.run_identity import RunIdentity, describe, differences, identity_from
from app.scenarios import SCENARIOS, get_scenario


def preset_claim_keys(preset: str) -> tuple[str, ...]:
    """The parameters every claim on `preset` rests on (`Scenario.claim_keys`), named with each claim
    besides those the step sets."""
    return get_scenario(preset).claim_keys if preset in SCENARIOS else ()


AGAIN = "press *Set up this step* to run it again."


@dataclass(frozen=True)
class BoundStep:
    """A step set up and not yet measured, with the run its set-up made."""

    lesson: str
    step: str
    identity: RunIdentity  # the run as the set-up left it
    edits: int  # the lab's edit count then (`Lab.edits`)
    restarts: int  # the lab's restart count then: earlier frames are of another run

    @property
    def key(self) -> tuple[str, str]:
        return (self.lesson, self.step)


def identity_of(lab: Lab) -> RunIdentity:
    """The identity of the lab's run now (on the loop thread)."""
    return identity_from(make_status(lab), lab.settings)


def bind(lab: Lab, lesson: str, step: str) -> BoundStep:
    """The step `step` of `lesson` bound to the lab's run now (on the loop thread, after its set-up)."""
    return BoundStep(lesson, step, identity_of(lab), lab.edits, lab.restarts)


def cancel_line(bound: BoundStep, now: RunIdentity, edits: int | None = None, last_edit: str = "") -> str | None:
    """One line saying what changed since the set-up (None: nothing). `edits` (the lab's edit count,
    when known) catches a change that was set back."""
    changed = differences(bound.identity, now)
    if changed:
        return f"Cancelled: after *Set up this step* {'; '.join(changed)}, so this run is not the step's — {AGAIN}"
    if edits is not None and edits != bound.edits:
        what = f" ({last_edit})" if last_edit else ""
        return (
            f"Cancelled: a setting was changed during the run{what} and set back, so part of this run is not "
            f"the step's — {AGAIN}"
        )
    return None


def claim_keys(step: Step, identity: RunIdentity) -> tuple[str, ...]:
    """The parameters a step's claim rests on: those its set-up sets and its preset's `claim_keys`."""
    keys = [f"{c.group}.{c.field}" for c in step.setup(None) if isinstance(c, SetParam)]
    keys += [k for k in preset_claim_keys(identity.preset) if k not in keys]
    return tuple(keys)


def run_line(step: Step, identity: RunIdentity, t: float) -> str:
    """The run a claim was measured on, in words."""
    return (
        f"*Measured on* {describe(identity, claim_keys(step, identity))}, over t = 0–{t:.1f} s since the reset, "
        "as the step set it up."
    )


def finish(lab: Lab, bound: BoundStep, step: Step, memo: Memo) -> tuple[Obs | None, str]:
    """On the loop thread: (the run's numbers, the claim naming its run), or (None, the cancellation
    line) when the run is no longer the step's. `memo`: the lesson's earlier steps' numbers (this
    step's are added to it)."""
    now = identity_of(lab)
    line = cancel_line(bound, now, lab.edits, lab.last_edit)
    if line is not None:
        return None, line
    obs = measure(lab)
    memo[bound.step] = obs
    return obs, f"{step.claim(obs, memo)} {run_line(step, now, obs['t'])}"
