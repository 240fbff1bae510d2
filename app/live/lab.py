"""The lab: one Session, its twin arm and the person's changes to it; it holds a run, no threads.

`Lab.apply(command)` applies one command of `app.core.commands` through its handler in `HANDLERS`
(a refused one becomes a notice, nothing raises); `Lab.advance(n)` runs n steps through `Session.run`,
logging each, and halts on divergence or a step error. The person's accepted changes are the
session's (`Session.changes`, the one store, `overrides` here). A switch and the recovery after a
halt are functions over (session, changes) in `app.core` (`switching`, `recovery`); the twin's life,
the drag's owner, the notices and the overpowered joints each have a module here. The Lab names no
preset. `app.live.loop.SimLoop` runs a Lab on its own thread with the run flags (`app.live.run_flags`);
tests drive a Lab directly.
"""

from __future__ import annotations

import time
import traceback
from collections import deque
from collections.abc import Callable
from typing import Any

from app.core.commands import Command, DragCommand, Reset, RestoreDefaults, SetParam, SetTwin, SwitchSession, label
from app.core.recovery import RECOVERY_STEPS, Health, recover
from app.core.session import Lockstep, RunResult, Session, StepRecord
from app.core.settings import Settings
from app.core.steplog import StepLog, session_log
from app.core.switching import BuiltSwitch, build_switch, case_switch_text, plan_switch, same_value, switch_executor
from app.core.twin import Twin
from app.live.drag_owner import DragOwner
from app.live.notices import Notice, Notices, in_knob_words, refusal_words
from app.live.overpowered import OverpoweredWatch
from app.live.twin_arm import TwinArm
from app.scenarios import PLAIN_PRESET, Offload, Scenario
from control.params import ParamError
from robots import guessed_text


class Lab:
    """One session and the person's changes to it (see the module docstring)."""

    def __init__(self, session: Session | str | Scenario = PLAIN_PRESET, log_seconds: float = 60.0, **args: Any):
        """A lab over `session`, or over a Session built from a preset (name or object) and `args`."""
        self.session = session if isinstance(session, Session) else Session(session, **args)
        self.robot_choice = str(args.get("robot") or "")  # "" = the scenario's default robot
        self.dt = float(self.session.world.model.opt.timestep)
        self._log_seconds = log_seconds
        self.log = session_log(self.session, log_seconds)
        self.twins = TwinArm(lambda reason: self.notify("warning", "Twin arm off", reason), log_seconds)
        self.health = Health()  # which overrides were in force while the simulation last ran healthy
        self.halted = ""  # why the simulation auto-paused, "" otherwise
        self.session_id = 0  # grows when the session (robot, scenario) is rebuilt
        self.restarts = 0  # grows at every reset or rebuild (the log starts over)
        self.total_steps = 0
        self.fallback_steps = 0  # fallback steps since the last reset
        # accepted changes of a parameter, the preset, case, robot or controller (never reset; a lesson step
        # compares it with its set-up's to see a change even when it was set back), the newest in words
        self.edits = 0
        self.last_edit = ""
        self.step_cpu_s = 0.0  # CPU time spent in steps
        self.drag = DragOwner()
        self.overpowering = OverpoweredWatch(lambda text: self.notify("warning", "Overpowered", text))
        self.notices = Notices()
        self.dirty = True  # something changed since the last frame
        self.defaults = self.session.params()  # the preset's (and case's) own values, before any change
        self.settings = Settings(0, self.session.params())
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
        notice (never raises)."""
        try:
            handler = HANDLERS.get(type(cmd))
            if handler is None:
                raise ValueError(f"unknown command {cmd!r}")
            handler(self, cmd)
        except (ValueError, KeyError) as exc:
            self.notify("error", "Refused", refusal_words(exc), getattr(cmd, "client_id", None))
        except Exception as exc:  # never let a command take the loop down
            traceback.print_exc()
            self.notify("error", "Command failed", f"{type(exc).__name__}: {exc}", getattr(cmd, "client_id", None))
        self.dirty = True

    # ---- stepping -------------------------------------------------------------------------------
    def advance(self, n: int, until: Callable[[StepRecord], bool] | None = None) -> RunResult:
        """Run n steps, logging each (and the twin in lockstep); halt at the first sign of divergence.
        `until`, asked after each step (as in `Session.run`), may end the run early."""
        cpu0 = time.thread_time()
        log, twin = self.log, self.twin

        def record(rec: StepRecord) -> None:
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
            self.halted = result.reason
            self.notify("error", "Simulation paused", f"{result.reason}. Press Reset to start again.")
        else:
            self.health.ran(result.steps, len(self.overrides))
            if self.overpowering.due(self.total_steps):
                self.overpowering.check(self.session)
        self.step_cpu_s += time.thread_time() - cpu0
        self.dirty = True
        return result

    @property
    def overpowered(self) -> str:
        """The joints the surroundings overpower, in words ("" when none; `app.live.overpowered`)."""
        return self.overpowering.text

    # ---- reset and recovery ---------------------------------------------------------------------
    def reset(self, cmd: Reset | None = None) -> None:
        """Back to t = 0 with the accepted settings; after a halt, recover (see the module docstring)."""
        if self.halted:  # rebuilt with the overrides, dropping them newest first until it runs (app.core.recovery)
            done = recover(self.session, self.overrides, self.robot_choice, self.health)
            self._install(done.session)
            for d in done.dropped:
                self.notify("warning", "Setting dropped", d.text())
            if done.halts_alone:
                self.notify("error", "Preset halts", f"the preset itself halts within {RECOVERY_STEPS} steps")
            self.halted = ""
        self.session.reset()  # the session re-applies its parameter overrides itself
        self._after_rebuild()
        self.twins.reset()

    def set_offload(self, offload: Offload | None) -> None:
        """Have this session, its twin and every later one compute their costly page signals (the
        polish margin) in `offload`, off the thread that steps them; None: inline."""
        self.offload = offload
        self.session.set_offload(offload)
        if self.twin is not None:
            self.twin.session.set_offload(offload)

    def _install(self, session: Session, log: StepLog | None = None, twin: Any = None) -> None:
        """Make `session` (its changes in force) the lab's, with an empty `log` (None: one made here) and
        the `twin` built beside it (None: built here if one runs; see `TwinArm.rebuild`)."""
        session.set_offload(self.offload)
        self.session = session
        self.session_id += 1
        self.defaults = session.params()
        self.log = log if log is not None else session_log(session, self._log_seconds)
        self._after_rebuild(clear_log=False)  # a new log is empty
        self.twins.rebuild(session, self.robot_choice, twin)
        if session.robot.name != getattr(self, "_guessed_said_for", None):
            self._say_guessed()

    def _after_rebuild(self, clear_log: bool = True) -> None:
        """After a reset or a new session: clear logs and drag."""
        self.drag.client = None
        self.overpowering.clear()
        self.fallback_steps = 0
        self.health.steps_since_change = 0
        if clear_log:
            self.log.clear()
        self.restarts += 1
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
        after, f = self.session.params().get(cmd.group), cmd.field
        if before is None or after is None or not same_value(before.values().get(f), after.values().get(f)):
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
        self.twins.restore_defaults()
        self.halted = ""

    def _edited(self, what: str) -> None:
        """Count an accepted change of the run's set-up (`edits`)."""
        self.edits += 1
        self.last_edit = what

    def _settings_changed(self) -> None:
        self.settings = Settings(self.settings.version + 1, self.session.params())
        self.dirty = True

    # ---- switching (app.core.switching) ----------------------------------------------------------
    def _switch(self, cmd: SwitchSession) -> None:
        plan = plan_switch(self.session, self.robot_choice, cmd)
        if plan is None:
            if cmd.executor is not None and cmd.executor != self.session.executor_name:
                self._switch_executor(cmd.executor)
            return
        self.install_switch(build_switch(plan, self.session.seed, self.overrides, self.defaults))

    def install_switch(self, built: BuiltSwitch) -> None:
        """Make a switch's new session (`app.core.switching.build_switch`) the lab's."""
        if built.robot_note:
            self.notify("info", "Robot changed", built.robot_note)
        plan = built.plan
        self.health.switched(len(built.kept), plan.case_switch, plan.new_preset or plan.case is not None)
        self.health.refused(built.refused)
        self.robot_choice = built.robot_choice
        self._edited(f"switched to {built.session.scenario.name} on {built.session.robot.name}")
        self._install(built.session, built.log, built.twin)
        self.halted = ""
        text = case_switch_text(built) if plan.case_switch else ""
        if text:
            self.notify("info", f"Case {plan.case}", text)

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

    def install_twin(self, twin: Twin) -> None:
        """A twin built off the loop thread (`app.core.twin.TwinRecipe`) for a SetTwin: it runs from here,
        and the scenario restarts so both arms start together (as `SetTwin` says)."""
        self.twins.install(twin)
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


# the handler of each command type (a command the table lacks is refused with a notice)
HANDLERS: dict[type, Callable[[Lab, Any], None]] = {
    DragCommand: Lab._apply_drag,
    Reset: Lab.reset,
    SwitchSession: Lab._switch,
    SetParam: Lab._set_param,
    RestoreDefaults: Lab._restore_defaults,
    SetTwin: Lab._set_twin,
}
