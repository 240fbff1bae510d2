"""The rope of the mass drop: slack gives no force, taut gives the spring-damper force, it never
pushes, and energy does not grow over bounces; in the scenario it pulls TCP and mass equally."""

from __future__ import annotations

import itertools

import mujoco
import numpy as np
import pytest

from app.headless.experiments.c_common import qp_session
from app.scenarios.mass_drop import RELEASE_TIME_S, MassDropParams, MassDropScenario
from app.sim.rope import Rope

ROPE = Rope(length_m=0.2, stiffness_n_per_m=800.0, damping_n_s_per_m=4.0)


def test_slack_rope_gives_zero_force():
    anchor = np.zeros(3)
    for end in ([0.0, 0.0, -0.1], [0.12, -0.1, -0.05], [0.0, 0.0, -0.2]):
        force, stretch = ROPE.force_on_end(anchor, np.zeros(3), np.array(end), np.array([0.0, 0.0, -3.0]))
        assert stretch <= 0.0
        np.testing.assert_array_equal(force, np.zeros(3))


def test_taut_rope_gives_the_spring_damper_force_along_the_rope():
    anchor = np.array([0.1, 0.0, 1.0])
    direction = np.array([0.6, 0.0, 0.8])  # unit, from the end towards the anchor
    end = anchor - 0.23 * direction  # stretch 0.03 m
    end_velocity = -0.5 * direction + np.array([0.0, 0.7, 0.0])  # moving away at 0.5 m/s, plus sideways
    force, stretch = ROPE.force_on_end(anchor, np.zeros(3), end, end_velocity)
    assert stretch == pytest.approx(0.03)
    expected = (800.0 * 0.03 + 4.0 * 0.5) * direction
    np.testing.assert_allclose(force, expected, rtol=1e-12)


def test_unloading_rope_never_pushes():
    # taut by 1 mm but shortening fast: k s + c ṡ = 0.8 − 8 < 0, so the tension is zero, not negative
    assert ROPE.tension(1e-3, -2.0) == 0.0
    assert ROPE.tension(1e-3, 0.0) == pytest.approx(0.8)


@pytest.mark.parametrize("bad", [{"length_m": 0.0}, {"stiffness_n_per_m": -1.0}, {"damping_n_s_per_m": float("nan")}])
def test_rope_refuses_nonsense(bad):
    values = {"length_m": 0.2, "stiffness_n_per_m": 800.0, "damping_n_s_per_m": 4.0, **bad}
    with pytest.raises(ValueError, match="rope"):
        Rope(**values)


def _bounce_energies(rope: Rope, seconds: float = 3.0, dt: float = 1e-3) -> tuple[list[float], float]:
    """A 1.25 kg free body dropped from a fixed anchor, stepped by MuJoCo with the rope force
    applied by mj_applyFT; the mechanical energy at each taut→slack transition, and at the start."""
    spec = mujoco.MjSpec()
    spec.option.timestep = dt
    body = spec.worldbody.add_body(name="m", pos=[0.0, 0.0, 0.0], mass=1.25, inertia=[6e-4] * 3)
    body.add_freejoint()
    model = spec.compile()
    data = mujoco.MjData(model)
    data.qvel[0] = 0.3  # a little sideways swing, so the rope's direction changes
    mujoco.mj_forward(model, data)
    g = 9.81

    def energy() -> float:
        _, stretch = rope.force_on_end(np.zeros(3), np.zeros(3), data.qpos[:3], data.qvel[:3])
        return (
            0.5 * 1.25 * float(data.qvel[:3] @ data.qvel[:3]) + 1.25 * g * data.qpos[2] + rope.potential_energy(stretch)
        )

    e0 = energy()
    out = []
    was_taut = False
    for _ in range(round(seconds / dt)):
        data.qfrc_applied[:] = 0.0
        force, stretch = rope.force_on_end(np.zeros(3), np.zeros(3), data.qpos[:3].copy(), data.qvel[:3].copy())
        mujoco.mj_applyFT(model, data, force, np.zeros(3), data.qpos[:3].copy(), 1, data.qfrc_applied)
        if was_taut and stretch <= 0.0:
            out.append(energy())
        was_taut = stretch > 0.0
        mujoco.mj_step(model, data)
    return out, e0


def test_undamped_rope_keeps_the_energy_over_bounces():
    """Without damping the energy after each bounce stays at the start's within the stepping error.
    Semi-implicit Euler keeps energy within O(ω Δt) of the peak spring energy (ω = 25 rad/s here)
    without drift; at Δt = 0.2 ms that is ≈ 0.3 % of the 2.45 J fall, so allow 0.5 % (12 mJ)."""
    energies, e0 = _bounce_energies(Rope(0.2, 800.0, 0.0), dt=2e-4)
    assert len(energies) >= 3
    scale = 1.25 * 9.81 * 0.2
    assert max(energies) <= e0 + 5e-3 * scale
    assert min(energies) >= e0 - 5e-3 * scale  # and nothing lost either: the rope is elastic


def test_damped_rope_loses_energy_at_every_bounce():
    energies, e0 = _bounce_energies(Rope(0.2, 800.0, 4.0))
    assert len(energies) >= 3
    assert energies[0] < e0
    assert all(b < a for a, b in itertools.pairwise(energies))


def test_released_mass_falls_freely_then_the_rope_pulls_tcp_and_mass_equally():
    params = MassDropParams(rope_length_m=0.05)
    scenario = MassDropScenario("position", params=params)
    session = qp_session(scenario, seed=0)
    session.reset()
    session.run(RELEASE_TIME_S)
    fall = np.sqrt(2 * params.drop_height / 9.81)  # s of free fall before the rope goes taut
    first_taut = None
    for _ in range(300):
        rec = session.step()
        if rec.signals["rope_tension_n"] > 0 and first_taut is None:
            first_taut = rec.t - RELEASE_TIME_S
            applied = session.world.applied  # cleared by the step; check the pair on the next one
        if first_taut is not None and rec.t - RELEASE_TIME_S > first_taut + 0.02:
            break
    assert first_taut == pytest.approx(fall, abs=3e-3)
    env = session.environment
    world = session.world
    env.apply(world, world.time)
    applied = [a for a in world.applied if a.body_id in (env.body_id, world.wrist_body)]
    assert len(applied) == 2
    np.testing.assert_allclose(applied[0].force_world, -applied[1].force_world)
    assert np.linalg.norm(applied[0].force_world) > params.mass_kg * 9.81  # catching: above the weight
    # the F/T sensor carries the TCP side of the rope (pulled down)
    assert world.external_wrench_at_sensor()[2] < -params.mass_kg * 9.81


def test_rig_parameters_are_set_through_the_session_and_apply_at_reset():
    from app.core.session import Session
    from control.params import ParamError

    session = Session("mass-drop")
    session.set_param("scenario", "rope_stiffness_n_per_m", 800.0)
    session.set_param("scenario", "payload_mass_error", 0.1)
    session.reset()
    env = session.environment
    assert env.rope.stiffness_n_per_m == 800.0
    assert session.world.model.body_mass[env.body_id] == pytest.approx(1.25 * 1.1)
    with pytest.raises(ParamError, match="drop_height_m"):
        session.set_param("scenario", "drop_height_m", 0.2)  # more than twice the 5 cm rope
    assert session.params()["scenario"].drop_height_m == pytest.approx(0.05)  # refused: unchanged
