"""Compiled before the URL: after the warm-up the loop meets no kernel signature it has not compiled
(that `serve` says the kernels are ready before it prints the URL: the smoke test in tests/test_cli.py).

As in `serve`, the warm-up here ends with every dispatcher closed (`app.live.closed_kernels`): a
signature the warm-up missed would halt the arm with a `NotWarmed` error, which the tests look for."""

from __future__ import annotations

import gc
import sys
import time
from collections.abc import Iterator

import numpy as np
import pytest

import robots
from app.core.commands import DragCommand, Play, SetParam, SwitchSession
from app.live import closed_kernels
from app.live.loop import SimLoop
from app.live.memory import freeze_start_up_objects
from app.live.ui.snapshot import capture
from app.live.warmup import warm_up

MAX_STEP_CPU_S = 0.080  # no step of the loop thread after a switch may cost a compile (0.1-10 s); 1.3-44 ms measured


def _signatures() -> dict[str, int]:
    """Compiled signatures of every numba dispatcher in the project's loaded modules."""
    from numba.core.registry import CPUDispatcher

    out = {}
    for name, mod in list(sys.modules.items()):
        if not name.startswith(("control", "app", "robots")) or mod is None:
            continue
        for _attr, obj in list(vars(mod).items()):
            if isinstance(obj, CPUDispatcher):
                out[f"{obj.py_func.__module__}.{obj.py_func.__qualname__}"] = len(obj.signatures)
    return out


@pytest.fixture(scope="module")
def warm_lines() -> Iterator[list[str]]:
    """`serve`'s warm-up on the default robot, once for this module; its progress lines."""
    lines: list[str] = []
    warm_up(None, lines.append)
    closed_kernels.close()
    freeze_start_up_objects()  # as `serve` does after its warm-up: no full pass walks the start-up heap
    yield lines
    gc.unfreeze()
    closed_kernels.reopen()


def _synced(lp: SimLoop) -> str:
    """Wait for the loop's queue; the scenario it runs (a halt for a kernel not warmed fails here)."""
    status = lp.sync(timeout=120.0)
    assert "not compiled" not in status.halted and not lp.failure, (status.halted, lp.failure)
    refused = [n.body for n in lp.take_notices() if "not compiled" in n.body]  # (the scene capture's)
    assert not refused, refused
    return status.scenario


def _hard_drag(lp: SimLoop, seconds: float) -> None:
    """The page's hardest drag (the tip pulled 1 m down) for `seconds`, then released."""
    link = lp.call(lambda s: s.robot.link_names[-1])
    q_tip = lp.call(lambda s: np.array(s.world.data.xpos[-1]))
    lp.submit(DragCommand("grab", 1, body_name=link, point_world=tuple(q_tip)))
    t0 = time.monotonic()
    while time.monotonic() - t0 < seconds:
        lp.submit(DragCommand("move", 1, body_name=link, target_world=(q_tip[0], q_tip[1], q_tip[2] - 1.0)))
        time.sleep(0.1)
    lp.submit(DragCommand("release", 1, body_name=link))


def test_after_the_warm_up_switches_and_a_hard_drag_compile_nothing_new(warm_lines):
    lines = warm_lines
    assert lines[0].startswith("compiling or loading") and any(line.startswith("[15/15]") for line in lines)
    before = _signatures()
    assert len(before) >= 30
    lp = SimLoop("free", capture=capture)  # the page's scene capture too
    lp.start(running=True)
    try:
        for scenario, executor in (("free", "projection"), ("limit-drop", "projection"), ("polish", "compliance-qp")):
            lp.submit(SwitchSession(scenario=scenario, executor=executor))
            lp.submit(Play())
            _hard_drag(lp, 1.5)
            _synced(lp)
    finally:
        lp.stop()
    after = _signatures()
    grown = {k: (before.get(k, 0), v) for k, v in after.items() if v > before.get(k, 0)}
    assert not grown, f"compiled inside the loop after the warm-up: {grown}"


def test_a_switch_to_every_robot_and_backend_the_page_offers_compiles_nothing_and_no_step_costs_a_compile(warm_lines):
    """After the warm-up on the default robot (kernel signatures depend on argument types, not on the
    arm or the QP backend), every robot the page's selector offers × both QP backends × both QP
    executors, with a hard drag: no numba signature is added and no step of the loop thread costs
    MAX_STEP_CPU_S of its CPU time (CPU, not wall time: the machine's load does not count)."""
    before = _signatures()
    lp = SimLoop("free", capture=lambda s: None)
    cpu: list[tuple[str, float]] = []  # (what ran, the loop thread's CPU time of one step)
    label = ["warm"]
    advance = lp.lab.advance

    def timed_advance(n, until=None):
        last = [time.thread_time()]

        def stamp(rec) -> bool:
            now = time.thread_time()
            cpu.append((label[0], now - last[0]))
            last[0] = now
            return until is not None and until(rec)

        return advance(n, until=stamp)

    lp.lab.advance = timed_advance  # type: ignore[method-assign]
    passes: list[tuple[int, float]] = []  # (generation, wall seconds) of each collector pass meanwhile
    began = [0.0]

    def on_gc(phase: str, info: dict) -> None:
        if phase == "start":
            began[0] = time.perf_counter()
        else:
            passes.append((info["generation"], time.perf_counter() - began[0]))

    gc.callbacks.append(on_gc)
    lp.start(running=True)
    try:
        for robot in robots.available():
            for backend in ("osqp", "dense"):
                for executor, scenario in (("projection", "free"), ("compliance-qp", "compliance")):
                    label[0] = f"{robot} / {backend} / {executor}"  # from the switch's first step on
                    lp.submit(SwitchSession(scenario=scenario, robot=robot, executor=executor))
                    lp.submit(SetParam("solver", "qp_backend", backend))
                    lp.submit(Play())
                    assert _synced(lp) == scenario
                    _hard_drag(lp, 0.6)
                    _synced(lp)
    finally:
        lp.stop()
        gc.callbacks.remove(on_gc)
    after = _signatures()
    grown = {k: (before.get(k, 0), v) for k, v in after.items() if v > before.get(k, 0)}
    assert not grown, f"compiled inside the loop after the warm-up: {grown}"
    measured = [(c, what) for what, c in cpu]
    assert len({what for _, what in measured} - {"warm"}) == 4 * len(robots.available())
    worst, where = max(measured)
    print(f"{len(measured)} steps after switches, longest {1e3 * worst:.1f} ms of loop-thread CPU ({where})")
    full = [round(1e3 * t, 1) for gen, t in passes if gen == 2]
    print(f"collector: {len(passes)} passes, the full ones took {full} ms")
    assert worst < MAX_STEP_CPU_S, (
        f"a step took {1e3 * worst:.1f} ms of the loop thread's CPU ({where}); full collector passes (ms): {full}"
    )
