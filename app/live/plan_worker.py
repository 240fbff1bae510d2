"""Swivel plans for the app's loop, computed in a process of their own.

Switching to a planned polish case needs the swivel path planned over the zig-zag
(`app.scenarios.polish.compute_plan`): ~4.5 s of Python on a quiet 2-core machine, which the loop
thread used to spend without stepping, publishing or answering a drag. With `Lab.defer_plans` the
switch raises `PlanPending` instead (nothing changed yet); the loop hands the plan to
`BackgroundPlanner`, keeps running the current preset, applies only urgent commands (drag, Pause),
and applies the switch again once the plan is cached. The plan is the same function of the same
arguments in either process.
"""

from __future__ import annotations

import os
from concurrent.futures import Future, ProcessPoolExecutor
from multiprocessing import get_context
from typing import Any

from app.live.priority import set_process_niceness
from app.scenarios.polish import PlanPending, compute_plan, store_plan


def _app_niceness() -> int:
    """The niceness of the process's main thread (the app's default priority; 0 where unknown)."""
    try:
        return os.getpriority(os.PRIO_PROCESS, os.getpid())
    except (OSError, AttributeError):
        return 0


class BackgroundPlanner:
    """One plan at a time in a spawned worker process (started on first use, kept for the next)."""

    def __init__(self) -> None:
        self._pool: ProcessPoolExecutor | None = None
        self._job: tuple[Future, PlanPending, Any] | None = None

    @property
    def busy(self) -> bool:
        """True while a plan is being computed."""
        return self._job is not None

    def start(self, command: Any, pending: PlanPending) -> None:
        """Compute the plan `pending` names; `command` is handed back by `take_done` once it is cached.
        Where no worker process can start, the plan is computed here (and is done at once)."""
        try:
            if self._pool is None:
                # at the app's priority: spawned from the loop thread, it would inherit that thread's
                self._pool = ProcessPoolExecutor(
                    max_workers=1,
                    mp_context=get_context("spawn"),
                    initializer=set_process_niceness,
                    initargs=(_app_niceness(),),
                )
            future = self._pool.submit(compute_plan, *pending.args)
        except Exception:  # no worker process here: plan in this thread, as without deferral
            future = Future()
            future.set_result(compute_plan(*pending.args))
        self._job = (future, pending, command)

    def take_done(self) -> tuple[Any, BaseException | None] | None:
        """(command, None) once its plan is cached, (command, error) if planning failed; None while
        the plan is still being computed or when nothing is."""
        if self._job is None or not self._job[0].done():
            return None
        future, pending, command = self._job
        self._job = None
        error = future.exception()
        if error is None:
            store_plan(pending.key, future.result())
        return command, error

    def stop(self) -> None:
        """End the worker process (a plan under way is abandoned)."""
        if self._pool is not None:
            self._pool.shutdown(wait=False, cancel_futures=True)
            self._pool = None
        self._job = None
