"""A posture at a TCP pose inside the joint limits, for an arm without the sidecar posture that
would seed it (a foreign URDF): a documented search, not a choice.

The search: IK (`control.coupling.project_to_pose`, damped Gauss-Newton) from each seed in turn —
the given seed (the sidecar's or home posture), the middle of the joint ranges, then 12 postures
drawn uniformly inside the limits with a fixed seed (so every run finds the same one) — each
solution moved along its self-motion loop to the wanted swivel (`move_to_swivel`) and kept when it
reaches the pose within `POSE_TOL` and every joint is inside its limits (an angle may move by ±2π).
Of the kept postures the one with the largest smallest distance to a joint limit wins.
"""

from __future__ import annotations

import numpy as np

from control.coupling import move_to_swivel, project_to_pose
from control.model import RobotModel
from robots import RobotDescription

POSE_TOL = 1e-6  # m and rad: what counts as reaching the pose
RANDOM_SEEDS = 12
SEARCH_SEED = 0


def limit_margin(robot: RobotDescription, q: np.ndarray) -> float:
    """Smallest distance (rad) from a limited joint to its nearest limit (inf if none is limited)."""
    limited = ~robot.endless
    if not np.any(limited):
        return float("inf")
    return float(np.min(np.minimum(q - robot.q_lower, robot.q_upper - q)[limited]))


def inside(robot: RobotDescription, q: np.ndarray) -> bool:
    """Every limited joint inside its limits."""
    limited = ~robot.endless
    return bool(np.all((q[limited] >= robot.q_lower[limited]) & (q[limited] <= robot.q_upper[limited])))


def _into_limits(robot: RobotDescription, q: np.ndarray) -> np.ndarray:
    """Each angle moved by ±2π into its limits where that helps (the same posture); endless ones into (−π, π]."""
    out = q.copy()
    for j in range(len(q)):
        if robot.endless[j]:
            out[j] = (out[j] + np.pi) % (2 * np.pi) - np.pi
            continue
        for shifted in (q[j], q[j] - 2 * np.pi, q[j] + 2 * np.pi):
            if robot.q_lower[j] <= shifted <= robot.q_upper[j]:
                out[j] = shifted
                break
    return out


def _pose_error(model: RobotModel, q: np.ndarray, position: np.ndarray, rotation: np.ndarray) -> float:
    pose = model.frame_pose(q, "tcp")
    return max(float(np.max(np.abs(pose.translation - position))), float(np.max(np.abs(pose.rotation - rotation))))


def search_posture(
    model: RobotModel,
    robot: RobotDescription,
    position: np.ndarray,
    rotation: np.ndarray,
    swivel_rad: float,
    seed_q: np.ndarray,
) -> np.ndarray | None:
    """The posture of the search described above, or None when no seed reaches the pose inside the limits."""
    rng = np.random.default_rng(SEARCH_SEED)
    seeds = [np.asarray(seed_q, dtype=float), 0.5 * (robot.q_lower + robot.q_upper)]
    seeds += list(rng.uniform(robot.q_lower, robot.q_upper, size=(RANDOM_SEEDS, robot.nq)))
    best, best_margin = None, -np.inf
    for seed in seeds:
        q = project_to_pose(model, seed, position, rotation, iters=200)
        if _pose_error(model, q, position, rotation) > POSE_TOL:
            continue  # this seed's IK did not reach the pose: no swivel to look for
        try:
            q = _into_limits(robot, move_to_swivel(model, q, swivel_rad))
        except ValueError:  # the swivel is not reached from this seed
            continue
        pose = model.frame_pose(q, "tcp")
        err = max(float(np.max(np.abs(pose.translation - position))), float(np.max(np.abs(pose.rotation - rotation))))
        if err > POSE_TOL or not inside(robot, q):
            continue
        margin = limit_margin(robot, q)
        if margin > best_margin:
            best, best_margin = q, margin
    return best
