"""Polish [T §IV-B]: press 20 N on a table, let the posture converge, then a six-segment zig-zag.

Protocol (Fig. 6-9 of [T]): the Rizon 4s starts elbow up with the tool pointing down just above
the table (Fig. 6a); the force law presses the TCP onto the table at 20 N while the TCP holds
its XY position and the nullspace QP moves the posture under the chosen objective; once the
self-motion has settled (or a timeout), the TCP tracks an XY zig-zag: S1, S3, S5 retract along
−X, S2, S4, S6 stretch forward along +X (Fig. 7), each with a minimum-jerk profile, while Y
advances by a fixed step per segment.

Every constant below is chosen once from the paper's description and physical sense (reason on
the same line) and is not re-tuned to match the paper's tables.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from app.scenarios import Environment, Scenario, Sensor, Work, reach
from app.scenarios.drop_postures import arm_size
from app.scenarios.polish_environment import PolishEnvironment
from app.scenarios.polish_plan import (
    PolishTarget,
    compute_plan,
    ik_seed,
    plan_cached,
    plan_key,
    planned_path,
    store_plan,
)
from app.scenarios.polish_stroke import (
    CONTACT_STIFFNESS_N_PER_M,
    CONTACT_TIME_S,
    CONVERGE_MIN_S,
    CONVERGE_TIMEOUT_S,
    FRICTION_V_EPS_M_PER_S,
    N_SEGMENTS,
    SANDER_AMPLITUDE_N,
    SENSOR_CUTOFF_HZ,
    START_GAP_M,
    START_SWIVEL_DEG,
    START_XY_M,
    TABLE_HEIGHT_M,
    TOOL_DOWN,
    PhaseClock,
    segment_waypoints,
)
from app.sim.contact import TableContact
from app.sim.disturbances import Sander
from app.sim.sensor import FTSensor
from app.sim.world import World
from control.coupling import move_to_swivel, project_to_pose
from control.executor import TaskTarget
from control.gains import NullspaceGains
from control.model import Dynamics, RobotModel
from control.params import ParamGroup, expect, param, replaced
from control.planner import PLAN_COSTS, Plan
from robots import RobotDescription

# an arm without sidecar postures: the paper's table and start scaled by the first of these it reaches
PLACEMENT_SCALES = (1.0, 0.9, 1.1, 0.8, 1.2, 0.7, 1.3, 0.6, 1.4, 0.5)
MIRROR_START_DEG = -30.0  # just across the W_a ridge (≈ −31° on the scan) from the Fig. 6a start: the other basin
# The app's cases: the gradient flow of the chosen objective from the Fig. 6a start, the same from the
# mirror start, or the globally planned swivel path with cost W_a or the directional coupling where its sign
# destabilises the force loop, max(P_d·f̂, 0)² (control.planner "signed").
MODES = ("flow", "mirror start", "planned W_a", "planned max(P_d·f̂, 0)²")


@dataclass(frozen=True)
class PolishParams(ParamGroup):
    """The polish preset's own parameters (in force from the next reset)."""

    title = "Polish preset"

    start_swivel_deg: float = param(
        START_SWIVEL_DEG,
        label="Start swivel",
        unit="deg",
        lo=-180.0,
        hi=180.0,
        step=5.0,
        help="elbow swivel of the start posture (0 = elbow up, Fig. 6a); applies at Reset",
        tag="DESIGN §8",
    )
    hold_swivel: bool = param(
        False,
        label="Hold the start swivel",
        help="the nullspace holds the start posture (W_j on it, no flow), for stability maps; applies at Reset",
        tag="[T18]",
    )
    armature_scale: float = param(
        1.0,
        label="Armature scale",
        lo=0.0,
        hi=4.0,
        step=0.25,
        help="scales the (unpublished) rotor armature of the model and the simulated arm alike; applies at Reset",
        tag="robots/rizon4s.toml",
    )


def plan_lead_s(gains: Mapping[str, ParamGroup]) -> float:
    """How far the target leads the planned path (s): W_j [T18] follows a moving q_d with the lag
    1/k0_j of the nullspace group; 0 without one (an executor without the [T] nullspace)."""
    nullspace = gains.get("nullspace")
    k0_j = float(nullspace.k0_j) if isinstance(nullspace, NullspaceGains) else 0.0
    return 1.0 / k0_j if k0_j > 0 else 0.0


def phase_text(t: float, sig: Mapping[str, float], scene: Any, variant: str = "") -> str:
    """The polish phase in words at time t from the step's signals and the frame's scene (see
    `PolishScenario.phase_text`)."""
    segment = sig.get("segment", math.nan)
    if math.isfinite(segment) and 1 <= segment <= N_SEGMENTS:
        stroke = "back" if int(segment) % 2 == 1 else "forward"
        return f"S{int(segment)} ({stroke} stroke)"
    if math.isfinite(segment) and segment > N_SEGMENTS:
        return "done: the zig-zag is over"
    if t < CONTACT_TIME_S:
        return "contact: pressing onto the table"
    swivel = sig.get("swivel_deg", math.nan)
    seconds = sig.get("settle_s", max(t - CONTACT_TIME_S, 0.0))
    if variant.startswith("planned"):  # the posture follows the planned swivel path, no objective's gradient
        planned = sig.get("swivel_plan_deg", math.nan)
        parts = [f"moving to the {variant} path's start"]
        if math.isfinite(swivel):
            parts.append(f"swivel {swivel:+.0f}°" + (f" (planned {planned:+.0f}°)" if math.isfinite(planned) else ""))
        parts.append(f"{seconds:.1f} s")
        return parts[0] + ": " + ", ".join(parts[1:])
    parts = ["settling"]
    objective = getattr(scene, "objective", None)
    W = (getattr(scene, "W", None) or {}).get(f"W_{objective}", sig.get(f"W_{objective}")) if objective else None
    if W is not None and np.isfinite(W):
        parts.append(f"W_{objective} = {W:.3g}")
    if math.isfinite(swivel):
        parts.append(f"swivel {swivel:+.0f}°")
    parts.append(f"{seconds:.1f} s")
    return parts[0] + ": " + ", ".join(parts[1:])


class PolishScenario(Scenario):
    """Scenario 1 of DESIGN §5 with its settings: friction μ, sander, start swivel."""

    name = "polish"
    cases = MODES
    case_arg = "mode"
    title = "Polish"
    description = (
        "Press 20 N on a table, let the elbow settle under the chosen nullspace objective, then polish "
        "a zig-zag. With high friction, coupled postures (W_j, W_f) can oscillate when stretching forward."
    )
    default_robot = "rizon4s"
    default_executor = "projection"
    table_height = TABLE_HEIGHT_M
    groups: ClassVar[Mapping[str, type[ParamGroup]]] = {"scenario": PolishParams}
    segments = N_SEGMENTS
    plot_layout = ("force", "coupling", "torque")
    tune_first = ("Motion–force", "Nullspace", "Latency")
    claim_keys = ("contact.mu", "nullspace.objective", "sensor.reading_delay_steps")

    def __init__(
        self,
        mu: float = 0.25,
        sander: bool = False,
        start_swivel_deg: float = START_SWIVEL_DEG,
        sensor_noise: bool = True,
        converge_timeout_s: float = CONVERGE_TIMEOUT_S,
        hold_swivel_deg: float | None = None,
        armature_scale: float = 1.0,
        plan_cost: str | None = None,
        mode: str = "flow",
    ):
        if mode not in MODES:
            raise ValueError(f"unknown polish case {mode!r}; choose one of {', '.join(MODES)}")
        self.mode = mode  # the app's "Case": how the posture is chosen (see MODES)
        if mode == "mirror start":
            start_swivel_deg = MIRROR_START_DEG
        elif mode.startswith("planned"):
            plan_cost = "a" if mode == "planned W_a" else "signed"
        if not np.isfinite(mu) or mu < 0:
            raise ValueError(f"friction coefficient mu must be finite and non-negative, got {mu!r}")
        self.mu = float(mu)
        self.sander = bool(sander)
        self.start_swivel_deg = float(start_swivel_deg)
        self.sensor_noise = bool(sensor_noise)
        if not np.isfinite(converge_timeout_s) or converge_timeout_s < CONVERGE_MIN_S:
            raise ValueError(f"converge_timeout_s must be at least {CONVERGE_MIN_S} s, got {converge_timeout_s!r}")
        self.converge_timeout_s = float(converge_timeout_s)
        if hold_swivel_deg is not None and not np.isfinite(hold_swivel_deg):
            raise ValueError(f"hold_swivel_deg must be a finite angle, got {hold_swivel_deg!r}")
        # the posture held fixed at this swivel by the nullspace (W_j on the start posture, no flow)
        self.hold_swivel_deg = None if hold_swivel_deg is None else float(hold_swivel_deg)
        if not np.isfinite(armature_scale) or armature_scale < 0:
            raise ValueError(f"armature_scale must be finite and non-negative, got {armature_scale!r}")
        self.armature_scale = float(armature_scale)  # robot and controller model alike (the armature is a guess)
        if plan_cost is not None and plan_cost not in PLAN_COSTS:
            raise ValueError(f"unknown plan cost {plan_cost!r}; choose one of {', '.join(PLAN_COSTS)}")
        self.plan_cost = plan_cost  # "planned" objective: track the globally planned swivel path
        self._q0_cache: dict[tuple[str, float, float], np.ndarray] = {}
        self.table_height = TABLE_HEIGHT_M  # the paper's geometry; moved for an arm without a sidecar (_place)
        self.start_xy = START_XY_M
        self._clock: PhaseClock | None = None
        self.plan: Plan | None = None
        self._environment: PolishEnvironment | None = None

    @property
    def chosen_case(self) -> str:
        """The app's case: how the posture is chosen (`MODES`)."""
        return self.mode

    @property
    def start_swivel_used_deg(self) -> float:
        """The swivel the run starts from (the held swivel when holding)."""
        return self.start_swivel_deg if self.hold_swivel_deg is None else self.hold_swivel_deg

    def prepare_robot(self, robot: RobotDescription) -> None:
        """For an arm without sidecar postures, place the table and the start from its reach."""
        if "postures" in robot.guessed:
            self._place(robot)

    def _place(self, robot: RobotDescription) -> None:
        """The table height and start XY for an arm without a sidecar: the paper's geometry scaled by
        the first of PLACEMENT_SCALES (1 first, then those nearest the arm's size beside the Rizon's)
        at which the start and every zig-zag corner are reached tool
        down inside the joint limits (`reach.search_posture`, then IK along the corners)."""
        model = RobotModel(robot.model)
        swivel = np.deg2rad(self.start_swivel_used_deg)
        import robots

        # the paper's geometry first, then the scales nearest this arm's size beside the Rizon 4s's
        ratio = arm_size(robot) / arm_size(robots.load(PolishScenario.default_robot))
        for scale in (1.0, *sorted((s for s in PLACEMENT_SCALES if s != 1.0), key=lambda s: abs(s - ratio))):
            xy = (START_XY_M[0] * scale, START_XY_M[1] * scale)
            height = TABLE_HEIGHT_M * scale
            start = np.array([*xy, height + START_GAP_M])
            q = reach.search_posture(model, robot, start, TOOL_DOWN, swivel, ik_seed(robot))
            if q is None or not self._corners_reached(model, robot, q, xy, height):
                continue
            self.table_height, self.start_xy = height, xy
            self._q0_cache[(robot.spec or robot.name, self.start_swivel_used_deg, height)] = q
            if scale != 1.0:
                robot.guessed["placement"] = (
                    f"the table at {height:.2f} m and the start at ({xy[0]:.2f}, {xy[1]:.2f}) m: the paper's"
                    f" geometry scaled ×{scale:g} to this arm's reach; the force and coupling results are for"
                    " that workspace"
                )
            return
        raise ValueError(
            f"{robot.name} reaches the polish start tool down inside its joint limits at no table placement"
            f" (the paper's geometry scaled ×{min(PLACEMENT_SCALES):g}–×{max(PLACEMENT_SCALES):g})"
        )

    @staticmethod
    def _corners_reached(model: RobotModel, robot: RobotDescription, q: np.ndarray, xy, height: float) -> bool:
        for corner in segment_waypoints(xy):
            p = np.array([corner[0], corner[1], height])
            q = project_to_pose(model, q, p, TOOL_DOWN, iters=200)
            if float(np.max(np.abs(model.frame_pose(q, "tcp").translation - p))) > 1e-6 or not reach.inside(robot, q):
                return False
        return True

    def phase_text(self, status: Any, scene: Any, memory: dict[str, Any]) -> str:
        """Contact, settling (objective W, swivel, seconds; a planned case: the swivel and the planned
        one), S1…S6, done (signals "segment", "settle_s", "swivel_deg")."""
        return phase_text(status.t, status.signals, scene, str(getattr(status, "variant", "") or ""))

    def executor_changes(self, groups: Mapping[str, ParamGroup], robot: RobotDescription) -> dict[str, ParamGroup]:
        """Holding a swivel or following a plan runs the W_j objective [T18] on the target's posture
        (the projection executor's nullspace group; none for another executor)."""
        if (self.hold_swivel_deg is None and self.plan_cost is None) or "nullspace" not in groups:
            return {}
        return {"nullspace": replaced(groups["nullspace"], "objective", "j")}

    def armature(self, nominal: np.ndarray) -> np.ndarray:
        """The nominal armature × `armature_scale`, for the controller model and the simulated arm alike
        (the armature is a guess: robots/rizon4s.toml)."""
        return nominal * self.armature_scale

    def params(self) -> dict[str, ParamGroup]:
        """ "scenario": the start swivel, holding it, the armature scale (used at the next reset)."""
        held = self.hold_swivel_deg is not None
        return {
            "scenario": PolishParams(
                start_swivel_deg=self.hold_swivel_deg if held else self.start_swivel_deg,  # type: ignore[arg-type]
                hold_swivel=held,
                armature_scale=self.armature_scale,
            )
        }

    def set_params(self, name: str, group: Any) -> None:
        """A new start swivel / hold / armature scale for the next reset."""
        p = expect(name, group, PolishParams if name == "scenario" else None)
        self.start_swivel_deg = p.start_swivel_deg
        self.hold_swivel_deg = p.start_swivel_deg if p.hold_swivel else None
        self.armature_scale = p.armature_scale

    def pending_work(self, robot: RobotDescription) -> Work | None:
        """The planned swivel path of a planned case, while it is not cached."""
        if self.plan_cost is None:
            return None
        key = plan_key(robot, self.start_swivel_used_deg, self.plan_cost, self.armature_scale)
        if plan_cached(key):
            return None
        return Work(
            f"the swivel path {self.plan_cost!r} for {robot.name}",
            compute_plan,
            (robot, self.start_swivel_used_deg, self.plan_cost),
            functools.partial(store_plan, key),
        )

    def start_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """TCP position and rotation at the start (2 mm above the table, tool down)."""
        return np.array([self.start_xy[0], self.start_xy[1], self.table_height + START_GAP_M]), TOOL_DOWN.copy()

    def initial_q(self, robot: RobotDescription) -> np.ndarray:
        """Posture at the start pose with the chosen swivel (elbow up at 0°), from the home posture."""
        key = (robot.spec or robot.name, self.start_swivel_used_deg, self.table_height)  # spec: URDFs share stems
        if key not in self._q0_cache:
            model = RobotModel(robot.model)
            p, R = self.start_pose()
            q = project_to_pose(model, ik_seed(robot), p, R, iters=200)
            q = move_to_swivel(model, q, np.deg2rad(self.start_swivel_used_deg))
            if not reach.inside(robot, q):  # an arm without a sidecar start: search (app.scenarios.reach)
                found = reach.search_posture(model, robot, p, R, np.deg2rad(self.start_swivel_used_deg), q)
                if found is None:
                    raise ValueError(
                        f"{robot.name} cannot reach the polish start ({p[0]:.2f}, {p[1]:.2f}, {p[2]:.2f}) m tool"
                        f" down at swivel {self.start_swivel_used_deg:g}° inside its joint limits"
                    )
                q = found
            self._q0_cache[key] = q
        return self._q0_cache[key].copy()

    def make_environment(self, world: World, rng: np.random.Generator) -> Environment:
        """Table contact (μ of this scenario), sander if enabled, and a fresh phase clock."""
        contact = TableContact(
            self.table_height,
            stiffness_n_per_m=CONTACT_STIFFNESS_N_PER_M,
            mu=self.mu,
            v_eps_m_per_s=FRICTION_V_EPS_M_PER_S,
        )
        sander = Sander(amplitude_n=SANDER_AMPLITUDE_N, enabled=self.sander)
        # reset() builds the environment and then the target: the target reads this clock.
        self._clock = PhaseClock(timeout_s=self.converge_timeout_s)
        self._environment = PolishEnvironment(contact, sander, self._clock)
        return self._environment

    def make_sensor(self, rng: np.random.Generator) -> Sensor:
        """F/T sensor of [T] §IV-A (noise off when sensor_noise is False; the filter stays)."""
        return FTSensor(rng, cutoff_hz=SENSOR_CUTOFF_HZ, noise=self.sensor_noise)

    def make_target(
        self, robot: RobotDescription, model: RobotModel, dyn0: Dynamics, gains: Mapping[str, ParamGroup]
    ) -> Callable[[float], TaskTarget]:
        """Hold the start XY with 20 N, then the zig-zag once the clock starts it; a plan is led by the
        W_j lag 1/k0_j of the nullspace group in force (`gains`)."""
        clock = self._clock if self._clock is not None else PhaseClock()
        p0, R0 = self.start_pose()
        q_posture = dyn0.q.copy()
        self.plan = None
        if self.plan_cost is not None:
            if self.table_height != TABLE_HEIGHT_M or self.start_xy != START_XY_M:
                raise ValueError("the planned cases plan on the paper's table; this arm's table was moved to its reach")
            self.plan = planned_path(robot, model, self.start_swivel_used_deg, self.plan_cost, self.armature_scale)
            clock.earliest_end_s = CONTACT_TIME_S + self.plan.transfer_s
        target = PolishTarget(p0, R0, q_posture, clock, self.plan, plan_lead_s(gains))
        if self._environment is not None:
            self._environment.target = target
        return target


def settle_now(session) -> object:
    """Run the settle phase of a polish session unpaced (as fast as the machine allows) until the
    posture has converged or the cap is reached: `Session.run` with the settle criterion as its
    `until`. Returns the `RunResult` (stop "until" when the settle phase ended; "done" when it
    had already ended or there is nothing to settle). The app runs the same phase in chunks on its
    loop (`Lab.settle_chunk`) so Pause and Reset act during it."""
    clock = getattr(session.environment, "clock", None)
    if not session.settle_pending():
        return session.run(steps=0)
    assert isinstance(clock, PhaseClock)
    remaining = CONTACT_TIME_S + clock.timeout_s - session.world.time + 2 * session.world.model.opt.timestep
    return session.run(max(remaining, 0.0), until=lambda r: clock.trajectory_start is not None)


SCENARIO = PolishScenario()
