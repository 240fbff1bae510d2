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
from app.live.warmup import warm_kernel
from control.kernel_registry import KERNELS


def test_a_workers_plain_states_call_no_compiled_code_and_have_the_compiled_snapshots_types(monkeypatch):
    """With `use_plain_states` (a warm-up worker) every kernel's samples are built without the compiled
    snapshot, so no kernel job waits for it; the plain state has the compiled one's argument types (each
    field and the record: the kernels compile the signatures the loop meets) and its values to 1e-9; the
    snapshot kernel's warm-up call has the loop's types."""
    import numba

    from control import kernel_registry
    from control.model import RobotModel

    robot, model = kernel_registry.sample_arm()
    q, dq = np.array(robot.home, dtype=float) + 0.1, np.full(7, 0.3)
    compiled, plain = model.compute(q, dq), model.compute_reference(q, dq)
    assert numba.typeof(plain.record) == numba.typeof(compiled.record)
    for name in ("q", "dq", "M", "M_inv", "h", "J", "dJ_dq", "Lambda_inv", "Lambda", "J_bar", "N", "Lambda_n"):
        a, b = getattr(plain, name), getattr(compiled, name)
        assert numba.typeof(a) == numba.typeof(b), name
        np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-9 * max(1.0, float(np.abs(b).max())), err_msg=name)

    # the snapshot kernel's warm-up call has the types of the loop's (`RobotModel.compute`: Pinocchio's
    # column-major M), so the arm's own job only loads it
    import control.model as model_module
    from app.live.warmup import warm_calls

    live: list[tuple] = []
    kernel = model_module.snapshot_into
    monkeypatch.setattr(model_module, "snapshot_into", lambda *a: live.append(a) or kernel(*a))
    model.compute(q, dq)
    monkeypatch.setattr(model_module, "snapshot_into", kernel)
    monkeypatch.setattr(kernel_registry, "_PLAIN_STATES", True)
    warm = [numba.typeof(a) for a in warm_calls("snapshot_into")[0]]
    assert warm == [numba.typeof(a) for a in live[0]]

    def no_compiled_state(*args, **kwargs):
        raise LookupError("the compiled snapshot")

    monkeypatch.setattr(RobotModel, "compute", no_compiled_state)
    for name, pair in KERNELS.items():
        assert pair.samples(np.random.default_rng(0)), name


def test_every_kernel_job_waits_for_the_kernels_it_calls_and_the_longest_chains_come_first():
    """Each registered kernel has one job, after the jobs of the kernels it calls (compiled once, by one
    process); the arm's snapshot as the loop computes it comes after the snapshot's kernels, and no job
    waits for it; the order they are listed in can run (each job's `after` comes before it), and a job
    listed before another ready at the same time has the longer chain of compiles after it: the law's
    first callee before every short kernel nothing waits on."""
    from app.live.warm_workers import SIMULATOR_JOB, _by_critical_path

    jobs = warm_jobs()
    names = [job.name for job in jobs]
    assert len(set(names)) == len(names) and len(jobs) == len(KERNELS) + 2
    assert {job.fn for job in jobs if job.name in KERNELS} == {warm_kernel} and SIMULATOR_JOB in names
    name_of = {id(pair.compiled): name for name, pair in KERNELS.items()}
    for job in jobs:
        assert all(names.index(a) < names.index(job.name) for a in job.after), job
        assert ARM_STATE_JOB not in job.after, job.name
        if job.name in KERNELS:
            wanted = {name_of[id(d)] for d in callees(KERNELS[job.name].compiled) if id(d) in name_of}
            assert wanted <= set(job.after), job.name
    arm = next(job for job in jobs if job.name == ARM_STATE_JOB)
    assert "snapshot_into" in arm.after
    law = KERNELS["projection_step_fused"].compiled
    assert KERNELS["projection_law_fused"].compiled in callees(law)  # (the calls are found)
    assert _by_critical_path(jobs) == jobs
    waited_on = {a for job in jobs for a in job.after}
    first_law_callee = min(names.index(a) for a in next(j for j in jobs if j.name == "projection_law_fused").after)
    lone_short = [n for n in names if n not in waited_on and n in KERNELS and n != "projection_step_fused"]
    assert all(first_law_callee < names.index(n) for n in lone_short if n not in ("cqp_problem_fused",)), names


def test_the_kernel_jobs_compile_every_argument_type_among_a_kernels_samples():
    """`warm_kernel` calls the first sample of each argument type: the dense QP's load is compiled with a
    P matrix and without one (None: the compliance QP keeps the P it loaded), the two calls the loop makes."""
    from control.kernels.dense_qp import dense_qp_load_fused

    warm_kernel("dense_qp_load_fused")
    third = {str(sig[2]) for sig in dense_qp_load_fused.signatures}
    assert {"none", "array(float64, 2d, C)"} <= third, third


def test_the_pool_runs_the_jobs_in_two_worker_processes_and_reports_each_one_of_how_many():
    """Four small kernels and two pid jobs after them in two workers: every job done once, the reports
    count up to 6 of 6 in order, a job after the kernels starts only once they are done, the time left is
    a number once a job has finished, and two processes ran."""
    small = ("_cross", "_mat3_vec", "_sqnorm", "_np_max")
    jobs = [WarmJob(n, warm_kernel, (n,)) for n in small]
    jobs += [WarmJob(f"pid {i}", _pid_after, (0.5,), small) for i in range(2)]
    reports: list[WarmProgress] = []
    pool = _Pool(jobs, 2, reports.append)
    pool.run()
    assert pool.failures == [] and pool.finished == {job.name for job in jobs}
    assert [r.done for r in reports] == sorted(r.done for r in reports) and reports[-1].done == 6
    assert {r.total for r in reports} == {6} and {r.stage for r in reports} == {"compiling"}
    first_pid = next(i for i, r in enumerate(reports) if any(c.startswith("pid") for c in r.current))
    assert reports[first_pid].done >= 5, "a pid job started before the kernels it comes after were done"
    assert math.isnan(reports[0].seconds_left) and not math.isnan(reports[-1].seconds_left)
    assert all(0.0 <= r.fraction <= 0.9 for r in reports) and reports[-1].fraction == pytest.approx(0.9)
    assert pool.results["pid 0"] != pool.results["pid 1"] and not any(w.up for w in pool.workers)


def _pid_after(seconds: float) -> int:
    time.sleep(seconds)  # both pid jobs under way at once: one in each worker
    return os.getpid()


def test_the_progress_line_names_which_kernel_of_how_many_and_the_time_left():
    line = progress_text(WarmProgress("compiling", 12, 41, ("coupling_fused",), 17.4, 0.3))
    assert line == "compiling kernel 12 of 41 (coupling_fused) · about 17 s left"
    assert progress_text(WarmProgress("loading", 3, 16, ("free / projection",), math.nan, 0.95)) == (
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
            assert counts == sorted(counts) and totals == {len(KERNELS) + 2}, (counts, totals)

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
    # the workers' jobs met every argument type the presets meet: this process's pass only loaded
    assert "compiled here" not in text, text
