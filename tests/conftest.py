"""Shared fixtures: robots and models are loaded once per session."""

from __future__ import annotations

import socket

import numpy as np
import pytest
import viser

import robots
from control.model import RobotModel


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
