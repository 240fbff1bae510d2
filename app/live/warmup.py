"""Compile before the loop: every compiled kernel the loop meets is compiled (or loaded from numba's
cache) before the loop starts, so the first drag or Pause never waits on a compile. `serve` prints the
URL first and, on a cold cache, has worker processes compile these passes' pieces as separate jobs
(`app.live.warm_workers`, which also runs `warm_up` itself afterwards: then it only loads).

Two passes, with a progress line each: every registered kernel (`control.kernel_registry.KERNELS`)
called once on its first sample input, then 1.1 s of every preset with every executor on the chosen
robot (the argument types the loop itself builds), followed by a hard drag (the paths a saturated
force or a failing QP take). Run on the calling thread before the loop starts; in one process, on a
fresh install, this is where the minute of compiling goes, afterwards seconds of loading.

One robot and the default QP backend cover every robot the page offers and both backends: numba
compiles per argument type (every arm's state is float64 arrays), not per arm or backend, and the
registered kernels' pass compiles the paths only OSQP takes (tests/test_faults_warmup.py switches to
every robot × backend × QP executor with a hard drag: no new signature, no step over 10 ms of CPU).
"""

from __future__ import annotations

import importlib
import time
from collections.abc import Callable

import numpy as np

from app.core.commands import DragCommand

DRAG_STEPS = 300  # then a hard drag (the tip pulled 1 m down: the page's maximum force, the QP's fallback)
WARM_CLIENT = -1  # the warm-up's own drag (no page has this client id)
WARM_STEPS = 1100  # steps of each preset × executor: 1.1 s, the polish live margin included (as tests/conftest.py)


def import_kernels() -> None:
    """Import every module that defines a compiled kernel (a warm-up worker's start, before its jobs)."""
    from app.live.closed_kernels import KERNEL_MODULES

    for name in KERNEL_MODULES:
        importlib.import_module(name)


def warm_calls(name: str) -> list[tuple]:
    """The arguments `warm_kernel` calls the registered kernel `name` with: the first of its samples of
    each argument type, its arrays copied in their own layout (a plain copy is row-major: another type
    for a column-major array, which the loop passes where Pinocchio's matrices go)."""
    import numba

    from control.kernel_registry import KERNELS

    calls, seen = [], set()
    for sample in KERNELS[name].samples(np.random.default_rng(0)):
        types = tuple(numba.typeof(a) for a in sample)
        if types not in seen:
            seen.add(types)
            calls.append(tuple(a.copy(order="K") if isinstance(a, np.ndarray) else a for a in sample))
    return calls


def warm_kernel(name: str) -> float:
    """Call the registered kernel `name` on `warm_calls(name)` (compiled, or loaded from numba's cache);
    the seconds it took. A module-level function: a warm-up worker process runs it."""
    from control.kernel_registry import KERNELS

    t0 = time.perf_counter()
    for args in warm_calls(name):
        KERNELS[name].compiled(*args)
    return time.perf_counter() - t0


def warm_arm_state() -> float:
    """One state of the shipped arm as the loop computes it (`RobotModel.compute`: the compiled
    snapshot's kernels); the seconds it took."""
    from control.kernel_registry import sample_arm

    t0 = time.perf_counter()
    robot, model = sample_arm()
    model.compute(np.array(robot.home, dtype=float), np.full(len(robot.home), 0.1))
    return time.perf_counter() - t0


def warm_simulator() -> float:
    """The simulator's own kernels (`app.sim`: the torque clip and joint stops, the contact, the F/T
    sensor's filter) on the types a step passes them: one step of the shipped arm's world pressed into
    a table, its reading measured twice; the seconds it took."""
    from app.sim.contact import TableContact
    from app.sim.sensor import FTSensor
    from app.sim.world import World
    from control.kernel_registry import sample_arm

    t0 = time.perf_counter()
    robot, _ = sample_arm()
    world = World(robot)
    world.step(np.zeros(len(robot.joint_names)))
    tcp_z = float(world.data.site_xpos[world.tcp_site, 2])
    for height in (tcp_z + 0.01, tcp_z - 0.01):  # in contact (the implicit friction's solve), then not
        TableContact(height).apply(world)
    sensor = FTSensor(np.random.default_rng(0))
    for t in (0.0, 1e-3):  # the filter's first reading, then the next
        sensor.measure(np.zeros(6), t)
    return time.perf_counter() - t0


def prepare_worker() -> None:
    """A warm-up worker process's start: every kernel module imported, the kernels' sample states from
    the plain-numpy snapshot (`control.kernel_registry.use_plain_states`: no kernel waits for another
    process to compile the snapshot)."""
    from control.kernel_registry import use_plain_states

    import_kernels()
    use_plain_states()


def warm_registered_kernels(progress: Callable[[int, int, str], None] | None = None) -> int:
    """Call every registered compiled kernel on its first sample; how many were called. `progress`
    hears (i, count, name) before each."""
    from control.kernel_registry import KERNELS

    for i, name in enumerate(KERNELS, 1):
        if progress is not None:
            progress(i, len(KERNELS), name)
        warm_kernel(name)
    return len(KERNELS)


def preset_pairs() -> list[tuple[str, str]]:
    """Every (preset, executor) the page offers, in the warm-up's order."""
    from app.core.executors import EXECUTORS
    from app.scenarios import SCENARIOS

    return [(s, e) for s in SCENARIOS for e in EXECUTORS]


def warm_preset(robot: str | None, scenario: str, executor: str) -> str:
    """WARM_STEPS of one preset with one executor on `robot`, then a hard drag for DRAG_STEPS; "" or,
    when the arm lacks the preset's posture (the page then runs it on the preset's own arm, as here),
    why. A module-level function: a warm-up worker process runs it."""
    from app.live.lab import Lab

    note = ""
    try:
        lab = Lab(scenario, robot=robot, executor=executor)
    except ValueError as exc:
        if robot is None:
            raise
        note, lab = f"on its own arm ({exc})", Lab(scenario, executor=executor)
    lab.advance(WARM_STEPS)
    link = lab.session.robot.link_names[-1]
    tip = np.array(lab.session.world.data.xpos[-1], dtype=float)
    lab.apply(DragCommand("grab", WARM_CLIENT, body_name=link, point_world=tuple(tip)))
    lab.apply(DragCommand("move", WARM_CLIENT, body_name=link, target_world=tuple(tip - (0.0, 0.0, 1.0))))
    lab.advance(DRAG_STEPS)
    return note


def warm_presets(robot: str | None, progress: Callable[[str], None]) -> int:
    """A few steps of every preset with every executor; how many pairs ran."""
    pairs = preset_pairs()
    for i, (scenario, executor) in enumerate(pairs, 1):
        progress(f"[{i}/{len(pairs)}] {scenario} / {executor}")
        note = warm_preset(robot, scenario, executor)
        if note:
            progress(f"[{i}/{len(pairs)}] {scenario} / {executor} {note}")
    return len(pairs)


# modules the running app imports on first use: the polish verdict's band-pass (scipy.signal, which
# imports scipy.stats: ~8 MB and up to a second the first time, when a live polish run is judged)
LATE_IMPORTS = ("scipy.signal",)


def import_late_modules() -> None:
    """Import LATE_IMPORTS now, so the first verdict does not wait on an import and the memory they take
    belongs to start-up (`bench --soak` counted it as growth after the first minute)."""
    for name in LATE_IMPORTS:
        importlib.import_module(name)


def warm_up(robot: str | None = None, progress: Callable[[str], None] = print) -> float:
    """Both passes (see the module docstring), after `import_late_modules`; the seconds they took."""
    t0 = time.perf_counter()
    import_late_modules()
    progress("compiling or loading the kernels (about a minute on the first run after an install) …")
    n = warm_registered_kernels()
    progress(f"{n} kernels ready; a few steps of every preset and executor …")
    warm_presets(robot, progress)
    return time.perf_counter() - t0
