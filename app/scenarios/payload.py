"""A payload carried at the TCP, present in the simulation and absent from the controller model.

Physics: the payload is a rigid body fixed to the last link (so its mass and inertia act on the
arm in MuJoCo), with MuJoCo's gravity compensation on that body switched on and its weight
applied instead as an explicit external force at its centre of mass every step. The arm feels
exactly the same as with MuJoCo gravity, but the weight now goes through `World.apply_force`, so
the F/T sensor (the payload hangs distal to it) and the oracle see it. The payload is registered
as carried by the sensor (`World.carried`), so the sensor also feels its inertia: in total it reads
m(g − a) at the payload's COM and the moment of that force about the sensor, plus −(I α + ω × I ω)
(`World.inertial_wrench_at_sensor`). The oracle τ̂_e sees the applied weight only.

Release: at the release time the payload's mass and inertia are set to zero in the compiled
model and its weight is no longer applied — for the arm this is the same as a gripper letting
go (the mass leaves with no force on the arm). Each new environment restores the payload.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from app.scenarios import Environment
from app.sim.world import World, _body_of_joint
from control.params import ParamGroup, expect, param
from robots import TCP_FRAME, RobotDescription

PAYLOAD_BODY = "payload"
PAYLOAD_RADIUS_M = 0.04
GRAVITY = 9.81


@dataclass(frozen=True)
class PayloadParams(ParamGroup):
    """The simulated payload (the controller model does not know it: its mass is a model error)."""

    title = "Payload"

    mass_kg: float = param(
        1.25,
        label="Payload mass",
        unit="kg",
        lo=0.0,
        hi=3.0,
        step=0.05,
        help="simulated mass at the tool",
        tag="[C] §IV",
    )


def add_payload_body(
    spec: mujoco.MjSpec, robot: RobotDescription, mass_kg: float, radius_m: float = PAYLOAD_RADIUS_M
) -> None:
    """Add the payload body at the TCP site of the last link (solid sphere inertia)."""
    if not mass_kg > 0:
        raise ValueError(f"payload mass must be positive, got {mass_kg!r}")
    last = _body_of_joint(spec, robot.joint_names[-1])
    tcp = next(s for s in spec.sites if s.name == TCP_FRAME)
    inertia = 0.4 * mass_kg * radius_m**2
    body = last.add_body(name=PAYLOAD_BODY, pos=list(tcp.pos), mass=mass_kg, inertia=[inertia] * 3, gravcomp=1.0)
    set_inertial_at_origin(body)


def set_inertial_at_origin(body: mujoco.MjsBody) -> None:
    """Put a body's centre of mass at its origin with its given inertia. MjSpec leaves `ipos`
    unset (NaN) when only mass and inertia are given, and the compiler then places the COM
    elsewhere (6 cm off the TCP for the payload); the explicit inertial frame fixes it."""
    body.ipos = [0.0, 0.0, 0.0]
    body.iquat = [1.0, 0.0, 0.0, 0.0]
    body.explicitinertial = True


class PayloadEnvironment(Environment):
    """Applies the payload weight each step until `release_time_s` (None: never released)."""

    def __init__(self, world: World, mass_kg: float, release_time_s: float | None = None):
        self.world = world
        self.body_id = int(world.model.body(PAYLOAD_BODY).id)
        self.mass_kg = float(mass_kg)
        self.inertia = np.full(3, 0.4 * mass_kg * PAYLOAD_RADIUS_M**2)
        self.release_time_s = release_time_s
        self.attach()

    def attach(self) -> None:
        """Put the payload (back) on the arm."""
        self.world.model.body_mass[self.body_id] = self.mass_kg
        self.world.model.body_inertia[self.body_id] = self.inertia
        self.world.carried.add(self.body_id)
        self.attached = True

    def release(self) -> None:
        """Let go of the payload."""
        self.world.model.body_mass[self.body_id] = 0.0
        self.world.model.body_inertia[self.body_id] = 0.0
        self.world.carried.discard(self.body_id)
        self.attached = False

    def params(self) -> dict[str, ParamGroup]:
        """Its one group, "payload" (the simulated mass; the controller model never includes it)."""
        return {"payload": PayloadParams(mass_kg=self.mass_kg)}

    def set_params(self, name: str, group: PayloadParams) -> None:
        """A new simulated payload mass (solid-sphere inertia), in force at once while attached."""
        p = expect(name, group, PayloadParams if name == "payload" else None)
        self.mass_kg = p.mass_kg
        self.inertia = np.full(3, 0.4 * p.mass_kg * PAYLOAD_RADIUS_M**2)
        if self.attached:
            self.attach()

    def apply(self, world: World, t: float) -> dict[str, float]:
        """Apply the weight at the payload's centre of mass (world frame) while attached."""
        if self.attached and self.release_time_s is not None and t >= self.release_time_s - 1e-12:
            self.release()
        if self.attached:
            com = world.data.xipos[self.body_id].copy()
            world.apply_force(self.body_id, com, np.array([0.0, 0.0, -self.mass_kg * GRAVITY]))
        return {"payload_attached": float(self.attached)}
