"""The lab: one Session (and its twin arm) with everything a person changes about it — no threads.

`Lab.apply(command)` applies one command of `app.core.commands` (a refused one becomes a `Notice`,
nothing raises); each command type has its handler in `HANDLERS`. `Lab.advance(n)` runs n steps
through `Session.run`, logging each, and halts on divergence or a step error. The person's accepted
changes are the session's (`Session.changes`, the one store, `overrides` here), replayed in order
on a rebuilt session and on the twin. After a halt, Reset recovers: if the preset with the current
overrides halts again within `RECOVERY_STEPS` steps, the overrides applied since the simulation
last ran healthy are dropped, newest first, until it runs (each dropped one is named in a notice).
The Lab names no preset: what it needs from one comes through the scenario hooks (`app.scenarios`).

`app.live.loop.SimLoop` runs a Lab on its own thread (pacing, the command queue, publishing); tests
drive a Lab directly.
"""

from __future__ import annotations

import math
import time
import traceback
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from app.core.commands import (
    Command,
    DragCommand,
    Pause,
    Play,
    Reset,
    RestoreDefaults,
    SetParam,
    SetSpeed,
    SettleNow,
    SetTwin,
    StepOnce,
    SwitchSession,
)
from app.core.params import field_spec
from app.core.recovery import RECOVERY_STEPS, Health, recover
from app.core.session import Lockstep, RunResult, Session, StepRecord, WorkPending
from app.core.settings import finite_number
from app.core.steplog import StepLog
from app.core.switching import BuiltSwitch, build_switch, case_switch_text, plan_switch, same_value, switch_executor
from app.core.twin import Twin
from app.live.drag_owner import DragOwner
from app.live.notices import Notice, Notices
from app.live.twin_arm import TwinArm
from app.scenarios import PLAIN_PRESET, Offload, Scenario
from app.scenarios.metrics import DeflectionProbe
from control.params import ParamError, ParamGroup
from robots import guessed_text

UNPACED_SPEED = 1000.0  # a requested speed this high means "as fast as possible": every wake-up runs a full burst
SPEED_RANGE = (0.01, UNPACED_SPEED)
MAX_SINGLE_STEP = 10_000  # steps one StepOnce may ask for
OVERPOWERED_NOTICE_S = 2.0  # simulated time between two "overpowered" notices
OVERPOWERED_CHECK_STEPS = 10  # steps between two looks for an overpowered joint (a look costs ~10 µs)


@dataclass(frozen=True)
class Settings:
    """The session's parameter groups in force (`Session.params()`, frozen); `version` grows."""

    version: int
    groups: dict[str, ParamGroup]

    @property
    def values(self) -> dict[str, dict[str, Any]]:
        """Group → field → value as plain data (for exports and tests)."""
        return {name: group.values() for name, group in self.groups.items()}


def label(o: SetParam) -> str:
    """How a notice names an override: "damper.lambda_ = 300.0", "posture_task.compliance[3] = 1.0"."""
    index = "" if o.index is None else f"[{o.index}]"
    return f"{o.group}.{o.field}{index} = {o.value!r}"


class Lab:
    """One session and the person's changes to it (see the module docstring)."""

    def __init__(
        self, scenario: str | Scenario | Session = PLAIN_PRESET, log_seconds: float = 60.0, **session_args: Any
    ):
        """A lab over `scenario`: a built `Session`, or a preset (name or object) built into one with
        `session_args`, `Session`'s own arguments (robot, executor, seed; "" = the preset's default)."""
        if isinstance(scenario, Session):
            self.session = scenario
        else:
            args: dict[str, Any] = {
                k: (v or None) if k in ("robot", "executor") else v for k, v in session_args.items()
            }
            self.session = Session(scenario, **args)
        self.seed = self.session.seed
        self.robot_choice = str(session_args.get("robot") or "")  # "" = the scenario's default robot
        self.dt = float(self.session.world.model.opt.timestep)
        self._log_seconds = log_seconds
        self.log = StepLog(
            self.session.robot.nq, capacity=round(log_seconds / self.dt), segments=self.session.scenario.segments
        )
        # a second session in lockstep with another objective (app.core.twin)
        self.twins = TwinArm(lambda reason: self.notify("warning", "Twin arm off", reason), log_seconds)
        self.health = Health()  # which overrides were in force while the simulation last ran healthy
        self.running = False
        self.halted = ""  # why the simulation auto-paused, "" otherwise
        self._resume_after_reset = False
        self.pending_steps = 0  # steps of a single-step request not yet run (run in chunks)
        self.settling = False  # "Settle now": the settle phase runs unpaced, in chunks, then paced again
        self.speed = 1.0
        self.pacing_epoch = 0  # grows when the pacing must restart (play, reset, switch, speed)
        self.session_id = 0  # grows when the session (robot, scenario) is rebuilt
        self.restarts = 0  # grows at every reset or rebuild (the log starts over)
        self.total_steps = 0
        self.fallback_steps = 0  # fallback steps since the last reset
        # accepted changes of a parameter, the preset, case, robot or controller (never reset; a lesson step
        # compares it with its set-up's to see a change even when it was set back), the newest in words
        self.edits = 0
        self.last_edit = ""
        self.step_cpu_s = 0.0  # CPU time spent in steps
        self.drag = DragOwner()  # who holds the drag spring
        self.overpowered = ""  # joints the surroundings overpower, in words (World.overpowered)
        self._overpowered_notice_t = -math.inf
        self._overpowered_check_at = 0  # total_steps at which advance() looks for an overpowered joint again
        self.notices = Notices()  # for the browser (`app.live.notices`)
        self.dirty = True  # something changed since the last frame
        self.defaults = self.session.params()  # the preset's (and case's) own values, before any change
        self._deflection: DeflectionProbe | None = None  # TCP and elbow at t = 0 (`app.scenarios.metrics`)
        self._arm_deflection()
        self.settings = Settings(0, self._read_settings())
        # a preset switch whose preset needs a costly computation first (a swivel plan) raises
        # WorkPending from `apply` (nothing changed) instead of computing it here; the app's loop
        # computes it elsewhere and applies the switch again
        self.defer_work = False
        self.offload: Offload | None = None  # where the sessions compute their costly page signals (`set_offload`)
        self._say_guessed()

    def _say_guessed(self) -> None:
        """A notice naming the robot values its description had to guess (a URDF without a sidecar)."""
        self._guessed_said_for = self.session.robot.name
        text = guessed_text(self.session.robot)
        if text:
            self.notify("warning", "Guessed robot values", text)

    @property
    def overrides(self) -> list[SetParam]:
        """The person's accepted parameter changes in force, oldest first (`Session.changes`)."""
        return self.session.changes

    # ---- commands -------------------------------------------------------------------------------
    def apply(self, cmd: Command) -> None:
        """Apply one command through its handler (`HANDLERS`); a refused or failing one becomes a
        notice (never raises, but for WorkPending with `defer_work`)."""
        try:
            handler = HANDLERS.get(type(cmd))
            if handler is None:
                raise ValueError(f"unknown command {cmd!r}")
            handler(self, cmd)
        except WorkPending:
            raise  # (only with defer_work, before anything changed)
        except (ValueError, KeyError) as exc:
            self.notify("error", "Refused", _reason(exc), getattr(cmd, "client_id", None))
        except Exception as exc:  # never let a command take the loop down
            traceback.print_exc()
            self.notify("error", "Command failed", f"{type(exc).__name__}: {exc}", getattr(cmd, "client_id", None))
        self.dirty = True

    def _play(self, cmd: Play) -> None:
        if self.halted:
            self.notify("warning", "Cannot play", "The simulation diverged: press Reset first.")
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
        if self.halted:
            self.notify("warning", "Cannot step", "The simulation diverged: press Reset first.")
            return
        steps = None if isinstance(cmd.steps, str) else finite_number(cmd.steps)
        if steps is None or steps != int(steps) or not 1 <= steps <= MAX_SINGLE_STEP:
            raise ValueError(f"step count must be a whole number 1…{MAX_SINGLE_STEP}, got {cmd.steps!r}")
        self.pending_steps += int(steps)

    # ---- stepping -------------------------------------------------------------------------------
    def advance(self, n: int, until: Callable[[StepRecord], bool] | None = None) -> RunResult:
        """Run n steps, logging each (and the twin in lockstep); halt at the first sign of divergence.
        `until`, asked after each step (as in `Session.run`), may end the run early."""
        cpu0 = time.thread_time()
        log, twin = self.log, self.twin
        deflection, session = self._deflection, self.session

        def record(rec: StepRecord) -> None:
            if deflection is not None:  # the scenario's `logs_deflection`: distances from the t = 0 pose
                rec.signals["tcp_dev_mm"], rec.signals["elbow_dev_mm"] = deflection.read(session)
            # the task target, for the replay's scene (the target of a planned or contact task is not a
            # function of time alone)
            signals, target = rec.signals, rec.target.position
            signals["target_x_m"], signals["target_y_m"], signals["target_z_m"] = target[0], target[1], target[2]
            log.append(rec)
            self.total_steps += 1
            if rec.fallback:
                self.fallback_steps += 1

        group = () if twin is None else (Lockstep(twin.session, twin.log.append),)
        result = self.session.run(steps=n, record=record, until=until, lockstep=group)
        for r in (result, *result.lockstep):
            if r.error is not None:  # a bug or numerical failure must not kill the server
                traceback.print_exception(r.error)
        if twin is not None and result.lockstep[0].halted:  # the twin stops alone, with its own reason
            self.twins.off(f"the twin arm (W_{twin.objective}) is switched off: {result.lockstep[0].reason}")
        if result.halted:
            self._halt(result.reason)
        else:
            self.health.ran(result.steps, len(self.overrides))
            if self.total_steps >= self._overpowered_check_at:
                self._overpowered_check_at = self.total_steps + OVERPOWERED_CHECK_STEPS
                self._check_overpowered()
        self.step_cpu_s += time.thread_time() - cpu0
        self.dirty = True
        return result

    def _check_overpowered(self) -> None:
        """Say when the surroundings (the drag) overpower a joint: in the status, and in a notice when
        it starts (at most every OVERPOWERED_NOTICE_S of simulated time)."""
        last = self.session.last
        was, self.overpowered = self.overpowered, self.session.world.overpowered(last.tau_ext if last else None)
        t = self.session.world.time
        if self.overpowered and not was and t - self._overpowered_notice_t >= OVERPOWERED_NOTICE_S:
            self._overpowered_notice_t = t
            self.notify(
                "warning",
                "Overpowered",
                f"{self.overpowered}: more than the motors can resist, so no controller can hold the arm here",
            )

    def step_pending(self, chunk: int) -> RunResult | None:
        """Run up to `chunk` steps of a pending single-step request (None if there is none)."""
        n = min(self.pending_steps, int(chunk))
        if n <= 0:
            return None
        self.pending_steps -= n
        result = self.advance(n)
        if result.halted:
            self.pending_steps = 0
        return result

    def _settle_now(self, cmd: SettleNow | None = None) -> None:
        """Start "Settle now" (see `SettleNow`); ValueError (a notice) when there is nothing to settle."""
        if self.halted:
            self.notify("warning", "Cannot settle", "The simulation diverged: press Reset first.")
            return
        if not self.session.settle_pending():
            raise ValueError("nothing to settle: the preset has no settle phase, or it has ended (Reset starts again)")
        self.settling = True
        self.running = True
        self.pending_steps = 0

    def settle_chunk(self, chunk: int) -> RunResult | None:
        """Run up to `chunk` steps of "Settle now" (None if it is not on). When the settle phase has
        ended (converged, or at its cap) the run goes on paced from here: the pacing restarts."""
        if not self.settling:
            return None
        result = self.advance(int(chunk))
        if result.halted:
            self.settling = False
        elif not self.session.settle_pending():
            self.settling = False
            self.pacing_epoch += 1
            self.notify("info", "Settled", f"the trajectory starts at t = {self.session.world.time:.3f} s; paced again")
        return result

    def _halt(self, reason: str) -> None:
        self._resume_after_reset = self.running
        self.running = False
        self.settling = False
        self.pending_steps = 0
        self.halted = reason
        self.notify("error", "Simulation paused", f"{reason}. Press Reset to start again.")

    # ---- reset and recovery ---------------------------------------------------------------------
    def reset(self, cmd: Reset | None = None) -> None:
        """Back to t = 0 with the accepted settings; after a halt, recover (see the module docstring)."""
        if self.halted:
            self._recover()
            self.halted = ""
            self.running = self._resume_after_reset
            self._resume_after_reset = False
        self.session.reset()  # the session re-applies its parameter overrides itself
        self._after_rebuild()
        self.twins.reset()

    def _recover(self) -> None:
        """The session rebuilt with the overrides, dropping them newest first until it runs (`app.core.recovery`)."""
        done = recover(self.session, self.overrides, self.robot_choice, self.health)
        self._install(done.session)
        for d in done.dropped:
            since = "since the simulation last ran healthy" if d.recent else "earlier"
            body = f"{label(d.change)} (applied {since}) is undone: with it the preset halts again ({d.reason})"
            self.notify("warning", "Setting dropped", body)
        if done.halts_alone:
            self.notify("error", "Preset halts", f"the preset itself halts within {RECOVERY_STEPS} steps")

    def set_offload(self, offload: Offload | None) -> None:
        """Have this session, its twin and every later one compute their costly page signals (the
        polish margin) in `offload`, off the thread that steps them; None: inline."""
        self.offload = offload
        self.session.set_offload(offload)
        if self.twin is not None:
            self.twin.session.set_offload(offload)

    def _install(self, session: Session) -> None:
        """Make `session` (its changes in force) the lab's; the twin follows."""
        session.set_offload(self.offload)
        self.session = session
        self.session_id += 1
        self.defaults = session.params()
        self.log = StepLog(
            session.robot.nq, capacity=round(self._log_seconds / self.dt), segments=session.scenario.segments
        )
        self._after_rebuild()
        self.twins.rebuild(session, self.robot_choice)
        if session.robot.name != getattr(self, "_guessed_said_for", None):
            self._say_guessed()

    def _after_rebuild(self) -> None:
        """After a reset or a new session: clear logs and drag."""
        self.drag.client = None
        self.settling = False
        self.overpowered = ""
        self._overpowered_notice_t = -math.inf
        self._overpowered_check_at = 0
        self.fallback_steps = 0
        self.health.steps_since_change = 0
        self.pending_steps = 0
        self.log.clear()
        self._arm_deflection()
        self.restarts += 1
        self.pacing_epoch += 1
        self._settings_changed()

    # ---- parameters -----------------------------------------------------------------------------
    def _set_param(self, cmd: SetParam) -> None:
        """One parameter change, validated by its group's dataclass; refused: a notice, nothing changes."""
        before = self.session.params().get(cmd.group)
        try:
            self.session.set_param(cmd.group, cmd.field, cmd.value, cmd.index)
        except ParamError as exc:
            self.notify("error", "Value refused", in_knob_words(str(exc), cmd.group, cmd.field), cmd.client_id)
            self._settings_changed()  # the panels show the value that is still in force
            return
        after = self.session.params().get(cmd.group)
        if (
            before is None
            or after is None
            or not same_value(before.values().get(cmd.field), after.values().get(cmd.field))
        ):
            self._edited(label(cmd))
        self.health.steps_since_change = 0
        self._settings_changed()  # the main arm took it: the panels show it whatever the twin does
        self.twins.follow_param(cmd)

    def _restore_defaults(self, cmd: RestoreDefaults | None = None) -> None:
        """Every parameter of the preset back to its defaults; the run restarts (twin too)."""
        self.health.healthy = 0
        self._edited("every parameter back to its default")
        self.session.restore_defaults()
        self._after_rebuild()
        self.twins.rebuild(self.session, self.robot_choice)
        if self.halted:
            self.halted = ""
            self.running = self._resume_after_reset
            self._resume_after_reset = False

    def _edited(self, what: str) -> None:
        """Count an accepted change of the run's set-up (`edits`)."""
        self.edits += 1
        self.last_edit = what

    def _set_speed(self, cmd: SetSpeed) -> None:
        value = finite_number(cmd.factor)
        if value is None or not SPEED_RANGE[0] <= value <= SPEED_RANGE[1]:
            raise ValueError(f"speed must be between {SPEED_RANGE[0]} and {SPEED_RANGE[1]}, got {cmd.factor!r}")
        self.speed = value
        self.pacing_epoch += 1

    def _settings_changed(self) -> None:
        self.settings = Settings(self.settings.version + 1, self._read_settings())
        self.dirty = True

    def _read_settings(self) -> dict[str, ParamGroup]:
        return self.session.params()

    # ---- switching (app.core.switching) ----------------------------------------------------------
    def _switch(self, cmd: SwitchSession) -> None:
        plan = plan_switch(self.session, self.robot_choice, cmd)
        if plan is None:
            if cmd.executor is not None and cmd.executor != self.session.executor_name:
                self._switch_executor(cmd.executor)
            return
        # with defer_work, raises WorkPending before anything changed
        self.install_switch(build_switch(plan, self.seed, self.overrides, self.defaults, self.defer_work))

    def install_switch(self, built: BuiltSwitch) -> None:
        """Make a switch's new session (`app.core.switching.build_switch`) the lab's."""
        if built.robot_note:
            self.notify("info", "Robot changed", built.robot_note)
        plan = built.plan
        if plan.case_switch:
            self.health.healthy = min(self.health.healthy, len(built.kept))
        elif plan.new_preset or plan.case is not None:
            self.health.healthy = len(built.kept)
        self.health.refused(built.refused)
        self.robot_choice = built.robot_choice
        self._edited(f"switched to {built.session.scenario.name} on {built.session.robot.name}")
        self._install(built.session)
        self.halted = ""
        text = case_switch_text(built) if plan.case_switch else ""
        if text:
            self.notify("info", f"Case {plan.case}", text)

    def _arm_deflection(self) -> None:
        """Take the TCP's and the elbow's positions now (t = 0) as the reference of the deflection signals,
        in the presets that log them (`Scenario.logs_deflection`)."""
        s = self.session
        self._deflection = DeflectionProbe(s) if s.scenario.logs_deflection else None

    def _switch_executor(self, name: str) -> None:
        switch_executor(self.session, name)  # re-applies the overrides the new executor has
        self._edited(f"controller {name}")
        self.twins.follow_executor(name)
        self._settings_changed()

    # ---- the twin arm ---------------------------------------------------------------------------
    @property
    def twin(self) -> Twin | None:
        """The twin arm, if one runs (`app.live.twin_arm`)."""
        return self.twins.twin

    def _set_twin(self, cmd: SetTwin) -> None:
        """Switch the twin off (None) or on with an objective; on restarts the scenario."""
        if cmd.objective is None or cmd.objective == "":
            self.twins.off()
            return
        self.twins.on(self.session, self.robot_choice, str(cmd.objective))  # ValueError: wrong objective
        self.reset()

    # ---- the drag spring ------------------------------------------------------------------------
    def _apply_drag(self, cmd: DragCommand) -> None:
        self.drag.apply(self.session, cmd)

    @property
    def drag_client(self) -> int | None:
        """The client holding the drag spring, if any (`app.live.drag_owner`)."""
        return self.drag.client

    # ---- output ---------------------------------------------------------------------------------
    def notify(self, level: str, title: str, body: str, client_id: int | None = None) -> None:
        """Queue a notice for the browser (and keep it in `notice_log`)."""
        self.notices.say(Notice(level, title, body, client_id))
        self.dirty = True

    @property
    def notice_log(self) -> deque[Notice]:
        """Every notice (for tests and logs)."""
        return self.notices.log

    def take_notices(self) -> list[Notice]:
        """Notices produced since the last call."""
        return self.notices.take()


# the handler of each command type (a command the table lacks is refused with a notice)
HANDLERS: dict[type, Callable[[Lab, Any], None]] = {
    DragCommand: Lab._apply_drag,
    Play: Lab._play,
    Pause: Lab._pause,
    StepOnce: Lab._step_once,
    SettleNow: Lab._settle_now,
    Reset: Lab.reset,
    SetSpeed: Lab._set_speed,
    SwitchSession: Lab._switch,
    SetParam: Lab._set_param,
    RestoreDefaults: Lab._restore_defaults,
    SetTwin: Lab._set_twin,
}


def _reason(exc: BaseException) -> str:
    text = str(exc) or type(exc).__name__
    if isinstance(exc, TypeError) and "unexpected keyword" in text:
        return f"this controller has no such setting ({text})"
    return text


def in_knob_words(message: str, group: str, field: str) -> str:
    """A refusal as the page's knob says it: "λ must be between 1 and 1000 1/s, got -5" for the
    parameter's "damper.lambda_ must be …" (the knob's label instead of the group and field names)."""
    try:
        label_text = field_spec(group, field).label
    except ParamError:
        return message
    prefix = f"{group}.{field}"
    if not label_text or not message.startswith(prefix):
        return message
    return label_text + message[len(prefix) :]
