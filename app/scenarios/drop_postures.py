"""Where a payload at the TCP drives the arm, and the limit-drop and mass-drop starts of an arm whose
sidecar names none (a foreign URDF): documented searches, not choices.

- The load of a point mass m at the TCP: τ = J_v(q)ᵀ (0, 0, −m g), J_v the TCP's linear Jacobian (its
  weight mapped to the joints; the controller does not know it, so this is what makes a joint fall).
- The limit drop [C] §IV-B: joint 4 (Γ₀ = e₄) falls under that load into a position limit. A start
  fits when the load's torque on joint 4 points toward the limit over the whole fall (FALL_SAMPLES
  postures from the start to the limit) and the TCP stays above the floor; the fall is FALL_RAD (the
  Gen3 L-shape's 1.0 rad, 1.5708 → 2.57 rad) or half the joint's range if that is less. The search:
  joint 2 over SHOULDER_STEPS values and joint 3 at 0 and ±π/2, joint 4 FALL_RAD from either limit,
  every other joint at home moved at least the dampers' influence distance d_i inside its limits; the
  start whose weakest torque toward the limit along the fall is largest wins.
- The mass drop [C] §IV-D: the TCP tool down in front of the base, half the arm's size forward of the
  shoulder at shoulder height (the Gen3's nominal TCP is 0.51 m forward of the base and 0.15 m above
  its shoulder, the Panda's 0.36 m and 0.15 m), by `reach.search_posture`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from app.scenarios import reach
from control.gains import DamperGains
from control.model import RobotModel
from robots import RobotDescription

GRAVITY_M_S2 = 9.81
FALLING_JOINT = 3  # joint 4 (0-based index 3), the elbow of a 7-DOF arm, as in [C] §IV-B
FALL_RAD = 1.0  # the Gen3 L-shape's distance to its limit
FALL_SAMPLES = 21
SHOULDER_STEPS = 25
FLOOR_CLEARANCE_M = 0.05  # the TCP stays this far above the floor over the fall
TOOL_DOWN = np.diag([-1.0, 1.0, -1.0])  # tool z along −world z (app/scenarios/polish.py TOOL_DOWN)


def payload_torque(model: RobotModel, q: np.ndarray, mass_kg: float) -> np.ndarray:
    """Joint torques of a point mass `mass_kg` at the TCP: J_v(q)ᵀ (0, 0, −m g)."""
    J = model.tcp_jacobian(np.asarray(q, dtype=float))
    return -mass_kg * GRAVITY_M_S2 * J[2, :].copy()


@dataclass(frozen=True)
class Fall:
    """Where joint `joint` falls from a start: `direction` +1 toward its upper limit, −1 toward its
    lower one; `limit` that limit (rad); `torque` the load's torque toward it along the way (N m,
    from the start to the limit)."""

    joint: int
    direction: int
    limit: float
    torque: np.ndarray

    @property
    def reaches_limit(self) -> bool:
        """The load pushes toward the limit over the whole way (no rest before it)."""
        return bool(np.all(self.torque > 0))


def fall_from(robot: RobotDescription, model: RobotModel, q0: np.ndarray, mass_kg: float, joint: int) -> Fall:
    """The fall of `joint` from `q0` under `mass_kg` at the TCP: toward the limit its load's torque
    points to at q0 (the upper one when it is zero), with that torque along the way."""
    q0 = np.asarray(q0, dtype=float)
    direction = 1 if payload_torque(model, q0, mass_kg)[joint] >= 0 else -1
    limit = float(robot.q_upper[joint] if direction > 0 else robot.q_lower[joint])
    torque = []
    for qj in np.linspace(q0[joint], limit, FALL_SAMPLES):
        q = q0.copy()
        q[joint] = qj
        torque.append(direction * payload_torque(model, q, mass_kg)[joint])
    return Fall(joint, direction, limit, np.array(torque))


def _inside_dampers(robot: RobotDescription, q: np.ndarray) -> np.ndarray:
    """q moved at least the dampers' influence distance d_i inside every limit."""
    d_i = DamperGains().influence_fraction * (robot.q_upper - robot.q_lower)
    return np.clip(q, robot.q_lower + d_i, robot.q_upper - d_i)


def _tcp_above_floor(model: RobotModel, q0: np.ndarray, fall: Fall) -> bool:
    for qj in np.linspace(q0[fall.joint], fall.limit, FALL_SAMPLES):
        q = q0.copy()
        q[fall.joint] = qj
        if model.frame_pose(q, "tcp").translation[2] < FLOOR_CLEARANCE_M:
            return False
    return True


def limit_drop_start(robot: RobotDescription, mass_kg: float, joint: int = FALLING_JOINT) -> tuple[np.ndarray, Fall]:
    """The limit-drop start of the search in the module docstring and its fall; ValueError when no
    start has the load pushing joint `joint` into a limit all the way."""
    model = RobotModel(robot.model)
    base = _inside_dampers(robot, robot.home)
    span = robot.q_upper - robot.q_lower
    d_i = DamperGains().influence_fraction * span
    shoulder = np.linspace(robot.q_lower[1] + d_i[1], robot.q_upper[1] - d_i[1], SHOULDER_STEPS)
    twists = [t for t in (0.0, np.pi / 2, -np.pi / 2) if robot.q_lower[2] + d_i[2] <= t <= robot.q_upper[2] - d_i[2]]
    drop = min(FALL_RAD, 0.5 * float(span[joint]))
    best: tuple[float, np.ndarray, Fall] | None = None
    for q2 in shoulder:
        for q3 in twists or [float(base[2])]:
            for start in (robot.q_lower[joint] + drop, robot.q_upper[joint] - drop):
                q = base.copy()
                q[1], q[2], q[joint] = q2, q3, start
                fall = fall_from(robot, model, q, mass_kg, joint)
                # the start must fall the full `drop` (toward the limit it is `drop` from, not the far one)
                if abs(fall.limit - start) > drop + 1e-9 or not fall.reaches_limit:
                    continue
                if not _tcp_above_floor(model, q, fall):
                    continue
                weakest = float(np.min(fall.torque))
                if best is None or weakest > best[0]:
                    best = (weakest, q, fall)
    if best is None:
        raise ValueError(
            f"{robot.name}: no posture found where a {mass_kg:g} kg load at the TCP pushes joint {joint + 1} into"
            " a limit all the way; give the limit drop's start as posture `l_shape` in the sidecar"
        )
    return best[1], best[2]


def guess_posture(
    robot: RobotDescription, posture: str, guessed_as: str, find: Callable[[], tuple[np.ndarray, str]]
) -> None:
    """For an arm without sidecar postures that lacks `posture`: `find()` gives the posture and, in
    words, how it was found; the posture is stored under its name and the words among the robot's
    guessed values as `guessed_as` (the page and the reports name them). Nothing for an arm whose
    sidecar gives it."""
    if "postures" not in robot.guessed or posture in robot.postures:
        return
    q, how = find()
    robot.postures[posture] = q
    robot.guessed[guessed_as] = how


def arm_size(robot: RobotDescription) -> float:
    """Sum of the distances between the joints from joint 2 to the TCP (m)."""
    model = robot.model
    length = sum(float(np.linalg.norm(model.jointPlacements[j].translation)) for j in range(2, model.njoints))
    return length + float(np.linalg.norm(model.frames[model.getFrameId("tcp")].placement.translation))


def mass_drop_target(robot: RobotDescription) -> np.ndarray:
    """The mass drop's TCP position: half the arm's size forward (+x) of the shoulder, at its height."""
    model = RobotModel(robot.model)
    shoulder = model.joint_origins(robot.home)[2]  # joint 2's origin: the shoulder
    return np.array([0.5 * arm_size(robot), 0.0, float(shoulder[2])])


def mass_drop_start(robot: RobotDescription) -> np.ndarray:
    """The mass drop's start: the TCP tool down at `mass_drop_target`, elbow up (swivel 0), inside the
    limits (`reach.search_posture` from the home posture); ValueError when it is out of reach."""
    model = RobotModel(robot.model)
    target = mass_drop_target(robot)
    q = reach.search_posture(model, robot, target, TOOL_DOWN, 0.0, robot.home)
    if q is None:
        raise ValueError(
            f"{robot.name} reaches no posture with the TCP tool down at ({target[0]:.2f}, 0, {target[2]:.2f}) m"
            " inside its limits; give the mass drop's start as posture `mass_drop_nominal` in the sidecar"
        )
    return q
