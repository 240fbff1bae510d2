"""Compile before the URL: every compiled kernel the loop meets is compiled (or loaded from numba's
cache) before `serve` says where the page is, so the first drag or Pause never waits on a compile.

Two passes, with a progress line each: every registered kernel (`control.kernel_registry.KERNELS`)
called once on its first sample input, then 1.1 s of every preset with every executor on the chosen
robot (the argument types the loop itself builds), followed by a hard drag (the paths a saturated
force or a failing QP take). Run on the calling thread before the loop
starts; on a fresh install this is where the minute of compiling goes, afterwards seconds of loading.

One robot and the default QP backend cover every robot the page offers and both backends: numba
compiles per argument type (every arm's state is float64 arrays), not per arm or backend, and the
registered kernels' pass compiles the paths only OSQP takes (tests/test_faults_warmup.py switches to
every robot × backend × QP executor with a hard drag: no new signature, no step over 10 ms of CPU).
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from app.core.commands import DragCommand

DRAG_STEPS = 300  # then a hard drag (the tip pulled 1 m down: the page's maximum force, the QP's fallback)
WARM_CLIENT = -1  # the warm-up's own drag (no page has this client id)
WARM_STEPS = 1100  # steps of each preset × executor: 1.1 s, the polish live margin included (as tests/conftest.py)


def warm_registered_kernels() -> int:
    """Call every registered compiled kernel on its first sample; how many were called."""
    from control.kernel_registry import KERNELS

    rng = np.random.default_rng(0)
    for pair in KERNELS.values():
        samples = pair.samples(rng)
        if samples:
            args = tuple(a.copy() if isinstance(a, np.ndarray) else a for a in samples[0])
            pair.compiled(*args)
    return len(KERNELS)


def warm_presets(robot: str | None, progress: Callable[[str], None]) -> int:
    """A few steps of every preset with every executor; how many pairs ran."""
    from app.core.executors import EXECUTORS
    from app.live.lab import Lab
    from app.scenarios import SCENARIOS

    pairs = [(s, e) for s in SCENARIOS for e in EXECUTORS]
    for i, (scenario, executor) in enumerate(pairs, 1):
        progress(f"[{i}/{len(pairs)}] {scenario} / {executor}")
        try:
            lab = Lab(scenario, robot=robot, executor=executor)
        except ValueError as exc:  # the arm lacks the preset's posture: the page runs it on the preset's own arm
            if robot is None:
                raise
            progress(f"[{i}/{len(pairs)}] {scenario} / {executor} on its own arm ({exc})")
            lab = Lab(scenario, executor=executor)
        lab.advance(WARM_STEPS)
        link = lab.session.robot.link_names[-1]
        tip = np.array(lab.session.world.data.xpos[-1], dtype=float)
        lab.apply(DragCommand("grab", WARM_CLIENT, body_name=link, point_world=tuple(tip)))
        lab.apply(DragCommand("move", WARM_CLIENT, body_name=link, target_world=tuple(tip - (0.0, 0.0, 1.0))))
        lab.advance(DRAG_STEPS)
    return len(pairs)


def warm_up(robot: str | None = None, progress: Callable[[str], None] = print) -> float:
    """Both passes (see the module docstring); the seconds they took."""
    t0 = time.perf_counter()
    progress("compiling or loading the kernels (about a minute on the first run after an install) …")
    n = warm_registered_kernels()
    progress(f"{n} kernels ready; a few steps of every preset and executor …")
    warm_presets(robot, progress)
    return time.perf_counter() - t0
