"""Run a grid of cells on any `concurrent.futures.Executor`, appending each result as it lands.

`run_sweep` submits every cell not yet in `DIR/cells.jsonl` to the executor it is given and
does not know or care what runs them (a local process pool, a Dask cluster's executor, ...).
A cell that raises an `Exception` is recorded with its error and the sweep goes on; anything
else raised (SystemExit, KeyboardInterrupt, a dead pool) stops the sweep with the finished cells
kept, and the same command resumes it.
"""

from __future__ import annotations

import os
import socket
import time
import traceback
from collections.abc import Callable
from concurrent.futures import Executor, Future, as_completed
from dataclasses import dataclass, field
from pathlib import Path

from tqdm import tqdm

from app.core.provenance import code_version, git_commit
from app.headless.sweep.store import CellStore, cell_key, write_csv


def spread_order(n: int) -> list[int]:
    """0 … n−1 in van der Corput order (0, n/2, n/4, 3n/4, …): a sweep stopped early has a coarse,
    even cover of the grid instead of its first rows."""

    def radical_inverse(i: int) -> float:
        x, f = 0.0, 0.5
        while i:
            x += f * (i & 1)
            i >>= 1
            f /= 2
        return x

    order: list[int] = []
    seen: set[int] = set()
    j = 0
    while len(order) < n:
        k = int(radical_inverse(j) * n)
        if k not in seen:
            seen.add(k)
            order.append(k)
        j += 1
    return order


def grouped(points: list[dict], group: str) -> list[tuple]:
    """A sort key per grid point that keeps the points sharing a value of axis `group` together (the
    groups in `spread_order`, the points of a group coarse to fine): a cell's process can reuse what
    the group's cells share (`SweepExperiment.group_axis`)."""
    values = list(dict.fromkeys(p[group] for p in points))
    rank = {values[i]: r for r, i in enumerate(spread_order(len(values)))}
    inner = coarse_to_fine([{k: v for k, v in p.items() if k != group} for p in points])
    return [(rank[p[group]], key) for p, key in zip(points, inner, strict=True)]


def coarse_to_fine(points: list[dict]) -> list[tuple]:
    """A sort key per grid point: coarse points of every axis first, then the finer ones in between.

    On each axis the values are ranked in `spread_order`; a point's level is the coarsest level
    that contains all its coordinates (level L holds the first 2^L ranks of each axis)."""
    names = list(points[0]) if points else []
    axis_rank = {}
    for name in names:
        values = list(dict.fromkeys(p[name] for p in points))
        axis_rank[name] = {values[i]: r for r, i in enumerate(spread_order(len(values)))}
    keys = []
    for p in points:
        ranks = tuple(axis_rank[n][p[n]] for n in names)
        level = max((r.bit_length() for r in ranks), default=0)
        keys.append((level, sum(ranks), ranks))
    return keys


def worker_id() -> str:
    """Host and process id of whoever runs this: "host:pid"."""
    return f"{socket.gethostname()}:{os.getpid()}"


def settings_env() -> dict[str, str]:
    """Process-wide settings of this run that a worker elsewhere must see too (the QP backend)."""
    from control.qp import BACKEND_ENV

    return {k: os.environ[k] for k in (BACKEND_ENV,) if k in os.environ}


def run_cell(cell: Callable[[dict, int], dict], params: dict, seed: int, env: dict[str, str] | None = None) -> dict:
    """Run one cell where the executor puts it (with the submitter's `settings_env`); an Exception
    becomes an "error" record. Its CPU time counts the processes it forked and waited for
    (`forked.call_forked`)."""
    from app.headless.sweep.forked import children_cpu_s

    os.environ.update(env or {})
    t0, c0, k0 = time.perf_counter(), time.process_time(), children_cpu_s()
    rec: dict = {"worker": worker_id(), "env": dict(env or {})}
    try:
        out = cell(params, seed)
        rec.update(status="ok", metrics=out["metrics"], stable=bool(out["stable"]), error=None)
    except Exception as exc:  # the sweep goes on; the error is kept with the cell
        tb = traceback.format_exception_only(type(exc), exc)[-1].strip()
        rec.update(status="error", metrics=None, stable=None, error=tb)
    rec["wall_s"] = time.perf_counter() - t0
    rec["cpu_s"] = time.process_time() - c0 + children_cpu_s() - k0
    return rec


@dataclass
class SweepResult:
    """What one invocation did."""

    total: int  # cells in the grid × seeds
    skipped: int  # finished earlier (resume)
    ran: int = 0
    failed: int = 0
    wall_s: float = 0.0
    records: list[dict] = field(default_factory=list)  # the grid's cells, in grid order (those finished)


def run_sweep(
    experiment: str,
    cell: Callable[[dict, int], dict],
    cells: list[tuple[dict, int]],
    out: Path,
    executor: Executor,
    retry_failed: bool = False,
    progress: bool = True,
    group: str | None = None,
) -> SweepResult:
    """Run the cells not finished yet in `out/cells.jsonl` on `executor`; write cells.csv. With `group`
    (an axis name) the cells sharing its value are sent together (`grouped`)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    store = CellStore(out / "cells.jsonl")
    if store.torn:
        print(f"{out / 'cells.jsonl'}: dropped a half-written last record ({store.torn} bytes): that cell runs again")
    code, commit = code_version(), git_commit()
    keyed = [(cell_key(experiment, params, seed), params, seed) for params, seed in cells]
    points = [p for p, _ in cells]
    spread = grouped(points, group) if group is not None and points and group in points[0] else coarse_to_fine(points)
    # submission order: every grid point's first seed before any second seed, coarse points first
    order = sorted(range(len(keyed)), key=lambda i: (keyed[i][2], spread[i]))
    todo = [keyed[i] for i in order if not store.finished(keyed[i][0], retry_failed)]
    result = SweepResult(total=len(keyed), skipped=len(keyed) - len(todo))
    t0 = time.perf_counter()
    futures: dict[Future, tuple[str, dict, int]] = {}
    bar = tqdm(total=len(todo), desc=f"sweep {experiment}", unit="cell", disable=not progress)
    try:
        env = settings_env()
        for k, p, s in todo:
            futures[executor.submit(run_cell, cell, p, s, env)] = (k, p, s)
        for fut in as_completed(futures):
            k, p, s = futures[fut]
            rec = fut.result()  # BaseException from a cell, or a dead pool, stops the sweep here
            rec.update(
                key=k, experiment=experiment, params=p, seed=s, code=code, commit=commit, finished_at=time.time()
            )
            store.append(rec)
            result.ran += 1
            result.failed += rec["status"] != "ok"
            bar.update()
            if result.failed:
                bar.set_postfix(failed=result.failed)
    finally:
        bar.close()
        for fut in futures:
            fut.cancel()
        result.wall_s = time.perf_counter() - t0
    result.records = [store.records[k] for k, _, _ in keyed if k in store.records]
    write_csv(out / "cells.csv", result.records)
    return result
