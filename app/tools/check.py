"""Cross-check of the controller model (Pinocchio) against the simulation (MuJoCo).

Both are built from the same URDF and sidecar, so they must agree to rounding error on the
joint inertia M, the bias forces C q̇ + g, the TCP pose and the TCP Jacobian. The tolerance is
1e-8 relative: measured disagreement is ~1e-15, so anything above 1e-8 is a modelling bug
(a lost armature, a fused frame, a wrong axis), not floating-point noise.
"""

from __future__ import annotations

import numpy as np

from app.sim.world import World
from control.model import RobotModel
from robots import RobotDescription

TOLERANCE = 1e-8


def _rel(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.max(np.abs(a - b)) / max(1.0, float(np.max(np.abs(b)))))


def cross_check(robot: RobotDescription, samples: int = 100, seed: int = 0) -> dict:
    """Worst relative errors between Pinocchio and MuJoCo over random (q, q̇)."""
    world = World(robot)
    model = RobotModel(robot.model)
    rng = np.random.default_rng(seed)
    lo = np.where(robot.endless, -np.pi, robot.q_lower)
    hi = np.where(robot.endless, np.pi, robot.q_upper)
    worst = {"M": 0.0, "bias": 0.0, "tcp_position": 0.0, "tcp_rotation": 0.0, "jacobian": 0.0}
    for _ in range(samples):
        q = rng.uniform(lo, hi)
        dq = rng.uniform(-robot.dq_max, robot.dq_max)
        world.set_state(q, dq)
        dyn = model.compute(q, dq)
        p_mj, R_mj = world.site_pose(world.tcp_site)
        errors = {
            "M": _rel(world.mass_matrix(), dyn.M),
            "bias": _rel(world.bias_forces(), dyn.h),
            "tcp_position": _rel(p_mj, dyn.tcp_position_world),
            "tcp_rotation": _rel(R_mj, dyn.tcp_rotation_world),
            "jacobian": _rel(world.tcp_jacobian(), dyn.J),
        }
        for key, value in errors.items():
            worst[key] = max(worst[key], value)
    return {
        "robot": robot.name,
        "samples": samples,
        "tolerance": TOLERANCE,
        "worst_relative_error": worst,
        "ok": all(v <= TOLERANCE for v in worst.values()),
    }
