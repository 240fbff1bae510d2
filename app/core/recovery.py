"""Recovery after a halt: the session rebuilt with the person's changes, dropping them newest first until
it runs — a function over (session, changes).

Reset after a halt builds the preset afresh with the accepted changes; if it halts again within
RECOVERY_STEPS steps, the newest change is undone and it is built again, until it runs (or the preset
alone halts). `Health` says which changes were in force while the simulation last ran healthy, so a
dropped change can be told as one applied since then or earlier.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

from app.core.commands import SetParam, label
from app.core.session import Session

RECOVERY_STEPS = 100  # "recovered": this many steps run without a halt


@dataclass
class Health:
    """`healthy`: the first `healthy` of the session's changes were all in force while the simulation ran
    RECOVERY_STEPS steps without a halt; `steps_since_change` counts the steps run since the last change."""

    healthy: int = 0
    steps_since_change: int = 0

    def ran(self, steps: int, changes: int) -> None:
        """`steps` ran without a halt with `changes` changes in force."""
        self.steps_since_change += steps
        if self.steps_since_change >= RECOVERY_STEPS:
            self.healthy = changes

    def switched(self, kept: int, case_switch: bool, new_preset: bool) -> None:
        """A switch carried `kept` changes to a new session: a new case keeps the healthy ones among them, a
        new preset counts them all as healthy (they are the groups a preset keeps), a new robot all it had."""
        if case_switch:
            self.healthy = min(self.healthy, kept)
        elif new_preset:
            self.healthy = kept

    def refused(self, positions: Sequence[int]) -> None:
        """The changes at `positions` were left out of a rebuilt session."""
        self.healthy -= sum(1 for i in positions if i < self.healthy)


@dataclass(frozen=True)
class Dropped:
    """A change recovery undid: applied since the simulation last ran healthy (`recent`) or earlier, and
    the halt it caused (`reason`)."""

    change: SetParam
    recent: bool
    reason: str

    def text(self) -> str:
        """The change undone and why, in words (a notice's body)."""
        since = "since the simulation last ran healthy" if self.recent else "earlier"
        return f"{label(self.change)} (applied {since}) is undone: with it the preset halts again ({self.reason})"


@dataclass(frozen=True)
class Recovered:
    """The rebuilt session (its changes in force), the changes undone, and whether the preset halts alone."""

    session: Session
    dropped: list[Dropped] = field(default_factory=list)
    halts_alone: bool = False


def rebuilt(session: Session, robot_choice: str) -> Session:
    """A fresh session of `session`'s preset, robot (`robot_choice`, "" = the preset's default), executor
    and seed, without changes."""
    return Session(session.preset, robot=robot_choice or None, executor=session.executor_name, seed=session.seed)


def recover(session: Session, changes: Sequence[SetParam], robot_choice: str, health: Health) -> Recovered:
    """`session` rebuilt with `changes` until it runs RECOVERY_STEPS steps without a halt, dropping the
    newest change each time it does not (see the module docstring); `health` follows the changes left."""
    changes = list(changes)
    dropped: list[Dropped] = []
    while True:
        fresh = rebuilt(session, robot_choice)
        health.refused(fresh.replay(changes))
        probe = fresh.run(steps=RECOVERY_STEPS)
        if not probe.halted:
            return Recovered(fresh, dropped)
        changes = fresh.changes  # those the rebuilt session accepted
        if not changes:
            return Recovered(fresh, dropped, halts_alone=True)
        recent = len(changes) - 1 >= health.healthy
        dropped.append(Dropped(changes.pop(), recent, probe.reason))
        health.healthy = min(health.healthy, len(changes))
