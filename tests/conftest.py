"""Shared fixtures (robots and models are loaded once per session; the free preset's app once per
module that asks) and helpers of the tests that talk to a running app.

Under pytest-xdist (`scripts/test.sh` runs `-n 2 --dist loadfile`: a module's tests on one worker,
so its module fixtures start once) each worker is made a session of its own (`os.setsid`), hence
an autogroup of its own: the app raises its autogroup's niceness while it runs and gives it back
(app/live/priority.py), and a worker's app must not change the niceness another worker's test reads.
"""

from __future__ import annotations

import os
import socket
import time
from collections.abc import Callable

import numpy as np
import pytest
import viser

import robots
from app.live.ui.viser_seam import camera_message  # noqa: F401  (the first message a browser sends)
from control.model import RobotModel


def pytest_configure(config) -> None:
    """Declares the `alone` marker; an xdist worker becomes a session (and an autogroup) of its own."""
    config.addinivalue_line(
        "markers", "alone: timed against the wall clock; scripts/test.sh runs it after the parallel phase, alone"
    )
    if os.environ.get("PYTEST_XDIST_WORKER"):
        try:
            os.setsid()
        except OSError:  # already a session or process group leader: it has its own
            pass


@pytest.fixture(scope="session", params=list(robots.BUILTIN))
def robot(request):
    return robots.load(request.param)


@pytest.fixture(scope="session")
def rizon():
    return robots.load("rizon4s")


@pytest.fixture(scope="session")
def gen3():
    return robots.load("gen3")


def random_configurations(robot, count: int, seed: int = 0, margin: float = 0.9):
    """Random joint positions inside the limits (endless joints in ±π)."""
    rng = np.random.default_rng(seed)
    lo = np.where(robot.endless, -np.pi, robot.q_lower)
    hi = np.where(robot.endless, np.pi, robot.q_upper)
    mid, half = (lo + hi) / 2, (hi - lo) / 2 * margin
    out = []
    while len(out) < count:
        q = rng.uniform(mid - half, mid + half)
        # keep away from singular postures so relative errors are meaningful
        if RobotModel(robot.model).compute(q, np.zeros(7)).min_eig_Lambda_inv > 1e-3:
            out.append(q)
    return out


def free_port() -> int:
    """A TCP port on 127.0.0.1 that is free right now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture(scope="session")
def warm_kernels() -> None:
    """Run every scenario with every executor for 1.1 simulated seconds (the polish live margin
    included), once per test run: numba compiles the kernels here where its cache is cold (a fresh
    checkout: about a minute of CPU) or loads them from it, so that a test timing the loop thread
    never meets that compile inside it."""
    from app.core.executors import EXECUTORS
    from app.live.lab import Lab
    from app.scenarios import SCENARIOS

    for scenario in SCENARIOS:
        for executor in EXECUTORS:
            result = Lab(scenario, executor=executor).advance(1100)
            assert not result.halted, (scenario, executor, result.reason)


@pytest.fixture(scope="module")
def server():
    """A bare viser server (no app) for scene and plot tests."""
    srv = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    yield srv
    srv.stop()


@pytest.fixture(scope="module")
def app():
    """The app on the free preset, paused, on a free port: one per module that asks for it."""
    from app.live.server import start_app

    a = start_app(port=0, scenario="free", running=False)
    yield a
    a.stop()


def wait_until(predicate: Callable[[], object], timeout: float = 10.0) -> bool:
    """Poll `predicate` every 20 ms until it is true (True) or `timeout` seconds have passed (False)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.02)
    return False


def browser_update(handle, value, client_id: int = 1) -> None:
    """What viser does when a browser changes an input: set the value, run the callbacks."""
    from app.live.ui.viser_seam import input_state

    state = input_state(handle)
    state.value = value
    for cb in state.update_cb:
        cb(viser.GuiEvent(client=None, client_id=client_id, target=handle))
