"""The polish preset's target over time: the zig-zag with 20 N along +z (`PolishTarget`) and the
planned nullspace path over it (`control.planner`), cached per robot, start, cost and armature."""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from app.scenarios.polish_stroke import (
    CONTACT_TIME_S,
    DESIRED_FORCE_N,
    N_SEGMENTS,
    SEGMENT_DURATION_S,
    START_XY_M,
    TABLE_HEIGHT_M,
    TOOL_DOWN,
    PhaseClock,
    friction_direction,
    min_jerk,
    segment_waypoints,
    trajectory_duration,
    trajectory_state,
)
from control.coupling import move_to_swivel, project_to_pose
from control.executor import TaskTarget, float_array
from control.kernels.records import RecordBlocks, target_record, target_record_dtype
from control.model import RobotModel
from control.planner import Plan, cost_map, loops_along
from control.planner import plan as make_plan
from robots import RobotDescription

# ---- the planned nullspace path (control.planner) --------------------------------------------------
PLAN_SAMPLE_S = 0.5  # trajectory samples of the plan: 31 over the 15 s zig-zag
PLAN_GRID_DEG = 4.0  # swivel grid of the plan: 90 postures per self-motion loop
PLAN_RATE_MAX_DEG_S = 20.0  # swivel-rate bound: the W_j flow (k0_j = 1/s) follows it within a few degrees
_PLAN_CACHE: dict[tuple, Plan] = {}


def ik_seed(robot: RobotDescription) -> np.ndarray:
    """Where the start pose's IK begins: the robot's `polish_start` posture if its sidecar names one,
    else its home posture."""
    return np.array(robot.postures.get("polish_start", robot.home), dtype=float)


def plan_key(robot: RobotDescription, start_swivel_deg: float, cost: str, armature_scale: float) -> tuple:
    return (robot.spec or robot.name, round(start_swivel_deg, 6), cost, armature_scale, PLAN_SAMPLE_S, PLAN_GRID_DEG)


def compute_plan(robot: RobotDescription, start_swivel_deg: float, cost: str, model: RobotModel | None = None) -> Plan:
    """The swivel path planned over the zig-zag from a start swivel, with a cost of PLAN_COSTS (no
    cache; picklable arguments, so that it can run in another process). `model` is
    `RobotModel(robot.model)`, built here when not given."""
    model = RobotModel(robot.model) if model is None else model
    p0, R0 = np.array([*START_XY_M, TABLE_HEIGHT_M]), TOOL_DOWN.copy()
    q0 = move_to_swivel(model, project_to_pose(model, ik_seed(robot), p0, R0, iters=200), np.deg2rad(start_swivel_deg))
    times = np.arange(0.0, trajectory_duration() + 1e-9, PLAN_SAMPLE_S)
    positions = np.array([[*trajectory_state(t)[0], TABLE_HEIGHT_M] for t in times])
    loops = loops_along(model, q0, positions, R0, robot.q_lower, robot.q_upper, np.deg2rad(PLAN_GRID_DEG))
    dirs = np.array([friction_direction(t) for t in times])
    costs = cost_map(model, loops, cost, dirs)
    return make_plan(
        loops, costs, PLAN_SAMPLE_S, np.deg2rad(start_swivel_deg), rate_max_rad_s=np.deg2rad(PLAN_RATE_MAX_DEG_S)
    )


def plan_cached(key: tuple) -> bool:
    """True when the plan of this key (`plan_key`) is in the cache."""
    return key in _PLAN_CACHE


def store_plan(key: tuple, plan: Plan) -> None:
    """Cache a plan computed elsewhere under its key (`PolishScenario.pending_work`)."""
    _PLAN_CACHE[key] = plan


def planned_path(
    robot: RobotDescription, model: RobotModel, start_swivel_deg: float, cost: str, armature_scale: float = 1.0
) -> Plan:
    """The swivel path planned over the zig-zag (cached per robot, start, cost and armature); `model`
    is `RobotModel(robot.model)`."""
    key = plan_key(robot, start_swivel_deg, cost, armature_scale)
    if key not in _PLAN_CACHE:
        _PLAN_CACHE[key] = compute_plan(robot, start_swivel_deg, cost, model)
    return _PLAN_CACHE[key]


class PolishTarget:
    """TaskTarget as a function of time: the zig-zag of Fig. 7 with 20 N along +z.

    Its inputs (start, rotation, posture, the plan's postures) are checked here, once, as the
    executors' type (`control.executor.float_array`); each step's target is built from them by
    arithmetic that keeps that type, into a target record taken from a block (`RecordBlocks`), so it
    takes `TaskTarget.of_record` (no check per step). Each record starts as the held target (the
    start, the rotation, zero velocity and acceleration, the wrench), so a step writes only the XY
    parts the zig-zag moves, and nothing while it holds. The arrays it builds from are checked again
    whenever one is assigned (`_CHECKED`), after construction too, and the held target follows; the
    start, rotation and wrench are held read-only (a change is an assignment)."""

    # the arrays each step's target is built from, and their shapes (None: a non-empty vector)
    _CHECKED: ClassVar[dict[str, tuple[int, ...] | None]] = {
        "start": (3,), "rotation": (3, 3), "q_posture": None, "wrench": (6,),
    }  # fmt: skip
    corners: np.ndarray  # (N_SEGMENTS + 1, 2) the zig-zag's corners, from the start
    _legs: list[list[float]]  # each segment's [start x, start y, length x, length y]

    def __init__(
        self,
        start_position: np.ndarray,
        rotation: np.ndarray,
        q_posture: np.ndarray,
        clock: PhaseClock,
        plan: Plan | None = None,
        plan_lead_s: float = 0.0,
    ):
        self.start = float_array("PolishTarget", "start_position", start_position, (3,))  # named as the argument
        self.rotation = rotation
        self.q_posture = q_posture
        self.clock = clock
        if plan is not None:
            n = self.q_posture.shape[0]
            float_array("PolishTarget", "plan.q", plan.q, (plan.t.shape[0], n))
            float_array("PolishTarget", "plan.t", plan.t, None)
        self.plan = plan
        self.plan_lead_s = float(plan_lead_s)
        self.wrench = np.array([0.0, 0.0, DESIRED_FORCE_N, 0.0, 0.0, 0.0])
        self._records = RecordBlocks(target_record_dtype(), template=self._held())

    def _held(self) -> np.ndarray:
        """The held target's record: the start, the rotation, no motion, the wrench."""
        return target_record(self.start, self.rotation, np.zeros(6), np.zeros(6), self.wrench)

    def __setattr__(self, name: str, value: object) -> None:
        shape = self._CHECKED.get(name, ())
        if shape != ():
            value = float_array("PolishTarget", name, value, shape)
            if name != "q_posture":  # read-only copies: an edit in place, which the held target would miss, fails
                value = value.copy()
                value.flags.writeable = False
        object.__setattr__(self, name, value)
        if name == "start":  # the zig-zag's corners start from it
            corners = segment_waypoints((float(self.start[0]), float(self.start[1])))
            object.__setattr__(self, "corners", corners)
            object.__setattr__(self, "_legs", np.hstack([corners[:-1], np.diff(corners, axis=0)]).tolist())
        if shape != () and name != "q_posture" and "_records" in self.__dict__:
            self._records.refill(self._held())  # the targets from now on start from the new values

    def __call__(self, t: float) -> TaskTarget:
        """The target at time t."""
        k, tau = self.clock.segment(t)
        record, fields, at = self._records.take()
        if k > N_SEGMENTS:
            fields["position"][at, :2] = self.corners[-1]
        elif k > 0:  # in floats: on two numbers numpy's arithmetic costs more than it saves
            ax, ay, lx, ly = self._legs[k - 1]
            T = SEGMENT_DURATION_S
            s_p, s_v, s_a = min_jerk(tau / T)
            s_v, s_a = s_v / T, s_a / (T * T)
            pos, vel, acc = fields["position"], fields["velocity"], fields["acceleration"]
            pos[at, 0], pos[at, 1] = ax + s_p * lx, ay + s_p * ly
            vel[at, 0], vel[at, 1] = s_v * lx, s_v * ly
            acc[at, 0], acc[at, 1] = s_a * lx, s_a * ly
        q_d = self.q_posture if self.plan is None else self.planned_posture(t)
        return TaskTarget.of_record(record, q_d, fields, at)  # checked in __init__

    def plan_time(self, t: float) -> float:
        """Time on the plan's clock at t: −transfer at the settle start, 0 at the trajectory start."""
        assert self.plan is not None
        if self.clock.trajectory_start is not None and t >= self.clock.trajectory_start:
            return t - self.clock.trajectory_start
        return min(t - CONTACT_TIME_S - self.plan.transfer_s, 0.0)

    def planned_posture(self, t: float) -> np.ndarray:
        """The planned posture at t: the transfer during the settle phase, held at its end until the
        trajectory starts, then the trajectory part (linear between plan samples)."""
        assert self.plan is not None
        pt = self.plan.t
        s = self.plan_time(t) + self.plan_lead_s  # lead by the W_j lag 1/k0_j
        if self.clock.trajectory_start is None or t < self.clock.trajectory_start:
            s = min(s, 0.0)  # hold the plan's start until the trajectory starts
        s = min(max(s, pt[0]), pt[-1])
        i = min(int(np.searchsorted(pt, s, side="right")) - 1, len(pt) - 2)
        w = (s - pt[i]) / (pt[i + 1] - pt[i])
        return (1.0 - w) * self.plan.q[i] + w * self.plan.q[i + 1]

    def planned_swivel_deg(self, t: float) -> float:
        """The planned swivel at t (deg), for the plots; NaN without a plan."""
        if self.plan is None:
            return float("nan")
        psi = np.unwrap(self.plan.swivel_rad)
        return float(np.rad2deg(np.interp(self.plan_time(t), self.plan.t, psi)))
