"""Table contact of [T] Fig. 4: one point at the TCP against a flat horizontal plane.

Normal force: a spring of stiffness k on the penetration depth, no damping,
F_n = k · max(0, z_table − z_tcp). Tangential force: Coulomb friction μ F_n against the TCP's
tangential velocity v_t, regularised near zero velocity as

    F_t = −μ F_n · v_t / √(‖v_t‖² + v_ε²) = −c(v_t) v_t,   c = μ F_n / √(‖v_t‖² + v_ε²),

which is smooth, odd in v_t, never exceeds μ F_n in magnitude, and equals Coulomb friction
(within 0.5 %) once ‖v_t‖ > 10 v_ε. Below v_ε it acts like a viscous damper of slope μF_n/v_ε.

Integration. Stepped explicitly, that damper is stable only while c·Δt/m < 2 (m the TCP's
tangential mass): with m = 1.4–2.9 kg at the polish postures, μF_n = 20 N and Δt = 1 ms this
fails below v_ε ≈ 7 mm/s. So the friction is integrated implicitly: with the damping
coefficient c frozen at the step's start (the secant of the law) and G = J_t M⁻¹ J_tᵀ the
tangential inverse mass of the TCP point, the applied force is the backward-Euler one,

    F_t = −c (I + Δt c G)⁻¹ v_t,

so that friction alone maps v_t to (I + Δt c G)⁻¹ v_t: eigenvalues in (0, 1] for every c ≥ 0,
i.e. stable and never reversing the sliding direction for any v_ε, and ‖F_t‖ ≤ c‖v_t‖ ≤ μF_n.
The other forces of the step (controller, gravity) are not in the implicit solve, so a steady
tangential push P creeps at P/c + Δt·G·P instead of P/c (at most Δt·G·μF_n ≈ 14 mm/s
at the lightest tangential mass and μF_n = 20 N, reached only when the push nears μF_n).
Forces are applied at the TCP point with `mj_applyFT` (through `World.apply_force`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from app.sim.world import World
from control.params import ParamGroup, expect, param


@dataclass(frozen=True)
class ContactParams(ParamGroup):
    """The table contact's tunables (see the module docstring)."""

    title = "Table contact"

    mu: float = param(
        0.25,
        label="Friction μ",
        lo=0.0,
        hi=1.5,
        step=0.05,
        help="Coulomb friction of the table, F_t = μ F_n",
        tag="[T] Fig. 4",
    )
    stiffness_n_per_m: float = param(
        30000.0,
        label="Contact stiffness",
        unit="N/m",
        lo=5000.0,
        hi=60000.0,
        step=1000.0,
        help="normal spring of the table (no damping)",
        tag="[T] Fig. 4",
    )
    # the implicit friction step is stable for any v_ε > 0; 1 mm/s is the smallest the tests cover
    v_eps_m_per_s: float = param(
        0.01, label="Friction v_ε", unit="m/s", lo=0.001, hi=0.1, step=0.001, help="friction smoothing speed"
    )


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
        implicit: bool = True,
    ):
        self.height = float(height)
        self.implicit = bool(implicit)  # False: the explicit law (kept to show why it is not used)
        # the spring acts on the TCP position this many steps old: 0, the position at the step's start
        # (`apply` reads the current `site_xpos`); a run records it with its contact settings
        self.spring_lag_steps = 0
        self.set_params(
            "contact", ContactParams(mu=mu, stiffness_n_per_m=stiffness_n_per_m, v_eps_m_per_s=v_eps_m_per_s)
        )
        self.state = ContactState(friction_force=np.zeros(3), point=np.zeros(3))

    def params(self) -> dict[str, ContactParams]:
        """Its one group, "contact"."""
        return {"contact": self._params}

    def set_params(self, name: str, group: ContactParams) -> None:
        """New friction / stiffness / smoothing (validated by `ContactParams`)."""
        self._params = p = expect(name, group, ContactParams if name == "contact" else None)
        self.mu, self.stiffness_n_per_m, self.v_eps_m_per_s = p.mu, p.stiffness_n_per_m, p.v_eps_m_per_s

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

    def implicit_forces(
        self, point: np.ndarray, velocity: np.ndarray, inverse_mass: np.ndarray, dt: float
    ) -> tuple[float, np.ndarray]:
        """(F_n, friction (3,)) of one backward-Euler step of the friction (module docstring):
        F_t = −c (I + Δt c G)⁻¹ v_t with G the (3, 3) inverse mass of the TCP point (its
        tangential 2×2 block is used) and Δt the step."""
        depth = self.height - float(point[2])
        if depth <= 0.0:
            return 0.0, np.zeros(3)
        f_n = self.stiffness_n_per_m * depth
        friction = np.zeros(3)
        friction[:2] = implicit_friction(self.mu * f_n, velocity[:2], self.v_eps_m_per_s, inverse_mass[:2, :2], dt)
        return f_n, friction

    def apply(self, world: World) -> ContactState:
        """Apply this step's contact force on the body carrying the TCP (implicit friction)."""
        data, site = world.data, world.tcp_site
        depth = self.height - float(data.site_xpos[site, 2])
        implicit = depth > 0.0 and self.implicit
        jacp, x = world.site_point_jacobian(site, solve=implicit)
        f_n, fx, fy, speed = contact_step(
            depth, jacp, data.qvel, _NO_SOLVE if x is None else x, implicit, self.stiffness_n_per_m, self.mu,
            self.v_eps_m_per_s, world.model.opt.timestep,
        )  # fmt: skip
        point = data.site_xpos[site].copy()
        if f_n > 0.0:
            world.apply_force(world.wrist_body, point, np.array([fx, fy, f_n]), copy=False)  # fresh arrays
        self.state = ContactState(f_n, np.array([fx, fy, 0.0]), point, speed)
        return self.state


def implicit_friction(
    coulomb_n: float, v_t: np.ndarray, v_eps: float, inverse_mass: np.ndarray, dt: float
) -> np.ndarray:
    """Backward-Euler friction force (2,) = −c (I + Δt c G)⁻¹ v_t, c = μF_n / √(‖v_t‖² + v_ε²).

    `coulomb_n` is μF_n, `inverse_mass` the (2, 2) tangential inverse mass G of the contact
    point (symmetric positive definite), `dt` the step. With G = 0 this is the explicit law.
    """
    # Python floats throughout: the same IEEE operations as the compiled step on every CPU (a numpy
    # dot product may fuse multiply-adds where the CPU has FMA, and then differs in the last bit)
    v0, v1 = np.asarray(v_t, dtype=float).tolist()
    c = coulomb_n / math.sqrt((v0 * v0 + v1 * v1) + v_eps * v_eps)
    s = dt * c
    (g00, g01), (g10, g11) = np.asarray(inverse_mass, dtype=float).tolist()
    a, b, cc, d = 1.0 + g00 * s, g01 * s, g10 * s, 1.0 + g11 * s  # I + Δt c G, solved in closed form
    det = a * d - b * cc
    k = -c / det
    return np.array([k * (d * v0 - b * v1), k * (a * v1 - cc * v0)])


def implicit_contact_reference(depth, velocity, inverse_mass, stiffness, mu, v_eps, dt) -> tuple:
    """`implicit_contact` by `implicit_friction`: (F_n, F_t x, F_t y) with F_n = k·depth and the
    backward-Euler friction of μF_n."""
    f_n = stiffness * depth
    fx, fy = implicit_friction(mu * f_n, velocity, v_eps, inverse_mass, dt)
    return f_n, float(fx), float(fy)


@njit(cache=True)
def implicit_contact(depth, velocity, inverse_mass, stiffness, mu, v_eps, dt):
    """Compiled `TableContact.implicit_forces` at a penetration depth > 0: (F_n, F_t x, F_t y), the
    arithmetic of `implicit_friction` term by term."""
    f_n = stiffness * depth
    v0, v1 = velocity[0], velocity[1]
    c = (mu * f_n) / np.sqrt((v0 * v0 + v1 * v1) + v_eps * v_eps)
    s = dt * c
    a, b = 1.0 + inverse_mass[0, 0] * s, inverse_mass[0, 1] * s
    cc, d = inverse_mass[1, 0] * s, 1.0 + inverse_mass[1, 1] * s
    k = -c / (a * d - b * cc)
    return f_n, k * (d * v0 - b * v1), k * (a * v1 - cc * v0)


def contact_step_reference(depth, jacp, qvel, solved, implicit, stiffness, mu, v_eps, dt) -> tuple:
    """`contact_step` in numpy: v = J_p q̇, G = J_p (M⁻¹ J_pᵀ)ᵀ (tangential block, only with
    `implicit`, else 0) and `implicit_contact_reference` at a positive depth; (F_n, F_t x, F_t y, ‖v_t‖)."""
    v = jacp[:2] @ qvel
    speed = float(np.sqrt(v @ v))
    if not depth > 0.0:
        return 0.0, 0.0, 0.0, speed
    G = jacp[:2] @ solved[:2].T if implicit else np.zeros((2, 2))
    return (*implicit_contact_reference(depth, v, G, stiffness, mu, v_eps, dt), speed)


_NO_SOLVE = np.zeros((3, 1))  # no M⁻¹ J_pᵀ: out of contact, or the explicit law


@njit(cache=True)
def contact_step(depth, jacp, qvel, solved, implicit, stiffness, mu, v_eps, dt):
    """One step of `TableContact.apply` from the site's translational Jacobian J_p and q̇: the point's
    velocity v = J_p q̇, with `implicit` its tangential inverse mass G = J_p M⁻¹ J_pᵀ from `solved`
    (M⁻¹ J_pᵀ as rows), and `implicit_contact` at a positive depth (G = 0 without `implicit`: the
    explicit law). Returns (F_n, F_t x, F_t y, tangential speed ‖v_t‖)."""
    nv = jacp.shape[1]
    v0 = 0.0
    v1 = 0.0
    for k in range(nv):
        v0 += jacp[0, k] * qvel[k]
        v1 += jacp[1, k] * qvel[k]
    speed = np.sqrt(v0 * v0 + v1 * v1)
    if not depth > 0.0:
        return 0.0, 0.0, 0.0, speed
    G = np.zeros((2, 2))
    if implicit:
        for i in range(2):
            for j in range(2):
                s = 0.0
                for k in range(nv):
                    s += jacp[i, k] * solved[j, k]
                G[i, j] = s
    velocity = np.empty(2)
    velocity[0], velocity[1] = v0, v1
    f_n, fx, fy = implicit_contact(depth, velocity, G, stiffness, mu, v_eps, dt)
    return f_n, fx, fy, speed
