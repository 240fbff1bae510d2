"""A preset's costly preparation for the app's loop, computed in a process of its own.

Some presets need a computation before their session is built (`Scenario.pending_work`): a
planned polish case needs the swivel path planned over the zig-zag, ~4.5 s of Python on a quiet
2-core machine, which the loop thread used to spend without stepping, publishing or answering a
drag. With `Lab.defer_work` the switch raises `WorkPending` instead (nothing changed yet); the
loop hands the work to `BackgroundPlanner`, keeps running the current preset, applies only urgent
commands (drag, Pause), and applies the switch again once the result is stored. The work is the
same function of the same arguments in either process.

The worker process comes back: when it dies (killed, out of memory) the pool is thrown away, a new one
is started and the work under way is submitted again (once: work that kills its worker twice fails
with a notice). Nothing is ever computed on the loop thread: where no worker process can start at
all, the work runs in a thread of its own. Nor does the loop thread start a worker: a spawn blocks
its caller for tens of milliseconds on a loaded machine, so every submission (the first, and the
one after a worker died) runs in a short-lived thread, and `take_done` answers None until it is in.
"""

from __future__ import annotations

import os
import threading
from concurrent.futures import Executor, Future, ProcessPoolExecutor, ThreadPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from multiprocessing import get_context
from typing import Any

from app.live.priority import set_process_niceness
from app.scenarios import Work


def app_niceness() -> int:
    """The niceness of the process's main thread (the app's default priority; 0 where unknown)."""
    try:
        return os.getpriority(os.PRIO_PROCESS, os.getpid())
    except (OSError, AttributeError):
        return 0


class BackgroundPlanner:
    """One piece of work at a time in a spawned worker process (started on first use, kept for the
    next, rebuilt when it dies; see the module docstring)."""

    def __init__(self) -> None:
        self._pool: Executor | None = None
        self._job: tuple[Future | None, Work, Any] | None = None
        self._retried = False  # the work under way was submitted again after its worker died
        self.rebuilds = 0  # pools started after a worker died
        self._lock = threading.Lock()  # the pool is made, used and thrown away under it
        self._generation = 0  # bumped by each start and stop: a late submission of older work is dropped

    @property
    def busy(self) -> bool:
        """True while work is being computed."""
        return self._job is not None

    def _new_pool(self) -> Executor:
        try:
            # at the app's priority: spawned from the loop thread, it would inherit that thread's
            return ProcessPoolExecutor(
                max_workers=1,
                mp_context=get_context("spawn"),
                initializer=set_process_niceness,
                initargs=(app_niceness(),),
            )
        except Exception:  # no worker process here: a thread, never the loop thread itself
            return ThreadPoolExecutor(max_workers=1, thread_name_prefix="torquelab-work")

    def _submit(self, work: Work, fresh: bool = False) -> Future:
        """Submit to the pool (a new one when `fresh`: its worker died), rebuilding it once if it is
        broken (its worker died while idle)."""
        if fresh:
            self._discard_pool()
        if self._pool is None:
            self._pool = self._new_pool()
        try:
            return self._pool.submit(work.compute, *work.args)
        except (BrokenProcessPool, RuntimeError):
            self._discard_pool()
            self.rebuilds += 1
            self._pool = self._new_pool()
            return self._pool.submit(work.compute, *work.args)

    def _discard_pool(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=False, cancel_futures=True)
            self._pool = None

    def _submit_in_thread(self, work: Work, command: Any, fresh: bool = False) -> None:
        """Submit from a thread of its own (module docstring); the job has no future until it is in."""
        generation = self._generation
        self._job = (None, work, command)

        def submit() -> None:
            with self._lock:
                if generation != self._generation:  # stopped or replaced meanwhile
                    return
                try:
                    future = self._submit(work, fresh)
                except Exception as exc:  # handed back by take_done as the work's error
                    future = Future()
                    future.set_exception(exc)
                if generation == self._generation:
                    self._job = (future, work, command)

        threading.Thread(target=submit, name="torquelab-submit", daemon=True).start()

    def start(self, command: Any, work: Work) -> None:
        """Compute `work`; `command` is handed back by `take_done` once its result is stored."""
        self._retried = False
        self._generation += 1
        self._submit_in_thread(work, command)

    def take_done(self) -> tuple[Any, BaseException | None] | None:
        """(command, None) once its work's result is stored, (command, error) if the work failed; None
        while it is still being submitted or computed (a dead worker's work is submitted again to a new
        pool) or when nothing is."""
        job = self._job
        if job is None:
            return None
        future, work, command = job
        if future is None or not future.done():
            return None
        error = future.exception()
        if isinstance(error, BrokenProcessPool) and not self._retried:
            self.rebuilds += 1  # the worker died under the work: a new one computes it again
            self._retried = True
            self._submit_in_thread(work, command, fresh=True)
            return None
        self._job = None
        if error is None:
            work.store(future.result())
        return command, error

    def stop(self) -> None:
        """End the worker process (work under way is abandoned; waits for a submission under way)."""
        self._generation += 1
        with self._lock:
            self._discard_pool()
        self._job = None
