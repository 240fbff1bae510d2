"""MuJoCo world against the Pinocchio model; gravity compensation; applied-force bookkeeping."""

from __future__ import annotations

import numpy as np
import pytest

from app.sim.world import World
from app.tools.check import TOLERANCE, cross_check
from control.model import RobotModel
from control.params import ParamError, replaced


def test_pinocchio_and_mujoco_agree(robot):
    report = cross_check(robot, samples=100, seed=7)
    for key, err in report["worst_relative_error"].items():
        assert err < TOLERANCE, (key, err)


def test_gravity_compensation_holds_home_for_two_seconds(robot):
    world = World(robot)
    model = RobotModel(robot.model)
    world.reset(robot.home)
    for _ in range(2000):
        world.step(model.compute(world.q, world.dq).h)
    assert np.max(np.abs(world.q - robot.home)) < 1e-3


def test_applied_tcp_force_shows_in_sensor_wrench_and_joint_torque(rizon):
    world = World(rizon)
    model = RobotModel(rizon.model)
    p_tcp, _ = world.site_pose(world.tcp_site)
    p_sensor, _ = world.site_pose(world.sensor_site)
    force = np.array([1.0, -2.0, 20.0])
    world.apply_force(world.wrist_body, p_tcp, force)
    wrench = world.external_wrench_at_sensor()
    np.testing.assert_allclose(wrench[:3], force)
    np.testing.assert_allclose(wrench[3:], np.cross(p_tcp - p_sensor, force), atol=1e-12)
    J = model.compute(world.q, world.dq).J
    np.testing.assert_allclose(world.external_joint_torque(), J[:3].T @ force, atol=1e-10)


def test_torque_delay_applies_each_command_that_many_steps_later(rizon):
    world = World(rizon)
    world.set_params("world", replaced(world.params()["world"], "torque_delay_ms", 3.0))
    assert world.params()["world"].torque_delay_ms == 3.0
    commands = [np.full(7, float(k)) for k in range(10)]
    applied = []
    for tau in commands:
        world.step(tau)
        applied.append(world.tau_applied[0])
    # the first command is held until the 3-step pipeline has filled, then each arrives 3 steps late
    assert applied == [0.0, 0.0, 0.0, 0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0]
    world.reset(rizon.home)  # a reset empties the pipeline but keeps the setting
    world.step(np.full(7, 9.0))
    assert world.tau_applied[0] == 9.0 and world.torque_delay_steps == 3


def test_torque_delay_refuses_nonsense(rizon):
    world = World(rizon)
    for field, bad in (
        ("torque_delay_ms", -1.0),
        ("torque_delay_ms", float("nan")),
        ("torque_delay_ms", 1e9),
        ("torque_delay_ms", "5"),
        ("latency", 1.0),
    ):
        with pytest.raises(ParamError):
            world.set_params("world", replaced(world.params()["world"], field, bad))
    assert world.torque_delay_steps == 0


def test_armature_scale_changes_the_simulated_arm_only(rizon):
    world = World(rizon)
    nominal = world.model.dof_armature[world.dof_adr].copy()
    world.set_params("world", replaced(world.params()["world"], "armature_scale", 2.0))
    np.testing.assert_allclose(world.model.dof_armature[world.dof_adr], 2.0 * nominal, rtol=1e-12)
    np.testing.assert_allclose(rizon.armature, nominal, rtol=1e-12)  # the controller's model keeps the nominal


def test_site_point_state_is_the_site_pose_velocity_and_inverse_mass_in_one(rizon):
    """The contact's one-Jacobian read (`site_point_state`) against the three single-purpose reads,
    and its inverse mass against J_p M⁻¹ J_pᵀ from MuJoCo's dense M."""
    import mujoco

    world = World(rizon)
    rng = np.random.default_rng(3)
    q = 0.5 * (rizon.q_lower + rizon.q_upper) + 0.3 * rng.standard_normal(7)
    world.reset(q, rng.standard_normal(7))
    point, velocity, G = world.site_point_state(world.tcp_site, inverse_mass=True)
    assert G is not None
    np.testing.assert_array_equal(point, world.site_pose(world.tcp_site)[0])
    np.testing.assert_allclose(velocity, world.site_velocity(world.tcp_site)[:3], rtol=0, atol=1e-14)
    np.testing.assert_allclose(G, world.site_inverse_mass(world.tcp_site), rtol=1e-12, atol=0)
    nv = world.model.nv
    jacp, M = np.zeros((3, nv)), np.zeros((nv, nv))
    mujoco.mj_jacSite(world.model, world.data, jacp, None, world.tcp_site)
    mujoco.mj_fullM(world.model, world.data, M)
    np.testing.assert_allclose(G, jacp @ np.linalg.solve(M, jacp.T), rtol=1e-9, atol=1e-12)
    assert world.site_point_state(world.tcp_site)[2] is None  # the inverse mass only when asked


def test_compiled_torque_clip_equals_numpy_minimum_of_maximum_and_tracks_the_stop_depth():
    """`clip_torque_track_stops` gives np.minimum(np.maximum(τ, lower), upper) exactly, NaN kept as
    NaN, and raises the recent and peak stop depths to max(q − hi, lo − q) where that is deeper
    (an endless joint's ±inf stops never register)."""
    from app.sim.world import clip_torque_track_stops

    rng = np.random.default_rng(6)
    upper = rng.uniform(10, 80, 7)
    limits = np.array([-upper, upper])
    adr = np.array([0, 2, 3, 4, 6, 7, 8])  # the arm's joints among other qpos entries
    lo, hi = rng.uniform(-3, -2, 7), rng.uniform(2, 3, 7)
    lo[5], hi[5] = -np.inf, np.inf  # an endless joint
    stops = np.array([lo, hi, np.full(7, -np.inf), np.full(7, -np.inf)])
    recent, peak = np.full(7, -np.inf), np.full(7, -np.inf)
    for k in range(200):
        tau = rng.normal(0, 60, 7)
        tau[rng.integers(0, 7)] = rng.choice([np.nan, np.inf, -np.inf, 0.0])
        qpos = rng.uniform(-3.2, 3.2, 9)
        if k % 50 == 0:
            stops[2].fill(-np.inf)
            recent.fill(-np.inf)
        out = clip_torque_track_stops(tau, limits, qpos, adr, stops)
        np.testing.assert_array_equal(out, np.minimum(np.maximum(tau, -upper), upper))
        depth = np.maximum(qpos[adr] - hi, lo - qpos[adr])
        recent, peak = np.maximum(recent, depth), np.maximum(peak, depth)
        np.testing.assert_array_equal(stops[2], recent)
        np.testing.assert_array_equal(stops[3], peak)
    assert stops[3, 5] == -np.inf and np.all(np.isfinite(stops[3, [0, 1, 2, 3, 4, 6]]))


def test_body_ids_are_mujocos_looked_up_once_and_an_unknown_name_is_refused_by_name(rizon):
    """`World.body_ids` gives MuJoCo's ids of the named bodies, the same array on a second ask (the
    scene and the twin ask every frame), and a ValueError naming the first body the model lacks."""
    import mujoco

    world = World(rizon)
    names = tuple(rizon.link_names)
    ids = world.body_ids(names)
    assert ids.tolist() == [mujoco.mj_name2id(world.model, mujoco.mjtObj.mjOBJ_BODY, n) for n in names]
    assert world.body_ids(names) is ids
    with pytest.raises(ValueError, match="no body named 'no_such_link'"):
        world.body_ids((names[0], "no_such_link"))
