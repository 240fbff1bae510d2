"""Inputs are typed where they are built, so the compiled steps never meet a new type.

`TaskTarget` coerces every field to a float64 array of its shape with finite entries, and refuses a
bad one at construction in one line; `ControlInputs` coerces the F/T reading. Then a target of
tuples, integers or float32 compiles nothing new, and no kernel compiles in the loop after a preset,
executor or robot switch (numba's dispatchers are counted: a new signature is a compile).
"""

from __future__ import annotations

import importlib
import pkgutil
import time

import numpy as np
import pytest
from numba.core.registry import CPUDispatcher

import control.kernels
from control.executor import ControlInputs, TaskTarget
from control.model import RobotModel


def _signatures() -> dict[str, int]:
    """How many type signatures each dispatcher of `control.kernels` has compiled or loaded."""
    out = {}
    for info in pkgutil.iter_modules(control.kernels.__path__):
        module = importlib.import_module(f"control.kernels.{info.name}")
        for name, value in vars(module).items():
            if isinstance(value, CPUDispatcher):
                out[f"{info.name}.{name}"] = len(value.signatures)
    return out


def _new_signatures(before: dict[str, int]) -> dict[str, int]:
    return {k: v for k, v in _signatures().items() if v != before.get(k, 0)}


def test_task_target_coerces_numbers_to_writeable_float64_arrays():
    base = np.zeros(3, dtype=np.float32)
    target = TaskTarget((1, 2, 3), np.eye(3, dtype=int), velocity=[0] * 6, wrench=base.repeat(2), q_posture=range(7))
    for name in ("position", "rotation", "velocity", "acceleration", "wrench", "q_posture"):
        a = getattr(target, name)
        assert type(a) is np.ndarray and a.dtype == np.float64, name
        assert a.flags.c_contiguous and a.flags.writeable, name
    assert target.rotation.shape == (3, 3) and target.q_posture.tolist() == list(range(7))
    frozen = np.arange(3.0)
    frozen.flags.writeable = False  # a read-only array is another numba type: copied
    assert TaskTarget(frozen, np.eye(3)).position.flags.writeable


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"position": None}, "position"),
        ({"position": (0.0, 0.0)}, "position"),
        ({"rotation": np.eye(4)}, "rotation"),
        ({"wrench": [0, 0, np.nan, 0, 0, 0]}, "wrench"),
        ({"velocity": [0, 0, np.inf, 0, 0, 0]}, "velocity"),
        ({"acceleration": "fast"}, "acceleration"),
        ({"q_posture": np.zeros((7, 1))}, "q_posture"),
    ],
)
def test_task_target_refuses_a_bad_field_at_construction_in_one_line(kwargs, field):
    args = {"position": np.zeros(3), "rotation": np.eye(3), **kwargs}
    with pytest.raises(ValueError, match=rf"^TaskTarget\.{field} ") as err:
        TaskTarget(**args)
    assert "\n" not in str(err.value)


def test_the_polish_target_checks_its_inputs_once_and_builds_every_steps_target_of_the_checked_type():
    """`PolishTarget` refuses a bad start or rotation at its construction (one line); the targets it
    builds each step without a check (`TaskTarget.trusted`) hold float64 C-contiguous arrays of the
    right shapes with finite entries, the same values a checked `TaskTarget` gets, along the zig-zag."""
    from app.scenarios.polish_plan import PolishTarget
    from app.scenarios.polish_stroke import CONTACT_TIME_S, PhaseClock, trajectory_duration

    clock = PhaseClock()
    q = np.linspace(-0.5, 0.5, 7)
    with pytest.raises(ValueError, match=r"^PolishTarget\.rotation ") as err:
        PolishTarget(np.zeros(3), np.eye(4), q, clock)
    assert "\n" not in str(err.value)
    with pytest.raises(ValueError, match=r"^PolishTarget\.start_position "):
        PolishTarget([0.0, np.nan, 0.5], np.eye(3), q, clock)
    target_fn = PolishTarget((0.4, 0.0, 0.3), np.eye(3, dtype=int), tuple(q), clock)
    clock.trajectory_start = CONTACT_TIME_S
    shapes = {"position": (3,), "rotation": (3, 3), "velocity": (6,), "acceleration": (6,), "wrench": (6,)}
    end = CONTACT_TIME_S + trajectory_duration() + 1.0
    for t in np.linspace(0.0, end, 41):
        built = target_fn(float(t))
        checked = TaskTarget(**{name: getattr(built, name) for name in (*shapes, "q_posture")})
        for name, shape in {**shapes, "q_posture": (7,)}.items():
            a = getattr(built, name)
            assert type(a) is np.ndarray and a.dtype == np.float64 and a.shape == shape, (t, name)
            assert a.flags.c_contiguous and np.all(np.isfinite(a)), (t, name)
            np.testing.assert_array_equal(a, getattr(checked, name))
    assert np.ptp([target_fn(float(t)).position[0] for t in np.linspace(CONTACT_TIME_S, end, 9)]) > 0.01


def _executors(robot, model):
    from app.core.executors import EXECUTORS

    return [EXECUTORS[name](robot, model) for name in ("projection", "compliance-qp")]


def test_a_target_of_tuples_integers_or_float32_compiles_nothing_and_steps_alike(rizon):
    model = RobotModel(rizon.model)
    dyn = model.compute(rizon.home, np.full(7, 0.1))
    p = dyn.tcp_position_world + 0.01
    plain = TaskTarget(p.copy(), np.eye(3), q_posture=rizon.home.copy())
    odd = TaskTarget(tuple(p), np.eye(3, dtype=int), velocity=np.zeros(6, np.float32), q_posture=tuple(rizon.home))
    for ex_plain, ex_odd in zip(_executors(rizon, model), _executors(rizon, model), strict=True):
        ex_plain.reset(dyn, plain)
        ex_odd.reset(dyn, odd)
        ex_plain.step(dyn, ControlInputs(0.0, plain, np.ones(6)))
        before = _signatures()
        ex_odd.step(dyn, ControlInputs(0.0, odd, (1, 1, 1, 1, 1, 1)))
        for k in range(3):
            a = ex_plain.step(dyn, ControlInputs(1e-3 * k, plain, np.ones(6)))
            b = ex_odd.step(dyn, ControlInputs(1e-3 * k, odd, (1, 1, 1, 1, 1, 1)))
            np.testing.assert_array_equal(a.tau, b.tau)
        assert not _new_signatures(before), ex_plain.name


def test_no_kernel_compiles_after_a_preset_executor_or_robot_switch(warm_kernels):
    """After the warm-up (every preset with every executor), each switch and the steps after it add
    no signature to any dispatcher (a new signature is a compile: seconds of CPU), and each of the
    first three steps after a switch takes under 10 ms of the thread's CPU. Polish is held to 50 ms
    instead: its first step computes the live posture margin (`control.margin.posture_margin`, six
    force-loop margins with the delays), 10-45 ms on this machine, none of it compiled code."""
    import robots
    from app.core.commands import SwitchSession
    from app.core.executors import EXECUTORS
    from app.live.lab import Lab
    from app.scenarios import SCENARIOS

    lab = Lab("free")
    lab.advance(2)
    before = _signatures()
    slowest: dict[str, float] = {}
    for robot in robots.available():
        for scenario in SCENARIOS:
            for executor in EXECUTORS:
                lab.apply(SwitchSession(scenario=scenario, robot=robot, executor=executor))
                for _ in range(3):
                    t0 = time.thread_time()
                    result = lab.advance(1)
                    slowest[scenario] = max(slowest.get(scenario, 0.0), time.thread_time() - t0)
                    assert not result.halted, (robot, scenario, executor, result.reason)
                assert not _new_signatures(before), (robot, scenario, executor, _new_signatures(before))
    for scenario, seconds in slowest.items():
        assert seconds < (0.050 if scenario == "polish" else 0.010), (scenario, seconds)
