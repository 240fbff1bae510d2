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
    builds each step without a check (`TaskTarget.of_record`) hold float64 C-contiguous arrays of the
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


def test_the_polish_targets_follow_the_zig_zag_and_a_new_start_or_wrench_from_the_next_step_on():
    """Each step's target starts as the held one (a record template) and gets only the XY parts the
    zig-zag moves: its position, velocity and acceleration equal `trajectory_state` within 1e-12 at
    every instant; a start or wrench assigned later is in the targets built after it, and a target
    built before keeps its values."""
    from app.scenarios.polish_plan import PolishTarget
    from app.scenarios.polish_stroke import (
        CONTACT_TIME_S,
        START_XY_M,
        PhaseClock,
        trajectory_duration,
        trajectory_state,
    )

    clock = PhaseClock(trajectory_start=CONTACT_TIME_S)
    start = np.array([*START_XY_M, 0.3])
    target_fn = PolishTarget(start, np.eye(3), np.zeros(7), clock)
    for t in np.linspace(0.0, CONTACT_TIME_S + trajectory_duration() + 1.0, 157):
        built = target_fn(float(t))
        xy, v, a = trajectory_state(max(float(t) - CONTACT_TIME_S, 0.0))
        np.testing.assert_allclose(built.position, [*xy, 0.3], atol=1e-12, err_msg=f"t = {t}")
        np.testing.assert_allclose(built.velocity, [*v, 0, 0, 0, 0], atol=1e-12, err_msg=f"t = {t}")
        np.testing.assert_allclose(built.acceleration, [*a, 0, 0, 0, 0], atol=1e-12, err_msg=f"t = {t}")
        np.testing.assert_array_equal(built.wrench, [0, 0, 20.0, 0, 0, 0])
    before = target_fn(0.5)
    target_fn.start = start + np.array([0.1, 0.0, 0.05])
    target_fn.wrench = [0, 0, 12.0, 0, 0, 0]
    after = target_fn(0.5)
    np.testing.assert_allclose(after.position, start + np.array([0.1, 0.0, 0.05]), atol=1e-15)
    np.testing.assert_array_equal(after.wrench, [0, 0, 12.0, 0, 0, 0])
    np.testing.assert_array_equal(before.position, start)
    np.testing.assert_array_equal(before.wrench, [0, 0, 20.0, 0, 0, 0])
    moved = target_fn(CONTACT_TIME_S + 1.0)  # the zig-zag now starts from the new start
    xy, _, _ = trajectory_state(1.0)
    np.testing.assert_allclose(moved.position[:2], xy + np.array([0.1, 0.0]), atol=1e-12)


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


WRONG_TYPES = {  # what a page, a script or a test might assign to an array field, by kind
    "tuple": lambda a: tuple(a.ravel().tolist()) if a.ndim == 1 else tuple(map(tuple, a.tolist())),
    "list": lambda a: a.tolist(),
    "int64": lambda a: np.rint(a).astype(np.int64),
    "float32": lambda a: a.astype(np.float32),
    "read-only": lambda a: _read_only(a),
    "None": lambda a: None,
    "text": lambda a: "0.5",
    "int": lambda a: 3,
}


def _read_only(a: np.ndarray) -> np.ndarray:
    out = a.copy()
    out.flags.writeable = False
    return out


def _assign(owner: object, name: str, value: object) -> str | None:
    """Assign; the error's text, or None when the assignment was taken."""
    try:
        setattr(owner, name, value)
    except (ValueError, AttributeError) as exc:
        assert "\n" not in str(exc) and name in str(exc), (name, str(exc))
        return str(exc)
    return None


def test_each_wrong_type_assigned_to_each_field_is_converted_or_refused_at_once_and_no_kernel_compiles(rizon):
    """Issue 34 (3): a tuple, list, int64, float32, read-only array, None, text or int assigned after
    construction to each field of a task target, of the step's inputs and of the polish target's
    arrays is converted to the kernels' type or refused there with a ValueError naming the field;
    a snapshot's record cannot be rebound. Then the executors step on what was taken with every
    dispatcher closed (`app.live.closed_kernels`): a type they did not meet would be a `NotWarmed`
    error at once, never a compile, and none comes; no dispatcher gains a signature."""
    from app.live import closed_kernels
    from app.scenarios.polish_plan import PolishTarget
    from app.scenarios.polish_stroke import PhaseClock
    from control.executor import TARGET_SHAPES

    model = RobotModel(rizon.model)
    dyn = model.compute(rizon.home, np.full(7, 0.1))
    good = {
        "position": dyn.tcp_position_world + 0.01, "rotation": np.eye(3), "velocity": np.full(6, 0.1),
        "acceleration": np.full(6, 0.2), "wrench": np.array([0.0, 0.0, 5.0, 0.0, 0.0, 0.0]), "q_posture": rizon.home,
    }  # fmt: skip
    executors = _executors(rizon, model)
    for ex in executors:  # every signature these steps take, loaded (or compiled on a cold cache) first
        ex.reset(dyn, TaskTarget(**good))
        ex.step(dyn, ControlInputs(0.0, TaskTarget(**good), np.ones(6), np.zeros(7)))
    before = _signatures()
    closed_kernels.close()
    try:
        taken, refused = 0, 0
        for name in TARGET_SHAPES:
            for kind, make in WRONG_TYPES.items():
                target = TaskTarget(**{k: v.copy() for k, v in good.items()})
                error = _assign(target, name, make(good[name]))
                if error is not None:
                    assert error.startswith(f"TaskTarget.{name} "), (name, kind, error)
                    refused += 1
                    continue
                taken += 1
                value = getattr(target, name)
                if kind == "None":  # only q_posture may be None (the executors then hold the posture)
                    assert name == "q_posture" and value is None, (name, kind)
                else:
                    assert type(value) is np.ndarray and value.dtype == np.float64, (name, kind)
                    assert value.flags.c_contiguous and value.flags.writeable, (name, kind)
                    np.testing.assert_array_equal(value, np.asarray(make(good[name]), dtype=float))
                inputs = ControlInputs(0.0, target, np.ones(6), np.zeros(7))
                for field_name, wrong in (("wrench_tcp", np.ones(6, np.float32)), ("tau_ext_oracle", [0] * 7)):
                    assert _assign(inputs, field_name, wrong) is None
                    assert getattr(inputs, field_name).dtype == np.float64
                for ex in executors:
                    out = ex.step(dyn, inputs)  # a NotWarmed (a type never met) would raise here
                    assert np.all(np.isfinite(out.tau)), (name, kind, ex.name)
        # the refused: every text, None where a vector is needed, a bare number
        assert refused == 3 * len(TARGET_SHAPES) - 1 and taken == 5 * len(TARGET_SHAPES) + 1, (refused, taken)
        inputs = ControlInputs(0.0, TaskTarget(**good), np.ones(6))
        for field_name in ("t", "target", "wrench_tcp", "tau_ext_oracle"):
            assert _assign(inputs, field_name, "0.5") is not None, field_name
        assert _assign(inputs, "t", np.float32(0.25)) is None and type(inputs.t) is float
        assert _assign(inputs, "wrench_tcp", (1, 2)) is not None
        with pytest.raises(AttributeError, match="TaskTarget has no field 'positon'"):
            inputs.target.positon = (0.0, 0.0, 0.0)  # a misspelt field is not a silent new attribute
        with pytest.raises(AttributeError, match=r"^Dynamics\.record "):
            dyn.record = dyn.record.copy()
        polish = PolishTarget(good["position"], np.eye(3), rizon.home, PhaseClock())
        for name, shape in PolishTarget._CHECKED.items():
            for kind, make in WRONG_TYPES.items():
                base = getattr(polish, name)
                error = _assign(polish, name, make(base))
                value = getattr(polish, name)
                assert value.dtype == np.float64 and value.ndim == len(shape or (7,))
                # the posture is shared as it is; the arrays of the held target are read-only copies
                assert value.flags.writeable == (name == "q_posture"), (name, kind)
                assert (error is None) == (kind not in ("None", "text", "int")), (name, kind, error)
                setattr(polish, name, base)
        for ex in executors:
            ex.step(dyn, ControlInputs(0.0, polish(0.5), np.zeros(6)))
    finally:
        closed_kernels.reopen()
    assert not _new_signatures(before), _new_signatures(before)


def test_after_the_warm_up_every_kernel_refuses_a_type_it_was_not_compiled_for_without_compiling():
    """`closed_kernels.close()` closes every dispatcher of the project (the registered kernels and
    the simulator's): each registered kernel still runs on its own sample, and refuses the same call
    with its first float array (else its first argument) as complex numbers with one `NotWarmed`
    naming it, adding no signature."""
    from app.live import closed_kernels
    from control.kernel_registry import KERNELS

    rng = np.random.default_rng(1)
    calls = {}
    for name, pair in KERNELS.items():
        args = pair.samples(rng)[0]
        pair.compiled(*args)  # loaded from numba's cache (compiled on a cold one) before the closing
        calls[name] = args
    found = closed_kernels.dispatchers()
    assert len(found) >= len(KERNELS) + 5 and any(k.startswith("app.sim.") for k in found)
    counts = {k: len(d.signatures) for k, d in found.items()}
    assert closed_kernels.close() == len(found) and closed_kernels.is_closed()
    try:
        for name, args in calls.items():
            KERNELS[name].compiled(*args)
            at = next((i for i, a in enumerate(args) if isinstance(a, np.ndarray) and a.dtype == np.float64), None)
            if at is None:  # no float array (records, scalars): complex numbers for the first argument
                at, wrong = 0, np.zeros(3, np.complex128)
            else:
                wrong = args[at].astype(np.complex128)
            t0 = time.perf_counter()
            with pytest.raises(closed_kernels.NotWarmed, match=rf"\.{name} was not compiled for these") as err:
                KERNELS[name].compiled(*args[:at], wrong, *args[at + 1 :])
            assert time.perf_counter() - t0 < 1.0, name  # a compile takes 0.1-10 s; a refusal microseconds
            assert "complex128" in str(err.value) and "\n" not in str(err.value), name
    finally:
        closed_kernels.reopen()
    assert not closed_kernels.is_closed()
    assert {k: len(d.signatures) for k, d in found.items()} == counts
