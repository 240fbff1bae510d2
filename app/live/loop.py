"""The real-time runner: the one thread that owns a `Lab` (its Session: MuJoCo, controller, solvers).

It applies the commands other threads queue (`app.core.commands`) between two steps, steps the lab at
1 kHz simulated time paced to wall time (`app.live.pacing`), and at 30 Hz publishes a `Frame`
(`app.live.frames`) that the server's publisher thread shows in the browser. Drag commands and Pause
jump the queue, and a single step runs in chunks of `STEP_CHUNK` steps with them applied between
chunks, so a release waits for at most one chunk. "Settle now" runs unpaced in chunks too, with
every command (Pause, Reset, a switch) applied between them. Unpaced, frames go out at 10 Hz. A
failure while building a frame skips that frame's failing part (`app.live.frames`) and the loop
goes on. Nothing outside this thread touches the Lab, except through `call()`, which runs a
function here between two steps.

On Linux the thread asks for a higher scheduling priority (niceness LOOP_NICENESS, this thread
only) where the system allows it (root, or an RLIMIT_NICE that permits it): the server's other
threads then do not delay the steps that are due, nor does a browser in the same session (Chromium
raises its own display threads to −8). A browser in another session is another autogroup: the app
raises its session's share against it (`app.live.priority`). Where it is refused, the thread keeps the
process's priority.
"""

from __future__ import annotations

import os
import sys
import threading
import time
import traceback
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import dataclass
from typing import Any, TypeVar

from app.core.commands import Command, DragCommand, Pause, Play, SetTwin, StepOnce, SwitchSession
from app.core.export import run_export
from app.core.session import Session, WorkPending
from app.core.settings import Settings
from app.core.steplog import StepLog
from app.core.switching import rebuilds
from app.core.twin import Twin
from app.live.frames import Frame, FrameBuilder, LoopStatus, PlotData, make_status
from app.live.lab import Lab
from app.live.memory import trim_heap_soon
from app.live.notices import Notice, refusal_words
from app.live.offload import LiveOffload
from app.live.pacing import Pacer, RateMeter, next_frame_due
from app.live.plan_worker import BackgroundPlanner
from app.live.run_flags import SPEED_RANGE, UNPACED_SPEED, RunFlags
from app.live.switch_builder import SwitchBuilder, switch_build, twin_build
from app.scenarios import PLAIN_PRESET

__all__ = ["SPEED_RANGE", "Frame", "LoopStatus", "Notice", "PlotData", "Settings", "SimLoop"]

T = TypeVar("T")
# Paced, the loop sleeps until the next frame is due and then runs every step due (about 33 at 1×,
# 30 Hz) in one burst just before building the frame, so a frame shows the state at its own instant.
# Each wake-up costs far more than its steps suggest: the first steps after a sleep run on caches
# the browser, the other threads or the host's other guests have used meanwhile (measured here, one
# step warm ~70 µs, the first after an 8 ms sleep ~800 µs, the next two ~250 and ~170 µs), so one
# wake-up per frame spends much less CPU per simulated second than one per 8 steps did. Commands
# still wake the loop at once (and run the steps due then); at a speed where more than a burst
# (`Pacer.max_burst`) is due within a frame, the loop also wakes when a full burst is due.
STEP_CHUNK = 100  # a single step runs in chunks this long; urgent commands are applied between them
URGENT = (DragCommand, Pause)  # commands that jump the queue
BURST_SLACK = 0.5  # a burst begun once its frame is due may delay that frame by this share of a period
UNPACED_PUBLISH_S = 0.1  # frame period while running unpaced (10 Hz instead of 30)
CALL_POLL_S = 0.1  # `call` looks this often whether a plan is being computed (its time is not counted)
DRAG_TIMEOUT_S = 20.0  # a drag with no update from its client for this long is released (a silent tab)
LOOP_NICENESS = -10  # the loop thread's niceness where the system allows it (below Chromium's −8)


def raise_thread_priority(niceness: int) -> int | None:
    """Give the calling thread the niceness `niceness` if that is a higher priority than it has (Linux,
    this thread only); returns its niceness afterwards, or None where per-thread priorities are not
    available. A refusal (no permission) leaves the priority as it was."""
    if sys.platform != "linux":
        return None
    tid = threading.get_native_id()
    current = os.getpriority(os.PRIO_PROCESS, tid)
    if niceness < current:
        try:
            os.setpriority(os.PRIO_PROCESS, tid, niceness)
        except OSError:
            pass
    return os.getpriority(os.PRIO_PROCESS, tid)


@dataclass(frozen=True)
class _Call:
    fn: Callable[[Session], Any]
    future: Future


class CommandQueue:
    """Two FIFO lanes: urgent commands (drag, Pause) are taken first. A Pause also drops the Play
    and single-step commands queued before it (it stops what they would start)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._urgent: deque[Command] = deque()
        self._normal: deque[Command | _Call] = deque()

    def put(self, item: Command | _Call) -> None:
        """Queue an item (thread-safe, never blocks)."""
        with self._lock:
            if isinstance(item, URGENT):
                self._urgent.append(item)
                if isinstance(item, Pause):
                    self._normal = deque(x for x in self._normal if not isinstance(x, (Play, StepOnce)))
            else:
                self._normal.append(item)

    def get(self, urgent_only: bool = False) -> Command | _Call | None:
        """The next item (urgent first), or None."""
        with self._lock:
            if self._urgent:
                return self._urgent.popleft()
            if self._normal and not urgent_only:
                return self._normal.popleft()
            return None

    def empty(self, urgent_only: bool = False) -> bool:
        """True when nothing is queued (with `urgent_only`: nothing `get(urgent_only=True)` would take)."""
        return not (self._urgent or (self._normal and not urgent_only))


class SimLoop:
    """Runs a Lab in its own thread in real time; see the module docstring."""

    def __init__(
        self,
        scenario: str = PLAIN_PRESET,
        robot: str | None = None,
        executor: str | None = None,
        seed: int = 0,
        publish_hz: float = 30.0,
        plot_hz: float = 10.0,
        log_seconds: float = 60.0,
        clock: Callable[[], float] = time.perf_counter,
        capture: Callable[[Session], Any] | None = None,
    ):
        self.lab = Lab(scenario, robot=robot, executor=executor, seed=seed, log_seconds=log_seconds)
        self.log_seconds = log_seconds
        self.flags = RunFlags(self.lab)  # running, settling, single steps, speed, pacing (`app.live.run_flags`)
        self.planner = BackgroundPlanner()
        self.builder = SwitchBuilder(self._wake_up)  # a switch's new session, built off this thread
        # the polish margin's live figures: in a worker process, not on the loop thread (`app.live.offload`)
        # (started by the first figure a preset asks for, from a thread of its own: nothing waits)
        self.offload = LiveOffload()
        self.lab.set_offload(self.offload)
        self._clock = clock
        self.publish_period = 1.0 / publish_hz
        self.frames = FrameBuilder(self.publish_period, 1.0 / plot_hz, capture)
        self._queue = CommandQueue()
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._started = False
        self.failure = ""  # why the loop thread died, "" while it runs or after a clean stop
        self.niceness: int | None = None  # the loop thread's niceness once it runs (None: not on Linux)
        self._pacer = Pacer(self.lab.dt)
        self._meter = RateMeter()
        self._pacing_epoch = -1
        self._frame: Frame | None = None
        self._frame_cond = threading.Condition()
        self._drag_seen: dict[int, float] = {}  # client id → wall time of its last grab or move
        self.status = make_status(self.lab, flags=self.flags)

    # ---- what the lab holds (read these on the loop thread, or through call()) ---------------------
    @property
    def session(self) -> Session:
        """The current session."""
        return self.lab.session

    @property
    def twin(self) -> Twin | None:
        """The twin arm, if one runs."""
        return self.lab.twin

    @property
    def log(self) -> StepLog:
        """The step log of the current session."""
        return self.lab.log

    @property
    def dt(self) -> float:
        """The control period (s)."""
        return self.lab.dt

    @property
    def notice_log(self) -> deque[Notice]:
        """Every notice sent (for tests and logs)."""
        return self.lab.notice_log

    @property
    def robot_choice(self) -> str:
        """The robot picked explicitly ("" = the scenario's default)."""
        return self.lab.robot_choice

    @property
    def settings(self) -> Settings:
        """The current tunables (read-only snapshot, replaced when anything changes)."""
        return self.lab.settings

    # ---- API for other threads ----------------------------------------------------------------
    def start(self, running: bool = True) -> None:
        """Start the loop thread (running paced, or paused)."""
        if self._thread is not None:
            return
        self.flags.running = running
        self._started = True
        self._thread = threading.Thread(target=self._run, name="torquelab-sim", daemon=True)
        self._thread.start()

    def stop(self, timeout: float = 5.0) -> bool:
        """Stop the loop thread; False if it did not end within `timeout` (it is kept, `alive` says so)."""
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout)
            if self._thread.is_alive():
                return False
            self._thread = None
        self.planner.stop()
        self.builder.stop()
        self.offload.stop()
        return True

    @property
    def alive(self) -> bool:
        """True while the loop thread runs."""
        return self._thread is not None and self._thread.is_alive()

    def submit(self, cmd: Command) -> None:
        """Queue a command; the loop applies it between two steps (thread-safe, never blocks)."""
        if isinstance(cmd, DragCommand) and cmd.kind in ("grab", "move"):
            self._drag_seen[cmd.client_id] = self._clock()
        elif isinstance(cmd, DragCommand) and cmd.kind == "release":
            self._drag_seen.pop(cmd.client_id, None)  # a page that let go (or left) is watched no more
        self._queue.put(cmd)
        self._wake.set()

    def call(self, fn: Callable[[Session], T], timeout: float = 10.0) -> T:
        """Run `fn(session)` in the loop thread between two steps and return its result. Before
        `start()` it runs here; RuntimeError once the loop thread has ended. `timeout` (TimeoutError)
        counts only the time no swivel plan is being computed: a call queued behind a switch to a
        planned case waits for the plan (seconds, more on a loaded machine) on top of it."""
        if threading.current_thread() is self._thread or not self._started:
            return fn(self.lab.session)
        if not self.alive:
            raise RuntimeError(f"the simulation loop is not running{': ' + self.failure if self.failure else ''}")
        fut: Future = Future()
        self._queue.put(_Call(fn, fut))
        self._wake.set()
        left = timeout
        while True:
            t0 = time.monotonic()
            try:
                return fut.result(max(0.0, min(left, CALL_POLL_S)))
            except TimeoutError:
                if fut.done():  # `fn` itself raised TimeoutError
                    raise
                if not self._waiting_for_work:
                    left -= time.monotonic() - t0
                if left <= 0.0:
                    raise TimeoutError(f"the simulation loop did not answer within {timeout:g} s") from None

    def sync(self, timeout: float = 10.0) -> LoopStatus:
        """Wait until every command queued before this call has been applied; returns the status then."""
        return self.call(lambda s: self._refresh_status(), timeout)

    def wait_frame(self, after_seq: int, timeout: float) -> Frame | None:
        """The newest frame with seq > `after_seq`, waiting up to `timeout` s; None on timeout."""
        with self._frame_cond:
            self._frame_cond.wait_for(lambda: self._frame is not None and self._frame.seq > after_seq, timeout)
            frame = self._frame
        return frame if frame is not None and frame.seq > after_seq else None

    def notify(self, level: str, title: str, body: str, client_id: int | None = None) -> None:
        """A notice for every page (or the page `client_id`) from another thread (the lab's notice
        queues are deques: appends are atomic); it goes out with the loop's own."""
        self.lab.notify(level, title, body, client_id)

    def take_notices(self) -> list[Notice]:
        """Notices produced since the last call (for the publisher)."""
        return self.lab.notices.take()

    def export(self, seconds: float, timeout: float = 10.0) -> dict[str, Any]:
        """The last `seconds` of the step log (every step) plus what produced it, copied in the loop thread."""
        return self.call(lambda s: run_export(s, self.lab.log, self.lab.twin, seconds), timeout)

    # ---- the thread -----------------------------------------------------------------------------
    def _run(self) -> None:
        try:
            self.niceness = raise_thread_priority(LOOP_NICENESS)
            self._loop()
        except BaseException as exc:  # reported to `serve`, which exits non-zero
            traceback.print_exc()
            self.failure = f"{type(exc).__name__}: {exc}"
            self._fail_queued_calls()

    def _loop(self) -> None:
        lab, flags = self.lab, self.flags
        next_publish = self._clock()
        while not self._stop.is_set():
            cut = False
            self._drain()
            self._follow_pacing()
            if flags.pending_steps:
                self._timed(flags.step_pending, STEP_CHUNK)
            elif flags.settling:  # "Settle now": unpaced chunks, every command applied between them
                self._timed(flags.settle_chunk, STEP_CHUNK)
                if self._meter.sample(self._clock(), lab.session.world.time):
                    lab.dirty = True
            elif flags.running:
                now = self._clock()
                n = self._pacer.due(now, lab.total_steps)
                if n:
                    # a burst a busy machine slows down ends when a frame is due, so frames keep their rate
                    frame_at = next_publish if next_publish > now else now + BURST_SLACK * self._publish_period()
                    result = self._timed(flags.advance, n, until=lambda _rec, at=frame_at: self._clock() >= at)
                    cut = result.stop == "until"
                if self._meter.sample(self._clock(), lab.session.world.time):
                    lab.dirty = True
            now = self._clock()
            if now >= next_publish:
                self._release_silent_drag(now)
                if lab.dirty or flags.running:
                    self._publish(now)
                next_publish = next_frame_due(next_publish, now, self._publish_period())
            if flags.pending_steps or flags.settling:
                continue
            if cut:
                continue  # the steps the cut burst left are due already
            wake_at = next_publish
            if flags.running:
                # wake at the next frame, or earlier when a full burst is due (a command wakes it at once)
                wake_at = min(wake_at, self._pacer.next_due(lab.total_steps + self._pacer.max_burst - 1))
            timeout = wake_at - self._clock()
            # cleared before the queue is looked at: a command queued after the look sets it again
            # and ends the wait at once (cleared after the wait, its wake-up could be lost). While a
            # preset's work is computed the commands behind its switch wait for it: they do not keep the
            # loop awake (it would spin a core beside the worker computing the work)
            self._wake.clear()
            if timeout > 2e-4 and self._queue.empty(urgent_only=self._waiting_for_work):
                self._wake.wait(timeout)

    def _release_silent_drag(self, now: float) -> None:
        """Release the drag of a client that sent no grab or move for DRAG_TIMEOUT_S (a tab that went
        silent without closing keeps no spring on the arm), with a notice to it."""
        client = self.lab.drag_client
        if client is None:
            return
        seen = self._drag_seen.get(client)
        if seen is None or now - seen <= DRAG_TIMEOUT_S:
            return
        self._drag_seen.pop(client, None)
        self.lab.apply(DragCommand("release", client_id=client))
        self.lab.notify(
            "warning", "Drag released", f"no drag update came for {DRAG_TIMEOUT_S:g} s: the spring is let go", client
        )

    def _publish_period(self) -> float:
        """Seconds to the next frame: `publish_period`, or UNPACED_PUBLISH_S while running unpaced
        ("Settle now", or the speed "as fast as possible"), so the page's drawing takes less of the
        machine the simulation is asked to use."""
        flags = self.flags
        if flags.settling or (flags.running and flags.speed >= UNPACED_SPEED):
            return max(self.publish_period, UNPACED_PUBLISH_S)
        return self.publish_period

    def _timed(self, work: Callable[..., T], n: int, **kwargs: Any) -> T:
        t0 = self._clock()
        result = work(n, **kwargs)
        self._meter.add_busy(self._clock() - t0)
        return result

    def _follow_pacing(self) -> None:
        """Restart the pacing when the lab asks (play, reset, switch, speed change)."""
        if self.flags.pacing_epoch != self._pacing_epoch:
            self._pacing_epoch = self.flags.pacing_epoch
            self._pacer.set_speed(self.flags.speed, self._clock(), self.lab.total_steps)
            self._meter.restart()

    def _drain(self) -> None:
        """Apply queued items; while a single step is under way only urgent ones (the rest keep
        their order behind it)."""
        lab = self.lab
        done = self.planner.take_done()
        if done is not None:  # the work a switch waited for: apply it first (its place in the order)
            command, error = done
            if error is None:
                self._apply(command)
            else:
                lab.notify("error", "Preparing the preset failed", f"{type(error).__name__}: {error}")
        # while the work is computed only urgent commands apply (the rest keep their order behind the switch)
        built = self.builder.take_done()
        if built is not None:  # a switch's new session: make it the lab's first (its place in the order)
            self._install(*built)
        while (item := self._queue.get(urgent_only=self.flags.pending_steps > 0 or self._waiting_for_work)) is not None:
            if isinstance(item, _Call):
                try:
                    item.future.set_result(item.fn(lab.session))
                except Exception as exc:
                    item.future.set_exception(exc)
            else:
                self._apply(item)

    @property
    def _waiting_for_work(self) -> bool:
        """A switch's session is being built or its preset's work computed: only urgent commands apply."""
        return self.planner.busy or self.builder.busy

    def _wake_up(self) -> None:
        self._wake.set()

    def _apply(self, command: Command) -> None:
        """`flags.apply`; a preset, case or robot switch's new session is built by `builder` (here, before
        the thread runs) and a switch whose preset needs work not done yet (a swivel plan) waits for
        `planner`; after a switch the memory the old session held goes back to the system (`app.live.memory`)."""
        if isinstance(command, SetTwin) and command.objective and self._thread is not None:
            try:  # what the twin takes from the main session is read here; the twin is built off this thread
                self.builder.start(command, twin_build(self.lab, str(command.objective), self.log_seconds))
            except ValueError as exc:
                self._install(command, None, exc)
            return
        if isinstance(command, SwitchSession) and rebuilds(command):
            build = switch_build(self.lab, command, self.log_seconds)
            if self._thread is not None:
                self.builder.start(command, build)
                return
            try:
                built, error = build(), None
            except Exception as exc:
                built, error = None, exc
            self._install(command, built, error)
            return
        try:
            self.flags.apply(command)
        except WorkPending as pending:
            self._plan(command, pending)

    def _install(self, command: SwitchSession | SetTwin, built: Any, error: BaseException | None) -> None:
        """Make a switch's built session (or a SetTwin's twin) the lab's; or hand its preset's work to
        `planner`; or say why it failed."""
        if isinstance(error, WorkPending):
            self._plan(command, error)
        elif isinstance(error, (ValueError, KeyError)):
            self.lab.notify("error", "Refused", refusal_words(error))
        elif error is not None:  # as `Lab.apply` says a failing command
            traceback.print_exception(error)
            self.lab.notify("error", "Command failed", f"{type(error).__name__}: {error}")
        elif isinstance(command, SetTwin) and built is not None:
            self.lab.install_twin(built)
            self.flags.follow()
        elif built is not None:
            self.lab.install_switch(built)
            self.flags.follow()
            trim_heap_soon()
        self.lab.dirty = True

    def _plan(self, command: Command, pending: WorkPending) -> None:
        """Compute a switch's preset work in `planner`; the switch is applied again once it is stored."""
        self.lab.notify(
            "info",
            "Preparing the preset",
            f"It starts once {pending.work.what} is computed (a few seconds); the current preset runs on.",
        )
        self.planner.start(command, pending.work)

    def _fail_queued_calls(self) -> None:
        while (item := self._queue.get()) is not None:
            if isinstance(item, _Call):
                item.future.set_exception(RuntimeError(f"the simulation loop stopped: {self.failure}"))

    def _refresh_status(self) -> LoopStatus:
        self.status = make_status(self.lab, self._meter.rtf, self._meter.load, flags=self.flags)
        return self.status

    def _publish(self, now: float) -> None:
        """Build and hand out a frame; a failure skips it (reported by the frame builder's error
        boundaries) and the loop goes on."""
        self.lab.dirty = False
        frame = self.frames.publish(self.lab, now, self._meter.rtf, self._meter.load, self.flags)
        if frame is None:
            return
        self.status = frame.status
        with self._frame_cond:
            self._frame = frame
            self._frame_cond.notify_all()
