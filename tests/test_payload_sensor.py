"""The wrist F/T sensor feels what it carries: a payload accelerated by the simulated arm reads
m(g − a) and its moment, checked against the interaction force MuJoCo computes for the payload's
attachment (its own `<force>`/`<torque>` sensors, from the RNE backward pass `cfrc_int`)."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

import robots
from app.scenarios.payload import PAYLOAD_BODY, PayloadEnvironment, add_payload_body
from app.sim.world import World
from control.model import RobotModel

MASS_KG = 1.25


def _world_with_payload_sensors() -> World:
    robot = robots.load("gen3")

    def customize(spec: mujoco.MjSpec) -> None:
        add_payload_body(spec, robot, MASS_KG)
        body = next(b for b in spec.bodies if b.name == PAYLOAD_BODY)
        body.add_site(name="payload_joint", pos=[0.0, 0.0, 0.0])
        spec.add_sensor(name="payload_f", type=mujoco.mjtSensor.mjSENS_FORCE, objtype=mujoco.mjtObj.mjOBJ_SITE,
                        objname="payload_joint")  # fmt: skip
        spec.add_sensor(name="payload_t", type=mujoco.mjtSensor.mjSENS_TORQUE, objtype=mujoco.mjtObj.mjOBJ_SITE,
                        objname="payload_joint")  # fmt: skip

    world = World(robot, customize=customize)
    world.reset(np.array(robot.postures["mass_drop_nominal"]))
    return world


def _mujoco_reading_at_sensor(world: World) -> np.ndarray:
    """The payload's push on the flange from MuJoCo's force/torque sensors (evaluated at the
    current state by mj_sensorAcc), moved to the F/T sensor origin in world axes (MuJoCo reports
    the parent's action on the child in the site frame)."""
    mujoco.mj_sensorAcc(world.model, world.data)
    site = world.model.site("payload_joint").id
    rot = world.data.site_xmat[site].reshape(3, 3)
    f_child = rot @ world.data.sensor("payload_f").data
    t_child = rot @ world.data.sensor("payload_t").data
    f, t = -f_child, -t_child
    r = world.data.site_xpos[site] - world.data.site_xpos[world.sensor_site]
    return np.concatenate([f, t + np.cross(r, f)])


def test_sensor_at_rest_reads_the_payload_weight_and_its_moment():
    world = _world_with_payload_sensors()
    env = PayloadEnvironment(world, MASS_KG)
    model = RobotModel(world.robot.model)
    for _ in range(3):
        env.apply(world, world.time)
        world.step(model.compute(world.q, world.dq).h + _payload_gravity_torque(world))
    env.apply(world, world.time)
    reading = world.external_wrench_at_sensor()
    np.testing.assert_allclose(reading[:3], [0.0, 0.0, -MASS_KG * 9.81], atol=0.05)
    np.testing.assert_allclose(reading, _mujoco_reading_at_sensor(world), atol=1e-6)


def _payload_gravity_torque(world: World) -> np.ndarray:
    jacp = np.zeros((3, world.model.nv))
    body = world.model.body(PAYLOAD_BODY).id
    mujoco.mj_jac(world.model, world.data, jacp, None, world.data.xipos[body], body)
    return (jacp.T @ np.array([0.0, 0.0, MASS_KG * 9.81]))[world.dof_adr]


def test_sensor_of_a_payload_shaken_by_the_arm_matches_mujocos_reaction_force():
    """Joint torques that swing the wrist hard (several m/s² at the payload): the sensor's reading
    equals MuJoCo's interaction force of the payload with the flange to 1e-6 N / N m at every step,
    and differs from the weight alone by the inertial force m·a (so the test can fail)."""
    world = _world_with_payload_sensors()
    env = PayloadEnvironment(world, MASS_KG)
    model = RobotModel(world.robot.model)
    rng = np.random.default_rng(3)
    amp = np.array([6.0, 6.0, 3.0, 6.0, 1.5, 1.5, 1.5])
    phase = rng.uniform(0, 2 * np.pi, 7)
    worst = 0.0
    inertial = []
    for k in range(400):
        t = world.time
        env.apply(world, t)
        if k > 0:
            reading = world.external_wrench_at_sensor()
            worst = max(worst, float(np.max(np.abs(reading - _mujoco_reading_at_sensor(world)))))
            inertial.append(np.linalg.norm(reading[:3] - np.array([0.0, 0.0, -MASS_KG * 9.81])))
        h = model.compute(world.q, world.dq).h + _payload_gravity_torque(world)
        world.step(h + amp * np.sin(2 * np.pi * 3.0 * t + phase))
    assert worst < 1e-6
    assert max(inertial) > 2.0  # N: the payload really was accelerated (> 1.6 m/s²)


def test_released_payload_leaves_the_sensor():
    world = _world_with_payload_sensors()
    env = PayloadEnvironment(world, MASS_KG, release_time_s=0.002)
    model = RobotModel(world.robot.model)
    for _ in range(5):
        env.apply(world, world.time)
        world.step(model.compute(world.q, world.dq).h)
    env.apply(world, world.time)
    assert not world.carried
    np.testing.assert_allclose(world.external_wrench_at_sensor(), np.zeros(6), atol=1e-12)


@pytest.mark.parametrize("bad", [0.0, -1.0])
def test_payload_mass_must_be_positive(bad):
    robot = robots.load("gen3")
    with pytest.raises(ValueError, match="payload mass"):
        World(robot, customize=lambda spec: add_payload_body(spec, robot, bad))


def test_payload_centre_of_mass_sits_at_the_tcp():
    world = _world_with_payload_sensors()
    body = world.model.body(PAYLOAD_BODY).id
    np.testing.assert_allclose(world.data.xipos[body], world.site_pose(world.tcp_site)[0], atol=1e-12)
    assert world.model.body_mass[body] == pytest.approx(MASS_KG)
