"""Mouse-drag spring, as in MuJoCo's viewer: pulls a grabbed point of a link toward a target.

F = m_eff (k d − c v), with d = target − point, v the point's velocity, and
m_eff = 1 / (âᵀ J_p M⁻¹ J_pᵀ â) the effective mass at the grabbed point along â = d/|d|, so the
spring feels equally stiff on a heavy shoulder and a light wrist. |F| is clamped to a maximum.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from app.sim.world import World
from control.params import ParamGroup, expect, param


@dataclass(frozen=True)
class DragParams(ParamGroup):
    """The mouse-drag spring's tunables."""

    title = "Mouse drag"

    max_force_n: float = param(
        150.0,
        label="Drag force limit",
        unit="N",
        lo=1.0,
        hi=300.0,
        step=5.0,
        help="the spring force is clamped to this",
    )
    stiffness_per_s2: float = param(
        400.0,
        label="Drag stiffness",
        unit="1/s²",
        lo=10.0,
        hi=2000.0,
        step=10.0,
        help="k, times the effective mass at the point",
    )
    damping_ratio: float = param(1.0, label="Drag damping ratio", lo=0.1, hi=3.0, step=0.1, help="c = 2ζ√k")


@dataclass
class DragState:
    """What the overlays need: the grabbed point, its target and the applied force (world)."""

    body_id: int
    point_world: np.ndarray
    target_world: np.ndarray
    force_world: np.ndarray


class DragSpring:
    """A spring from a point fixed on a body to a target point, applied every simulation step."""

    def __init__(self, stiffness_per_s2: float = 400.0, damping_ratio: float = 1.0, max_force_n: float = 150.0):
        self.set_params(
            "drag", DragParams(max_force_n=max_force_n, stiffness_per_s2=stiffness_per_s2, damping_ratio=damping_ratio)
        )
        self.body_id: int | None = None
        self.point_body = np.zeros(3)
        self.target_world = np.zeros(3)
        self.state: DragState | None = None

    def params(self) -> dict[str, DragParams]:
        """Its one group, "drag"."""
        return {"drag": self._params}

    def set_params(self, name: str, group: DragParams) -> None:
        """New force limit / stiffness / damping (validated by `DragParams`)."""
        self._params = p = expect(name, group, DragParams if name == "drag" else None)
        self.max_force_n, self.stiffness_per_s2, self.damping_ratio = p.max_force_n, p.stiffness_per_s2, p.damping_ratio

    @property
    def active(self) -> bool:
        return self.body_id is not None

    def grab(self, world: World, body_id: int, point_world: np.ndarray) -> None:
        """Start dragging `body_id` at a world point; the point is remembered in the body frame."""
        R = world.data.xmat[body_id].reshape(3, 3)
        self.point_body = R.T @ (np.asarray(point_world, dtype=float) - world.data.xpos[body_id])
        self.body_id = int(body_id)
        self.target_world = np.asarray(point_world, dtype=float).copy()

    def move(self, target_world: np.ndarray) -> None:
        """Set where the grabbed point is pulled to."""
        target = np.asarray(target_world, dtype=float)
        if target.shape == (3,) and np.all(np.isfinite(target)):
            self.target_world = target.copy()

    def release(self) -> None:
        """Stop pulling."""
        self.body_id = None
        self.state = None

    def point_world(self, world: World) -> np.ndarray:
        """Current world position of the grabbed point."""
        assert self.body_id is not None
        R = world.data.xmat[self.body_id].reshape(3, 3)
        return world.data.xpos[self.body_id] + R @ self.point_body

    def apply(self, world: World) -> np.ndarray:
        """Apply this step's spring force to the world; returns the force (zero when released)."""
        if self.body_id is None:
            return np.zeros(3)
        body = self.body_id
        p = self.point_world(world)
        d = self.target_world - p
        jacp = np.zeros((3, world.model.nv))
        mujoco.mj_jac(world.model, world.data, jacp, None, p, body)
        v = jacp @ world.data.qvel
        dist = float(np.linalg.norm(d))
        direction = d / dist if dist > 1e-9 else np.array([0.0, 0.0, 1.0])
        row = direction @ jacp  # âᵀ J_p
        minv_row = np.zeros(world.model.nv)
        mujoco.mj_solveM(world.model, world.data, minv_row.reshape(1, -1), row.reshape(1, -1))
        inv_mass = float(row @ minv_row)
        m_eff = 1.0 / max(inv_mass, 1e-6)
        k = self.stiffness_per_s2
        c = 2.0 * self.damping_ratio * np.sqrt(k)
        force = m_eff * (k * d - c * v)
        norm = float(np.linalg.norm(force))
        if norm > self.max_force_n:
            force *= self.max_force_n / norm
        world.apply_force(body, p, force)
        self.state = DragState(body, p, self.target_world.copy(), force)
        return force
