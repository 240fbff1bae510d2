"""Timing benchmarks: median and p95 in µs of the pieces of one 1 kHz control step.

Each entry builds its objects once and returns a zero-argument callable that is timed
repeatedly. Figures are also given as a share of the 1000 µs real-time budget and as a
real-time factor (1000 µs over the median: how many times faster than real time a loop doing
only this would run).

`--vs-placo PYTHON` also times placo's DynamicsSolver (the compiled peer of the [C] QP step) on
the same URDF, in the Python of another virtual environment (`app/tools/placo_peer.py`, see there),
and reports the ratio of our [C] QP executor step to placo's step.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import mujoco
import numpy as np

import robots
from app.sim.world import World
from control.model import RobotModel

BUDGET_US = 1000.0


def time_call(fn: Callable[[], object], repeats: int = 300, warmup: int = 20) -> dict:
    """Median / p95 wall time of fn() in µs, per step when fn runs `fn.steps_per_call` steps."""
    for _ in range(warmup):
        fn()
    samples = np.empty(repeats)
    for i in range(repeats):
        t0 = time.perf_counter()
        fn()
        samples[i] = time.perf_counter() - t0
    us = samples * 1e6 / getattr(fn, "steps_per_call", 1)
    med = float(np.median(us))
    return {
        "median_us": med,
        "p95_us": float(np.percentile(us, 95)),
        "share_of_1ms": med / BUDGET_US,
        "real_time_factor": BUDGET_US / med,
    }


def _snapshot(robot):
    model = RobotModel(robot.model)
    q, dq = robot.home, np.full(7, 0.1)
    return lambda: model.compute(q, dq)


def _dlambda_analytic(robot):
    model = RobotModel(robot.model)
    dyn = model.compute(robot.home, np.zeros(7))
    return lambda: model.dLambda_dq(dyn)


def _dlambda_fd(robot):
    model = RobotModel(robot.model)
    return lambda: model.dLambda_dq_fd(robot.home)


def _mj_step(robot):
    world = World(robot)
    return lambda: mujoco.mj_step(world.model, world.data)


# name -> factory(robot) returning the callable to time; other modules append their entries.
BENCHES: dict[str, Callable] = {
    "dynamics_snapshot": _snapshot,
    "dLambda_dq_analytic": _dlambda_analytic,
    "dLambda_dq_finite_diff": _dlambda_fd,
    "mj_step": _mj_step,
    "qp_executor_step": lambda robot: _qp_executor_step(robot),
    "tang_step_W_a": lambda robot: _tang_step(robot, "a"),
    "tang_step_W_j": lambda robot: _tang_step(robot, "j"),
    "tang_session_step_W_a": lambda robot: _tang_session_step(robot),
    "polish_live_margin": lambda robot: _polish_live_margin(robot),
    "polish_live_rate": lambda robot: _polish_live_rate(robot),
    "app_step_polish_W_a": lambda robot: _app_step(robot),
}


def _qp_executor_step(robot):
    """[C] executor: snapshot + estimation (fusion) + QP + inverse dynamics, moving state."""
    from control.compliance_qp import make_compliance_qp
    from control.executor import ControlInputs, TaskTarget

    model = RobotModel(robot.model)
    ex = make_compliance_qp(robot, model)
    dyn0 = model.compute(robot.home, np.zeros(7))
    target = TaskTarget(position=dyn0.tcp_position_world, rotation=dyn0.tcp_rotation_world, q_posture=robot.home)
    ex.reset(dyn0, target)
    phase = np.arange(7.0)
    wrench = np.array([1.0, -2.0, 3.0, 0.1, 0.0, -0.1])
    k = [0]

    def step():
        k[0] += 1
        s = 0.01 * k[0] + phase
        dyn = model.compute(robot.home + 0.05 * np.sin(s), 0.2 * np.cos(s))
        return ex.step(dyn, ControlInputs(t=1e-3 * k[0], target=target, wrench_tcp=wrench))

    return step


def placo_step(python: str, robot, steps: int = 2000, timeout_s: float = 300.0) -> dict:
    """Median µs of placo's DynamicsSolver step on the robot's URDF, run by `python` (a venv with
    placo==0.10.2) on `app/tools/placo_peer.py`. The frame task is on the flange (placo reads the URDF
    alone, which has no TCP frame: the cost is the same). ValueError with the reason on failure."""
    import json
    import subprocess
    from pathlib import Path

    script = Path(__file__).with_name("placo_peer.py")
    cmd = [python, str(script), str(robot.urdf_path), robot.flange_frame, str(steps), json.dumps(robot.home.tolist())]
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s, check=False)
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise ValueError(f"could not run placo with {python}: {exc}") from exc
    lines = proc.stdout.strip().splitlines()
    if proc.returncode != 0 or not lines:
        last = (proc.stderr.strip().splitlines() or lines or ["no output"])[-1]
        raise ValueError(f"placo run with {python} failed: {last}")
    out = json.loads(lines[-1])
    out["real_time_factor"] = BUDGET_US / out["step_us"]
    return out


def run_bench(
    robot_name: str = robots.DEFAULT_ROBOT,
    repeats: int = 300,
    only: list[str] | None = None,
    placo_python: str | None = None,
) -> dict:
    """Run every registered benchmark (or those in `only`) on one robot; ValueError for an unknown name.
    With `placo_python`, also placo's step (`placo_step`) and the ratio of our [C] QP step to it."""
    unknown = sorted(set(only or ()) - set(BENCHES))
    if unknown:
        raise ValueError(f"unknown benchmark {', '.join(unknown)}; choose from {', '.join(BENCHES)}")
    robot = robots.load(robot_name)
    results = {}
    for name, factory in BENCHES.items():
        if only and name not in only:
            continue
        results[name] = time_call(factory(robot), repeats=repeats)
    a, f = results.get("dLambda_dq_analytic"), results.get("dLambda_dq_finite_diff")
    summary = {}
    if a and f:
        summary["dLambda_analytic_speedup_vs_fd"] = f["median_us"] / a["median_us"]
    report: dict = {"robot": robot.name, "repeats": repeats, "results": results, "summary": summary}
    if placo_python is not None:
        peer = report["placo"] = placo_step(placo_python, robot)
        ours = results.get("qp_executor_step")
        if ours:
            summary["qp_executor_step_over_placo"] = ours["median_us"] / peer["step_us"]
    return report


def _tang_step(robot, objective: str):
    """[T] executor: snapshot + W gradient (analytic ∂Λx/∂q) + nullspace QP + law, moving state."""
    from control.executor import ControlInputs, TaskTarget
    from control.gains import NullspaceGains
    from control.motion_force import make_projection_executor

    model = RobotModel(robot.model)
    ex = make_projection_executor(robot, model, nullspace=NullspaceGains(objective=objective))
    q0 = robot.home.copy()
    dyn0 = model.compute(q0, np.zeros(7))
    target = TaskTarget(
        dyn0.tcp_position_world.copy(), dyn0.tcp_rotation_world.copy(), wrench=np.r_[0, 0, 20.0, 0, 0, 0]
    )
    ex.reset(dyn0, target)
    wrench = np.array([1.0, -2.0, 19.0, 0.1, 0.0, 0.0])
    state = {"k": 0}

    def step():
        k = state["k"] = state["k"] + 1
        q = q0 + 0.01 * np.sin(0.01 * k + np.arange(7))
        dyn = model.compute(q, np.full(7, 0.05))
        return ex.step(dyn, ControlInputs(t=1e-3 * k, target=target, wrench_tcp=wrench))

    return step


def _tang_session_step(robot):
    """One whole polish Session step (sim, contact, sensor, [T] executor with W_a); always the Rizon 4s."""
    from app.core.session import Session
    from app.scenarios.polish import PolishScenario

    session = Session(PolishScenario(mu=0.25))
    session.set_param("nullspace", "objective", "a")
    session.run(0.3)
    return session.step


def _app_step(robot):
    """One step as the app's loop runs it, in a burst of a 30 Hz frame's 33 steps (`Lab.advance`:
    the Session steps, the step log, the divergence check), polish with W_a in contact; always the
    Rizon 4s. As in the app's loop, the live margin (`polish_live_margin`, once per simulated second)
    and the live rate (`polish_live_rate`, ten times) are computed in the worker process
    (`app.live.offload`): the step pays only their snapshot and submission."""
    from app.live.lab import Lab
    from app.live.offload import LiveOffload

    lab = Lab("polish")
    offload = LiveOffload()
    if not offload.ready(120.0):
        raise RuntimeError("the live margin's worker process did not start within 120 s")
    lab.set_offload(offload)
    lab.session.set_param("nullspace", "objective", "a")
    lab.advance(1000)  # past the first live margin and into steady contact

    def burst():
        return lab.advance(33)

    burst.steps_per_call = 33  # type: ignore[attr-defined]
    return burst


def _polish_live_margin(robot):
    """The polish scenario's live force-loop margin signal (`live_margin`: Λx of the posture, the
    K_f^d search over two friction directions and three speeds), which runs once per simulated
    second, not every step, and in the app in the worker process, not on the loop thread; always the
    Rizon 4s, at the posture of `tang_session_step_W_a`."""
    from app.core.session import Session
    from app.scenarios.polish import PolishScenario

    session = Session(PolishScenario(mu=0.25))
    session.set_param("nullspace", "objective", "a")
    session.run(0.3)
    env, t = session.environment, session.world.time
    return lambda: env.live_margin(t)  # type: ignore[attr-defined]


def _polish_live_rate(robot):
    """The polish scenario's live decay rate σ (`live_rate`: Λx of the posture, one map of the force
    loop with its latency, one eigenvalue problem), which runs ten times per simulated second (every
    100 steps; in the app in the worker process); always the Rizon 4s, at the posture of
    `polish_live_margin`."""
    from app.core.session import Session
    from app.scenarios.polish import PolishScenario

    session = Session(PolishScenario(mu=0.25))
    session.set_param("nullspace", "objective", "a")
    session.run(0.3)
    env, t = session.environment, session.world.time
    return lambda: env.live_rate(t)  # type: ignore[attr-defined]


# ---- the QP solve alone (control/qp.py), per backend, on problems the executors built ----------
def _nullspace_qp_solve(robot, backend: str):
    """[T15–17] nullspace QP: one solve (warm-started) on a cycle of 50 problems of a moving state."""
    from control.coupling import POLISH_SUBSPACES, objective_gradient
    from control.gains import NullspaceGains
    from control.nullspace import NullspaceQP, damper_bounds

    model = RobotModel(robot.model)
    gains = NullspaceGains()
    problems = []
    for k in range(50):
        q = robot.home + 0.05 * np.sin(0.02 * k + np.arange(7.0))
        dyn = model.compute(q, np.zeros(7))
        _, grad = objective_gradient("a", dyn, POLISH_SUBSPACES, model)
        lo, up = damper_bounds(q, robot.q_lower, robot.q_upper, 0.5 * robot.dq_max, robot.endless, gains)
        problems.append((dyn.J.copy(), gains.k0_a * grad, lo, up))
    solver = NullspaceQP(backend=backend)
    at = [0]

    def solve():
        at[0] = (at[0] + 1) % len(problems)
        return solver.solve(*problems[at[0]])

    return solve


def _compliance_qp_solve(robot, backend: str):
    """[C9, C10, C17–24] acceleration QP: one solve on a cycle of the 50 problems the executor built
    along the moving state of `qp_executor_step`."""
    from control.compliance_qp import AccelerationQP, make_compliance_qp
    from control.executor import ControlInputs, TaskTarget
    from control.gains import ComplianceQPSettings

    model = RobotModel(robot.model)
    ex = make_compliance_qp(robot, model, fused=False)  # every step's QP goes through `ex.qp.solve`
    dyn0 = model.compute(robot.home, np.zeros(7))
    target = TaskTarget(position=dyn0.tcp_position_world, rotation=dyn0.tcp_rotation_world, q_posture=robot.home)
    ex.reset(dyn0, target)
    problems = []
    inner = ex.qp.solve

    def capture(P, q):
        a = ex.qp
        problems.append((P.copy(), q.copy(), a.A.copy(), a.l.copy(), a.u.copy(), a.lb.copy(), a.ub.copy()))
        return inner(P, q)

    ex.qp.solve = capture  # type: ignore[method-assign]
    wrench = np.array([1.0, -2.0, 3.0, 0.1, 0.0, -0.1])
    for k in range(1, 51):
        s = 0.01 * k + np.arange(7.0)
        dyn = model.compute(robot.home + 0.05 * np.sin(s), 0.2 * np.cos(s))
        ex.step(dyn, ControlInputs(t=1e-3 * k, target=target, wrench_tcp=wrench))
    solver = AccelerationQP(7, 0, ComplianceQPSettings(), backend)
    at = [0]

    def solve():
        at[0] = (at[0] + 1) % len(problems)
        P, q, A, l, u, lb, ub = problems[at[0]]
        solver.A[:], solver.l[:], solver.u[:], solver.lb[:], solver.ub[:] = A, l, u, lb, ub
        return solver.solve(P, q)

    return solve


BENCHES.update(
    {
        f"qp_solve_{kind}_{backend}": (lambda f, b: lambda robot: f(robot, b))(factory, backend)
        for kind, factory in (("nullspace", _nullspace_qp_solve), ("compliance", _compliance_qp_solve))
        for backend in ("dense", "osqp")
    }
)
