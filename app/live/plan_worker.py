"""A preset's costly preparation for the app's loop, computed in a process of its own.

Some presets need a computation before their session is built (`Scenario.pending_work`): a
planned polish case needs the swivel path planned over the zig-zag, ~4.5 s of Python on a quiet
2-core machine, which the loop thread used to spend without stepping, publishing or answering a
drag. With `Lab.defer_work` the switch raises `WorkPending` instead (nothing changed yet); the
loop hands the work to `BackgroundPlanner`, keeps running the current preset, applies only urgent
commands (drag, Pause), and applies the switch again once the result is stored. The work is the
same function of the same arguments in either process.
"""

from __future__ import annotations

import os
from concurrent.futures import Future, ProcessPoolExecutor
from multiprocessing import get_context
from typing import Any

from app.live.priority import set_process_niceness
from app.scenarios import Work


def _app_niceness() -> int:
    """The niceness of the process's main thread (the app's default priority; 0 where unknown)."""
    try:
        return os.getpriority(os.PRIO_PROCESS, os.getpid())
    except (OSError, AttributeError):
        return 0


class BackgroundPlanner:
    """One piece of work at a time in a spawned worker process (started on first use, kept for the next)."""

    def __init__(self) -> None:
        self._pool: ProcessPoolExecutor | None = None
        self._job: tuple[Future, Work, Any] | None = None

    @property
    def busy(self) -> bool:
        """True while work is being computed."""
        return self._job is not None

    def start(self, command: Any, work: Work) -> None:
        """Compute `work`; `command` is handed back by `take_done` once its result is stored. Where no
        worker process can start, the work is computed here (and is done at once)."""
        try:
            if self._pool is None:
                # at the app's priority: spawned from the loop thread, it would inherit that thread's
                self._pool = ProcessPoolExecutor(
                    max_workers=1,
                    mp_context=get_context("spawn"),
                    initializer=set_process_niceness,
                    initargs=(_app_niceness(),),
                )
            future = self._pool.submit(work.compute, *work.args)
        except Exception:  # no worker process here: compute in this thread, as without deferral
            future = Future()
            future.set_result(work.compute(*work.args))
        self._job = (future, work, command)

    def take_done(self) -> tuple[Any, BaseException | None] | None:
        """(command, None) once its work's result is stored, (command, error) if the work failed; None
        while it is still being computed or when nothing is."""
        if self._job is None or not self._job[0].done():
            return None
        future, work, command = self._job
        self._job = None
        error = future.exception()
        if error is None:
            work.store(future.result())
        return command, error

    def stop(self) -> None:
        """End the worker process (work under way is abandoned)."""
        if self._pool is not None:
            self._pool.shutdown(wait=False, cancel_futures=True)
            self._pool = None
        self._job = None
