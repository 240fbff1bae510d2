"""Disturbances applied at the TCP: the electric sander of [T] Fig. 5b.

An eccentric pad spinning at `rpm` exerts a force of constant magnitude rotating in the tool
plane (perpendicular to the tool axis): F(t) = a (cos ωt · x_tool + sin ωt · y_tool), ω = 2π rpm/60.
The amplitude a = m e ω² of the imbalance is set directly in newtons.
"""

from __future__ import annotations

import numpy as np

from app.sim.world import World


class Sander:
    """Rotating eccentric force at the TCP (default 7000 RPM)."""

    def __init__(self, amplitude_n: float = 10.0, rpm: float = 7000.0, enabled: bool = True):
        self.amplitude_n = 0.0
        self.rpm = 0.0
        self.enabled = bool(enabled)
        self.configure(amplitude_n=amplitude_n, rpm=rpm)

    def configure(self, **changes: object) -> None:
        """Set amplitude_n, rpm or enabled; ValueError on negative or non-finite values."""
        for key, value in changes.items():
            if key == "enabled":
                self.enabled = bool(value)
                continue
            if key not in ("amplitude_n", "rpm"):
                raise ValueError(f"sander has no setting {key!r}")
            x = float(value)  # type: ignore[arg-type]
            if not np.isfinite(x) or x < 0:
                raise ValueError(f"sander {key} must be a finite non-negative number, got {value!r}")
            setattr(self, key, x)

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
