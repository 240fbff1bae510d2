"""The loop's run flags: running, "Settle now", the steps of a single step still to run, the speed and the
pacing epoch, with the commands that set them (Play, Pause, StepOnce, SettleNow, SetSpeed).

The loop (`app.live.loop.SimLoop`) owns one `RunFlags` beside its Lab and steps through it: `advance`,
`step_pending` and `settle_chunk` run the lab's steps and stop the flags when the lab halts. Every other
command goes to the Lab (`apply`), and the flags follow what it did: a reset or a new session ends a
settle or a single step and restarts the pacing; a reset that recovered from a halt resumes the run if
it was running when it halted. Tests drive a Lab alone, or a Lab with its flags, without a thread.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from app.core.commands import Command, Pause, Play, SetSpeed, SettleNow, StepOnce, SwitchSession
from app.core.session import RunResult, StepRecord
from app.core.settings import finite_number
from app.live.lab import Lab

UNPACED_SPEED = 1000.0  # a requested speed this high means "as fast as possible": every wake-up runs a full burst
SPEED_RANGE = (0.01, UNPACED_SPEED)
MAX_SINGLE_STEP = 10_000  # steps one StepOnce may ask for


class RunFlags:
    """How the loop runs `lab` (see the module docstring)."""

    def __init__(self, lab: Lab, running: bool = False):
        self.lab = lab
        self.running = running
        self.settling = False  # "Settle now": the settle phase runs unpaced, in chunks, then paced again
        self.pending_steps = 0  # steps of a single-step request not yet run (run in chunks)
        self.speed = 1.0
        self.pacing_epoch = 0  # grows when the pacing must restart (play, reset, switch, speed)
        self._resume_after_reset = False  # running when the lab halted
        self._restarts = lab.restarts

    def apply(self, cmd: Command) -> None:
        """A run-flag command here; any other through `Lab.apply` (WorkPending passes through), then
        follow what it did. A refused one becomes a notice."""
        handler = HANDLERS.get(type(cmd))
        if handler is None:
            was_halted = bool(self.lab.halted)
            self.lab.apply(cmd)
            self.follow(resume=was_halted and not isinstance(cmd, SwitchSession))
            return
        try:
            handler(self, cmd)
        except ValueError as exc:
            self.lab.notify("error", "Refused", str(exc), getattr(cmd, "client_id", None))
        self.lab.dirty = True

    def follow(self, resume: bool = False) -> None:
        """After the lab changed: a reset or a new session ends a settle or a single step and restarts the
        pacing; with `resume`, a halt the lab recovered from resumes what ran before it."""
        if self.lab.restarts != self._restarts:
            self._restarts = self.lab.restarts
            self.settling = False
            self.pending_steps = 0
            self.pacing_epoch += 1
        if resume and not self.lab.halted:
            self.running = self._resume_after_reset
            self._resume_after_reset = False

    # ---- the commands ---------------------------------------------------------------------------
    def _play(self, cmd: Play) -> None:
        if self.lab.halted:
            self.lab.notify("warning", "Cannot play", "The simulation diverged: press Reset first.")
        elif not self.running:
            self.running = True
            self.pacing_epoch += 1

    def _pause(self, cmd: Pause) -> None:
        self.running = False
        self.settling = False
        self.pending_steps = 0

    def _step_once(self, cmd: StepOnce) -> None:
        self.running = False
        self.settling = False
        if self.lab.halted:
            self.lab.notify("warning", "Cannot step", "The simulation diverged: press Reset first.")
            return
        steps = None if isinstance(cmd.steps, str) else finite_number(cmd.steps)
        if steps is None or steps != int(steps) or not 1 <= steps <= MAX_SINGLE_STEP:
            raise ValueError(f"step count must be a whole number 1…{MAX_SINGLE_STEP}, got {cmd.steps!r}")
        self.pending_steps += int(steps)

    def _settle_now(self, cmd: SettleNow) -> None:
        """Start "Settle now" (see `SettleNow`); ValueError (a notice) when there is nothing to settle."""
        if self.lab.halted:
            self.lab.notify("warning", "Cannot settle", "The simulation diverged: press Reset first.")
            return
        if not self.lab.session.settle_pending():
            raise ValueError("nothing to settle: the preset has no settle phase, or it has ended (Reset starts again)")
        self.settling = True
        self.running = True
        self.pending_steps = 0

    def _set_speed(self, cmd: SetSpeed) -> None:
        value = finite_number(cmd.factor)
        if value is None or not SPEED_RANGE[0] <= value <= SPEED_RANGE[1]:
            raise ValueError(f"speed must be between {SPEED_RANGE[0]} and {SPEED_RANGE[1]}, got {cmd.factor!r}")
        self.speed = value
        self.pacing_epoch += 1

    # ---- stepping -------------------------------------------------------------------------------
    def advance(self, n: int, until: Callable[[StepRecord], bool] | None = None) -> RunResult:
        """`Lab.advance`; a halt stops the run (Reset resumes it if it was running)."""
        result = self.lab.advance(n, until=until)
        if result.halted:
            self._resume_after_reset = self.running
            self.running = False
            self.settling = False
            self.pending_steps = 0
        return result

    def step_pending(self, chunk: int) -> RunResult | None:
        """Run up to `chunk` steps of a pending single-step request (None if there is none)."""
        n = min(self.pending_steps, int(chunk))
        if n <= 0:
            return None
        self.pending_steps -= n
        return self.advance(n)

    def settle_chunk(self, chunk: int) -> RunResult | None:
        """Run up to `chunk` steps of "Settle now" (None if it is not on). When the settle phase has
        ended (converged, or at its cap) the run goes on paced from here: the pacing restarts."""
        if not self.settling:
            return None
        result = self.advance(int(chunk))
        if not result.halted and not self.lab.session.settle_pending():
            self.settling = False
            self.pacing_epoch += 1
            t = self.lab.session.world.time
            self.lab.notify("info", "Settled", f"the trajectory starts at t = {t:.3f} s; paced again")
        return result


# the handler of each run-flag command type (the Lab's `HANDLERS` has the others)
HANDLERS: dict[type, Callable[[RunFlags, Any], None]] = {
    Play: RunFlags._play,
    Pause: RunFlags._pause,
    StepOnce: RunFlags._step_once,
    SettleNow: RunFlags._settle_now,
    SetSpeed: RunFlags._set_speed,
}
