"""The supervised worker process the live app computes in (`app.live.workers.Worker`)."""

from __future__ import annotations

import os
import signal
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
