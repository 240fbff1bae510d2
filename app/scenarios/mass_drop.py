"""Mass drop [C] §IV-D (Fig. 5): "A 1.25 kg mass is attached at the wrist, lifted to the
attachment point, and released." The mass hangs from the Gen3's tool on a rope; a hand holds it at
the attachment point; at the release it falls, the rope goes taut and jerks the arm; the TCP must
stay put. Three modes: Position (an acceleration-based joint PID standing in for the arm's internal
position loop), Torque + Residual and Torque + Fusion (pose task non-compliant, Γ = 0; nullspace
compliant, Γ₀ = I). A second case, "held-release" (labelled so in the report), is the opposite
transient: the arm holds the mass rigidly and lets it go (an unloading step, no impact).

Constants, chosen once from the paper and physical sense, not tuned afterwards:
- posture `mass_drop_nominal` (robots/gen3.toml): the nominal posture with the TCP 5 cm forward; for an
  arm without a sidecar the start `app.scenarios.drop_postures.mass_drop_start` finds;
- mass 1.25 kg, a free body in MuJoCo (steel sphere, 3.4 cm radius); the rope attaches at the TCP,
  distal to the F/T sensor (the sensor feels the rope's pull, as in [C]'s compliance experiment);
- rope length 0.05 m: [C] gives none for this experiment; a short loop at the wrist. The mass is
  released at the attachment point, so it falls the rope's length. (With the 18 cm of [C]'s
  compliance experiment the catch, mg + √((mg)² + 2kmg·d) ≈ 61 N, exceeds the ≈ 48 N at the TCP
  that the Gen3's 9 N m wrist joint 6 holds, and the paper's arm survived 90 drops.)
- rope stiffness 500 N/m: an elastic cord (the 12 N weight stretches it 2.5 cm); it also stands
  in for the joint and link flexibility our rigid model lacks ([C] names robot flexibility as the
  main limitation of its results);
- rope damping 5 N s/m: damping ratio ≈ 0.1 of the mass on the cord, a lightly damped polymer;
- release at t = 1.5 s: the PID integral and the observer have settled (both < 0.3 s);
- analysis window 4 s from the release ([C] §IV-D);
- Position mode: joint PID with a triple real pole at ω = 20 rad/s (K_p = 3ω², K_d = 3ω,
  K_i = ω³): a stiff position loop without overshoot; no external-torque estimate;
- Torque modes: TCP pose task K_p = ω² = 400 s⁻², K_d = 2ω = 40 s⁻¹ (the same 20 rad/s bandwidth,
  critically damped), weight 1e4; posture task K_p = 1, K_d = 2, weight 1, Γ₀ = I; K_I = 50 s⁻¹;
- F/T sensor: Gaussian noise σ = 0.1 N / 0.005 N m per channel, no filter (a digital 6-axis
  sensor read within 1 ms, [C] §IV-A); the 1 Hz sinusoid of the [T] sensor model is not used;
- actuator torque ripple: Gaussian σ = 0.05 N m per joint per step (the low-level torque loop is
  never exact);
- stabilisation band 1 mm around the target.
What varies between repetitions (`MassDropParams`, drawn by the experiment, seeded): the drop
height (a hand lifts the mass to the attachment point within ±1 cm), the rope stiffness (±20 %,
cord and knot) and the true mass (±10 % about the 1.25 kg, which no controller is told).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import mujoco
import numpy as np

from app.scenarios import Environment, PhaseMark, Scenario, Sensor
from app.scenarios.drop_postures import guess_posture, mass_drop_start, mass_drop_target
from app.scenarios.metrics import RESIDUAL_WINDOW_S, STABLE_BAND_M, DropFold, run_fold
from app.scenarios.payload import PayloadEnvironment, PayloadParams, add_payload_body, set_inertial_at_origin
from app.sim.rope import Rope
from app.sim.sensor import FTSensor
from app.sim.world import World
from control.compliance_qp import ComplianceQPExecutor, PoseTask
from control.executor import Executor
from control.gains import EstimatorGains, PoseTaskGains, PostureTaskGains
from control.params import ParamError, ParamGroup, expect, param, replaced
from robots import RobotDescription

MODES = ("position", "torque-residual", "torque-fusion")
CASES = ("rope-drop", "held-release")
PAYLOAD_KG = 1.25
MASS_BODY = "drop_mass"
MASS_RADIUS_M = 0.034  # a 1.25 kg steel sphere
RELEASE_TIME_S = 1.5
WINDOW_S = 4.0
PID_OMEGA = 20.0  # rad/s
TASK_OMEGA = 20.0  # rad/s
OBSERVER_GAIN = 50.0  # 1/s
FORCE_NOISE_STD = 0.1  # N
TORQUE_NOISE_STD = 0.005  # N m (sensor moment channels)
ACTUATOR_RIPPLE_STD = 0.05  # N m


def drop_metrics(t: np.ndarray, deviation_m: np.ndarray) -> dict:
    """Peak deflection, stabilisation time and residual error of the TCP after the release
    (`metrics.DropFold`, the app's readouts too) of one run's deviation (m) over time; empty before the
    release."""
    return run_fold(DropFold(RELEASE_TIME_S, "dev_mm"), {"t": t, "dev_mm": 1e3 * np.asarray(deviation_m)})


@dataclass(frozen=True)
class MassDropParams(ParamGroup):
    """The mass-drop rig (group "scenario"): what a repetition may vary; in force from the next reset."""

    title = "Mass-drop rig"

    rope_length_m: float = param(
        0.05, label="Rope length", unit="m", lo=0.02, hi=0.5, step=0.01, help="rest length of the rope", tag="[C] §IV-D"
    )
    rope_stiffness_n_per_m: float = param(
        500.0, label="Rope stiffness", unit="N/m", lo=100.0, hi=1e5, step=50.0, help="axial stiffness of the taut rope"
    )
    rope_damping_n_s_per_m: float = param(
        5.0, label="Rope damping", unit="N s/m", lo=0.0, hi=200.0, step=1.0, help="axial damping of the taut rope"
    )
    drop_height_m: float = param(
        0.05,
        label="Drop height",
        unit="m",
        lo=0.0,
        hi=0.5,
        step=0.005,
        help="free fall before the rope goes taut (the rope length: released at the attachment point)",
        tag="[C] §IV-D",
    )
    payload_mass_error: float = param(
        0.0,
        label="Mass error",
        lo=-0.5,
        hi=0.5,
        step=0.01,
        help="true mass = 1.25 kg × (1 + error); no controller is told",
    )

    def check(self) -> None:
        """The drop may not exceed twice the rope length (the mass is held below the wrist)."""
        if self.drop_height_m > 2 * self.rope_length_m:
            raise ParamError(
                f"drop_height_m must be at most twice the rope length ({2 * self.rope_length_m:g} m), "
                f"got {self.drop_height_m:g}"
            )

    @property
    def drop_height(self) -> float:
        """Free fall before the rope goes taut (m)."""
        return float(self.drop_height_m)

    @property
    def mass_kg(self) -> float:
        """The true mass in the simulation."""
        return PAYLOAD_KG * (1.0 + self.payload_mass_error)

    @property
    def rope(self) -> Rope:
        return Rope(self.rope_length_m, self.rope_stiffness_n_per_m, self.rope_damping_n_s_per_m)


def wrist_ft_sensor(rng: np.random.Generator) -> Sensor:
    """The [C] scenarios' wrist F/T sensor: white noise of the stds above, no sine, no filter."""
    return FTSensor(
        rng,
        force_noise_var=FORCE_NOISE_STD**2,
        torque_noise_var=TORQUE_NOISE_STD**2,
        sine_amplitude_n=0.0,
        cutoff_hz=0.0,
    )


def _ripple(world: World, rng: np.random.Generator) -> None:
    world.data.qfrc_applied[world.dof_adr] += ACTUATOR_RIPPLE_STD * rng.standard_normal(len(world.dof_adr))


class RippleAndPayload(PayloadEnvironment):
    """Second case: the payload held rigidly at the TCP, let go at RELEASE_TIME_S; torque ripple."""

    def __init__(self, world: World, rng: np.random.Generator, mass_kg: float = PAYLOAD_KG):
        super().__init__(world, mass_kg, release_time_s=RELEASE_TIME_S)
        self.rng = rng

    def apply(self, world: World, t: float) -> dict[str, float]:
        signals = super().apply(world, t)
        _ripple(world, self.rng)
        return signals


def add_drop_mass(spec: mujoco.MjSpec, mass_kg: float) -> None:
    """The hanging mass: a free body (solid sphere) in the world; its state is set by the environment."""
    inertia = 0.4 * mass_kg * MASS_RADIUS_M**2
    body = spec.worldbody.add_body(name=MASS_BODY, pos=[0.0, 0.0, 0.2], mass=mass_kg, inertia=[inertia] * 3)
    set_inertial_at_origin(body)
    body.add_freejoint()
    body.add_geom(type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[MASS_RADIUS_M, 0, 0], rgba=[0.3, 0.3, 0.35, 1])


class RopeDrop(Environment):
    """The mass on its rope from the TCP: held at the release point until RELEASE_TIME_S, then free.

    Each step, at the current state, the rope's tension (`Rope`)
    pulls the mass towards the TCP and the TCP towards the mass (equal and opposite, `mj_applyFT`),
    plus the seeded actuator torque ripple. Before the release a hand holds the mass still at the
    release point, `drop_height` below the point where the rope goes taut (no force on the arm)."""

    def __init__(self, world: World, rng: np.random.Generator, params: MassDropParams):
        self.world = world
        self.rng = rng
        self.rig = params
        self.rope = params.rope
        self.body_id = int(world.model.body(MASS_BODY).id)
        joint = int(world.model.body_jntadr[self.body_id])
        self.qpos_adr = int(world.model.jnt_qposadr[joint])
        self.dof_adr = int(world.model.jnt_dofadr[joint])
        self.mass_kg = params.mass_kg
        world.model.body_mass[self.body_id] = self.mass_kg  # the rig's mass applies from this reset on
        world.model.body_inertia[self.body_id] = 0.4 * self.mass_kg * MASS_RADIUS_M**2
        world.refresh_constants()  # as if compiled with this mass (a rig set by set_param steps as one built with it)
        self.attached = True  # on its rope for the whole run (the scene draws it at its body)
        self.released = False
        self.tension = 0.0
        self._jacp = np.zeros((3, world.model.nv))
        self._hold(*self._refresh())
        mujoco.mj_kinematics(world.model, world.data)

    def _refresh(self) -> tuple[np.ndarray, np.ndarray]:
        """(TCP position, TCP velocity) at the current state (the world keeps its kinematics current)."""
        m, d = self.world.model, self.world.data
        mujoco.mj_jacSite(m, d, self._jacp, None, self.world.tcp_site)
        return d.site_xpos[self.world.tcp_site].copy(), self._jacp @ d.qvel

    def _hold(self, anchor: np.ndarray, anchor_velocity: np.ndarray) -> None:
        """Put the mass at the release point, at rest (a hand holding it)."""
        d = self.world.data
        below = self.rope.length_m - self.rig.drop_height
        d.qpos[self.qpos_adr : self.qpos_adr + 3] = anchor - np.array([0.0, 0.0, below])
        d.qpos[self.qpos_adr + 3 : self.qpos_adr + 7] = (1.0, 0.0, 0.0, 0.0)
        d.qvel[self.dof_adr : self.dof_adr + 6] = 0.0

    def mass_state(self) -> tuple[np.ndarray, np.ndarray]:
        """(position, linear velocity) of the mass, world frame (free joint: world-frame velocity)."""
        d = self.world.data
        return d.qpos[self.qpos_adr : self.qpos_adr + 3].copy(), d.qvel[self.dof_adr : self.dof_adr + 3].copy()

    def apply(self, world: World, t: float) -> dict[str, float]:
        anchor, anchor_velocity = self._refresh()
        if not self.released and t >= RELEASE_TIME_S - 1e-12:
            self.released = True
        stretch = 0.0
        self.tension = 0.0
        if not self.released:
            self._hold(anchor, anchor_velocity)
        else:
            end, end_velocity = self.mass_state()
            force, stretch = self.rope.force_on_end(anchor, anchor_velocity, end, end_velocity)
            self.tension = float(np.linalg.norm(force))
            if self.tension > 0.0:
                world.apply_force(self.body_id, end, force)
                world.apply_force(world.wrist_body, anchor, -force)
        _ripple(world, self.rng)
        x, y, z = world.data.xipos[self.body_id].tolist()  # where the mass is, for the replay's scene
        return {
            "mass_released": float(self.released),
            "rope_tension_n": self.tension,
            "rope_stretch_mm": 1e3 * stretch,
            "payload_x_m": x,
            "payload_y_m": y,
            "payload_z_m": z,
        }

    def overlay(self) -> dict[str, np.ndarray]:
        end, _ = self.mass_state()
        return {"rope_end": end}


def _searched_start(robot: RobotDescription) -> tuple[np.ndarray, str]:
    """The mass drop's start found by `mass_drop_start`, and how, in words."""
    x, _, z = mass_drop_target(robot)
    return mass_drop_start(robot), (
        f"the mass drop starts with the TCP tool down at ({x:.2f}, 0, {z:.2f}) m, half the arm's size in front"
        " of the shoulder at its height (app/scenarios/drop_postures.py), not [C]'s nominal posture: the"
        " TCP's deflection after the catch depends on the posture (the arm's inertia and torque margins there)"
    )


class MassDropScenario(Scenario):
    name = "mass-drop"
    cases = MODES
    case_arg = "mode"
    title = "Mass drop [C]"
    description = (
        "A 1.25 kg mass on a 5 cm elastic cord from the Gen3's tool is let go at the attachment point at "
        "t = 1.5 s: it falls, the rope goes taut and jerks the arm. Compare a stiff joint position loop "
        "with torque control fed by the momentum observer alone or fused with the F/T sensor: peak "
        "deflection, stabilisation time and residual error of the TCP."
    )
    default_robot = "gen3"
    starts_paused = True  # the release is over in seconds
    default_executor = "compliance-qp"
    logs_deflection = True
    groups: ClassVar[Mapping[str, type[ParamGroup]]] = {"scenario": MassDropParams, "payload": PayloadParams}
    plot_layout = ("deflection", "torque")
    phase_marks = (PhaseMark("mass_released", "drop"), PhaseMark("payload_attached", "release", rising=False))
    tune_first = ("Compliance", "Safety")

    def phase_text(self, status: Any, scene: Any, memory: dict[str, Any]) -> str:
        """Holding the mass, then dropped (signal "mass_released")."""
        released = status.signals.get("mass_released")
        if released is None:
            return ""
        return "dropped: the mass hangs on the rope" if released > 0.5 else "holding the mass"

    def __init__(self, mode: str = "torque-fusion", case: str = "rope-drop", params: MassDropParams | None = None):
        if mode not in MODES:
            raise ValueError(f"mode must be one of {', '.join(MODES)}, got {mode!r}")
        if case not in CASES:
            raise ValueError(f"case must be one of {', '.join(CASES)}, got {case!r}")
        self.mode = mode
        self.case = case
        self.rig = params or MassDropParams()  # not `params`: that is the Scenario's parameter groups

    def readout_fold(self) -> DropFold:
        """The TCP's peak deflection, stabilisation time and residual error after the release (as the
        experiment measures them), kept running over every logged step."""
        return DropFold(RELEASE_TIME_S)

    def readout_text(self, values: Mapping[str, float]) -> list[str]:
        """The TCP's peak, stabilisation time and residual after the drop."""
        if "peak_deflection_mm" not in values:
            return []
        return [
            f"TCP after the drop (every step since the release): peak {values['peak_deflection_mm']:.1f} mm · "
            f"back within {1e3 * STABLE_BAND_M:g} mm for good {values['stabilization_time_s']:.2f} s after "
            f"it · residual (mean of the last {RESIDUAL_WINDOW_S:g} s) {values['residual_error_mm']:.2f} mm"
        ]

    def params(self) -> dict[str, ParamGroup]:
        """ "scenario": the rig (rope, drop height, mass error), used from the next reset."""
        return {"scenario": self.rig}

    def set_params(self, name: str, group: Any) -> None:
        """A new rig for the next reset (the mass is set on the compiled model then)."""
        self.rig = expect(name, group, MassDropParams if name == "scenario" else None)

    def initial_q(self, robot: RobotDescription) -> np.ndarray:
        return self.named_posture(robot, "mass_drop_nominal")

    def prepare_robot(self, robot: RobotDescription) -> None:
        """For an arm without sidecar postures, find its start (`drop_postures.mass_drop_start`) and
        say so among the guessed values."""
        guess_posture(robot, "mass_drop_nominal", "mass_drop", lambda: _searched_start(robot))

    def customize_world(self, spec: mujoco.MjSpec, robot: RobotDescription) -> None:
        if self.case == "held-release":
            add_payload_body(spec, robot, self.rig.mass_kg)
        else:
            add_drop_mass(spec, self.rig.mass_kg)

    def make_environment(self, world: World, rng: np.random.Generator) -> Environment:
        if self.case == "held-release":
            return RippleAndPayload(world, rng, self.rig.mass_kg)
        return RopeDrop(world, rng, self.rig)

    def make_sensor(self, rng: np.random.Generator) -> Sensor:
        return wrist_ft_sensor(rng)

    @property
    def chosen_case(self) -> str:
        """The controller mode (`MODES`)."""
        return self.mode

    def prepare_executor(self, executor: Executor, robot: RobotDescription) -> None:
        """Position: no task (the posture task is the joint PID). Torque modes: one pose task. Only the
        [C] QP executor; other executors are left as they are."""
        if isinstance(executor, ComplianceQPExecutor):
            executor.set_tasks([] if self.mode == "position" else [PoseTask()])

    def executor_changes(self, groups: Mapping[str, ParamGroup], robot: RobotDescription) -> dict[str, ParamGroup]:
        """Position: joint PID, no estimate, feedback off. Torque modes: stiff pose task, compliant
        nullspace, the mode's estimate, feedback on (the [C] QP executor's groups; none for another)."""
        if "compliance_qp" not in groups:
            return {}
        if self.mode == "position":
            w = PID_OMEGA
            return {
                "posture_task": PostureTaskGains(
                    stiffness=3 * w * w, damping=3 * w, integral=w**3, weight=1.0, compliance=0.0
                ),
                "estimator": EstimatorGains(source="none", observer_gain=OBSERVER_GAIN),
                "compliance_qp": replaced(groups["compliance_qp"], "feedback", False),
            }
        w = TASK_OMEGA
        source = "residual" if self.mode == "torque-residual" else "fusion"
        return {
            "pose_task": PoseTaskGains(stiffness=w * w, damping=2 * w, weight=1e4, compliance=0.0),
            "posture_task": PostureTaskGains(stiffness=1.0, damping=2.0, weight=1.0, compliance=1.0),
            "estimator": EstimatorGains(source=source, observer_gain=OBSERVER_GAIN),
            "compliance_qp": replaced(groups["compliance_qp"], "feedback", True),
        }


SCENARIO = MassDropScenario()
