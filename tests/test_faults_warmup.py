"""Compiled before the URL: after the warm-up the loop meets no kernel signature it has not compiled
(that `serve` says the kernels are ready before it prints the URL: the smoke test in tests/test_cli.py)."""

from __future__ import annotations

import sys
import time

import numpy as np

from app.core.commands import DragCommand, Play, SwitchSession
from app.live.loop import SimLoop
from app.live.warmup import warm_up


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


def test_after_the_warm_up_switches_and_a_hard_drag_compile_nothing_new():
    lines: list[str] = []
    warm_up(None, lines.append)
    assert lines[0].startswith("compiling or loading") and any(line.startswith("[15/15]") for line in lines)
    before = _signatures()
    assert len(before) >= 30
    lp = SimLoop("free", capture=lambda s: None)
    lp.start(running=True)
    try:
        for scenario, executor in (("free", "projection"), ("limit-drop", "projection"), ("polish", "compliance-qp")):
            lp.submit(SwitchSession(scenario=scenario, executor=executor))
            lp.submit(Play())
            link = lp.call(lambda s: s.robot.link_names[-1])
            q_tip = lp.call(lambda s: np.array(s.world.data.xpos[-1]))
            lp.submit(DragCommand("grab", 1, body_name=link, point_world=tuple(q_tip)))
            t0 = time.monotonic()
            while time.monotonic() - t0 < 1.5:  # the page's hardest drag: far below the arm
                lp.submit(DragCommand("move", 1, body_name=link, target_world=(q_tip[0], q_tip[1], q_tip[2] - 1.0)))
                time.sleep(0.1)
            lp.submit(DragCommand("release", 1, body_name=link))
            lp.sync(timeout=120.0)
    finally:
        lp.stop()
    after = _signatures()
    grown = {k: (before.get(k, 0), v) for k, v in after.items() if v > before.get(k, 0)}
    assert not grown, f"compiled inside the loop after the warm-up: {grown}"
