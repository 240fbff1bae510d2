"""The first start's compile on every core, off the serving process: numba's on-disk cache filled by
worker processes while the page shows how far it is.

`first_start(robot, progress)` is `serve`'s warm-up. Where numba's cache lacks a kernel (a fresh
install, a changed kernel: `cache_is_filled`), the warm-up's jobs (`warm_jobs`: every registered
kernel on the first of its samples of each argument type, the arm's snapshot as the loop computes it,
the simulator's kernels) run in `WORKERS` spawned processes (`app.live.workers.Worker`), each job
handed to the first free one, longest chain of compiles first; each compiles what its job meets and
writes it to the cache. A job waits for the kernels it calls (`WarmJob.after`), so that no two
processes compile the same code at once; a worker's samples come from the plain-numpy snapshot
(`control.kernel_registry.use_plain_states`), so no kernel waits for the compiled one. Then this
process runs the warm-up itself (`app.live.warmup.warm_up`: every kernel, then every preset ×
executor), which now only loads from the cache (seconds), so the loop meets every signature loaded;
`first_start` counts what it compiled all the same (none, when the jobs met every type the presets
meet). A job that fails in a worker (or a worker that cannot start) costs only time: whatever it left
out is compiled by that last pass.

`progress` hears a `WarmProgress` when a job starts or ends and for each step of the last pass; the
page (`app.live.ui.warmup_page`) and the terminal show it as `progress_text`.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import dataclass
from types import ModuleType
from typing import Any

from app.live.warmup import (
    prepare_worker,
    preset_pairs,
    warm_arm_state,
    warm_kernel,
    warm_simulator,
    warm_up,
)
from app.live.workers import Worker

WORKERS = 2  # the machine's cores a first start is sized for (the serving process waits meanwhile)
POLL_S = 0.05  # how often the finished jobs are looked for
ARM_STATE_JOB = "the arm's snapshot"
SIMULATOR_JOB = "the simulator's kernels"


@dataclass(frozen=True)
class WarmJob:
    """One job of the first start: `fn(*args)` in a worker, once the jobs named in `after` are done."""

    name: str
    fn: Callable[..., Any]
    args: tuple = ()
    after: tuple[str, ...] = ()


@dataclass(frozen=True)
class WarmProgress:
    """How far the warm-up is: `done` of `total` in its stage ("compiling": the workers' jobs,
    "loading": this process's pass), what is under way, and the seconds left (NaN: not known yet)."""

    stage: str
    done: int
    total: int
    current: tuple[str, ...]
    seconds_left: float
    fraction: float  # of the whole warm-up, 0…1


def progress_text(p: WarmProgress) -> str:
    """One line for the page and the terminal: which of how many, what, and the time left."""
    names = ", ".join(p.current)
    if p.stage == "loading":
        what = f"loading the compiled kernels: step {p.done} of {p.total}"
    else:
        what = f"compiling kernel {p.done} of {p.total}"
    left = "" if math.isnan(p.seconds_left) else f" · about {max(1, round(p.seconds_left))} s left"
    return f"{what}{f' ({names})' if names else ''}{left}"


def callees(dispatcher: Any) -> set[Any]:
    """The compiled kernels `dispatcher`'s function calls by a global name or a module's attribute."""
    from numba.core.registry import CPUDispatcher

    code, names = dispatcher.py_func.__code__, dispatcher.py_func.__globals__
    found = set()
    for name in code.co_names:
        value = names.get(name)
        if isinstance(value, CPUDispatcher):
            found.add(value)
        elif isinstance(value, ModuleType):  # `L._matmul_into`
            found.update(v for n in code.co_names if isinstance(v := getattr(value, n, None), CPUDispatcher))
    found.discard(dispatcher)
    return found


def warm_jobs() -> list[WarmJob]:
    """The first start's jobs: every registered kernel after those it calls (each compiled once, by
    one process, then loaded from the cache by its callers; a worker's samples come from the
    plain-numpy snapshot, so none waits for the compiled one), the arm's snapshot as the loop computes
    it after the snapshot's kernels, and the simulator's kernels (`warm_simulator`); each ready job is
    handed out in the order of the longest chain of jobs waiting on it (`_by_critical_path`). The
    presets' steps are left to this process's pass (`warm_up`), which then meets no type left to
    compile (`first_start` counts it; `tests/test_first_start.py`)."""
    from control.kernel_registry import KERNELS
    from control.kernels.snapshot import snapshot_into

    name_of = {id(pair.compiled): name for name, pair in KERNELS.items()}

    def after(dispatcher: Any) -> tuple[str, ...]:
        return tuple(sorted(name_of[id(d)] for d in callees(dispatcher) if id(d) in name_of))

    jobs = [WarmJob(name, warm_kernel, (name,), after(pair.compiled)) for name, pair in KERNELS.items()]
    snapshot = (*after(snapshot_into), name_of[id(snapshot_into)])
    jobs.append(WarmJob(ARM_STATE_JOB, warm_arm_state, (), snapshot))
    jobs.append(WarmJob(SIMULATOR_JOB, warm_simulator))
    return _by_critical_path(_in_order(jobs))


# seconds a job's compile took on two cores (a first start, measured with its jobs' start and end): only
# the order of the jobs reads them, a job not named here counts SHORT_JOB_S
COMPILE_S = {
    "projection_law_fused": 7.4, "snapshot_into": 5.3, "cqp_problem_fused": 3.8, "projection_step_fused": 2.5,
    "dense_qp_load_fused": 1.1, "inertia_contraction_fused": 1.0, "coupling_fused": 1.0,
    "gradient_contraction_fused": 1.0, SIMULATOR_JOB: 0.7,
}  # fmt: skip
SHORT_JOB_S = 0.2


def _by_critical_path(jobs: list[WarmJob]) -> list[WarmJob]:
    """`jobs` (each after those it waits for) sorted by the longest chain of compiles from each to the
    end, itself and the jobs waiting on it (`COMPILE_S`), longest first (a stable sort), then put in an
    order that can run: a free worker takes the first ready job, so the law's kernels, the law and its
    step start at once, the snapshot and the compliance QP's long compiles on the other worker, and the
    short jobs fill the gaps."""
    chain: dict[str, float] = {}
    waiters: dict[str, list[str]] = {job.name: [] for job in jobs}
    for job in jobs:
        for name in job.after:
            waiters[name].append(job.name)
    for job in reversed(jobs):  # every job after those it waits for: its waiters' chains are known
        rest = max((chain[w] for w in waiters[job.name]), default=0.0)
        chain[job.name] = COMPILE_S.get(job.name, SHORT_JOB_S) + rest
    return _in_order(sorted(jobs, key=lambda job: -chain[job.name]))


def _in_order(jobs: list[WarmJob]) -> list[WarmJob]:
    """`jobs` with each after those it waits for, otherwise in their order (ValueError on a cycle)."""
    placed: list[WarmJob] = []
    done: set[str] = set()
    left = list(jobs)
    while left:
        job = next((j for j in left if set(j.after) <= done), None)
        if job is None:
            raise ValueError(f"warm-up jobs wait on each other: {', '.join(j.name for j in left)}")
        placed.append(job)
        done.add(job.name)
        left.remove(job)
    return placed


def cache_is_filled() -> bool:
    """True when numba's on-disk cache holds an up-to-date entry for every compiled kernel of the
    project (its index exists and matches the kernel's source)."""
    from app.live.closed_kernels import dispatchers

    try:
        return all(d._cache._cache_file._load_index() for d in dispatchers().values())
    except Exception:  # a cache numba cannot read: compile
        return False


class _Pool:
    """The workers and the jobs: hands each free worker the first job whose `after` are done."""

    def __init__(self, jobs: list[WarmJob], workers: int, progress: Callable[[WarmProgress], None]):
        self.waiting = list(jobs)
        self.count = len(jobs)
        self.progress = progress
        self.finished: set[str] = set()
        self.failures: list[str] = []
        self.results: dict[str, Any] = {}  # each finished job's answer
        self.running: dict[int, tuple[WarmJob, Future, float]] = {}
        self.busy_s = 0.0  # the workers' wall time on finished jobs
        self.workers = [Worker(f"torquelab-warm-{i}", warm=prepare_worker) for i in range(workers)]

    def run(self) -> None:
        for worker in self.workers:
            worker.start()
        try:
            while self.waiting or self.running:
                for i, worker in enumerate(self.workers):
                    self._collect(i)
                    if i not in self.running and worker.up:
                        self._hand(i, worker)
                if all(w.gave_up is not None for w in self.workers):
                    self.failures.append(f"no worker process: {self.workers[0].gave_up}")
                    return
                if self.waiting and not self.running and not any(set(j.after) <= self.finished for j in self.waiting):
                    self.failures.append(f"jobs waiting on each other: {', '.join(j.name for j in self.waiting)}")
                    return
                time.sleep(POLL_S)
        finally:
            for worker in self.workers:
                worker.stop()

    def _collect(self, i: int) -> None:
        under_way = self.running.get(i)
        if under_way is None or not under_way[1].done():
            return
        job, answer, started = self.running.pop(i)
        self.busy_s += time.monotonic() - started
        error = answer.exception(0)
        if error is not None:
            self.failures.append(f"{job.name}: {type(error).__name__}: {error}")
        else:
            self.results[job.name] = answer.result(0)
        self.finished.add(job.name)
        self._report()

    def _hand(self, i: int, worker: Worker) -> None:
        job = next((j for j in self.waiting if set(j.after) <= self.finished), None)
        if job is None:
            return
        answer = worker.submit(job.fn, *job.args)
        if answer is None:  # (the worker just died: a new one starts)
            return
        self.waiting.remove(job)
        self.running[i] = (job, answer, time.monotonic())
        self._report()

    def _report(self) -> None:
        done = len(self.finished)
        left = self.count - done
        mean = self.busy_s / done if done else math.nan
        current = tuple(job.name for job, _, _ in self.running.values())
        shown = done + len(self.running)  # a job is counted from its start: "kernel 1 of 45" while the first runs
        self.progress(
            WarmProgress(
                "compiling", min(shown, self.count), self.count, current,
                mean * left / len(self.workers), 0.9 * done / self.count,
            )
        )  # fmt: skip


def fill_cache(progress: Callable[[WarmProgress], None], workers: int = WORKERS) -> list[str]:
    """Run `warm_jobs()` in `workers` worker processes (see the module docstring); what failed."""
    pool = _Pool(warm_jobs(), workers, progress)
    pool.run()
    return pool.failures


def compiles_here() -> int:
    """How many kernel signatures this process compiled (numba's cache misses) rather than loaded."""
    from app.live.closed_kernels import dispatchers

    return sum(sum(d.stats.cache_misses.values()) for d in dispatchers().values())


def first_start(
    robot: str | None, progress: Callable[[WarmProgress], None], workers: int = WORKERS
) -> tuple[float, bool, list[str], int]:
    """`serve`'s warm-up (the module docstring): (seconds, whether workers compiled, what failed in them,
    how many signatures this process's pass compiled itself: none when the workers' jobs met every type
    the presets meet)."""
    t0 = time.perf_counter()
    compiled = not cache_is_filled()
    failures = fill_cache(progress, workers) if compiled else []
    base = 0.9 if compiled else 0.0
    steps = [0]
    total = 1 + len(preset_pairs())

    def loading(line: str) -> None:  # warm_up's lines: its first, then "[i/n] preset / executor"
        if line.startswith("["):
            steps[0], name = min(steps[0] + 1, total), line.split("] ", 1)[-1]
        elif steps[0] == 0:
            steps[0], name = 1, "every registered kernel"
        else:
            return
        fraction = base + (1 - base) * steps[0] / total
        progress(WarmProgress("loading", steps[0], total, (name,), math.nan, fraction))

    before = compiles_here()
    warm_up(robot, loading)
    return time.perf_counter() - t0, compiled, failures, compiles_here() - before
