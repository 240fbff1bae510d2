"""One simulated experiment in progress: world + controller model + executor + environment.

`Session.step()` advances everything by one 1 kHz step in a fixed order:
1. the controller model computes one `Dynamics` snapshot at the measured (q, q̇) — shared by the
   executor, the coupling metrics and the overlays;
2. the environment (contact, sander, payloads) and the drag spring apply their forces for this
   step at the current state;
3. the F/T sensor model turns the true wrench at the sensor into a reading, mapped to the TCP;
4. the executor computes τ; 5. MuJoCo steps.
`Session.run(seconds, until=…, record=…)` is the one run loop around it, with the one divergence
check: the web app's loop and the headless experiments both run through it, so they agree step
for step.

The session is the one store of parameter changes: `set_param` keeps every accepted change in
order (`changes`), re-applies them after a reset or an executor switch, and `replay` hands them to
a new session (a rebuild, the twin arm).
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import math
import weakref
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pinocchio as pin

import robots
from app.core.commands import SetParam
from app.core.executors import make_executor
from app.scenarios import PLAIN_PRESET, Environment, Offload, Scenario, Sensor, Work, get_scenario
from app.scenarios.metrics import DeflectionProbe
from app.sim.drag import DragSpring
from app.sim.world import World, WorldParams
from control.executor import ControlInputs, ControlOutput, Executor, TaskTarget
from control.kernels.geometry import move_wrench_fused
from control.model import Dynamics, RobotModel
from control.params import ParamError, ParamGroup, expect, param, replaced, spec_of


@dataclass(frozen=True)
class TargetParams(ParamGroup):
    """The task target's tunable: the desired contact force."""

    title = "Task target"

    force_setpoint_n: float = param(
        20.0,
        label="Force setpoint F̂",
        unit="N",
        lo=0.0,
        hi=60.0,
        step=0.5,
        help="desired force the table exerts on the tool, +z (Table II: 20 N)",
        tag="[T12]",
    )


class _TargetOwner:
    """The "target" group of a target that carries a desired wrench (a `wrench` array, F^e_z [T12])."""

    def __init__(self, target_fn: Any):
        self.target_fn = target_fn

    @property
    def wrench(self) -> np.ndarray | None:
        """The target's desired wrench, or None when it carries none."""
        wrench = getattr(self.target_fn, "wrench", None)
        return wrench if isinstance(wrench, np.ndarray) else None

    def params(self) -> dict[str, ParamGroup]:
        if self.wrench is None:
            return {}
        return {"target": TargetParams(force_setpoint_n=float(self.wrench[2]))}

    def set_params(self, name: str, group: Any) -> None:
        wrench = self.wrench
        p = expect(name, group, TargetParams if name == "target" and wrench is not None else None)
        assert wrench is not None
        new = wrench.copy()
        new[2] = p.force_setpoint_n
        self.target_fn.wrench = new  # assigned, not edited in place: the target builds from what it is given


def _weakly(method: Callable[[], Any]) -> Callable[[], Any]:
    """`method` (bound) without keeping its object alive. The environment's hooks back into its
    session would otherwise close a reference cycle, and a session in a cycle is freed (its MuJoCo
    data, step buffers, compiled-code arrays) only by the collector's full pass, not when dropped."""
    ref = weakref.WeakMethod(method)
    name = method.__qualname__  # not the method: it holds its object

    def call() -> Any:
        bound = ref()
        if bound is None:
            raise ReferenceError(f"{name}: its object is gone")
        return bound()

    return call


class WorkPending(Exception):
    """Raised by `Session(..., defer_work=True)` before anything is built when the preset needs a
    costly computation first (`work`, see `Scenario.pending_work`): do it (elsewhere), store it, and
    build the session again."""

    def __init__(self, work: Work):
        super().__init__(f"{work.what} is not computed yet")
        self.work = work


@dataclass(frozen=True)
class RunResult:
    """How far `Session.run` got and why it stopped.

    `stop` is "done" (all steps ran), "until" (the `until` predicate ended it), "diverged" (NaN,
    runaway velocity or a state MuJoCo had to reset) or "error" (a step raised `error`); `reason`
    says it in words for the two halts."""

    steps: int  # steps run in this call
    t: float  # s, simulated time at the end
    stop: str
    reason: str = ""
    error: BaseException | None = None
    lockstep: tuple[RunResult, ...] = ()  # one per session stepped in lockstep (`Lockstep`), in order

    @property
    def halted(self) -> bool:
        """True when the run ended on divergence or an error."""
        return self.stop in ("diverged", "error")


@dataclass(frozen=True)
class Lockstep:
    """A session `Session.run` steps right after its own at every step (the twin arm), with its own
    `record`. Its divergence or error stops it alone, with its own result; the main run goes on."""

    session: Session
    record: Callable[[StepRecord], None] | None = None


@dataclass
class StepRecord:
    """What one step produced; the UI and the logs read this."""

    t: float
    q: np.ndarray
    dq: np.ndarray
    tau: np.ndarray
    wrench_tcp: np.ndarray  # sensor reading mapped to the TCP (what the controller saw)
    target: TaskTarget
    fallback: bool
    signals: dict[str, float] = field(default_factory=dict)  # executor + environment scalars
    tau_ext: np.ndarray | None = None  # true external joint torque τ_ext of this step (N·m, sim truth)


class Session:
    """A scenario running on one robot with one executor."""

    def __init__(
        self,
        scenario: str | Scenario = PLAIN_PRESET,
        robot: str | None = None,
        executor: str | None = None,
        seed: int = 0,
        q0: np.ndarray | None = None,
        defer_work: bool = False,
        changes: Iterable[SetParam] = (),
    ):
        """`changes` are `set_param` calls made as the session is built: those of the "scenario"
        group on its copy of the scenario before anything else is (so a start swivel or an armature
        scale is in force from t = 0), the others once it is built; a refused one raises ParamError."""
        # accepted set_param changes, oldest first, each with its field's whole value after it
        self._changes: list[tuple[SetParam, Any]] = []
        # a copy: scenario parameters set on this session must not leak into the shared preset
        self._scenario_origin = get_scenario(scenario) if isinstance(scenario, str) else scenario
        self.scenario = copy.copy(self._scenario_origin)
        changes = list(changes)
        for c in changes:
            if c.group == "scenario":
                self._set_scenario_param(c)
        self.robot = robots.load(robot or robots.chosen(self.scenario.default_robot))
        self._armature_nominal = self.robot.armature.copy()  # what `Scenario.armature` scales
        self.scenario.prepare_robot(self.robot)  # e.g. the table placed for an arm without sidecar postures
        self.robot.set_armature(self.scenario.armature(self._armature_nominal))  # before model and world
        work = self.scenario.pending_work(self.robot)
        if work is not None and defer_work:
            raise WorkPending(work)
        self.model = RobotModel(self.robot.model)
        self.executor_name = executor or self.scenario.default_executor
        self.seed = seed
        self.world = World(
            self.robot,
            table_height=self.scenario.table_height,
            customize=lambda spec: self.scenario.customize_world(spec, self.robot),
        )
        self.drag = DragSpring()
        self.executor: Executor = make_executor(self.executor_name, self.robot, self.model)
        self._configure_executor_for_scenario()
        self._q0_override = q0
        self.offload: Offload | None = None  # the runner's place for costly page signals (`set_offload`)
        self.reset()
        for c in changes:
            if c.group != "scenario":
                self.set_param(c.group, c.field, c.value, c.index)

    def _dynamics(self) -> Dynamics:
        """The step's dynamics snapshot (`Environment.connect`)."""
        return self.dyn

    def set_offload(self, offload: Offload | None) -> None:
        """Give the environment (now and after every reset) a place off the loop thread for its costly
        page signals (`app.scenarios.Offload`); None: it computes them inline."""
        self.offload = offload
        self.environment.connect(_weakly(self.params), offload, _weakly(self._dynamics))

    # ---- lifecycle ----------------------------------------------------------------------------
    def reset(self) -> None:
        """Back to t = 0: initial posture, fresh environment/sensor noise (same seed), no drag."""
        armature = self.scenario.armature(self._armature_nominal)  # a "scenario" change may have set it
        self.robot.set_armature(armature)
        self.world.set_armature(armature)
        q0 = self._q0_override if self._q0_override is not None else self.scenario.initial_q(self.robot)
        self.world.reset(np.asarray(q0, dtype=float))
        self.drag.release()
        rng = np.random.default_rng(self.seed)
        self.environment: Environment = self.scenario.make_environment(self.world, rng)
        self.environment.connect(_weakly(self.params), self.offload, _weakly(self._dynamics))
        self.sensor: Sensor = self.scenario.make_sensor(rng)
        self.dyn: Dynamics = self.model.compute(self.world.q, self.world.dq)
        self._apply_executor_changes()  # a "scenario" change may have changed them (e.g. holding a swivel)
        gains = self.executor.params()
        self.target_fn: Callable[[float], TaskTarget] = self.scenario.make_target(
            self.robot, self.model, self.dyn, gains
        )
        self._reinstall(("environment", "sensor", "target"))
        self.executor.reset(self.dyn, self.target_fn(0.0))
        # the TCP's and the elbow's positions now (t = 0): the reference of the deflection signals, in the
        # presets that log them (`Scenario.logs_deflection`)
        self._deflection = DeflectionProbe(self) if self.scenario.logs_deflection else None
        self.steps = 0
        self.last: StepRecord | None = None

    def set_executor(self, name: str) -> None:
        """Switch the controller (takes effect at the next step, integrators cleared)."""
        self.executor = make_executor(name, self.robot, self.model)
        self.executor_name = name
        self._configure_executor_for_scenario()
        self._reinstall(("executor",))
        self.executor.reset(self.dyn, self.target_fn(self.world.time))

    def _configure_executor_for_scenario(self) -> None:
        """The scenario sets up the executor it runs with: its tasks and limits (`prepare_executor`),
        then its parameter changes (`_apply_executor_changes`)."""
        self.scenario.prepare_executor(self.executor, self.robot)
        self._apply_executor_changes()

    def _apply_executor_changes(self) -> None:
        """Hand the scenario's parameter changes (`Scenario.executor_changes`) to the executor, then
        the values set with `set_param` on its groups again (they stay in force)."""
        changes = self.scenario.executor_changes(self.executor.params(), self.robot)
        if not changes:
            return
        for name, new in changes.items():
            self.executor.set_params(name, new)
        mine = self.executor.params()
        for name, fields in self.overrides().items():
            if name not in changes or name not in mine:
                continue
            current = mine[name]
            for field_name, value in fields.items():
                try:
                    spec_of(current, field_name)
                    current = replaced(current, field_name, value)
                except ParamError:
                    continue
            self.executor.set_params(name, current)

    @property
    def preset(self) -> Scenario:
        """The scenario as given (without the parameters set on this session's copy)."""
        return self._scenario_origin

    # ---- parameters (control.params) -----------------------------------------------------------
    def params(self) -> dict[str, ParamGroup]:
        """Every parameter group of this session by name: the executor's ("motion_force",
        "nullspace", "pose_task", "posture_task", "damper", "estimator", "compliance_qp", "joint_hold"), the
        environment's ("contact", "sander", "payload"), "sensor", "world", "drag", "target" and
        "scenario" — those the running parts have. The groups are frozen: safe to hand to any thread."""
        return {name: owner.params()[name] for name, owner in self._owners().items()}

    def set_param(self, group: str, field: str, value: Any, index: int | None = None) -> ParamGroup:
        """Set one field (or element `index` of a vector field) of a group, validated by its
        dataclass, and hand the new group to its owner; returns the new group. A refused value
        raises ParamError ("group.field ...") and changes nothing. The value is remembered and
        re-applied after `reset()` (environment, sensor and target are rebuilt then) and after an
        executor switch; a "scenario" change takes effect at the next reset."""
        owners = self._owners()
        if group not in owners:
            raise ParamError(f"this session has no parameter group {group!r} (it has {', '.join(owners)})")
        owner = owners[group]
        try:
            new = replaced(owner.params()[group], field, value, index)
        except ParamError as exc:
            raise ParamError(f"{group}.{exc}") from None
        owner.set_params(group, new)
        self._changes.append((SetParam(group, field, value, index), getattr(new, field)))
        return new

    def _set_scenario_param(self, c: SetParam) -> None:
        """A "scenario" change on the scenario copy alone (the rest of the session is not built yet)."""
        groups = self.scenario.params()
        if "scenario" not in groups:
            raise ParamError(f"the {self.scenario.name} scenario has no parameter group 'scenario'")
        try:
            new = replaced(groups["scenario"], c.field, c.value, c.index)
        except ParamError as exc:
            raise ParamError(f"scenario.{exc}") from None
        self.scenario.set_params("scenario", new)
        self._changes.append((SetParam(c.group, c.field, c.value, c.index), getattr(new, c.field)))

    @property
    def changes(self) -> list[SetParam]:
        """The changes `set_param` accepted since construction (or `restore_defaults`), oldest first."""
        return [change for change, _ in self._changes]

    def replay(self, changes: Iterable[SetParam]) -> list[int]:
        """`set_param` each change in order (e.g. another session's `changes`); returns the positions
        of those this session refuses (they are left out)."""
        refused = []
        for i, c in enumerate(changes):
            try:
                self.set_param(c.group, c.field, c.value, c.index)
            except ParamError:
                refused.append(i)
        return refused

    def overrides(self) -> dict[str, dict[str, Any]]:
        """The values set through `set_param` since construction (or `restore_defaults`), by group:
        each changed field's value after its last change."""
        out: dict[str, dict[str, Any]] = {}
        for change, value in self._changes:
            out.setdefault(change.group, {})[change.field] = value
        return out

    def settle_pending(self) -> bool:
        """True while the preset's settle phase has not ended (`Environment.settle_pending`)."""
        return bool(self.environment.settle_pending())

    def restore_defaults(self) -> None:
        """Every parameter back to the preset's defaults (a fresh executor, world, drag and scenario
        copy), then `reset()`."""
        self._changes = []
        self.scenario = copy.copy(self._scenario_origin)
        self.world.set_params("world", WorldParams())
        self.drag = DragSpring()
        self.executor = make_executor(self.executor_name, self.robot, self.model)
        self._configure_executor_for_scenario()
        self.reset()

    def _owners(self) -> dict[str, Any]:
        """Group name → the object that owns it (a name defined twice is a bug: RuntimeError)."""
        out: dict[str, Any] = {}
        parts = (
            self.executor,
            self.environment,
            self.sensor,
            self.world,
            self.drag,
            _TargetOwner(self.target_fn),
            self.scenario,
        )
        for owner in parts:
            for name in owner.params():
                if name in out:
                    raise RuntimeError(f"parameter group {name!r} is defined twice")
                out[name] = owner
        return out

    def _reinstall(self, parts: tuple[str, ...]) -> None:
        """Re-apply remembered values to the groups of rebuilt parts (those they still have)."""
        if not self._changes:
            return
        owners = self._owners()
        objects = {
            "environment": self.environment,
            "sensor": self.sensor,
            "executor": self.executor,
        }
        for group, fields in self.overrides().items():
            owner = owners.get(group)
            if owner is None:
                continue
            is_part = any(owner is objects.get(p) for p in parts) or ("target" in parts and group == "target")
            if not is_part:
                continue
            current = owner.params()[group]
            for name, value in fields.items():
                try:
                    spec_of(current, name)
                    current = replaced(current, name, value)
                except ParamError:
                    continue
            owner.set_params(group, current)

    # ---- stepping -----------------------------------------------------------------------------
    def step(self) -> StepRecord:
        """Advance one control period (one MuJoCo timestep)."""
        world = self.world
        t = world.time
        dyn = self.model.compute(world.q, world.dq)  # [1] one snapshot per step, shared
        self.dyn = dyn
        env_signals = self.environment.apply(world, t)  # [2] environment forces
        drag_force = self.drag.apply(world)
        true_wrench_sensor = world.external_wrench_at_sensor()
        reading_sensor = self.sensor.measure(true_wrench_sensor, t)  # [3] F/T reading
        wrench_tcp = self._sensor_to_tcp(reading_sensor, dyn)
        target = self.target_fn(t)
        tau_ext = world.external_joint_torque()
        # the target was checked where it was built (its scenario), the reading and τ^e are fresh
        # float64 vectors made here: no per-step coercion
        inputs = ControlInputs.trusted(t, target, wrench_tcp, tau_ext)
        out = self._safe_step(dyn, inputs)  # [4]
        world.step(out.tau)  # [5]
        self.steps += 1
        # the executor's signals (a new dict every step), then the environment's (they win a shared
        # name), then ‖F‖ of the drag as np.linalg.norm computes it
        signals = out.info
        signals.update(env_signals)
        signals["drag_force_n"] = math.sqrt(float(drag_force.dot(drag_force)))
        if self._deflection is not None:  # the scenario's `logs_deflection`: distances (mm) from the t = 0 pose
            signals["tcp_dev_mm"], signals["elbow_dev_mm"] = self._deflection.read(self)
        self.environment.observe(signals, t)
        self.last = StepRecord(
            t=t,
            q=dyn.q,
            dq=dyn.dq,
            tau=world.tau_applied,  # a new array every step (`World.step`)
            wrench_tcp=wrench_tcp,
            target=target,
            fallback=out.fallback,
            signals=signals,
            tau_ext=tau_ext,
        )
        return self.last

    def run(
        self,
        seconds: float | None = None,
        *,
        steps: int | None = None,
        until: Callable[[StepRecord], bool] | None = None,
        record: Callable[[StepRecord], None] | None = None,
        lockstep: tuple[Lockstep, ...] = (),
    ) -> RunResult:
        """Step for `seconds` of simulated time (or `steps` steps): the one run loop of the app and
        the experiments. After each step `record(rec)` is called, then each `lockstep` session steps
        (and records), then the state is checked for divergence, then `until(rec)` may end the run
        early. An exception from a step (or from `record`) ends the run too; it is returned in the
        result, not raised. A lockstep session that diverges or raises stops there with its own
        result (`RunResult.lockstep`, stop "diverged" or "error"); the others go on; one still
        stepping when the run ends has stop "done"."""
        if steps is None:
            if seconds is None:
                raise ValueError("run needs seconds or steps")
            steps = round(seconds / self.world.model.opt.timestep)
        if not lockstep:
            return self._run(int(steps), until, record, None)
        group = _Group(lockstep)
        result = self._run(int(steps), until, record, group)
        return dataclasses.replace(result, lockstep=group.results())

    def _run(
        self,
        steps: int,
        until: Callable[[StepRecord], bool] | None,
        record: Callable[[StepRecord], None] | None,
        group: _Group | None,
    ) -> RunResult:
        done = 0
        try:
            for _ in range(steps):
                rec = self.step()
                done += 1
                if record is not None:
                    record(rec)
                if group is not None and group.active:
                    group.step()
                if self.world.diverged():
                    return RunResult(done, self.world.divergence_time, "diverged", self._divergence_reason())
                if until is not None and until(rec):
                    return RunResult(done, self.world.time, "until")
        except Exception as exc:  # a bug or numerical failure ends the run; the caller decides
            return RunResult(
                done, self.world.time, "error", f"the simulation step raised {type(exc).__name__}: {exc}", exc
            )
        return RunResult(done, self.world.time, "done")

    def diverged(self) -> bool:
        """NaN or runaway state in the simulation, or MuJoCo had to reset an unstable state."""
        return self.world.diverged()

    def _divergence_reason(self) -> str:
        return f"the simulation diverged at t = {self.world.divergence_time:.3f} s (NaN or runaway velocity)"

    # ---- helpers ------------------------------------------------------------------------------
    def _safe_step(self, dyn: Dynamics, inputs: ControlInputs) -> ControlOutput:
        try:
            out = self.executor.step(dyn, inputs)
        except (ValueError, ArithmeticError, np.linalg.LinAlgError):
            out = ControlOutput(tau=dyn.h.copy(), fallback=True, info={"executor_error": 1.0})
        tau = out.tau if type(out.tau) is np.ndarray else np.asarray(out.tau, dtype=float)
        if not math.isfinite(float(tau.dot(tau))):  # NaN/inf anywhere (one dot product)
            out = ControlOutput(tau=dyn.h.copy(), fallback=True, info={**out.info, "executor_error": 1.0})
        return out

    def _sensor_to_tcp(self, wrench_sensor: np.ndarray, dyn: Dynamics) -> np.ndarray:
        """Move a wrench [f; m] (world axes) from the sensor origin to the TCP with the controller's
        own kinematics: f is unchanged, m_tcp = m_sensor + (p_sensor − p_tcp) × f (compiled)."""
        return move_wrench_fused(wrench_sensor, self._sensor_position(dyn), dyn.tcp_position_world)

    def _sensor_position(self, dyn: Dynamics) -> np.ndarray:
        # the joint placements are this step's (compute()); the snapshot updates the TCP frame only
        return pin.updateFramePlacement(self.model.model, self.model.data, self._sensor_frame_id).translation

    @functools.cached_property
    def _sensor_frame_id(self) -> int:
        return self.model.model.getFrameId(robots.SENSOR_FRAME)  # a name lookup: once per session


class _Group:
    """The lockstep sessions of one `Session.run`: which still step, and each one's result."""

    def __init__(self, members: tuple[Lockstep, ...]):
        self.members = members
        self.done = [0] * len(members)
        self.stopped: list[RunResult | None] = [None] * len(members)
        self.active = list(range(len(members)))

    def step(self) -> None:
        """One step of every member still stepping; a divergence or an error stops that member."""
        for i in tuple(self.active):
            member = self.members[i]
            world = member.session.world
            try:
                rec = member.session.step()
                self.done[i] += 1
                if member.record is not None:
                    member.record(rec)
                if world.diverged():
                    reason = member.session._divergence_reason()
                    self._stop(i, RunResult(self.done[i], world.divergence_time, "diverged", reason))
            except Exception as exc:
                reason = f"the simulation step raised {type(exc).__name__}: {exc}"
                self._stop(i, RunResult(self.done[i], world.time, "error", reason, exc))

    def _stop(self, i: int, result: RunResult) -> None:
        self.stopped[i] = result
        self.active.remove(i)

    def results(self) -> tuple[RunResult, ...]:
        """Each member's result: how it stopped, or "done" if it stepped to the end of the run."""
        out = []
        for i, member in enumerate(self.members):
            stopped = self.stopped[i]
            out.append(stopped if stopped is not None else RunResult(self.done[i], member.session.world.time, "done"))
        return tuple(out)
