"""The MuJoCo world: the arm from the same URDF as the controller model, torque motors, a floor,
an optional table, and sites for the TCP and the F/T sensor.

MuJoCo's own contacts are disabled: the table contact of [T] Fig. 4 is a point spring applied
by `app.sim.contact` with `mj_applyFT`, and drag forces, sanders and payload forces are applied
the same way. Every external force applied during a step is recorded so the F/T sensor model can
compute the true wrench at the flange.

So MuJoCo gets no link geometry at all: the URDF's visual and collision elements are dropped
before import (`simulation_urdf`), which spares it the meshes' cost (a real arm's visual meshes
are megabytes, in formats MuJoCo does not read) and their `package://` names; masses come from
the URDF's inertials only, as in Pinocchio. The page draws the visual meshes itself
(app.live.ui.scene). Joints outside the arm's chain (fingers, a second arm) are removed from the
spec with their bodies welded at the locked position (`lock_joint`), as Pinocchio's reduced model
has them.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import mujoco
import numpy as np
import pinocchio as pin
from numba import njit

from control.params import ParamGroup, expect, param
from robots import SENSOR_FRAME, TCP_FRAME, RobotDescription

TIMESTEP_S = 1e-3
MAX_TORQUE_DELAY_MS = 20.0  # actuator latency the simulation accepts (torque loop, bus, filters)
HARD_STOP_BEYOND_RAD = 0.01  # the mechanical stop sits this far beyond the URDF (software) limit
# Stops as stiff as MuJoCo stays stable with: a critically damped reference with the shortest time
# constant it recommends (2 timesteps) and an impedance of 0.99 within 1 mrad, so that the largest
# drag (300 N) sinks a joint less than HARD_STOP_GIVE_RAD into its stop (tested on every preset).
HARD_STOP_SOLREF = (2 * TIMESTEP_S, 1.0)  # (time constant s, damping ratio)
HARD_STOP_SOLIMP = (0.95, 0.99, 0.001, 0.5, 2.0)  # (d_min, d_max, width rad, midpoint, power)
HARD_STOP_GIVE_RAD = 0.02


def _contiguous(index: np.ndarray) -> slice | np.ndarray:
    """A slice equal to an ascending run of indices (a cheaper copy than fancy indexing), else the index."""
    if len(index) and np.array_equal(index, np.arange(index[0], index[0] + len(index))):
        return slice(int(index[0]), int(index[0]) + len(index))
    return index


_BAD_STATE_WARNINGS = tuple(  # MuJoCo resets such a state and counts the warning; we halt instead
    int(w)
    for w in (mujoco.mjtWarning.mjWARN_BADQPOS, mujoco.mjtWarning.mjWARN_BADQVEL, mujoco.mjtWarning.mjWARN_BADQACC)
)
_BAD_QPOS, _BAD_QVEL, _BAD_QACC = _BAD_STATE_WARNINGS


@dataclass(frozen=True)
class WorldParams(ParamGroup):
    """The simulation's own tunables: actuator latency and the simulated arm's armature."""

    title = "Simulation"

    torque_delay_ms: float = param(
        0.0,
        label="Torque delay",
        unit="ms",
        lo=0.0,
        hi=MAX_TORQUE_DELAY_MS,
        step=1.0,
        help="actuation delay: the joints get each torque this late (rounded to whole 1 ms steps). "
        "Default 0: the one period a sampled loop needs end to end sits on the F/T reading "
        "(sensor.reading_delay_steps); a drive that latches its command on the next bus cycle adds "
        "1 ms here, and neither paper states its command path's delay; a few ms make a high λ ring",
    )
    armature_scale: float = param(
        1.0,
        label="Armature × (simulated)",
        lo=0.25,
        hi=4.0,
        step=0.05,
        help="the simulated arm's rotor armature times this; the controller model keeps the nominal "
        "(a model error on purpose, DESIGN §4)",
    )


@dataclass
class AppliedForce:
    """An external force applied at a world point on a body during the current step."""

    body_id: int
    point_world: np.ndarray
    force_world: np.ndarray
    torque_world: np.ndarray


def simulation_urdf(urdf_text: str) -> str:
    """The URDF without its links' visual and collision elements (what MuJoCo imports)."""
    root = ET.fromstring(urdf_text)
    for link in root.iter("link"):
        for tag in ("visual", "collision"):
            for element in link.findall(tag):
                link.remove(element)
    return ET.tostring(root, encoding="unicode")


def lock_joint(spec: mujoco.MjSpec, name: str, value: float) -> None:
    """Weld a joint's body to its parent at joint position `value` (rad or m) and remove the joint:
    the body's pose becomes its pose with the joint at `value` (a rotation about, or a slide along,
    the joint axis through the joint's anchor)."""
    joint = spec.joint(name)
    if joint is None:
        raise ValueError(f"MuJoCo import lost joint {name!r}")
    body = joint.parent
    if value != 0.0:
        axis = np.asarray(joint.axis, dtype=float)
        axis = axis / np.linalg.norm(axis)
        anchor = np.asarray(joint.pos, dtype=float)
        rot_flat = np.empty(9)
        mujoco.mju_quat2Mat(rot_flat, np.asarray(body.quat, dtype=float))
        rot_body = rot_flat.reshape(3, 3)
        if joint.type == mujoco.mjtJoint.mjJNT_SLIDE:
            body.pos = np.asarray(body.pos, dtype=float) + rot_body @ (axis * value)
        elif joint.type == mujoco.mjtJoint.mjJNT_HINGE:
            turn = np.empty(4)
            mujoco.mju_axisAngle2Quat(turn, axis, value)
            rot_turn = np.empty(9)
            mujoco.mju_quat2Mat(rot_turn, turn)
            # parent ← body: T_b · (anchor) · R(axis, value) · (−anchor)
            body.pos = np.asarray(body.pos, dtype=float) + rot_body @ (anchor - rot_turn.reshape(3, 3) @ anchor)
            quat = np.empty(4)
            mujoco.mju_mulQuat(quat, np.asarray(body.quat, dtype=float), turn)
            body.quat = quat
        else:
            raise ValueError(f"joint {name!r} can only be locked at its zero")
    spec.delete(joint)


def build_spec(robot: RobotDescription, table_height: float | None = None) -> mujoco.MjSpec:
    """MjSpec of the arm: torque motors at the URDF limits, armature, floor, table, TCP/sensor sites;
    the URDF's other joints locked (`lock_joint`), no link geometry (`simulation_urdf`)."""
    spec = mujoco.MjSpec.from_string(simulation_urdf(robot.urdf_path.read_text()))
    spec.compiler.fusestatic = False
    spec.compiler.discardvisual = False
    spec.compiler.inertiafromgeom = mujoco.mjtInertiaFromGeom.mjINERTIAFROMGEOM_FALSE
    for eq in list(spec.equalities):  # a URDF <mimic> between locked joints: they are fixed now
        if eq.type == mujoco.mjtEq.mjEQ_JOINT and (eq.name1 in robot.locked or eq.name2 in robot.locked):
            spec.delete(eq)
    for name, value in robot.locked.items():
        lock_joint(spec, name, float(value))
    spec.option.timestep = TIMESTEP_S
    spec.option.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
    spec.option.gravity = [0.0, 0.0, -9.81]
    for j, (name, eff, arm) in enumerate(zip(robot.joint_names, robot.tau_max, robot.armature, strict=True)):
        joint = spec.joint(name)
        if joint is None:
            raise ValueError(f"MuJoCo import lost joint {name!r} of {robot.urdf_path.name}")
        joint.armature = float(arm)
        _hard_stop(joint, bool(robot.endless[j]), float(robot.q_lower[j]), float(robot.q_upper[j]))
        act = spec.add_actuator(name=f"motor_{name}", target=name, trntype=mujoco.mjtTrn.mjTRN_JOINT)
        act.set_to_motor()
        act.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
        act.ctrlrange = [-float(eff), float(eff)]
    world = spec.worldbody
    world.add_geom(name="floor", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[2, 2, 0.05], rgba=[0.9, 0.9, 0.92, 1])
    if table_height is not None:
        world.add_geom(
            name="table",
            type=mujoco.mjtGeom.mjGEOM_BOX,
            size=[0.4, 0.5, max(table_height, 0.01) / 2],
            pos=[0.55, 0.0, table_height / 2],
            rgba=[0.6, 0.45, 0.3, 1],
        )
    for geom in spec.geoms:
        geom.contype = 0
        geom.conaffinity = 0
    # Sites on the body of the last joint, at the Pinocchio frame placements (works when the
    # importer fused the flange into that body).
    last_body = _body_of_joint(spec, robot.joint_names[-1])
    for frame in (TCP_FRAME, SENSOR_FRAME):
        placement = robot.model.frames[robot.model.getFrameId(frame)].placement
        quat = pin.Quaternion(placement.rotation)
        last_body.add_site(
            name=frame,
            pos=placement.translation.tolist(),
            quat=[quat.w, quat.x, quat.y, quat.z],
            size=[0.01, 0.01, 0.01],
        )
    return spec


def _hard_stop(joint: mujoco.MjsJoint, endless: bool, lower: float, upper: float) -> None:
    """The joint's mechanical stops: stiff MuJoCo limits HARD_STOP_BEYOND_RAD beyond the URDF
    (software) limits; an endless joint has none."""
    if endless:
        joint.limited = mujoco.mjtLimited.mjLIMITED_FALSE
        return
    joint.limited = mujoco.mjtLimited.mjLIMITED_TRUE
    joint.range = [lower - HARD_STOP_BEYOND_RAD, upper + HARD_STOP_BEYOND_RAD]
    joint.margin = 0.0
    joint.solref_limit = HARD_STOP_SOLREF
    joint.solimp_limit = HARD_STOP_SOLIMP


def _body_of_joint(spec: mujoco.MjSpec, joint_name: str) -> mujoco.MjsBody:
    for body in spec.bodies:
        if any(j.name == joint_name for j in body.joints):
            return body
    raise ValueError(f"no body carries joint {joint_name!r}")


class World:
    """A running MuJoCo simulation of one arm, stepped with joint torques at 1 kHz."""

    def __init__(
        self,
        robot: RobotDescription,
        table_height: float | None = None,
        customize: Callable[[mujoco.MjSpec], None] | None = None,
    ):
        spec = build_spec(robot, table_height)
        if customize is not None:
            customize(spec)
        self.spec = spec
        self.model = spec.compile()
        self.data = mujoco.MjData(self.model)
        self.robot = robot
        self.table_height = table_height
        self.qpos_adr = np.array([self.model.joint(n).qposadr[0] for n in robot.joint_names])
        self.dof_adr = np.array([self.model.joint(n).dofadr[0] for n in robot.joint_names])
        # the arm's entries as slices when contiguous (as they are: the arm comes first), else the index
        self._qpos_at, self._qvel_at = _contiguous(self.qpos_adr), _contiguous(self.dof_adr)
        self.actuator_ids = np.array([self.model.actuator(f"motor_{n}").id for n in robot.joint_names])
        self._ctrl_at = _contiguous(self.actuator_ids)
        self.tcp_site = self.model.site(TCP_FRAME).id
        self.sensor_site = self.model.site(SENSOR_FRAME).id
        self.wrist_body = int(self.model.site_bodyid[self.tcp_site])
        self._sensor_body = int(self.model.site_bodyid[self.sensor_site])
        self._distal_to_sensor: dict[int, bool] = {}  # body id -> in the sensor's subtree (model is fixed)
        self._jacp = np.zeros((3, self.model.nv))  # Jacobian buffers (mj_jac* overwrite them)
        self._jacr = np.zeros((3, self.model.nv))
        self._solve_buf = np.zeros((3, self.model.nv))
        self.reset_at: float | None = None  # simulated time at which MuJoCo reset an unstable state
        self._warning_counts = self.data.warning.number  # a live view of MjData's warning counters
        # live views of the MjData arrays read or written every step (MjData's buffers never move;
        # each attribute read would build a new array object)
        self._qfrc_applied = self.data.qfrc_applied
        self._views = all(isinstance(at, slice) for at in (self._qpos_at, self._qvel_at, self._ctrl_at))  # else copies
        self._qpos_all, self._qvel_all = self.data.qpos, self.data.qvel
        tau_max = np.asarray(robot.tau_max, dtype=float)
        self._tau_limits = np.array([-tau_max, tau_max])  # rows: lower, upper (N m)
        # the deepest each joint went into its mechanical stop (rad, ≤ 0: short of it) at any step since
        # `take_stop_depth` last read it: checked every step, not sampled when someone looks. Rows:
        # the stop's lower and upper position (±inf for an endless joint), the depth since the last
        # look, the depth since the reset (`STOP_ROWS`)
        bounded = ~np.asarray(robot.endless, dtype=bool)
        self._stops = np.array(
            [
                np.where(bounded, np.asarray(robot.q_lower, dtype=float) - HARD_STOP_BEYOND_RAD, -np.inf),
                np.where(bounded, np.asarray(robot.q_upper, dtype=float) + HARD_STOP_BEYOND_RAD, np.inf),
                np.full(len(robot.joint_names), -np.inf),
                np.full(len(robot.joint_names), -np.inf),
            ]
        )
        if self._views:
            self._ctrl_arm = self.data.ctrl[self._ctrl_at]
            self._qpos_arm, self._qvel_arm = self.data.qpos[self._qpos_at], self.data.qvel[self._qvel_at]
            self._qfrc_applied_arm = self._qfrc_applied[self._qvel_at]
        self.applied: list[AppliedForce] = []
        self._body_ids: dict[tuple[str, ...], np.ndarray] = {}  # `body_ids`, per tuple of names asked for
        self.carried: set[int] = set()  # payload bodies distal to the F/T sensor (their inertia loads it)
        self._acc_valid = False  # MuJoCo's body accelerations (cacc) hold the last step's values
        self.tau_applied = np.zeros(len(robot.joint_names))
        self.torque_delay_steps = 0
        self._tau_pipeline: deque[np.ndarray] = deque()
        self._armature_nominal = self.model.dof_armature[self.dof_adr].copy()
        self.world_params = WorldParams()
        self.reset(robot.home)

    # ---- state -----------------------------------------------------------------------------
    @property
    def time(self) -> float:
        return float(self.data.time)

    @property
    def q(self) -> np.ndarray:
        return self._qpos_arm.copy() if self._views else self.data.qpos[self._qpos_at]

    @property
    def dq(self) -> np.ndarray:
        return self._qvel_arm.copy() if self._views else self.data.qvel[self._qvel_at]

    def reset(self, q: np.ndarray, dq: np.ndarray | None = None) -> None:
        """Put the arm at (q, q̇), time 0, no forces."""
        mujoco.mj_resetData(self.model, self.data)
        self.data.qpos[self.qpos_adr] = q
        self.data.qvel[self.dof_adr] = 0.0 if dq is None else dq
        mujoco.mj_forward(self.model, self.data)
        self.applied.clear()
        self.data.qfrc_applied[:] = 0.0
        self._tau_pipeline.clear()
        self._acc_valid = False
        self.reset_at = None
        self._stops[2:].fill(-np.inf)

    @property
    def divergence_time(self) -> float:
        """The simulated time of a divergence (s): when MuJoCo reset an unstable state (which zeroes
        `time`), else the time now."""
        return self.reset_at if self.reset_at is not None else self.time

    # ---- settings ---------------------------------------------------------------------------
    def params(self) -> dict[str, WorldParams]:
        """Its one parameter group, "world"."""
        return {"world": self.world_params}

    def set_params(self, name: str, group: WorldParams) -> None:
        """New torque delay (rounded to whole timesteps; queued torques beyond it are dropped) and
        armature scale (written into the MuJoCo model at once)."""
        p = expect(name, group, WorldParams if name == "world" else None)
        self.world_params = p
        self.torque_delay_steps = round(p.torque_delay_ms * 1e-3 / self.model.opt.timestep)
        while len(self._tau_pipeline) > self.torque_delay_steps:
            self._tau_pipeline.popleft()
        self.model.dof_armature[self.dof_adr] = self._armature_nominal * p.armature_scale

    def set_armature(self, armature: np.ndarray) -> None:
        """The simulated arm's nominal rotor armature (kg m², one per joint; what the world group's
        `armature_scale` multiplies), written into the MuJoCo model at once."""
        self._armature_nominal = np.array(armature, dtype=float)
        self.model.dof_armature[self.dof_adr] = self._armature_nominal * self.world_params.armature_scale

    def refresh_constants(self) -> None:
        """Recompute the constants MuJoCo derives from masses and inertias at compile time (`mj_setConst`:
        subtree masses, M at qpos0 and the inverse weights) after a body's mass or inertia was
        changed, keeping the state (positions, velocities); for use between steps, e.g. at a reset.
        Without it a mass set on the compiled model steps otherwise than the same mass compiled in."""
        qpos, qvel = self.data.qpos.copy(), self.data.qvel.copy()
        mujoco.mj_setConst(self.model, self.data)
        self.data.qpos[:] = qpos
        self.data.qvel[:] = qvel
        mujoco.mj_forward(self.model, self.data)

    def site_pose(self, site_id: int) -> tuple[np.ndarray, np.ndarray]:
        """(position, rotation matrix) of a site in the world."""
        return self.data.site_xpos[site_id].copy(), self.data.site_xmat[site_id].reshape(3, 3).copy()

    def site_velocity(self, site_id: int) -> np.ndarray:
        """Twist [v; ω] of a site in world-aligned axes at the site origin."""
        jacp, jacr = self._jacp, self._jacr
        mujoco.mj_jacSite(self.model, self.data, jacp, jacr, site_id)
        out = np.empty(6)
        np.matmul(jacp, self.data.qvel, out=out[:3])
        np.matmul(jacr, self.data.qvel, out=out[3:])
        return out

    def site_inverse_mass(self, site_id: int) -> np.ndarray:
        """(3, 3) translational inverse mass J_p M⁻¹ J_pᵀ of a site point (world axes): the
        acceleration of that point per newton applied there, from MuJoCo's own factorised M: the
        single-purpose read that `site_point_state` (itself the contact step's test reference) is
        tested against."""
        jacp = self._jacp
        mujoco.mj_jacSite(self.model, self.data, jacp, None, site_id)
        x = self._solve_buf
        mujoco.mj_solveM(self.model, self.data, x, jacp)
        return jacp @ x.T

    def site_point_jacobian(self, site_id: int, solve: bool = False) -> tuple[np.ndarray, np.ndarray | None]:
        """(J_p (3, nv), M⁻¹ J_pᵀ as rows (3, nv) when `solve`, else None) of a site point, world axes:
        buffers this world owns, overwritten by the next call (read them before stepping)."""
        jacp = self._jacp
        mujoco.mj_jacSite(self.model, self.data, jacp, None, site_id)
        if not solve:
            return jacp, None
        mujoco.mj_solveM(self.model, self.data, self._solve_buf, jacp)
        return jacp, self._solve_buf

    def site_point_state(
        self, site_id: int, inverse_mass: bool = False
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """(position, linear velocity, inverse mass J_p M⁻¹ J_pᵀ or None) of a site point, world axes:
        `site_pose`, `site_velocity`[:3] and `site_inverse_mass` from one translational Jacobian."""
        jacp, x = self.site_point_jacobian(site_id, solve=inverse_mass)
        velocity = jacp.dot(self.data.qvel)  # ndarray.dot: less call overhead than @
        G = None if x is None else jacp.dot(x.T)
        return self.data.site_xpos[site_id].copy(), velocity, G

    # ---- forces -----------------------------------------------------------------------------
    def apply_force(
        self,
        body_id: int,
        point_world: np.ndarray,
        force_world: np.ndarray,
        torque_world: np.ndarray | None = None,
        copy: bool = True,
    ) -> None:
        """Apply an external force (and torque) at a world point on a body for the next step.
        `copy=False`: the caller hands over float arrays it will not change (they are kept as given)."""
        t = np.zeros(3) if torque_world is None else np.asarray(torque_world, dtype=float)
        if copy:
            p, f, t = np.array(point_world, dtype=float), np.array(force_world, dtype=float), t.copy()
        else:
            p, f = point_world, force_world
        mujoco.mj_applyFT(self.model, self.data, f, t, p, body_id, self._qfrc_applied)
        self.applied.append(AppliedForce(body_id, p, f, t))

    def external_wrench_at_sensor(self) -> np.ndarray:
        """True wrench [f; m] (world axes, about the sensor origin) the F/T sensor carries: the forces
        applied this step on the bodies distal to it (the sensor's body and its subtree: payload
        weights, a rope, drag, contact) plus the inertial load of the carried payloads
        (`inertial_wrench_at_sensor`), so a payload reads m(g − a), not only its weight."""
        s0, s1, s2 = self.data.site_xpos[self.sensor_site].tolist()
        fx = fy = fz = mx = my = mz = 0.0  # Python floats: the same IEEE arithmetic, no array per term
        distal = self._distal_to_sensor
        for a in self.applied:
            inside = distal.get(a.body_id)
            if inside is None:
                inside = distal[a.body_id] = self._is_in_subtree(a.body_id, self._sensor_body)
            if inside:
                f0, f1, f2 = a.force_world.tolist()
                p0, p1, p2 = a.point_world.tolist()
                t0, t1, t2 = a.torque_world.tolist()
                r0, r1, r2 = p0 - s0, p1 - s1, p2 - s2
                fx, fy, fz = fx + f0, fy + f1, fz + f2
                # torque + r × f
                mx += t0 + (r1 * f2 - r2 * f1)
                my += t1 + (r2 * f0 - r0 * f2)
                mz += t2 + (r0 * f1 - r1 * f0)
        wrench = np.array([fx, fy, fz, mx, my, mz])
        if self.carried:
            wrench += self.inertial_wrench_at_sensor()
        return wrench

    def inertial_wrench_at_sensor(self) -> np.ndarray:
        """Wrench [f; m] (world axes, about the sensor origin) the carried payloads' inertia puts on
        the sensor: −m a at each centre of mass and −(I α + ω × I ω) about it (Newton–Euler), from
        MuJoCo's body accelerations of the last step (one step old, as a sampled sensor is).
        Their weights are applied as external forces (`app.scenarios.payload`), so in total the
        sensor reads m(g − a) at the COM and its moment about the sensor origin."""
        wrench = np.zeros(6)
        if not self._acc_valid:
            return wrench  # no step taken yet: the payload is at rest
        p_sensor = self.data.site_xpos[self.sensor_site]
        gravity = self.model.opt.gravity
        acc = np.zeros(6)
        vel = np.zeros(6)
        for body in self.carried:
            mass = float(self.model.body_mass[body])
            if mass <= 0.0:
                continue
            # [rot; lin] at the COM, world axes; MuJoCo's linear part is a − g (an accelerometer's)
            mujoco.mj_objectAcceleration(self.model, self.data, mujoco.mjtObj.mjOBJ_BODY, body, acc, 0)
            mujoco.mj_objectVelocity(self.model, self.data, mujoco.mjtObj.mjOBJ_BODY, body, vel, 0)
            a_com = acc[3:] + gravity
            rot = self.data.ximat[body].reshape(3, 3)
            inertia_world = rot @ np.diag(self.model.body_inertia[body]) @ rot.T
            omega = vel[:3]
            force = -mass * a_com
            torque = -(inertia_world @ acc[:3] + np.cross(omega, inertia_world @ omega))
            wrench[:3] += force
            wrench[3:] += torque + np.cross(self.data.xipos[body] - p_sensor, force)
        return wrench

    def external_joint_torque(self) -> np.ndarray:
        """True external joint torque τ^e of the forces applied this step (sim truth)."""
        return self._qfrc_applied_arm.copy() if self._views else self._qfrc_applied[self._qvel_at]

    def _is_in_subtree(self, body_id: int, root_id: int) -> bool:
        b = body_id
        while b > 0:
            if b == root_id:
                return True
            b = int(self.model.body_parentid[b])
        return root_id == 0

    # ---- stepping ---------------------------------------------------------------------------
    def step(self, tau: np.ndarray) -> None:
        """Advance one timestep with joint torques τ (clipped to the motor limits), then clear forces.
        With a torque delay of d steps the motors apply the command of d steps ago (the first
        command is held until the pipeline has filled)."""
        # np.clip's result (NaN kept), and in the same compiled call how deep each joint is in its stop
        # in the state this step starts from: the one the last step (or a reset) left
        ctrl = clip_torque_track_stops(tau, self._tau_limits, self._qpos_all, self.qpos_adr, self._stops)
        if self.torque_delay_steps > 0:
            self._tau_pipeline.append(ctrl)
            ctrl = self._tau_pipeline[0]
            if len(self._tau_pipeline) > self.torque_delay_steps:
                self._tau_pipeline.popleft()
        self.tau_applied = ctrl
        if self._views:
            self._ctrl_arm[:] = ctrl
        else:
            self.data.ctrl[self._ctrl_at] = ctrl
        # mj_step2 integrates with the forces and controls set on the kinematics of this state;
        # mj_step1 then computes the kinematics (site poses, Jacobians, M) of the new state, so
        # the next step's contact and drag forces see the current position, not the previous
        # one (a one-step-late contact spring acts like a negative damper of k·Δt).
        t_before = self.data.time
        mujoco.mj_step2(self.model, self.data)
        mujoco.mj_step1(self.model, self.data)
        if self.data.time < t_before and self.reset_at is None:
            # MuJoCo reset an unstable state (time back to 0): keep when it happened
            self.reset_at = t_before + self.model.opt.timestep
        if self.carried:
            # body accelerations (cacc) for the sensor's inertial load: the acceleration of the
            # step just taken, on the kinematics of the new state (a sensor sampled once a step)
            mujoco.mj_rnePostConstraint(self.model, self.data)
        self._acc_valid = bool(self.carried)
        self._qfrc_applied.fill(0.0)
        self.applied.clear()

    def body_ids(self, names: tuple[str, ...]) -> np.ndarray:
        """Body ids of `names` in this world's model, looked up once per tuple of names (the scene and
        the twin read link poses every frame); ValueError naming a body the model does not have."""
        ids = self._body_ids.get(names)
        if ids is None:
            found = [mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, name) for name in names]
            missing = [name for name, i in zip(names, found, strict=True) if i < 0]
            if missing:
                raise ValueError(f"the simulation has no body named {missing[0]!r}")
            ids = self._body_ids[names] = np.array(found, dtype=np.intp)
        return ids

    def overpowered(self, tau_ext: np.ndarray | None) -> str:
        """Joints the surroundings overpower, in words ("" if none): an external torque |τ_ext| beyond
        the motor's torque limit, or the joint pressed against its mechanical stop."""
        robot = self.robot
        depth = self.take_stop_depth()  # every step since the last look, not this step alone
        parts = []
        for j in range(len(robot.joint_names)):
            tau = 0.0 if tau_ext is None else abs(float(tau_ext[j]))
            if tau > robot.tau_max[j]:
                parts.append(f"joint {j + 1}: external torque {tau:.0f} N·m > its {robot.tau_max[j]:.0f} N·m limit")
            elif depth[j] > -1e-3:  # at (or into) the stop, not merely near the software limit
                parts.append(f"joint {j + 1} is pressed against its hard stop ({1e3 * max(depth[j], 0.0):.1f} mrad in)")
        return "; ".join(parts)

    def take_stop_depth(self) -> np.ndarray:
        """The deepest each joint went into its stop (rad) at any step since the last call; starts over."""
        stops = self._stops
        track_stop_depth(self._qpos_all, self.qpos_adr, stops)  # the last step's state (`step` checks the rest)
        out = stops[2].copy()
        stops[2].fill(-np.inf)
        return out

    @property
    def stop_depth(self) -> np.ndarray:
        """The deepest each joint went into its stop (rad) at any step since the reset: the world's own
        array (filling it with −inf starts the count over)."""
        track_stop_depth(self._qpos_all, self.qpos_adr, self._stops)  # the last step's state
        return self._stops[3]

    def diverged(self) -> bool:
        """True when the state holds NaN/inf or a runaway velocity (‖q̇‖ > 1e3), or MuJoCo had to reset
        an unstable state since the last `reset` (it does so silently, counting a warning)."""
        qvel, qpos = self._qvel_all, self._qpos_all
        # a dot product is NaN/inf when any element is, and `not <=` is True for NaN: one cheap test
        if not float(qvel.dot(qvel)) <= 1e6 or not math.isfinite(float(qpos.dot(qpos))):
            return True
        counts = self._warning_counts.tolist()
        return counts[_BAD_QPOS] > 0 or counts[_BAD_QVEL] > 0 or counts[_BAD_QACC] > 0

    # ---- model quantities for cross-checks --------------------------------------------------
    def mass_matrix(self) -> np.ndarray:
        """Dense joint-space inertia of the arm joints (after mj_forward)."""
        full = np.zeros((self.model.nv, self.model.nv))
        mujoco.mj_fullM(self.model, self.data, full)
        return full[np.ix_(self.dof_adr, self.dof_adr)]

    def bias_forces(self) -> np.ndarray:
        """C q̇ + g of the arm joints (after mj_forward)."""
        return self.data.qfrc_bias[self.dof_adr].copy()

    def tcp_jacobian(self) -> np.ndarray:
        """(6, 7) TCP Jacobian [jacp; jacr] in world axes (after mj_forward)."""
        jacp = np.zeros((3, self.model.nv))
        jacr = np.zeros((3, self.model.nv))
        mujoco.mj_jacSite(self.model, self.data, jacp, jacr, self.tcp_site)
        return np.vstack([jacp, jacr])[:, self.dof_adr]

    def set_state(self, q: np.ndarray, dq: np.ndarray) -> None:
        """Set (q, q̇) and recompute derived quantities without stepping."""
        self.data.qpos[self.qpos_adr] = q
        self.data.qvel[self.dof_adr] = dq
        mujoco.mj_forward(self.model, self.data)


def track_stop_depth_reference(qpos: np.ndarray, adr: np.ndarray, stops: np.ndarray) -> None:
    """`track_stop_depth` in numpy: the depth past the stops d = max(q − q⁺, q⁻ − q) raises the
    recent and peak rows stops[2], stops[3] in place."""
    q = qpos[adr]
    depth = np.maximum(q - stops[1], stops[0] - q)
    np.maximum(stops[2], depth, out=stops[2])
    np.maximum(stops[3], depth, out=stops[3])


def clip_torque_track_stops_reference(tau, limits, qpos, adr, stops) -> np.ndarray:
    """`clip_torque_track_stops` in numpy: np.minimum(np.maximum(τ, limits[0]), limits[1]) (NaN kept)
    and `track_stop_depth_reference`."""
    track_stop_depth_reference(qpos, adr, stops)
    return np.minimum(np.maximum(tau, limits[0]), limits[1])


@njit(cache=True)
def track_stop_depth(qpos, adr, stops):
    """stops[2, j], stops[3, j] = their max with how far joint j (at qpos[adr[j]]) is past its stop
    now (rad; < 0: short of it), the stop being stops[0, j] below and stops[1, j] above."""
    for j in range(adr.shape[0]):
        q = qpos[adr[j]]
        d = max(q - stops[1, j], stops[0, j] - q)
        if d > stops[2, j]:
            stops[2, j] = d
        if d > stops[3, j]:
            stops[3, j] = d


@njit(cache=True)
def clip_torque_track_stops(tau, limits, qpos, adr, stops):
    """min(max(τ, limits[0]), limits[1]) element by element as a new array (NaN stays NaN, as with
    np.minimum/np.maximum): the motors' torque limits; and `track_stop_depth(qpos, adr, stops)`,
    in one call (one dispatch per step)."""
    track_stop_depth(qpos, adr, stops)
    out = np.empty(tau.shape[0])
    for i in range(tau.shape[0]):
        x = tau[i]
        if x < limits[0, i]:
            x = limits[0, i]
        elif x > limits[1, i]:
            x = limits[1, i]
        out[i] = x
    return out
