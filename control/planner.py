"""The globally planned nullspace path ([T] §IV-B names it as future work).

"For a given TCP trajectory, a globally optimal nullspace path can be planned offline on the
continuous nullspace surface." At each sample of the trajectory the self-motion of the 7-DOF
arm is a loop parametrised by the elbow swivel angle ψ (DESIGN §8); this module samples that
loop on a fixed swivel grid at every trajectory sample and finds, by dynamic programming, the
swivel path that minimises Σ cost(ψ_i, t_i)·Δt + rate penalty·Σ(Δψ/Δt)²·Δt with the joint
limits (grid points outside them are forbidden) and a maximum swivel rate as constraints.
The plan is executed by tracking the planned posture in the nullspace (W_j [T18] with a
moving q_d). Pure math over `control.coupling`'s swivel tools: numpy + pinocchio only.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from control.coupling import (
    POLISH_SUBSPACES,
    move_to_swivel,
    project_to_pose,
    swivel_scan,
    terms_of,
    within_limits_mod_2pi,
)
from control.model import RobotModel


def swivel_of_points(shoulder: np.ndarray, elbow: np.ndarray, wrist: np.ndarray) -> float:
    """Elbow swivel angle (rad) of shoulder, elbow and wrist points: the formula of
    `control.coupling.swivel_angle` (0 = elbow straight up, right-handed about shoulder→wrist).

    Written on Python floats: it runs every step for the status line, and numpy's helpers on
    3-vectors cost more in call overhead than the arithmetic."""
    s0, s1, s2 = float(shoulder[0]), float(shoulder[1]), float(shoulder[2])
    u0, u1, u2 = float(wrist[0]) - s0, float(wrist[1]) - s1, float(wrist[2]) - s2
    norm = math.sqrt(u0 * u0 + u1 * u1 + u2 * u2)
    u0, u1, u2 = u0 / norm, u1 / norm, u2 / norm
    r0, r1, r2 = -u2 * u0, -u2 * u1, 1.0 - u2 * u2  # world +z minus its component along u
    if math.sqrt(r0 * r0 + r1 * r1 + r2 * r2) < 1e-9:  # shoulder→wrist vertical: world +x instead
        r0, r1, r2 = 1.0 - u0 * u0, -u0 * u1, -u0 * u2
    norm = math.sqrt(r0 * r0 + r1 * r1 + r2 * r2)
    r0, r1, r2 = r0 / norm, r1 / norm, r2 / norm
    e0, e1, e2 = float(elbow[0]) - s0, float(elbow[1]) - s1, float(elbow[2]) - s2
    along = e0 * u0 + e1 * u1 + e2 * u2
    d0, d1, d2 = e0 - along * u0, e1 - along * u1, e2 - along * u2
    c0, c1, c2 = r1 * d2 - r2 * d1, r2 * d0 - r0 * d2, r0 * d1 - r1 * d0  # ref × d
    return math.atan2(u0 * c0 + u1 * c1 + u2 * c2, r0 * d0 + r1 * d1 + r2 * d2)


# ---- the self-motion loops along a trajectory -------------------------------------------------
class LoopGrid(NamedTuple):
    """Postures on a fixed swivel grid at each trajectory sample."""

    swivel_rad: np.ndarray  # (m,) grid, ascending in (−π, π]
    q: np.ndarray  # (k, m, n) posture at sample i with swivel grid[j] (NaN where not reached)
    feasible: np.ndarray  # (k, m) reached and inside the joint limits


def loops_along(
    model: RobotModel,
    q_start: np.ndarray,
    positions: np.ndarray,
    rotation: np.ndarray,
    q_lower: np.ndarray,
    q_upper: np.ndarray,
    grid_step_rad: float = np.deg2rad(4.0),
) -> LoopGrid:
    """Sample the self-motion loop of every TCP pose (positions (k, 3), one rotation) on a swivel grid.

    Sample 0 is traced with `swivel_scan` from q_start and moved onto each grid swivel
    (`move_to_swivel`); each later sample continues every grid posture of the previous one:
    pulled onto the new pose (`project_to_pose`) and back onto its swivel. A grid point whose
    Newton steps fail, or that leaves the joint limits, is infeasible there.
    """
    k = len(positions)
    grid = _grid(grid_step_rad)
    n = len(q_start)
    Q = np.full((k, len(grid), n), np.nan)
    ok = np.zeros((k, len(grid)), dtype=bool)
    q0 = project_to_pose(model, q_start, positions[0], rotation, iters=100)
    scan = swivel_scan(model, q0, POLISH_SUBSPACES, q_lower, q_upper, step_rad=grid_step_rad / 2)
    psi_scan = _wrap_array(scan.swivel_rad)
    for j, psi in enumerate(grid):
        near = int(np.argmin(np.abs(_wrap_array(psi_scan - psi))))
        Q[0, j], ok[0, j] = _on_swivel(model, scan.q[near], psi, positions[0], rotation, project=False)
    for i in range(1, k):
        for j, psi in enumerate(grid):
            if not ok[i - 1, j] and np.isnan(Q[i - 1, j, 0]):
                continue
            Q[i, j], ok[i, j] = _on_swivel(model, Q[i - 1, j], psi, positions[i], rotation, project=True)
    inside = np.all(within_limits_mod_2pi(np.nan_to_num(Q), q_lower, q_upper), axis=2)
    return LoopGrid(grid, wrap_into_limits(Q, q_lower, q_upper), ok & inside)


def wrap_into_limits(q: np.ndarray, q_lower: np.ndarray, q_upper: np.ndarray) -> np.ndarray:
    """Each joint angle moved by ±2π into [q_lower, q_upper] where that lands inside (the
    continuation of a self-motion loop may leave the interval while an equivalent angle is in it)."""
    out = np.array(q, dtype=float)
    two_pi = 2.0 * np.pi
    for shift in (two_pi, -two_pi):
        moved = out + shift
        use = ((out < q_lower) | (out > q_upper)) & (moved >= q_lower) & (moved <= q_upper)
        out = np.where(use, moved, out)
    return out


def _on_swivel(
    model: RobotModel, q: np.ndarray, psi: float, position: np.ndarray, rotation: np.ndarray, project: bool
) -> tuple[np.ndarray, bool]:
    try:
        q1 = project_to_pose(model, q, position, rotation, iters=50) if project else np.array(q, dtype=float)
        q1 = move_to_swivel(model, q1, float(psi), iters=60, tol_rad=1e-5)
    except ValueError:
        return np.full(len(q), np.nan), False
    pose = model.frame_pose(q1, "tcp")
    good = np.linalg.norm(pose.translation - position) < 1e-6 and np.linalg.norm(pose.rotation - rotation) < 1e-5
    return q1, bool(good)


def _grid(step_rad: float) -> np.ndarray:
    m = round(2 * np.pi / step_rad)
    return -np.pi + (np.arange(m) + 1) * (2 * np.pi / m)  # (−π, π], includes 0 when m is even


def _wrap_array(a: np.ndarray) -> np.ndarray:
    return (np.asarray(a, dtype=float) + np.pi) % (2 * np.pi) - np.pi


# ---- costs -----------------------------------------------------------------------------------
PLAN_COSTS = ("a", "d", "directional", "signed")


def cost_map(model: RobotModel, loops: LoopGrid, cost: str, friction_dirs: np.ndarray | None = None) -> np.ndarray:
    """(k, m) cost at every sample and grid posture (inf where infeasible).

    "a", "d": W_a, W_d = ‖P‖²_F [T22]; "directional": (P_d·f̂)² [T10] with f̂ (k, 2) the unit friction
    direction in world xy at each sample (zero rows: no sliding, cost 0); "signed": max(P_d·f̂, 0)²,
    the directional coupling only where its sign feeds the friction back into the force loop
    (P_d·f̂ > 0 raises the K_f^d the loop needs, `control.margin`; P_d·f̂ < 0 lowers it), each
    sample along its own stroke's friction direction.
    """
    if cost not in PLAN_COSTS:
        raise ValueError(f"unknown plan cost {cost!r}; choose one of {', '.join(PLAN_COSTS)}")
    k, m = loops.feasible.shape
    if cost in ("directional", "signed") and (friction_dirs is None or np.shape(friction_dirs) != (k, 2)):
        raise ValueError(f"the {cost} cost needs one friction direction per sample")
    out = np.full((k, m), np.inf)
    zeros = np.zeros(loops.q.shape[2])
    for i in range(k):
        for j in range(m):
            if not loops.feasible[i, j]:
                continue
            terms = terms_of(model.compute(loops.q[i, j], zeros), POLISH_SUBSPACES)
            if cost == "a":
                out[i, j] = float(np.sum(terms.P_a**2))
            elif cost == "d":
                out[i, j] = float(np.sum(terms.P_d**2))
            else:
                assert friction_dirs is not None
                p_d = float(terms.P_d[0, :2] @ friction_dirs[i])  # [T10] along f̂
                out[i, j] = p_d**2 if cost == "directional" else max(p_d, 0.0) ** 2
    return out


# ---- dynamic programming over the swivel grid ---------------------------------------------------
class Plan(NamedTuple):
    """A planned swivel path: the transfer at the start pose, then the trajectory samples."""

    t: np.ndarray  # (K,) s; < 0 during the transfer (t = 0: trajectory start)
    swivel_rad: np.ndarray  # (K,) planned swivel
    q: np.ndarray  # (K, n) planned posture
    cost: np.ndarray  # (K,) stage cost along the plan (0 during the transfer)
    total_cost: float  # Σ stage cost·Δt + rate penalty over the trajectory
    rate_max_rad_s: float
    transfer_s: float
    grid_rad: np.ndarray  # (m,) the swivel grid
    cost_map: np.ndarray  # (k, m) stage cost at the trajectory samples (inf: infeasible)


def plan_swivel_path(
    costs: np.ndarray,
    feasible: np.ndarray,
    grid: np.ndarray,
    dt: float,
    rate_max_rad_s: float,
    rate_weight: float,
    start_index: int | None = None,
    transfer_steps: int = 0,
) -> tuple[np.ndarray, float]:
    """Grid indices (transfer_steps + k,) of the path minimising Σ costs[i, j_i]·dt + rate_weight·
    Σ ((ψ_{i+1} − ψ_i)/dt)²·dt over the circle of swivels, with |Δψ| ≤ rate_max·dt and only
    feasible grid points. With `start_index` the path begins there and first spends
    `transfer_steps` steps at sample 0's loop at zero stage cost (the transfer during the settle
    phase), where the rate penalty is 1000× smaller: it only keeps the transfer smooth and does
    not decide where the trajectory part starts. Returns (indices, total cost); ValueError when
    no feasible path exists."""
    k, m = costs.shape
    step = float(grid[1] - grid[0])
    reach = int(np.floor(rate_max_rad_s * dt / step + 1e-9))
    shifts = np.arange(-reach, reach + 1)
    penalty = rate_weight * (shifts * step / dt) ** 2 * dt
    stage_cost = np.where(feasible, costs, np.inf) * dt
    rows = [np.where(feasible[0], 0.0, np.inf)] * transfer_steps + [stage_cost[i] for i in range(k)]
    V = np.full(m, np.inf)
    if start_index is None:
        V = rows[0].copy()
    else:
        if not feasible[0, start_index]:
            raise ValueError("the start posture is outside the joint limits")
        V[start_index] = rows[0][start_index]
    back = np.zeros((len(rows), m), dtype=int)
    for i in range(1, len(rows)):
        # candidate predecessors j − s for every shift s (circular)
        scale = 1e-3 if i <= transfer_steps else 1.0
        cand = np.stack([np.roll(V, s) + scale * p for s, p in zip(shifts, penalty, strict=True)])
        best = np.argmin(cand, axis=0)
        V = cand[best, np.arange(m)] + rows[i]
        back[i] = (np.arange(m) - shifts[best]) % m
    j = int(np.argmin(V))
    total = float(V[j])
    if not np.isfinite(total):
        raise ValueError("no feasible swivel path within the joint limits and the swivel-rate bound")
    path = [j]
    for i in range(len(rows) - 1, 0, -1):
        j = int(back[i, j])
        path.append(j)
    return np.array(path[::-1]), total


def plan(
    loops: LoopGrid,
    costs: np.ndarray,
    dt: float,
    start_swivel_rad: float,
    rate_max_rad_s: float = np.deg2rad(20.0),
    rate_weight: float | None = None,
    transfer_s: float | None = None,
) -> Plan:
    """The planned path from the start swivel through the trajectory samples (see module docstring).

    rate_weight defaults to 0.1·median(feasible cost)/rate_max² (the median of the positive costs
    where some are 0, e.g. the signed cost): moving at the maximum rate costs a tenth of a typical
    stage cost. transfer_s defaults to the time for half a turn at rate_max
    plus 1 s. The start swivel is rounded to the nearest grid point.
    """
    grid = loops.swivel_rad
    finite = costs[np.isfinite(costs)]
    if finite.size == 0:
        raise ValueError("no feasible posture along the trajectory")
    typical = float(np.median(finite[finite > 0])) if np.any(finite > 0) else 1.0
    w = rate_weight if rate_weight is not None else 0.1 * typical / rate_max_rad_s**2
    T_tr = transfer_s if transfer_s is not None else np.pi / rate_max_rad_s + 1.0
    n_tr = int(np.ceil(T_tr / dt))
    start = int(np.argmin(np.abs(_wrap_array(grid - start_swivel_rad))))
    idx, total = plan_swivel_path(costs, loops.feasible, grid, dt, rate_max_rad_s, w, start, n_tr)
    k = costs.shape[0]
    sample = np.r_[np.zeros(n_tr, dtype=int), np.arange(k)]
    t = np.r_[-(n_tr - np.arange(n_tr)) * dt, np.arange(k) * dt]
    q = loops.q[sample, idx]
    stage = np.r_[np.zeros(n_tr), costs[np.arange(k), idx[n_tr:]]]
    return Plan(t, grid[idx], q, stage, total, rate_max_rad_s, n_tr * dt, grid, costs)
