"""A preset's costly preparation for the app's loop, computed in a process of its own.

Some presets need a computation before their session is built (`Scenario.pending_work`): a
planned polish case needs the swivel path planned over the zig-zag, ~4.5 s of Python on a quiet
2-core machine, which the loop thread used to spend without stepping, publishing or answering a
drag. The loop's switch builds its session with `defer_work`, which raises `WorkPending` instead
(nothing changed yet); the loop hands the work to `BackgroundPlanner`, keeps running the current
preset, applies only urgent commands (drag, Pause), and applies the switch again once the result
is stored. The work is the
same function of the same arguments in either process.

The worker process (`app.live.workers.Worker`, at the app's priority) is started on first use, in a
thread of its own, and comes back: when it dies (killed, out of memory) a new one starts and the work
under way is submitted again (once: work that kills its worker twice fails with a notice). Until a
worker is up, `take_done` (the loop calls it every round) answers None and submits the work once one is.
Nothing is ever computed on the loop thread: where no worker process can start at all, the work runs
in a thread of its own.
"""

from __future__ import annotations

from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

from app.live.workers import Worker, WorkerLost
from app.scenarios import Work

WORKER_NAME = "torquelab-plan"


@dataclass
class _Job:
    command: Any  # handed back by take_done
    work: Work
    future: Future | None = None  # None until the work is submitted
    retried: bool = False  # the work was submitted again after its worker died


class BackgroundPlanner:
    """One piece of work at a time in a spawned worker process (started on first use, kept for the
    next, replaced when it dies; see the module docstring)."""

    def __init__(self) -> None:
        self.worker = Worker(WORKER_NAME)
        self._job: _Job | None = None
        self._threads: ThreadPoolExecutor | None = None  # where no worker process can start

    @property
    def busy(self) -> bool:
        """True while work is being computed."""
        return self._job is not None

    @property
    def rebuilds(self) -> int:
        """Worker processes replaced after one died."""
        return self.worker.losses

    def _submit(self, job: _Job) -> None:
        """Hand the work to the worker (the future stays None while none is up), or to a thread where
        no worker process can start."""
        work = job.work
        if self.worker.gave_up is None:
            job.future = self.worker.submit(work.compute, *work.args)
            return
        if self._threads is None:
            self._threads = ThreadPoolExecutor(max_workers=1, thread_name_prefix="torquelab-work")
        job.future = self._threads.submit(work.compute, *work.args)

    def start(self, command: Any, work: Work) -> None:
        """Compute `work`; `command` is handed back by `take_done` once its result is stored."""
        self._job = _Job(command, work)
        self._submit(self._job)

    def take_done(self) -> tuple[Any, BaseException | None] | None:
        """(command, None) once its work's result is stored, (command, error) if the work failed; None
        while it is still being submitted or computed (a dead worker's work is submitted again to a new
        one) or when nothing is."""
        job = self._job
        if job is None:
            return None
        if job.future is None:
            self._submit(job)
        if job.future is None or not job.future.done():
            return None
        error = job.future.exception()
        if isinstance(error, WorkerLost) and not job.retried:
            job.retried = True  # the worker died under the work: a new one computes it again
            self._submit(job)
            return None
        self._job = None
        if error is None:
            job.work.store(job.future.result())
        return job.command, error

    def stop(self) -> None:
        """End the worker process (work under way is abandoned); a later `start` starts a new one."""
        self.worker.stop()
        self.worker = Worker(WORKER_NAME)
        self._job = None
        if self._threads is not None:
            self._threads.shutdown(wait=False, cancel_futures=True)
            self._threads = None
