"""The executor a sweep's cells go to: a local process pool, or a Dask cluster's executor.

This is the only place that knows the engines. `open_executor(None, jobs)` is a
`ProcessPoolExecutor` (no extra dependency); `open_executor("tcp://HOST:PORT", …)` the
executor of a `distributed.Client` connected to that scheduler; `open_executor("local", jobs)`
starts a `distributed.LocalCluster` of `jobs` one-thread worker processes for trying it on one
machine. Dask is the optional extra `torquelab[cluster]`.

Local pool workers end with their parent: on Linux each asks the kernel for SIGKILL when the parent
dies (`prctl(PR_SET_PDEATHSIG)`), elsewhere a thread in each worker ends it once its parent is
gone, so a sweep killed with `kill -9` leaves no worker computing on (they held ~170 MB each).
"""

from __future__ import annotations

import ctypes
import os
import re
import signal
import sys
import threading
import time
from collections.abc import Iterator
from concurrent.futures import Executor, ProcessPoolExecutor
from contextlib import contextmanager

from app.headless.sweep.grid import SweepError

ADDRESS = re.compile(r"^(tcp|tls|ws|wss|inproc)://[^\s/:]+(:\d+)?/?$")
CONNECT_TIMEOUT_S = 30


PARENT_POLL_S = 1.0  # how often a worker without PR_SET_PDEATHSIG looks whether its parent lives
PR_SET_PDEATHSIG = 1


def die_with_parent(parent_pid: int | None = None) -> None:
    """Pool initializer: end this worker when its parent process dies (see the module docstring)."""
    parent = parent_pid if parent_pid is not None else os.getppid()
    if sys.platform == "linux":
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            if libc.prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0) == 0:
                if os.getppid() != parent:  # the parent died before the request took effect
                    os._exit(1)
                return
        except (OSError, AttributeError):
            pass

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(PARENT_POLL_S)
        os._exit(1)

    threading.Thread(target=watch, name="torquelab-parent-watch", daemon=True).start()


def check_cluster(cluster: str | None) -> None:
    """SweepError for a --cluster value that is neither "local" nor a scheduler address."""
    if cluster is None or cluster == "local":
        return
    if not ADDRESS.match(cluster):
        raise SweepError(f"--cluster {cluster!r}: give a scheduler address like tcp://HOST:8786, or local")


def _distributed():
    try:
        import distributed
    except ImportError:
        raise SweepError("--cluster needs Dask: pip install 'torquelab[cluster]'") from None
    return distributed


@contextmanager
def open_executor(cluster: str | None, jobs: int) -> Iterator[tuple[Executor, str]]:
    """(executor, one-line description) for the engine chosen; shuts it down on exit."""
    check_cluster(cluster)
    if cluster is None:
        with ProcessPoolExecutor(max_workers=jobs, initializer=die_with_parent, initargs=(os.getpid(),)) as pool:
            yield pool, f"local process pool, {jobs} process{'es' if jobs > 1 else ''}"
        return
    distributed = _distributed()
    if cluster == "local":
        with (
            distributed.LocalCluster(
                n_workers=jobs, threads_per_worker=1, processes=True, dashboard_address=None
            ) as local,
            distributed.Client(local) as client,
        ):
            yield client.get_executor(), f"Dask LocalCluster, {jobs} worker process{'es' if jobs > 1 else ''}"
        return
    try:
        client = distributed.Client(cluster, timeout=CONNECT_TIMEOUT_S)
    except OSError as exc:
        raise SweepError(f"--cluster {cluster}: cannot reach the scheduler ({exc})") from None
    with client:
        n = len(client.scheduler_info().get("workers", {}))
        yield client.get_executor(), f"Dask cluster at {cluster}, {n} worker(s)"
