"""Disturbances applied at the TCP: the electric sander of [T] Fig. 5b.

An eccentric pad spinning at `rpm` exerts a force of constant magnitude rotating in the tool
plane (perpendicular to the tool axis): F(t) = a (cos ωt · x_tool + sin ωt · y_tool), ω = 2π rpm/60.
The amplitude a = m e ω² of the imbalance is set directly in newtons.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from app.sim.world import World
from control.params import ParamGroup, expect, param


@dataclass(frozen=True)
class SanderParams(ParamGroup):
    """The electric sander of [T] Fig. 5b."""

    title = "Sander"

    enabled: bool = param(True, label="Sander", help="eccentric rotating force on the tool", tag="[T] Fig. 5b")
    amplitude_n: float = param(
        10.0, label="Sander amplitude", unit="N", lo=0.0, hi=40.0, step=1.0, help="imbalance force"
    )
    rpm: float = param(7000.0, label="Sander speed", unit="RPM", lo=0.0, hi=10000.0, step=100.0, help="pad speed")


class Sander:
    """Rotating eccentric force at the TCP (default 7000 RPM)."""

    def __init__(self, amplitude_n: float = 10.0, rpm: float = 7000.0, enabled: bool = True):
        self.set_params("sander", SanderParams(enabled=enabled, amplitude_n=amplitude_n, rpm=rpm))

    def params(self) -> dict[str, SanderParams]:
        """Its one group, "sander"."""
        return {"sander": self._params}

    def set_params(self, name: str, group: SanderParams) -> None:
        """New switch / amplitude / speed (validated by `SanderParams`)."""
        self._params = p = expect(name, group, SanderParams if name == "sander" else None)
        self.enabled, self.amplitude_n, self.rpm = p.enabled, p.amplitude_n, p.rpm

    def force(self, t: float, tool_rotation_world: np.ndarray) -> np.ndarray:
        """Sander force (world, N) at time t for the tool orientation given."""
        if not self.enabled or self.amplitude_n == 0.0:
            return np.zeros(3)
        w = 2.0 * np.pi * self.rpm / 60.0
        x_tool, y_tool = tool_rotation_world[:, 0], tool_rotation_world[:, 1]
        return self.amplitude_n * (np.cos(w * t) * x_tool + np.sin(w * t) * y_tool)

    def apply(self, world: World, t: float) -> np.ndarray:
        """Apply the sander force at the TCP for this step; returns it."""
        if not self.enabled or self.amplitude_n == 0.0:
            return np.zeros(3)
        point, rot = world.site_pose(world.tcp_site)
        f = self.force(t, rot)
        if np.any(f):
            world.apply_force(world.wrist_body, point, f)
        return f
