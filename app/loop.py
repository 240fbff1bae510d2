"""The real-time loop: the one thread that owns the Session (MuJoCo, controller, solvers).

It steps the simulation at 1 kHz simulated time paced to wall time (`app.pacing`), applies the
commands other threads queued (`app.commands`) between two steps, logs every step
(`app.steplog`), auto-pauses on NaN/divergence, and at 30 Hz publishes a `Frame` — the scene
snapshot, the status, plot data, the current settings and any notices — that the server's
publisher thread shows in the browser. Nothing outside this thread touches the Session, except
through `call()`, which runs a function here between two steps.
"""

from __future__ import annotations

import dataclasses
import math
import queue
import threading
import time
import traceback
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import dataclass, field
from typing import Any, TypeVar

import numpy as np

from app.commands import (
    Command,
    Configure,
    DragCommand,
    Pause,
    Play,
    Reset,
    SetSpeed,
    SetTwin,
    StepOnce,
    SwitchSession,
)
from app.executors import EXECUTORS
from app.pacing import Pacer, RateMeter
from app.scenarios import Scenario
from app.session import DRAG_FIELDS, Session, StepRecord
from app.settings import finite_number, settings_of
from app.steplog import StepLog
from app.twin import Twin
from app.variants import make_variant, variant_of

try:  # the scene snapshot is optional: the loop runs without it (tests, headless)
    from app.ui.snapshot import capture as _capture_scene
except ImportError:  # pragma: no cover - only while the scene module is missing
    _capture_scene = None  # type: ignore[assignment]

T = TypeVar("T")
SPEED_RANGE = (0.1, 1.0)
PLOT_WINDOW_S = 10.0
WAKE_STEPS = 2  # the loop sleeps until this many steps are due, then runs them in one burst
SETTINGS_TARGETS = ("executor", "environment", "sensor", "drag", "target", "world")


@dataclass(frozen=True)
class Notice:
    """A message for the browser: to one client (`client_id`) or to all (None)."""

    level: str  # "info", "warning" or "error"
    title: str
    body: str
    client_id: int | None = None


@dataclass(frozen=True)
class LoopStatus:
    """What the loop is doing, for the status line and the tests."""

    running: bool = False
    t: float = 0.0  # s, simulated time of the session
    steps: int = 0  # steps since the last reset
    speed: float = 1.0  # requested simulated seconds per wall second
    rtf: float = 0.0  # achieved real-time factor over the last window
    load: float = 0.0  # fraction of wall time spent computing steps
    scenario: str = ""
    scenario_title: str = ""
    scenario_text: str = ""  # what the preset shows, one paragraph
    variant: str = ""  # the scenario's case, "" if it has none
    variants: tuple[str, ...] = ()  # the cases it can run in
    focus_joint: int | None = None  # 0-based joint the scenario is about (phase plot), if any
    twin: str = ""  # nullspace objective of the twin arm ("j", "f", "a", "d"), "" when there is none
    robot: str = ""
    executor: str = ""
    halted: str = ""  # why the loop auto-paused (divergence), "" otherwise
    fallback: bool = False  # the last step used a fallback solution (QP failed)
    fallback_steps: int = 0  # fallback steps since the last reset
    drag_client: int | None = None  # client holding the drag spring
    step_cpu_s: float = 0.0  # CPU time the loop thread spent in steps since it started
    signals: dict[str, float] = field(default_factory=dict)  # last step's scalar signals


@dataclass(frozen=True)
class Settings:
    """Current tunables per target ("executor", "environment", "sensor", "drag"); `version` grows."""

    version: int
    values: dict[str, dict[str, Any]]


@dataclass(frozen=True)
class PlotData:
    """The last seconds of logged signals, decimated, plus the slower monitor series."""

    columns: dict[str, np.ndarray]  # StepLog columns
    monitor: dict[str, np.ndarray]  # "t", "rtf", "W_f", "W_a", "W_d" sampled at the publish rate
    q_lower: np.ndarray
    q_upper: np.ndarray
    dq_max: np.ndarray
    tau_max: np.ndarray


@dataclass(frozen=True)
class Frame:
    """One publication of the loop to the browser side."""

    seq: int
    session_id: int  # grows when the session (robot, scenario) is rebuilt
    robot: Any  # RobotDescription of the current session
    status: LoopStatus
    settings: Settings
    scene: Any = None  # SceneSnapshot, if the scene module is present
    plot: PlotData | None = None  # the newest plot data (kept in later frames until replaced)
    plot_seq: int = 0  # grows when `plot` is new data


@dataclass(frozen=True)
class _Call:
    fn: Callable[[Session], Any]
    future: Future


class SimLoop:
    """Owns a Session in its own thread and runs it in real time; see the module docstring."""

    def __init__(
        self,
        scenario: str = "free",
        robot: str | None = None,
        executor: str | None = None,
        seed: int = 0,
        publish_hz: float = 30.0,
        plot_hz: float = 10.0,
        log_seconds: float = 60.0,
        clock: Callable[[], float] = time.perf_counter,
        capture: Callable[[Session], Any] | None = None,
        settings_reader: Callable[[Session], dict[str, dict[str, Any]]] | None = None,
    ):
        self._settings_reader = settings_reader
        self._clock = clock
        self._seed = seed
        self._robot_choice = robot or ""  # "" = the scenario's default robot
        self.session = Session(scenario, robot=robot or None, executor=executor or None, seed=seed)
        self.publish_period = 1.0 / publish_hz
        self.plot_period = 1.0 / plot_hz
        self._capture: Callable[[Session], Any] | None = capture if capture is not None else _capture_scene
        self._log_seconds = log_seconds
        self.dt = float(self.session.world.model.opt.timestep)
        self.log = StepLog(self.session.robot.nq, capacity=round(log_seconds / self.dt))
        self._monitor: deque[tuple[float, float, float, float, float]] = deque(
            maxlen=round(PLOT_WINDOW_S / self.publish_period) + 2
        )
        self._queue: queue.SimpleQueue[Command | _Call] = queue.SimpleQueue()
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._pacer = Pacer(self.dt)
        self._meter = RateMeter()
        self._running = False
        self._resume_after_reset = False
        self._halted = ""
        self._total_steps = 0
        self._fallback_steps = 0
        self._step_cpu_s = 0.0
        self._drag_client: int | None = None
        self.twin: Twin | None = None  # a second session in lockstep with another objective (app.twin)
        self._overrides: dict[str, dict[str, Any]] = {t: {} for t in SETTINGS_TARGETS}
        self._session_id = 0
        self._settings = Settings(0, self._read_settings())
        self._seq = 0
        self._frame: Frame | None = None
        self._frame_cond = threading.Condition()
        self._notices: deque[Notice] = deque(maxlen=100)
        self.notice_log: deque[Notice] = deque(maxlen=100)  # every notice ever sent (for tests/logs)
        self.status = self._make_status()
        self._next_plot = 0.0
        self._plot: PlotData | None = None
        self._plot_seq = 0
        self._dirty = True

    # ---- API for other threads ----------------------------------------------------------------
    def start(self, running: bool = True) -> None:
        """Start the loop thread (running paced, or paused)."""
        if self._thread is not None:
            return
        self._running = running
        self._thread = threading.Thread(target=self._run, name="torquelab-sim", daemon=True)
        self._thread.start()

    def stop(self, timeout: float = 5.0) -> None:
        """Stop the loop thread."""
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout)
        self._thread = None

    @property
    def alive(self) -> bool:
        """True while the loop thread runs."""
        return self._thread is not None and self._thread.is_alive()

    def submit(self, cmd: Command) -> None:
        """Queue a command; the loop applies it between two steps (thread-safe, never blocks)."""
        self._queue.put(cmd)
        self._wake.set()

    def call(self, fn: Callable[[Session], T], timeout: float = 10.0) -> T:
        """Run `fn(session)` in the loop thread between two steps and return its result."""
        if threading.current_thread() is self._thread or not self.alive:
            return fn(self.session)
        fut: Future = Future()
        self._queue.put(_Call(fn, fut))
        self._wake.set()
        return fut.result(timeout)

    def sync(self, timeout: float = 10.0) -> LoopStatus:
        """Wait until every command queued before this call has been applied; returns the status then."""
        return self.call(lambda s: self._refresh_status(), timeout)

    def wait_frame(self, after_seq: int, timeout: float) -> Frame | None:
        """The newest frame with seq > `after_seq`, waiting up to `timeout` s; None on timeout."""
        with self._frame_cond:
            self._frame_cond.wait_for(lambda: self._frame is not None and self._frame.seq > after_seq, timeout)
            frame = self._frame
        return frame if frame is not None and frame.seq > after_seq else None

    def take_notices(self) -> list[Notice]:
        """Notices produced since the last call (for the publisher)."""
        out = []
        while True:
            try:
                out.append(self._notices.popleft())
            except IndexError:
                return out

    @property
    def robot_choice(self) -> str:
        """The robot picked explicitly ("" = the scenario's default)."""
        return self._robot_choice

    def export(self, seconds: float, timeout: float = 10.0) -> dict[str, Any]:
        """The last `seconds` of the step log (every step) plus what produced it, copied in the loop thread."""

        def grab(session: Session) -> dict[str, Any]:
            columns = self.log.window(seconds, self.dt)
            twin = self.twin
            if twin is not None and "t" in columns:  # the twin's columns beside the main ones, same rows
                columns |= {f"twin_{k}": v for k, v in twin.columns_at(columns["t"]).items() if k != "t"}
            return {
                "columns": columns,
                "twin_objective": twin.objective if twin is not None else None,
                "scenario": session.scenario.name,
                "robot": session.robot.name,
                "executor": session.executor_name,
                "dt": self.dt,
                "seed": self._seed,
                "settings": self._settings.values,
            }

        return self.call(grab, timeout)

    @property
    def settings(self) -> Settings:
        """The current tunables (read-only snapshot, replaced when anything changes)."""
        return self._settings

    # ---- the thread -----------------------------------------------------------------------------
    def _run(self) -> None:
        now = self._clock()
        self._pacer.restart(now, self._total_steps)
        self._meter.restart()
        next_publish = now
        while not self._stop.is_set():
            self._drain()
            now = self._clock()
            if self._running:
                n = self._pacer.due(now, self._total_steps)
                if n:
                    self._advance(n)
                if self._meter.sample(self._clock(), self.session.world.time):
                    self._dirty = True
            now = self._clock()
            if now >= next_publish:
                if self._dirty or self._running:
                    self._publish(now)
                next_publish = now + self.publish_period
            wake_at = next_publish
            if self._running:
                # wake when WAKE_STEPS steps are due: fewer wake-ups, ≤ 2 ms of latency
                wake_at = min(wake_at, self._pacer.next_due(self._total_steps + WAKE_STEPS - 1))
            timeout = wake_at - self._clock()
            if timeout > 2e-4 and self._queue.empty():
                self._wake.wait(timeout)
                self._wake.clear()

    def _advance(self, n: int) -> None:
        """Run n steps (`Session.run`), logging each; halt at the first sign of divergence."""
        t0, cpu0 = self._clock(), time.thread_time()
        log, twin = self.log, self.twin

        def record(rec: StepRecord) -> None:
            log.append(rec)
            self._total_steps += 1
            if rec.fallback:
                self._fallback_steps += 1
            if twin is not None:
                twin.step()

        result = self.session.run(steps=n, record=record)
        if result.error is not None:  # a bug or numerical failure must not kill the server
            traceback.print_exception(result.error)
        if result.halted:
            self._halt(result.reason)
        elif twin is not None and twin.diverged():
            self._drop_twin(f"the twin arm (W_{twin.objective}) diverged; it is switched off")
        self._meter.add_busy(self._clock() - t0)
        self._step_cpu_s += time.thread_time() - cpu0
        self._dirty = True

    def _halt(self, reason: str) -> None:
        self._resume_after_reset = self._running
        self._running = False
        self._halted = reason
        self._notify("error", "Simulation paused", f"{reason}. Press Reset to start again.")
        self._dirty = True

    # ---- commands -------------------------------------------------------------------------------
    def _drain(self) -> None:
        while True:
            try:
                item = self._queue.get_nowait()
            except queue.Empty:
                return
            if isinstance(item, _Call):
                try:
                    item.future.set_result(item.fn(self.session))
                except Exception as exc:
                    item.future.set_exception(exc)
                continue
            try:
                self._apply(item)
            except (ValueError, KeyError) as exc:
                self._notify("error", "Refused", _reason(exc), getattr(item, "client_id", None))
            except Exception as exc:  # never let a command take the loop down
                traceback.print_exc()
                self._notify("error", "Command failed", f"{type(exc).__name__}: {exc}")
            self._dirty = True

    def _apply(self, cmd: Command) -> None:
        if isinstance(cmd, DragCommand):
            self._apply_drag(cmd)
        elif isinstance(cmd, Play):
            if self._halted:
                self._notify("warning", "Cannot play", "The simulation diverged: press Reset first.")
                return
            if not self._running:
                self._running = True
                self._restart_pacing()
        elif isinstance(cmd, Pause):
            self._running = False
        elif isinstance(cmd, StepOnce):
            self._running = False
            if self._halted:
                self._notify("warning", "Cannot step", "The simulation diverged: press Reset first.")
                return
            steps = int(cmd.steps)
            if not 1 <= steps <= 10_000:
                raise ValueError(f"step count must be 1…10000, got {cmd.steps!r}")
            self._advance(steps)
        elif isinstance(cmd, Reset):
            self._reset()
        elif isinstance(cmd, SetSpeed):
            self._set_speed(cmd.factor)
        elif isinstance(cmd, SwitchSession):
            self._switch(cmd)
        elif isinstance(cmd, Configure):
            self._configure(cmd)
        elif isinstance(cmd, SetTwin):
            self._set_twin(cmd.objective)
        else:
            raise ValueError(f"unknown command {cmd!r}")

    # ---- the twin arm ---------------------------------------------------------------------------
    def _set_twin(self, objective: str | None) -> None:
        """Switch the twin off (None) or on with an objective; on restarts the scenario."""
        if objective is None or objective == "":
            self.twin = None
            self._dirty = True
            return
        self.twin = self._new_twin(str(objective))  # ValueError for a wrong objective or executor
        self._reset()

    def _rebuild_twin(self) -> None:
        """After a new session: the same twin objective on it, or no twin if it cannot have one."""
        if self.twin is None:
            return
        objective = self.twin.objective
        try:
            self.twin = self._new_twin(objective)
        except ValueError as exc:
            self._drop_twin(f"the twin arm is switched off: {exc}")

    def _new_twin(self, objective: str) -> Twin:
        s = self.session
        return Twin(
            s.scenario,
            self._robot_choice or None,
            s.executor_name,
            self._seed,
            objective,
            self.dt,
            self._overrides,
            self._log_seconds,
        )

    def _drop_twin(self, reason: str) -> None:
        self.twin = None
        self._notify("warning", "Twin arm off", reason)
        self._dirty = True

    def _apply_drag(self, cmd: DragCommand) -> None:
        drag = self.session.drag
        if cmd.kind == "grab":
            point = _vec3(cmd.point_world)
            if point is None:
                raise ValueError("grab needs a finite 3-D point")
            body_id = self.session.world.model.body(cmd.body_name).id  # KeyError for unknown names
            if body_id == 0:
                raise ValueError("the world body cannot be dragged")
            drag.grab(self.session.world, body_id, point)
            self._drag_client = cmd.client_id
        elif cmd.kind == "move":
            target = _vec3(cmd.target_world)
            if target is not None and drag.active and cmd.client_id == self._drag_client:
                drag.move(target)
        elif cmd.kind == "release":
            if cmd.client_id == self._drag_client:
                drag.release()
                self._drag_client = None
        else:
            raise ValueError(f"unknown drag command {cmd.kind!r}")

    def _reset(self) -> None:
        self.session.reset()
        self._after_rebuild(reapply=("environment", "sensor", "target"))
        if self.twin is not None:
            self.twin.reset(self._overrides)
        if self._halted:
            self._halted = ""
            self._running = self._resume_after_reset

    def _set_speed(self, factor: object) -> None:
        value = finite_number(factor)
        if value is None or not SPEED_RANGE[0] <= value <= SPEED_RANGE[1]:
            raise ValueError(f"speed must be between {SPEED_RANGE[0]} and {SPEED_RANGE[1]}, got {factor!r}")
        self._pacer.set_speed(value, self._clock(), self._total_steps)
        self._meter.restart()

    def _switch(self, cmd: SwitchSession) -> None:
        s = self.session
        if cmd.scenario is None and cmd.robot is None and cmd.variant is None:
            if cmd.executor is not None and cmd.executor != s.executor_name:
                if cmd.executor not in EXECUTORS:
                    raise ValueError(f"unknown executor {cmd.executor!r}; choose one of {', '.join(EXECUTORS)}")
                twin, self.twin = self.twin, None
                s.set_executor(cmd.executor)
                self._overrides["executor"] = self._reapply("executor", self._overrides["executor"])
                self.twin = twin
                if twin is not None:
                    try:
                        twin.set_executor(cmd.executor, self._overrides["executor"])
                    except ValueError as exc:
                        self._drop_twin(f"the twin arm is switched off: {exc}")
                self._settings_changed()
            return
        scenario = cmd.scenario if cmd.scenario is not None else s.scenario.name
        robot_choice = self._robot_choice if cmd.robot is None else cmd.robot
        # a new scenario brings its default executor unless one is asked for explicitly
        executor = cmd.executor if cmd.executor is not None else (None if cmd.scenario is not None else s.executor_name)
        if cmd.variant is not None:
            spec: str | Scenario = make_variant(scenario, cmd.variant)
        elif cmd.scenario is None:
            spec = s.scenario  # same scenario object, same case (robot switch)
        else:
            spec = scenario
        try:
            new = Session(spec, robot=robot_choice or None, executor=executor, seed=self._seed)
        except ValueError as exc:
            if cmd.scenario is None or not robot_choice:
                raise
            # a preset that needs its own arm (a posture the picked one lacks): run it on its default robot
            new = Session(spec, robot=None, executor=executor, seed=self._seed)
            self._notify("info", "Robot changed", f"{exc}. Using {new.robot.name}.")
            robot_choice = ""
        self.session = new
        self._robot_choice = robot_choice
        self._session_id += 1
        if cmd.scenario is not None or cmd.variant is not None:
            self._overrides = {t: {} for t in SETTINGS_TARGETS if t != "drag"} | {"drag": self._overrides["drag"]}
        self.log = StepLog(new.robot.nq, capacity=round(self._log_seconds / self.dt))
        twin, self.twin = self.twin, None  # the old twin belongs to the old session
        self._after_rebuild(reapply=SETTINGS_TARGETS)
        self.twin = twin
        self._rebuild_twin()
        self._halted = ""

    def _after_rebuild(self, reapply: tuple[str, ...]) -> None:
        """After a reset or a new session: keep the user's accepted settings, clear logs and drag."""
        for target in reapply:
            self._overrides[target] = self._reapply(target, self._overrides[target])
        self._drag_client = None
        self._fallback_steps = 0
        self.log.clear()
        self._monitor.clear()
        self._restart_pacing()
        self._settings_changed()

    def _reapply(self, target: str, changes: dict[str, Any]) -> dict[str, Any]:
        """Apply remembered changes one by one; keep only those the target still accepts."""
        kept = {}
        for key, value in changes.items():
            try:
                self._configure_target(target, {key: value})
                kept[key] = value
            except (ValueError, TypeError, KeyError):
                pass
        return kept

    def _configure(self, cmd: Configure) -> None:
        if cmd.target not in SETTINGS_TARGETS:
            self._notify("error", "Invalid setting", f"unknown settings target {cmd.target!r}", cmd.client_id)
            return
        try:
            self._check_types(cmd.target, dict(cmd.changes))
            self._configure_target(cmd.target, dict(cmd.changes))
        except (ValueError, TypeError, KeyError, AttributeError) as exc:
            self._notify("error", "Value refused", _reason(exc), cmd.client_id)
            self._settings_changed()  # the panels show the value that is still in force
            return
        self._overrides[cmd.target].update(cmd.changes)
        self._settings_changed()

    def _check_types(self, target: str, changes: dict[str, Any]) -> None:
        """Refuse a value whose kind differs from the current one (text for a number...)."""
        current = self._settings.values.get(target, {})
        for key, value in changes.items():
            if key not in current:
                continue
            now = current[key]
            if isinstance(now, bool):
                ok = isinstance(value, bool)
            elif isinstance(now, (int, float)):  # a scalar gain may become per-axis values
                ok = finite_number(value) is not None or (
                    not isinstance(value, bool) and _finite_array(value) is not None
                )
            elif isinstance(now, str):
                ok = isinstance(value, str)
            elif isinstance(now, list):
                ok = isinstance(value, (list, tuple)) or finite_number(value) is not None
            else:
                ok = True
            if not ok:
                raise ValueError(f"{key} must be like {now!r}, got {value!r}")

    def _configure_target(self, target: str, changes: dict[str, Any]) -> None:
        self.session.configure(target, changes)
        if self.twin is not None:
            self.twin.configure(target, changes)

    # ---- publishing ----------------------------------------------------------------------------
    def _restart_pacing(self) -> None:
        self._pacer.restart(self._clock(), self._total_steps)
        self._meter.restart()

    def _settings_changed(self) -> None:
        self._settings = Settings(self._settings.version + 1, self._read_settings())
        self._dirty = True

    def _read_settings(self) -> dict[str, dict[str, Any]]:
        s = self.session
        values: dict[str, dict[str, Any]] = {t: {} for t in SETTINGS_TARGETS}
        if self._settings_reader is not None:
            try:
                values.update(self._settings_reader(s))
            except Exception:  # a reader bug must not stop the simulation
                traceback.print_exc()
        values["drag"] = {k: float(getattr(s.drag, k)) for k in DRAG_FIELDS}
        if self._settings_reader is not None:
            return values
        return {
            "executor": settings_of(s.executor),
            "environment": settings_of(s.environment),
            "sensor": settings_of(s.sensor),
            "drag": {k: float(getattr(s.drag, k)) for k in DRAG_FIELDS},
            "target": {},
            "world": s.world.settings(),
        }

    def _notify(self, level: str, title: str, body: str, client_id: int | None = None) -> None:
        notice = Notice(level, title, body, client_id)
        self._notices.append(notice)
        self.notice_log.append(notice)

    def _refresh_status(self) -> LoopStatus:
        self.status = self._make_status()
        return self.status

    def _make_status(self) -> LoopStatus:
        s = self.session
        last = s.last
        variant = variant_of(s.scenario)
        return LoopStatus(
            running=self._running,
            t=s.world.time,
            steps=s.steps,
            speed=self._pacer.speed,
            rtf=self._meter.rtf if self._running else 0.0,
            load=self._meter.load if self._running else 0.0,
            scenario=s.scenario.name,
            scenario_title=str(getattr(s.scenario, "title", s.scenario.name)),
            scenario_text=str(getattr(s.scenario, "description", "")),
            variant=variant.current if variant else "",
            variants=variant.options if variant else (),
            focus_joint=getattr(s.scenario, "focus_joint", None),
            twin=self.twin.objective if self.twin is not None else "",
            robot=s.robot.name,
            executor=s.executor_name,
            halted=self._halted,
            fallback=bool(last.fallback) if last is not None else False,
            fallback_steps=self._fallback_steps,
            drag_client=self._drag_client,
            step_cpu_s=self._step_cpu_s,
            signals=_with_posture_objective(s, dict(last.signals) if last is not None else {}),
        )

    def _publish(self, now: float) -> None:
        self._dirty = False
        status = self._make_status()
        self.status = status
        scene = None
        if self._capture is not None:
            try:
                scene = self._capture(self.session)
            except Exception:  # a drawing problem must not stop the simulation
                traceback.print_exc()
                self._capture = None
                self._notify("warning", "Scene disabled", "capturing the scene failed; see the server log")
        if scene is not None and self.twin is not None:
            positions, wxyz = self.twin.link_poses(scene.link_names)
            scene = dataclasses.replace(
                scene,
                twin_link_positions=positions,
                twin_link_wxyz=wxyz,
                twin_objective=self.twin.objective,
                twin_W=self.twin.W,
            )
        self._monitor.append(_monitor_row(status, scene))
        if now >= self._next_plot:
            self._next_plot = now + self.plot_period
            self._plot = self._plot_data()
            self._plot_seq += 1
        self._seq += 1
        frame = Frame(
            seq=self._seq,
            session_id=self._session_id,
            robot=self.session.robot,
            status=status,
            settings=self._settings,
            scene=scene,
            plot=self._plot,
            plot_seq=self._plot_seq,
        )
        with self._frame_cond:
            self._frame = frame
            self._frame_cond.notify_all()

    def _plot_data(self) -> PlotData:
        every = max(1, round(PLOT_WINDOW_S / self.dt / 500))  # ≈ 500 points per series
        columns = self.log.window(PLOT_WINDOW_S, self.dt, every)
        if self.twin is not None and "t" in columns:
            columns["twin_force_error_n"] = self.twin.force_error_at(columns["t"])
        mon = np.array(self._monitor) if self._monitor else np.zeros((0, 5))
        monitor = {k: mon[:, i].copy() for i, k in enumerate(("t", "rtf", "W_f", "W_a", "W_d"))}
        r = self.session.robot
        return PlotData(columns, monitor, r.q_lower.copy(), r.q_upper.copy(), r.dq_max.copy(), r.tau_max.copy())


def _with_posture_objective(session: Session, signals: dict[str, float]) -> dict[str, float]:
    """Add W_j = ½‖q − q_posture‖² [T18] when the executor did not report it."""
    if "W_j" not in signals:
        q_posture = getattr(session.executor, "q_posture", None)
        if q_posture is None and session.last is not None:
            q_posture = session.last.target.q_posture
        if q_posture is not None:
            e = session.world.q - np.asarray(q_posture, dtype=float)
            signals["W_j"] = 0.5 * float(e @ e)
    return signals


def _monitor_row(status: LoopStatus, scene: Any) -> tuple[float, float, float, float, float]:
    """(t, real-time factor, W_f, W_a, W_d); the W are NaN near a singularity, where Λx is ill-conditioned
    and W_a runs into the 1e8s (the overlays hide there too)."""
    W = getattr(scene, "W", None) or {}
    sig = status.signals
    singular = bool(getattr(scene, "near_singular", False))

    def pick(key: str) -> float:
        value = W.get(key, sig.get(key, math.nan))
        return math.nan if singular else float(value)

    return (status.t, status.rtf, pick("W_f"), pick("W_a"), pick("W_d"))


def _finite_array(value: object) -> np.ndarray | None:
    """A finite numeric array, or None."""
    if isinstance(value, (str, bytes)):
        return None
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        return None
    return arr if np.all(np.isfinite(arr)) else None


def _vec3(value: object) -> np.ndarray | None:
    """A finite 3-vector, or None."""
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        return None
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        return None
    return arr


def _reason(exc: BaseException) -> str:
    text = str(exc) or type(exc).__name__
    if isinstance(exc, TypeError) and "unexpected keyword" in text:
        return f"this controller has no such setting ({text})"
    return text
