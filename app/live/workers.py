"""A worker process that comes back: work off the calling thread, in a spawned process of its own.

Three parts of the live app compute in a process of their own: the polish margin's live figures
(`app.live.offload`: many small jobs from the loop thread), a preset's costly preparation
(`app.live.plan_worker`: one job of seconds from the loop thread) and the self-motion scans
(`app.live.ui.selfmotion`: one job a second from the preview's thread). `Worker` is what they share;
each keeps only what it computes and what it does with the answer.

- **Spawned** (it inherits none of the server's threads) at the app's niceness plus
  `niceness_above_app`, set in the worker itself: spawned from the loop thread it would inherit that
  thread's priority.
- **Nothing waits on the calling thread.** The worker is started, and warmed (`warm`: its imports),
  in a short-lived thread, since a spawn blocks its caller for tens of milliseconds on a loaded
  machine; until it is ready `submit` answers None and the caller skips the job or submits it again
  later. No thread of this process carries the traffic either: the caller pickles and writes a job
  itself and reads the answers with a zero-timeout poll when it asks whether one is in
  (`Future.done`). A helper thread would take the GIL from the loop thread for every job and answer,
  and on a loaded machine the loop thread then waits for that thread to be scheduled; this is why
  `concurrent.futures.ProcessPoolExecutor` (a manager thread and a queue feeder thread) is not used.
  So the pipe and the jobs belong to one calling thread; `stop` may come from another.
- **It comes back.** A worker that dies (killed, out of memory) is noticed at the next write or read:
  its jobs under way end with `WorkerLost` (the caller decides whether to submit them again) and a new
  worker starts. After FAILED_STARTS_MAX starts in a row that did not come up, or at once where no
  process can start here, it gives up (`gave_up` says why) and `submit` answers None from then on.
- **It ends with the app.** `stop` ends it; a worker whose app died (even by kill -9) reads the end of
  its pipe, or, in the middle of a job or its warm-up, sees within ORPHAN_CHECK_S that its parent
  changed, and exits (a `ProcessPoolExecutor` worker lives on).

A job and its answer are pickled whole into the pipe: keep them small (a few kB) when several are
under way, or the worker, blocked writing an answer, and the caller, blocked writing a job, wait on
each other.
"""

from __future__ import annotations

import os
import pickle
import threading
import time
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future
from multiprocessing import get_context
from multiprocessing.connection import Connection
from typing import Any

from app.live.priority import set_process_niceness

READY_TIMEOUT_S = 120.0  # a worker that is not up (its imports done) by then is ended and started again
FAILED_STARTS_MAX = 3  # starts in a row that did not come up before the worker is given up
ORPHAN_CHECK_S = 0.5  # how often a worker looks whether its app is still there


class WorkerLost(RuntimeError):
    """The worker process died (or was ended, or never came up) before it answered."""


def app_niceness() -> int:
    """The niceness of the process's main thread (the app's default priority; 0 where unknown)."""
    try:
        return os.getpriority(os.PRIO_PROCESS, os.getpid())
    except (OSError, AttributeError):
        return 0


def _exit_when_orphaned(app_pid: int, every_s: float = ORPHAN_CHECK_S) -> None:
    """Exit this worker process at once when the app that spawned it is gone (its parent changes)."""
    while True:
        time.sleep(every_s)
        if os.getppid() != app_pid:
            os._exit(0)


def _serve(conn: Connection, niceness: int, warm: Callable[[], None] | None) -> None:
    """The worker process: warm up, say so, then answer each (fn, args) with (True, fn(*args)) or
    (False, its error), in order, until told to stop (None) or the app is gone (the pipe's end, or
    a new parent while a job or the warm-up is under way)."""
    threading.Thread(target=_exit_when_orphaned, args=(os.getppid(),), name="orphan-watch", daemon=True).start()
    set_process_niceness(niceness)
    if warm is not None:
        warm()
    try:
        conn.send("ready")
        while (job := conn.recv()) is not None:
            fn, args = job
            try:
                answer = pickle.dumps((True, fn(*args)))
            except Exception as exc:  # handed back as the job's error (so is an answer that cannot be pickled)
                answer = _pickled_error(exc)
            conn.send_bytes(answer)
    except (EOFError, OSError):  # the app is gone
        return


def _pickled_error(exc: Exception) -> bytes:
    """(False, exc) pickled; an error that cannot be pickled goes as a RuntimeError with its words."""
    try:
        return pickle.dumps((False, exc))
    except Exception:
        return pickle.dumps((False, RuntimeError(f"{type(exc).__name__}: {exc}")))


class _Answer(Future):
    """A job's answer: asking whether it is done reads the answers that have come in (no thread does)."""

    def __init__(self, owner: Worker):
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


class Worker:
    """One spawned worker process, started on first use and replaced when it dies (module docstring).

    `name` names the process and its threads; `warm` (a module-level function) runs in the worker
    before it says it is ready."""

    def __init__(self, name: str, niceness_above_app: int = 0, warm: Callable[[], None] | None = None):
        self.name = name
        self.niceness_above_app = niceness_above_app
        self.warm = warm
        self._conn: Connection | None = None  # set once the worker is up
        self._process: Any = None
        self._waiting: deque[_Answer] = deque()  # jobs written, oldest first
        self._starting = False
        self._closed = False
        self._changed = threading.Condition()  # guards start, loss and stop; the pipe is the caller's
        self.starts = 0  # workers that came up (more than one: one died and was replaced)
        self.losses = 0  # workers lost (died, or ended for not answering) while the app ran on
        self.failed_starts = 0  # starts in a row that did not come up
        self.gave_up: str | None = None  # why no worker will start any more; None while one may

    @property
    def up(self) -> bool:
        """True while a worker takes jobs."""
        return self._conn is not None

    @property
    def stopped(self) -> bool:
        """True once `stop` was called (no worker starts any more)."""
        return self._closed

    @property
    def pid(self) -> int | None:
        """The worker's process id while it is up."""
        return self._process.pid if self._conn is not None else None

    def start(self) -> None:
        """Start a worker in a short-lived thread (no-op while one is up or starting, once stopped or given up)."""
        with self._changed:
            if self._conn is not None or self._starting or self._closed or self.gave_up is not None:
                return
            self._starting = True
        threading.Thread(target=self._start, name=f"{self.name}-start", daemon=True).start()

    def _start(self) -> None:
        ctx = get_context("spawn")
        niceness = min(19, app_niceness() + self.niceness_above_app)
        try:
            ours, theirs = ctx.Pipe()
            process = ctx.Process(target=_serve, args=(theirs, niceness, self.warm), name=self.name, daemon=True)
            process.start()
            theirs.close()
        except Exception as exc:  # no worker process can run here
            with self._changed:
                self._starting = False
                self.gave_up = f"no worker process can start here ({type(exc).__name__}: {exc})"
                self._changed.notify_all()
            return
        try:
            ready = ours.poll(READY_TIMEOUT_S) and ours.recv() == "ready"
        except (OSError, EOFError):
            ready = False
        with self._changed:
            self._starting = False
            up = ready and not self._closed
            if up:
                self._conn, self._process = ours, process
                self.starts += 1
                self.failed_starts = 0
            elif not self._closed:
                self.failed_starts += 1
                if self.failed_starts >= FAILED_STARTS_MAX:
                    self.gave_up = f"the worker process did not come up {self.failed_starts} times in a row"
            self._changed.notify_all()
        if not up:
            _end(ours, process)

    def ready(self, timeout: float) -> bool:
        """Start the worker if needed and wait up to `timeout` s until it takes jobs (False at once when
        its start failed)."""
        self.start()
        with self._changed:
            self._changed.wait_for(lambda: self._conn is not None or not self._starting, timeout)
            return self._conn is not None

    def submit(self, fn: Callable[..., Any], /, *args: Any) -> Future | None:
        """fn(*args) in the worker (fn a module-level function, the arguments picklable); None while no
        worker is up (one is started) or when it just died (a new one is started)."""
        conn = self._conn
        if conn is None:
            self.start()
            return None
        answer = _Answer(self)
        try:
            conn.send((fn, args))
        except (OSError, ValueError):  # the worker is gone (or the pipe closed by stop)
            self._lost(conn, "died")
            return None
        self._waiting.append(answer)
        return answer

    def call(self, fn: Callable[..., Any], /, *args: Any, timeout: float) -> Any:
        """fn(*args) in the worker, waiting for it up to `timeout` s to come up and as long again for the
        answer (the calling thread waits without the GIL). Raises the job's own error, WorkerLost when
        the worker died or did not come up, TimeoutError when it did not answer in time (it is then
        ended and a new one started)."""
        if not self.ready(timeout):
            raise WorkerLost(self.gave_up or f"{self.name}: the worker process did not come up")
        answer = self.submit(fn, *args)
        if answer is None:
            raise WorkerLost(f"{self.name}: the worker process died")
        try:
            return answer.result(timeout)
        except TimeoutError:
            if (conn := self._conn) is not None and not answer.done():
                self._lost(conn, f"did not answer within {timeout:g} s")
            raise

    def take_answers(self, timeout: float) -> None:
        """Hand the answers that are in (waiting up to `timeout` s for the first) to their jobs, in order."""
        conn = self._conn
        if conn is None:  # (stopped while a job was being written: it is never answered)
            self._fail_waiting(f"{self.name}: the worker process is gone")
            return
        try:
            while self._waiting and conn.poll(timeout):
                message = conn.recv_bytes()
                _settle(self._waiting.popleft(), message)
                timeout = 0.0
        except (OSError, EOFError, ValueError):
            self._lost(conn, "died")

    def _lost(self, conn: Connection, why: str) -> None:
        """The worker died (or is ended): its jobs end with WorkerLost, a new worker starts."""
        with self._changed:
            if self._conn is not conn:
                return
            self._conn, process = None, self._process
            self.losses += 1
        threading.Thread(target=_end, args=(conn, process), name=f"{self.name}-end", daemon=True).start()
        self._fail_waiting(f"{self.name}: the worker process {why}")
        self.start()

    def _fail_waiting(self, why: str) -> None:
        while self._waiting:
            answer = self._waiting.popleft()
            if not answer.cancelled():
                answer.set_exception(WorkerLost(why))

    def stop(self) -> None:
        """End the worker (jobs under way end with WorkerLost); no new one starts after this."""
        with self._changed:
            self._closed = True
            conn, process = self._conn, self._process
            self._conn = None
            self._changed.notify_all()
        if conn is not None:
            try:
                conn.send(None)
            except (OSError, ValueError):
                pass
            _end(conn, process)
        self._fail_waiting(f"{self.name}: the worker process was stopped")


def _settle(answer: _Answer, message: bytes) -> None:
    """Give a job the answer the worker sent (an answer that cannot be read here is its error)."""
    if answer.cancelled():
        return
    try:
        ok, value = pickle.loads(message)
    except Exception as exc:
        answer.set_exception(exc)
        return
    if ok:
        answer.set_result(value)
    else:
        answer.set_exception(value)


def _end(conn: Connection, process: Any) -> None:
    """Close our end of the pipe and let the worker go (it ends at EOF; killed if it does not soon)."""
    conn.close()
    if process is not None:
        process.join(0.5)
        if process.is_alive():
            process.kill()
