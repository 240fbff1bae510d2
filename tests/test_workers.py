"""The supervised worker process the live app computes in (`app.live.workers.Worker`): the live
figures' offload, the planner and the self-motion scans each run one."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import threading
import time

import pytest

from app.live.workers import FAILED_STARTS_MAX, Worker, WorkerLost
from app.scenarios import Work


def _fail_to_warm() -> None:
    raise RuntimeError("no imports here")


def _raise_holding_a_lock() -> None:
    raise ValueError("bad input", threading.Lock())


def _thread_id() -> int:
    return threading.get_ident()


def _alive(pid: int) -> bool:
    """True while `pid` runs (a zombie, exited but not reaped yet, counts as gone)."""
    try:
        os.kill(pid, 0)
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(")")[-1].split()[0] != "Z"
    except ProcessLookupError:
        return False
    except OSError:
        return True


def _until(predicate, timeout: float = 60.0) -> bool:
    deadline = time.monotonic() + timeout
    while not predicate() and time.monotonic() < deadline:
        time.sleep(0.02)
    return predicate()


@pytest.fixture
def worker():
    """A worker, not started yet (stopped after the test)."""
    worker = Worker("torquelab-test")
    yield worker
    worker.stop()


def test_a_worker_answers_in_order_and_hands_back_each_jobs_error_with_its_type(worker):
    assert worker.submit(pow, 2, 3) is None  # not up yet: the caller skips the job
    assert worker.ready(60.0) and worker.pid not in (None, os.getpid())
    futures = [worker.submit(pow, 2, k) for k in range(20)]
    assert [f.result(timeout=30.0) for f in futures if f is not None] == [2**k for k in range(20)]
    with pytest.raises(ValueError, match="invalid literal"):
        worker.call(int, "x", timeout=30.0)
    with pytest.raises(TypeError, match="cannot pickle"):  # an answer that cannot travel is an error
        worker.call(threading.Lock, timeout=30.0)
    with pytest.raises(RuntimeError, match=r"ValueError: .*bad input"):  # so is an error that cannot: its words
        worker.call(_raise_holding_a_lock, timeout=30.0)
    assert worker.call(pow, 3, 2, timeout=30.0) == 9 and worker.losses == 0 and worker.starts == 1


def test_a_killed_worker_fails_its_jobs_and_a_new_one_answers_without_the_caller_waiting(worker):
    assert worker.ready(60.0)
    first = worker.pid
    under_way = worker.submit(time.sleep, 5.0)
    assert under_way is not None and first is not None
    os.kill(first, signal.SIGKILL)
    t0 = time.perf_counter()
    error = under_way.exception(timeout=10.0)
    noticed = time.perf_counter() - t0
    assert isinstance(error, WorkerLost) and worker.losses == 1 and noticed < 1.0
    t0 = time.perf_counter()
    assert worker.submit(pow, 2, 2) is None  # the new worker is starting: skipped, not waited for
    assert time.perf_counter() - t0 < 0.1
    assert worker.ready(60.0) and worker.pid != first and worker.call(pow, 2, 5, timeout=30.0) == 32
    assert _until(lambda: not _alive(first), 5.0)


def test_a_call_that_does_not_answer_in_time_ends_the_stuck_worker_and_a_new_one_answers(worker):
    assert worker.ready(60.0)
    stuck = worker.pid
    assert stuck is not None
    t0 = time.perf_counter()
    with pytest.raises(TimeoutError):
        worker.call(time.sleep, 60.0, timeout=1.0)
    assert 1.0 <= time.perf_counter() - t0 < 5.0 and worker.losses == 1
    assert _until(lambda: not _alive(stuck), 5.0), "the stuck worker was left running"
    assert worker.call(os.getpid, timeout=60.0) not in (stuck, os.getpid())


def test_a_worker_that_never_comes_up_is_given_up():
    worker = Worker("torquelab-test", warm=_fail_to_warm)
    for _ in range(FAILED_STARTS_MAX):
        assert not worker.ready(60.0)
    assert worker.gave_up is not None and str(FAILED_STARTS_MAX) in worker.gave_up
    assert worker.submit(pow, 2, 2) is None and not worker.ready(0.0) and worker.starts == 0


def test_the_planner_computes_in_a_thread_of_its_own_once_no_worker_comes_up():
    from app.live.plan_worker import BackgroundPlanner

    planner = BackgroundPlanner()
    planner.worker = Worker("torquelab-test", warm=_fail_to_warm)
    stored: list[int] = []
    try:
        planner.start("switch", Work("a stand-in plan", _thread_id, (), stored.append))
        deadline = time.monotonic() + 60.0
        while (done := planner.take_done()) is None and time.monotonic() < deadline:
            time.sleep(0.02)
        assert done == ("switch", None) and planner.worker.gave_up is not None
        assert stored and stored[0] != threading.get_ident()  # a thread of its own, not the caller's
    finally:
        planner.stop()


def test_the_scans_run_in_the_servers_process_once_no_scan_process_comes_up():
    import numpy as np

    import robots
    from app.live.ui.selfmotion import SelfMotionPreview, scan_worker
    from control.coupling import POLISH_SUBSPACES

    rizon = robots.load("rizon4s")
    q = np.asarray(rizon.postures.get("polish_start", rizon.home), dtype=float)
    preview = SelfMotionPreview.__new__(SelfMotionPreview)  # the scan machinery only, no widgets
    preview._in_process, preview._scan_failures, preview.scan_restarts, preview._models = True, 0, 0, {}
    preview._scale = None  # W in SI units (no characteristic length set)
    preview._worker = scan_worker()
    try:
        there = preview._scan(rizon, q, POLISH_SUBSPACES, "a")
    finally:
        preview._worker.stop()
    with pytest.raises(WorkerLost):  # a stopped preview scans nowhere, not in this process either
        preview._scan(rizon, q, POLISH_SUBSPACES, "a")
    assert preview._in_process and preview._scan_failures == 0
    preview._worker = Worker("torquelab-test", warm=_fail_to_warm)
    here = preview._scan(rizon, q, POLISH_SUBSPACES, "a")
    assert not preview._in_process and preview._worker.gave_up is not None
    np.testing.assert_array_equal(here.W, there.W)


def test_the_live_apps_workers_exit_when_the_app_is_killed():
    """The offload's, the planner's and the scan's workers, one of them in a 60 s job, end within 5 s
    of the app's kill -9 (a ProcessPoolExecutor worker lived on; ours finished its job first)."""
    script = textwrap.dedent(
        """
        import os, signal, time
        from app.live.offload import LiveOffload
        from app.live.plan_worker import BackgroundPlanner
        from app.live.ui.selfmotion import scan_worker

        if __name__ == "__main__":
            workers = [LiveOffload(), BackgroundPlanner().worker, scan_worker()]
            pids = [w.call(os.getpid, timeout=120.0) for w in workers]
            workers[1].submit(time.sleep, 60.0)  # computing when the app dies
            print(" ".join(str(p) for p in pids), flush=True)
            os.kill(os.getpid(), signal.SIGKILL)
        """
    )
    proc = subprocess.Popen(
        [sys.executable, "-c", script], stdout=subprocess.PIPE, text=True, env={**os.environ, "PYTHONPATH": os.getcwd()}
    )
    assert proc.stdout is not None
    pids = [int(p) for p in proc.stdout.readline().split()]
    try:
        assert proc.wait(timeout=60) == -signal.SIGKILL and len(pids) == 3
        assert _until(lambda: not any(_alive(p) for p in pids), 5.0), "a worker outlived the killed app"
    finally:
        for pid in pids:
            if _alive(pid):
                os.kill(pid, signal.SIGKILL)
