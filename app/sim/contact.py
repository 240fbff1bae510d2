"""Table contact of [T] Fig. 4: one point at the TCP against a flat horizontal plane.

Normal force: a spring of stiffness k on the penetration depth, no damping,
F_n = k · max(0, z_table − z_tcp). Tangential force: Coulomb friction μ F_n against the TCP's
tangential velocity v_t, regularised near zero velocity as

    F_t = −μ F_n · v_t / √(‖v_t‖² + v_ε²),

which is smooth, odd in v_t, never exceeds μ F_n in magnitude, and equals Coulomb friction
(within 0.5 %) once ‖v_t‖ > 10 v_ε. Below v_ε it acts like a viscous damper of slope μF_n/v_ε;
v_ε is chosen so that this slope times the 1 ms step stays well below the TCP's effective mass
(explicit integration of a stiffer damper would chatter). Forces are applied at the TCP point
with `mj_applyFT` (through `World.apply_force`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from app.sim.world import World


@dataclass
class ContactState:
    """What the contact did this step (world frame)."""

    normal_force_n: float = 0.0
    friction_force: np.ndarray | None = None  # (3,) N
    point: np.ndarray | None = None  # (3,) m
    tangential_speed: float = 0.0  # m/s


class TableContact:
    """Point contact between the TCP and the plane z = height."""

    def __init__(
        self,
        height: float,
        stiffness_n_per_m: float = 30000.0,
        mu: float = 0.25,
        v_eps_m_per_s: float = 0.01,
    ):
        self.height = float(height)
        self.stiffness_n_per_m = 0.0
        self.mu = 0.0
        self.v_eps_m_per_s = 1.0
        self.configure(stiffness_n_per_m=stiffness_n_per_m, mu=mu, v_eps_m_per_s=v_eps_m_per_s)
        self.state = ContactState(friction_force=np.zeros(3), point=np.zeros(3))

    def configure(self, **changes: object) -> None:
        """Set stiffness_n_per_m, mu or v_eps_m_per_s; ValueError on negative/NaN values."""
        for key, value in changes.items():
            if key not in ("stiffness_n_per_m", "mu", "v_eps_m_per_s", "height"):
                raise ValueError(f"table contact has no setting {key!r}")
            x = float(value)  # type: ignore[arg-type]
            if not np.isfinite(x) or (x < 0 and key != "height") or (key == "v_eps_m_per_s" and x <= 0):
                raise ValueError(f"table contact {key} must be a finite non-negative number, got {value!r}")
            setattr(self, key, x)

    def forces(self, point: np.ndarray, velocity: np.ndarray) -> tuple[float, np.ndarray]:
        """(F_n, friction force (3,)) at a TCP position and linear velocity."""
        depth = self.height - float(point[2])
        if depth <= 0.0:
            return 0.0, np.zeros(3)
        f_n = self.stiffness_n_per_m * depth
        v_t = np.array([velocity[0], velocity[1], 0.0])
        speed2 = float(v_t @ v_t)
        friction = -self.mu * f_n * v_t / np.sqrt(speed2 + self.v_eps_m_per_s**2)
        return f_n, friction

    def apply(self, world: World) -> ContactState:
        """Apply this step's contact force on the body carrying the TCP."""
        point, _ = world.site_pose(world.tcp_site)
        velocity = world.site_velocity(world.tcp_site)[:3]
        f_n, friction = self.forces(point, velocity)
        if f_n > 0.0:
            force = friction + np.array([0.0, 0.0, f_n])
            world.apply_force(world.wrist_body, point, force)
        speed = float(np.hypot(velocity[0], velocity[1]))
        self.state = ContactState(f_n, friction, point, speed)
        return self.state
