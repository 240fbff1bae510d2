"""The live figures an environment computes for the page, in a process of their own (`app.scenarios.Offload`).

The polish preset's force-loop margin (σ ten times a simulated second, the K_f^d margin once) is a
few hundred microseconds (σ) to a few milliseconds (K_f^d) of small numpy operations, Python that
holds the GIL: in a thread it would still take the loop thread's turn, so it runs in a spawned
worker process instead. The loop thread only takes a snapshot (the posture's Λx, the groups) and
writes it to the worker's pipe; the environment takes the results in order as they come, a few
milliseconds later.

No thread of this process carries the traffic: the loop thread pickles and writes a job itself (a
few kB, far below the pipe's buffer for the few jobs the environment lets be under way) and reads
the answers with a zero-timeout poll when it asks whether one is in. A helper thread would have to
take the GIL from the loop thread for every job and answer, and on a loaded machine the loop thread
then waits for that thread to be scheduled.

Nothing waits on the loop thread: the worker is started from a short-lived thread (a spawn blocks its
caller for tens of milliseconds on a loaded machine) and warmed there (its imports), and until it is
ready, or after it died until a new one is, `submit` answers None and the environment skips that
sample. Work under way when the worker dies ends with an error (the environment shows NaN for it).
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future
from multiprocessing import get_context
from multiprocessing.connection import Connection
from typing import Any

from app.live.plan_worker import app_niceness
from app.live.priority import set_process_niceness

READY_TIMEOUT_S = 120.0  # a worker that has not imported the scenarios by then is given up (and tried again)
# the worker runs this much nicer than the app: woken by a job, it must not take the core the loop
# thread (or, headless, the stepping thread) is on; a figure a few milliseconds late costs nothing
WORKER_NICENESS_ABOVE_APP = 10


def _serve(conn: Connection, niceness: int) -> None:
    """The worker process: import the scenarios (MuJoCo, the controller's modules), say so, then answer
    each (fn, args) with (True, fn(*args)) or (False, the error in words), in order, until told to stop
    (None) or the app is gone."""
    set_process_niceness(niceness)
    import importlib

    from app.scenarios import SCENARIOS

    for module in SCENARIOS.values():  # the presets' modules, so no first figure waits for an import
        importlib.import_module(f"app.scenarios.{module}")
    conn.send("ready")
    while True:
        try:
            job = conn.recv()
        except (EOFError, OSError):
            return
        if job is None:
            return
        fn, args = job
        try:
            answer = (True, fn(*args))
        except Exception as exc:  # handed back as the job's error
            answer = (False, f"{type(exc).__name__}: {exc}")
        try:
            conn.send(answer)
        except OSError:  # the app is gone
            return


class _Answer(Future):
    """A job's result: asking whether it is done reads the answers that have come in (no thread does)."""

    def __init__(self, owner: LiveOffload):
        super().__init__()
        self._owner = owner

    def done(self) -> bool:
        """True once the worker's answer is in (reads any that have come, without waiting)."""
        if not super().done():
            self._owner.take_answers(0.0)
        return super().done()

    def result(self, timeout: float | None = None) -> Any:
        """The answer, waiting up to `timeout` s for it (TimeoutError after that)."""
        self._wait(timeout)
        return super().result(0)

    def exception(self, timeout: float | None = None) -> BaseException | None:
        """The job's error (None when it has a result), waiting up to `timeout` s."""
        self._wait(timeout)
        return super().exception(0)

    def _wait(self, timeout: float | None) -> None:
        deadline = None if timeout is None else time.monotonic() + timeout
        while not super().done():
            left = 1.0 if deadline is None else deadline - time.monotonic()
            if left <= 0:
                return
            self._owner.take_answers(min(left, 1.0))


class LiveOffload:
    """One spawned worker process for the environments' live figures (module docstring)."""

    def __init__(self) -> None:
        self._conn: Connection | None = None  # set once the worker is up and warm
        self._process: Any = None
        self._waiting: deque[_Answer] = deque()  # jobs written, oldest first
        self._starting = False
        self._closed = False
        self._lock = threading.Lock()  # guards start and stop; the pipe is the loop thread's
        self._ready = threading.Event()
        self.starts = 0  # workers started (more than one: one died and was replaced)

    def start(self) -> None:
        """Start the worker in a short-lived thread (no-op while one runs or starts, or once stopped)."""
        with self._lock:
            if self._conn is not None or self._starting or self._closed:
                return
            self._starting = True
        threading.Thread(target=self._start, name="torquelab-offload-start", daemon=True).start()

    def _start(self) -> None:
        ctx = get_context("spawn")
        ours, theirs = ctx.Pipe()
        niceness = min(19, app_niceness() + WORKER_NICENESS_ABOVE_APP)
        process = ctx.Process(target=_serve, args=(theirs, niceness), name="torquelab-offload", daemon=True)
        try:
            process.start()
            theirs.close()
            ready = ours.poll(READY_TIMEOUT_S) and ours.recv() == "ready"
        except (OSError, EOFError):
            ready = False
        with self._lock:
            self._starting = False
            if not ready or self._closed:
                _end(ours, process)
                return
            self._conn, self._process = ours, process
            self.starts += 1
            self._ready.set()

    def ready(self, timeout: float) -> bool:
        """Start the worker if needed and wait up to `timeout` s until it takes work (tests, benches)."""
        self.start()
        return self._ready.wait(timeout)

    def submit(self, fn: Callable[..., Any], /, *args: Any) -> Future | None:
        """fn(*args) in the worker (fn a module-level function, the arguments picklable); None while it
        is not ready (starting it) or just died (starting a new one): the caller skips this sample."""
        conn = self._conn
        if conn is None:
            self.start()
            return None
        answer = _Answer(self)
        try:
            conn.send((fn, args))
        except (OSError, ValueError):  # the worker is gone (or the pipe closed by stop)
            self._lost(conn)
            return None
        self._waiting.append(answer)
        return answer

    def take_answers(self, timeout: float) -> None:
        """Hand the answers that are in (waiting up to `timeout` s for the first) to their jobs, in order."""
        conn = self._conn
        if conn is None:
            return
        try:
            while self._waiting and conn.poll(timeout):
                ok, value = conn.recv()
                answer = self._waiting.popleft()
                if ok:
                    answer.set_result(value)
                else:
                    answer.set_exception(RuntimeError(value))
                timeout = 0.0
        except (OSError, EOFError, ValueError):
            self._lost(conn)

    def _lost(self, conn: Connection) -> None:
        """The worker died: its jobs end with an error, a new worker starts."""
        with self._lock:
            if self._conn is not conn:
                return
            self._conn, process = None, self._process
            self._ready.clear()
        threading.Thread(target=_end, args=(conn, process), name="torquelab-offload-end", daemon=True).start()
        while self._waiting:
            self._waiting.popleft().set_exception(RuntimeError("the live figures' worker process died"))
        self.start()

    def stop(self) -> None:
        """End the worker (work under way is abandoned); no new one starts after this."""
        with self._lock:
            self._closed = True
            conn, process = self._conn, self._process
            self._conn = None
            self._ready.clear()
        if conn is not None:
            try:
                conn.send(None)
            except (OSError, ValueError):
                pass
            _end(conn, process)


def _end(conn: Connection, process: Any) -> None:
    """Close our end of the pipe and let the worker go (it ends at EOF; killed if it does not soon)."""
    conn.close()
    if process is not None:
        process.join(0.5)
        if process.is_alive():
            process.kill()
