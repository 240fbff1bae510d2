"""The projection executor [T7-14] in closed loop with the MuJoCo world."""

from __future__ import annotations

import numpy as np
import pytest

from app.scenarios.polish import PolishScenario
from app.sim.world import World
from control import coupling as c
from control.executor import ControlInputs, TaskTarget
from control.gains import MotionForceGains, NullspaceGains
from control.model import RobotModel
from control.motion_force import make_projection_executor
from control.params import ParamError, replaced, with_values


def _push_sideways(rizon, shaping: bool, steps: int = 300, push_n: float = 15.0) -> np.ndarray:
    """Hold the polish start pose in free space (F̂ = 0), push the TCP along +x with an ideal
    (noise-free, unfiltered) F/T reading, and return the TCP acceleration history (steps, 6)."""
    q0 = PolishScenario().initial_q(rizon)
    world = World(rizon)
    world.reset(q0)
    model = RobotModel(rizon.model)
    ex = make_projection_executor(
        rizon, model, gains=MotionForceGains(shaping=shaping), nullspace=NullspaceGains(objective="j")
    )
    dyn = model.compute(world.q, world.dq)
    target = TaskTarget(dyn.tcp_position_world.copy(), dyn.tcp_rotation_world.copy(), q_posture=q0)
    ex.reset(dyn, target)
    velocities = [world.site_velocity(world.tcp_site)]  # at rest
    for _ in range(steps):
        dyn = model.compute(world.q, world.dq)
        point, _ = world.site_pose(world.tcp_site)
        force = np.array([push_n, 0.0, 0.0])
        world.apply_force(world.wrist_body, point, force)
        wrench_tcp = np.concatenate([force, np.zeros(3)])  # applied at the TCP: no moment there
        out = ex.step(dyn, ControlInputs(t=world.time, target=target, wrench_tcp=wrench_tcp))
        assert not out.fallback
        world.step(out.tau)
        velocities.append(world.site_velocity(world.tcp_site))
    return np.diff(np.array(velocities), axis=0) / world.model.opt.timestep


def test_shaped_inertia_keeps_motion_forces_out_of_the_force_subspace(rizon):
    """[T9]: D̂ ẍ_f = u_f + F_f^e, so a push in the motion subspace leaves ẍ_f = 0."""
    acc_shaped = _push_sideways(rizon, shaping=True)
    acc_natural = _push_sideways(rizon, shaping=False)
    az_shaped = np.max(np.abs(acc_shaped[:, 2]))
    az_natural = np.max(np.abs(acc_natural[:, 2]))
    # natural inertia: the push couples into z through P_f (Table I): ẍ_z ≈ P_f F_m at the start
    model = RobotModel(rizon.model)
    dyn = model.compute(PolishScenario().initial_q(rizon), np.zeros(7))
    predicted = abs(float(c.terms_of(dyn, c.POLISH_SUBSPACES).P_f[0, 0] * 15.0))
    assert az_natural == pytest.approx(predicted, rel=1e-3)  # first step, before any feedback
    assert az_natural > 0.5  # m/s²: the coupling is substantial at this posture
    assert az_shaped < 1e-3 * az_natural  # only the 1 ms discretisation remains
    # the motion subspace still feels the push (same A, impedance unchanged)
    assert np.max(np.abs(acc_shaped[:, 0])) > 1.0


def test_executor_survives_nan_input_and_flags_it(rizon):
    model = RobotModel(rizon.model)
    ex = make_projection_executor(rizon, model)
    q0 = PolishScenario().initial_q(rizon)
    dyn = model.compute(q0, np.zeros(7))
    target = TaskTarget(dyn.tcp_position_world.copy(), dyn.tcp_rotation_world.copy())
    ex.reset(dyn, target)
    out = ex.step(dyn, ControlInputs(t=0.0, target=target, wrench_tcp=np.full(6, np.nan)))
    assert np.all(np.isfinite(out.tau))
    assert out.fallback and out.info["sensor_invalid"] == 1.0
    ok = ex.step(dyn, ControlInputs(t=0.001, target=target, wrench_tcp=np.zeros(6)))
    assert not ok.fallback


def test_set_params_switches_objective_and_axes_without_rebuilding_the_qp(rizon):
    model = RobotModel(rizon.model)
    ex = make_projection_executor(rizon, model)
    qp = ex.qp
    ex.set_params("nullspace", with_values(ex.nullspace, {"objective": "d", "k0_d": 0.1}))
    ex.set_params("motion_force", replaced(ex.gains, "force_kp", 0.3))
    assert ex.nullspace.objective == "d" and ex.nullspace.k0 == 0.1 and ex.gains.force_kp == 0.3
    ex.set_params("motion_force", replaced(ex.gains, "force_axes", "px py"))
    assert ex.sub.force_axes == (0, 1) and ex.force_integral.shape == (2,)
    assert ex.qp is qp
    with pytest.raises(ParamError, match="force_kd"):
        ex.set_params("motion_force", replaced(ex.gains, "force_kd", -1.0))
    with pytest.raises(ParamError, match="no parameter"):
        replaced(ex.gains, "stiffness", 3.0)
    with pytest.raises(ParamError, match="no parameter group"):
        ex.set_params("damper", ex.gains)
    assert ex.gains.force_kd == 200.0  # a rejected change leaves the gains as they were


def test_static_contact_force_converges_to_the_desired_force(rizon):
    """On the table with an ideal sensor, u_f [T12] settles at F^e_z = F̂ = 20 N."""
    from app.core.session import Session

    session = Session(PolishScenario(mu=0.25, sensor_noise=False), seed=0)
    session.set_param("nullspace", "objective", "j")
    forces = []
    for _ in range(1200):
        forces.append(session.step().signals["contact_force_n"])
    assert np.mean(forces[-200:]) == pytest.approx(20.0, abs=0.2)
