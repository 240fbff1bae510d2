"""The first start (`app.live.warm_workers`, `serve`): the page at once, the kernels compiled in worker
processes with the progress on it, the arm running by itself afterwards.

The jobs' order is held to the kernels' calls and to what their samples need; the pool is run on a
few kernels in two worker processes; and the real command is started on an empty numba cache, as
after an install (every kernel compiles in the workers: real work, nothing slowed or faked), while
headless Chromium watches the page show the progress and then the arm run.
"""

from __future__ import annotations

import math
import os
import re
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from app.live.warm_workers import ARM_STATE_JOB, WarmJob, WarmProgress, _Pool, callees, progress_text, warm_jobs
from app.live.warmup import NO_ARM_STATE, warm_kernel
from control.kernel_registry import KERNELS


def test_the_kernels_listed_as_needing_no_arm_state_are_exactly_those_whose_samples_compute_none(monkeypatch):
    """A kernel in NO_ARM_STATE may compile before the arm's snapshot; one missing from it only waits."""
    from control.model import RobotModel

    def no_state(*args, **kwargs):
        raise LookupError("a state of the arm")

    monkeypatch.setattr(RobotModel, "compute", no_state)
    free = []
    for name, pair in KERNELS.items():
        try:
            pair.samples(np.random.default_rng(0))
        except LookupError:
            continue
        free.append(name)
    assert sorted(free) == sorted(NO_ARM_STATE)


def test_every_kernel_job_waits_for_the_kernels_it_calls_and_every_preset_for_every_kernel():
    """Each registered kernel has one job, after the jobs of the kernels it calls (compiled once, by one
    process) and after the arm's snapshot when its samples need a state; the presets come after
    every kernel; the order they are listed in can run (each job's `after` comes before it)."""
    jobs = warm_jobs(None)
    names = [job.name for job in jobs]
    kernels = [job for job in jobs if job.kind == "kernel"]
    assert len(set(names)) == len(names) and len(kernels) == len(KERNELS) + 1
    name_of = {id(pair.compiled): name for name, pair in KERNELS.items()}
    for job in jobs:
        assert all(names.index(a) < names.index(job.name) for a in job.after), job
        if job.name in KERNELS:
            wanted = {name_of[id(d)] for d in callees(KERNELS[job.name].compiled) if id(d) in name_of}
            assert wanted <= set(job.after), job.name
            assert (ARM_STATE_JOB in job.after) == (job.name not in NO_ARM_STATE), job.name
    presets = [job for job in jobs if job.kind == "preset"]
    assert len(presets) == 15 and all({k.name for k in kernels} <= set(job.after) for job in presets)
    law = KERNELS["projection_step_fused"].compiled
    assert KERNELS["projection_law_fused"].compiled in callees(law)  # (the calls are found)


def test_the_pool_runs_the_jobs_in_two_worker_processes_and_reports_each_one_of_how_many():
    """Four small kernels and two pid jobs in two workers: every job done once, the reports count up
    to 4 of 4 then 2 of 2, the time left is a number once a job has finished, and two processes ran."""
    small = ("_cross", "_mat3_vec", "_sqnorm", "_np_max")
    jobs = [WarmJob(n, "kernel", warm_kernel, (n,)) for n in small]
    jobs += [WarmJob(f"pid {i}", "preset", _pid_after, (0.5,), small) for i in range(2)]
    reports: list[WarmProgress] = []
    pool = _Pool(jobs, 2, reports.append)
    pool.run()
    assert pool.failures == [] and pool.finished == {job.name for job in jobs}
    kernels = [r for r in reports if r.kind == "kernel"]
    assert [r.done for r in kernels] == sorted(r.done for r in kernels) and kernels[-1].done == 4
    assert {r.total for r in kernels} == {4} and {r.total for r in reports if r.kind == "preset"} == {2}
    assert math.isnan(reports[0].seconds_left) and not math.isnan(reports[-1].seconds_left)
    assert all(0.0 <= r.fraction <= 0.9 for r in reports) and reports[-1].fraction == pytest.approx(0.9)
    assert pool.results["pid 0"] != pool.results["pid 1"] and not any(w.up for w in pool.workers)


def _pid_after(seconds: float) -> int:
    time.sleep(seconds)  # both pid jobs under way at once: one in each worker
    return os.getpid()


def test_the_progress_line_names_which_kernel_of_how_many_and_the_time_left():
    line = progress_text(WarmProgress("compiling", "kernel", 12, 41, ("coupling_fused",), 17.4, 0.3))
    assert line == "compiling kernel 12 of 41 (coupling_fused) · about 17 s left"
    assert progress_text(WarmProgress("loading", "kernel", 3, 16, ("free / projection",), math.nan, 0.95)) == (
        "loading the compiled kernels: step 3 of 16 (free / projection)"
    )


# ---- the real command, in headless Chromium ---------------------------------------------------------------
@pytest.mark.browser
@pytest.mark.slow
def test_the_page_shows_the_warm_up_while_kernels_compile_then_the_arm_runs_by_itself(tmp_path):
    """`torquelab serve` on an empty numba cache (the first start after an install): the page answers as
    soon as the URL is printed and shows "getting ready" with the line "compiling kernel N of M", which
    counts up; then the lab replaces it and its status line shows the arm running (t grows) without a click.

    Chromium is up before the command starts and opens the page the moment the URL is printed; the cache
    is empty, so the compile the page watches is every registered kernel (tens of seconds on two cores),
    longer than a page takes to open on a loaded machine."""
    from playwright.sync_api import sync_playwright

    from app.tools.bench_serve import CHROMIUM_ARGS
    from tests.test_browser import VIEWPORT, chromium_path, wait_for

    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path), PYTHONUNBUFFERED="1")
    lines: list[str] = []
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=chromium_path(), headless=True, args=CHROMIUM_ARGS)
        page = browser.new_page(viewport=VIEWPORT)
        page.set_default_timeout(120_000)  # a page on a loaded machine takes seconds per read
        proc = subprocess.Popen(
            [sys.executable, "-m", "app.cli", "serve", "--scenario", "polish", "--port", "0"],
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env,
        )  # fmt: skip
        try:
            assert proc.stdout is not None
            for line in proc.stdout:
                lines.append(line)
                if "open http://" in line:
                    break
            url = re.search(r"open (http://\S+)", "".join(lines))
            assert url is not None, "".join(lines)
            page.goto(url.group(1), timeout=180_000)
            counts: list[int] = []
            totals: set[int] = set()

            def progress_shown() -> bool:
                found = re.search(r"compiling kernel (\d+) of (\d+)", page.inner_text("body"))
                if found:
                    counts.append(int(found.group(1)))
                    totals.add(int(found.group(2)))
                return len(set(counts)) >= 2

            wait_for(progress_shown, 180, "the page to show the warm-up's progress counting up")
            assert "getting ready" in page.inner_text("body")
            assert counts == sorted(counts) and totals == {len(KERNELS) + 1}, (counts, totals)

            def t_shown() -> float | None:
                found = re.search(r"t = (\d+\.\d+) s · ▶ running", page.inner_text("body"))
                return float(found.group(1)) if found else None

            first = wait_for(t_shown, 600, "the lab's status line with the arm running")
            wait_for(lambda: (t_shown() or 0.0) > first + 0.2, 60, "the simulated time to advance")
            assert "getting ready" not in page.inner_text("body")
        finally:
            browser.close()
            proc.send_signal(signal.SIGTERM)
            out, _ = proc.communicate(timeout=60)
            lines.append(out)
    text = "".join(lines)
    assert "compiled in worker processes and loaded" in text and "the arm is running" in text, text
