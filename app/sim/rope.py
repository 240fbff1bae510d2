"""A rope between two points: a one-sided spring-damper, stiff when taut, slack otherwise.

tension T = max(0, k·s + c·ṡ) when the stretch s = |p_anchor − p_end| − L is positive, else 0;
the force on the rope's end is T·û (û the unit vector from the end to the anchor), the force on
the anchor is its opposite. The max(0, ·) keeps the damper from pushing while the rope unloads:
a rope can only pull. Both forces are applied with `mj_applyFT` (through `World.apply_force`),
so they are equal and opposite by construction and the F/T sensor sees the anchor side.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Rope:
    """Rest length L (m), axial stiffness k (N/m) and damping c (N s/m) of a rope."""

    length_m: float
    stiffness_n_per_m: float
    damping_n_s_per_m: float

    def __post_init__(self) -> None:
        for name in ("length_m", "stiffness_n_per_m"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and np.isfinite(value) and value > 0):
                raise ValueError(f"rope {name} must be a positive number, got {value!r}")
        c = self.damping_n_s_per_m
        if not (isinstance(c, int | float) and np.isfinite(c) and c >= 0):
            raise ValueError(f"rope damping_n_s_per_m must be a non-negative number, got {c!r}")

    def tension(self, stretch_m: float, stretch_rate_m_per_s: float) -> float:
        """T = max(0, k s + c ṡ) for s > 0, 0 when slack (s ≤ 0)."""
        if stretch_m <= 0.0:
            return 0.0
        return max(0.0, self.stiffness_n_per_m * stretch_m + self.damping_n_s_per_m * stretch_rate_m_per_s)

    def force_on_end(
        self, anchor: np.ndarray, anchor_velocity: np.ndarray, end: np.ndarray, end_velocity: np.ndarray
    ) -> tuple[np.ndarray, float]:
        """(force on the rope's free end, world axes, N; stretch in m) for the two endpoints' states."""
        d = np.asarray(anchor, dtype=float) - np.asarray(end, dtype=float)
        dist = float(np.linalg.norm(d))
        stretch = dist - self.length_m
        if stretch <= 0.0 or dist == 0.0:
            return np.zeros(3), stretch
        u = d / dist
        rate = float(u @ (np.asarray(anchor_velocity, dtype=float) - np.asarray(end_velocity, dtype=float)))
        return self.tension(stretch, rate) * u, stretch

    def potential_energy(self, stretch_m: float) -> float:
        """Elastic energy ½ k s² stored when taut (0 when slack)."""
        return 0.5 * self.stiffness_n_per_m * max(stretch_m, 0.0) ** 2
