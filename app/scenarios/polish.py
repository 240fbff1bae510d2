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

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from app.scenarios import Environment, Scenario, Sensor
from app.sim.contact import TableContact
from app.sim.disturbances import Sander
from app.sim.sensor import FTSensor
from app.sim.world import World
from control.coupling import move_to_swivel, project_to_pose
from control.executor import TaskTarget
from control.model import Dynamics, RobotModel
from robots import RobotDescription

# ---- geometry -------------------------------------------------------------------------------
TABLE_HEIGHT_M = 0.20  # table top 0.2 m above the robot base: TCP 0.34 m below home, mid-workspace
START_XY_M = (0.65, -0.20)  # trajectory start, stretched forward (S1 retracts first) on the right
START_GAP_M = 0.002  # TCP starts 2 mm above the table: a short approach at the law's free-space speed
TOOL_DOWN = np.diag([-1.0, 1.0, -1.0])  # tool z axis along −world z, x along −world x (as at home)
START_SWIVEL_DEG = 0.0  # Fig. 6a "elbow up": elbow straight above the shoulder–wrist line

# ---- trajectory (Fig. 7) --------------------------------------------------------------------
SEGMENT_DX_M = 0.20  # x between 0.45 and 0.65 m: keeps the elbow clear of full flexion and the arm of full reach
SEGMENT_DY_M = 0.06  # y advances 6 cm per segment: a zig-zag across 0.36 m of table
SEGMENT_DURATION_S = 2.5  # peak speed 1.875·0.21/2.5 ≈ 0.16 m/s: a hand-polishing pace
N_SEGMENTS = 6
HOLD_AFTER_S = 0.5  # rest at the end so the last segment's transient is recorded

# ---- phases ---------------------------------------------------------------------------------
CONTACT_TIME_S = 1.0  # approach + 20 N settle (force loop settles in ~0.1 s)
CONVERGE_MIN_S = 1.0  # the posture converges at least this long
CONVERGE_TIMEOUT_S = 15.0  # give up waiting for the self-motion to stop (gradient flows crawl on plateaus)
CONVERGED_SPEED_RAD_S = 0.01  # ‖q̇‖ below this for CONVERGED_HOLD_S counts as converged
CONVERGED_HOLD_S = 0.3

# ---- contact, sensor, disturbance -------------------------------------------------------------
DESIRED_FORCE_N = 20.0  # Table II
CONTACT_STIFFNESS_N_PER_M = 30000.0  # [T] §IV-A
FRICTION_V_EPS_M_PER_S = 0.01  # 16× below cruise speed: Coulomb from 0.1 m/s on (implicit step: stable at any v_ε)
SENSOR_CUTOFF_HZ = 25.0  # [T] §IV-A first-order low-pass of the F/T reading
SANDER_AMPLITUDE_N = 10.0  # 7000 RPM, ≈ 4 g imbalance at a 5 mm orbit (m e ω²)


def min_jerk(s: float) -> tuple[float, float, float]:
    """Position, velocity and acceleration (per unit length, per unit time²) of a 0→1 minimum-jerk
    profile at normalised time s ∈ [0, 1]."""
    s = min(max(s, 0.0), 1.0)
    p = 10 * s**3 - 15 * s**4 + 6 * s**5
    v = 30 * s**2 - 60 * s**3 + 30 * s**4
    a = 60 * s - 180 * s**2 + 120 * s**3
    return p, v, a


def segment_waypoints(start_xy: tuple[float, float] = START_XY_M) -> np.ndarray:
    """(N_SEGMENTS + 1, 2) XY corners of the zig-zag: odd segments −X, even segments +X."""
    pts = [np.array(start_xy, dtype=float)]
    for k in range(N_SEGMENTS):
        dx = -SEGMENT_DX_M if k % 2 == 0 else SEGMENT_DX_M
        pts.append(pts[-1] + np.array([dx, SEGMENT_DY_M]))
    return np.array(pts)


@dataclass
class PhaseClock:
    """When the trajectory starts: set by the environment once the posture has converged."""

    trajectory_start: float | None = None
    quiet_since: float | None = None
    timeout_s: float = CONVERGE_TIMEOUT_S

    def observe(self, t: float, joint_speed: float) -> None:
        """Update with the measured joint speed (the TCP is held, so this is the self-motion)."""
        if self.trajectory_start is not None:
            return
        if t >= CONTACT_TIME_S + self.timeout_s:
            self.trajectory_start = t
            return
        if t < CONTACT_TIME_S + CONVERGE_MIN_S or joint_speed > CONVERGED_SPEED_RAD_S:
            self.quiet_since = None
            return
        if self.quiet_since is None:
            self.quiet_since = t
        elif t - self.quiet_since >= CONVERGED_HOLD_S:
            self.trajectory_start = t

    def segment(self, t: float) -> tuple[int, float]:
        """(segment index 1..6, or 0 before and 7 after the trajectory; time into the segment)."""
        if self.trajectory_start is None or t < self.trajectory_start:
            return 0, 0.0
        tau = t - self.trajectory_start
        k = int(tau // SEGMENT_DURATION_S)
        if k >= N_SEGMENTS:
            return N_SEGMENTS + 1, tau - N_SEGMENTS * SEGMENT_DURATION_S
        return k + 1, tau - k * SEGMENT_DURATION_S

    def finished(self, t: float) -> bool:
        """True once the trajectory and the final hold are over."""
        return self.trajectory_start is not None and t >= self.trajectory_start + trajectory_duration() + HOLD_AFTER_S


def trajectory_duration() -> float:
    """Duration of the six segments, s."""
    return N_SEGMENTS * SEGMENT_DURATION_S


class PolishEnvironment(Environment):
    """Table contact, optional sander, and the phase clock of the protocol."""

    def __init__(self, contact: TableContact, sander: Sander, clock: PhaseClock):
        self.contact = contact
        self.sander = sander
        self.clock = clock
        self._sander_force = np.zeros(3)

    def apply(self, world: World, t: float) -> dict[str, float]:
        """Contact and sander forces for this step; advances the phase clock."""
        self.clock.observe(t, float(np.linalg.norm(world.dq)))
        state = self.contact.apply(world)
        self._sander_force = self.sander.apply(world, t)
        friction = state.friction_force if state.friction_force is not None else np.zeros(3)
        segment, _ = self.clock.segment(t)
        return {
            "contact_force_n": state.normal_force_n,
            "friction_x_n": float(friction[0]),
            "friction_y_n": float(friction[1]),
            "tcp_speed_m_s": state.tangential_speed,
            "segment": float(segment),
        }

    def configure(self, **changes: object) -> None:
        """mu, stiffness_n_per_m, v_eps_m_per_s (contact); sander_amplitude_n, sander_enabled."""
        contact = {k: v for k, v in changes.items() if k in ("mu", "stiffness_n_per_m", "v_eps_m_per_s")}
        sander = {}
        if "sander_amplitude_n" in changes:
            sander["amplitude_n"] = changes["sander_amplitude_n"]
        if "sander_enabled" in changes:
            sander["enabled"] = changes["sander_enabled"]
        rest = set(changes) - set(contact) - {"sander_amplitude_n", "sander_enabled"}
        if rest:
            raise ValueError(f"polish environment has no setting {', '.join(sorted(rest))}")
        self.contact.configure(**contact)
        self.sander.configure(**sander)

    def overlay(self) -> dict[str, np.ndarray]:
        """Contact force and friction at the contact point (world)."""
        s = self.contact.state
        point = s.point if s.point is not None else np.zeros(3)
        friction = s.friction_force if s.friction_force is not None else np.zeros(3)
        return {
            "contact_point": point,
            "contact_force": friction + np.array([0.0, 0.0, s.normal_force_n]),
            "sander_force": self._sander_force,
        }


class SensorAdapter(Sensor):
    """The scenario's `Sensor` over the F/T sensor model."""

    def __init__(self, sensor: FTSensor):
        self.ft = sensor

    def measure(self, true_wrench: np.ndarray, t: float) -> np.ndarray:
        """Noisy, filtered reading (world axes, at the sensor)."""
        return self.ft.measure(true_wrench, t)

    def configure(self, **changes: object) -> None:
        """Noise and filter settings of `FTSensor`."""
        self.ft.configure(**changes)

    def reset(self) -> None:
        """Clear the filter state."""
        self.ft.reset()


class PolishScenario(Scenario):
    """Scenario 1 of DESIGN §5 with its settings: friction μ, sander, start swivel."""

    name = "polish"
    title = "Polish"
    description = (
        "Press 20 N on a table, let the elbow settle under the chosen nullspace objective, then polish "
        "a zig-zag. With high friction, coupled postures (W_j, W_f) can oscillate when stretching forward."
    )
    default_robot = "rizon4s"
    default_executor = "projection"
    table_height = TABLE_HEIGHT_M

    def __init__(
        self,
        mu: float = 0.25,
        sander: bool = False,
        start_swivel_deg: float = START_SWIVEL_DEG,
        sensor_noise: bool = True,
        converge_timeout_s: float = CONVERGE_TIMEOUT_S,
    ):
        if not np.isfinite(mu) or mu < 0:
            raise ValueError(f"friction coefficient mu must be finite and non-negative, got {mu!r}")
        self.mu = float(mu)
        self.sander = bool(sander)
        self.start_swivel_deg = float(start_swivel_deg)
        self.sensor_noise = bool(sensor_noise)
        if not np.isfinite(converge_timeout_s) or converge_timeout_s < CONVERGE_MIN_S:
            raise ValueError(f"converge_timeout_s must be at least {CONVERGE_MIN_S} s, got {converge_timeout_s!r}")
        self.converge_timeout_s = float(converge_timeout_s)
        self._q0_cache: dict[tuple[str, float], np.ndarray] = {}
        self._clock: PhaseClock | None = None

    def start_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """TCP position and rotation at the start (2 mm above the table, tool down)."""
        return np.array([START_XY_M[0], START_XY_M[1], TABLE_HEIGHT_M + START_GAP_M]), TOOL_DOWN.copy()

    def initial_q(self, robot: RobotDescription) -> np.ndarray:
        """Posture at the start pose with the chosen swivel (elbow up at 0°), from the home posture."""
        key = (robot.name, self.start_swivel_deg)
        if key not in self._q0_cache:
            model = RobotModel(robot.model)
            p, R = self.start_pose()
            q = project_to_pose(model, robot.home, p, R, iters=200)
            q = move_to_swivel(model, q, np.deg2rad(self.start_swivel_deg))
            self._q0_cache[key] = q
        return self._q0_cache[key].copy()

    def make_environment(self, world: World, rng: np.random.Generator) -> Environment:
        """Table contact (μ of this scenario), sander if enabled, and a fresh phase clock."""
        contact = TableContact(
            TABLE_HEIGHT_M,
            stiffness_n_per_m=CONTACT_STIFFNESS_N_PER_M,
            mu=self.mu,
            v_eps_m_per_s=FRICTION_V_EPS_M_PER_S,
        )
        sander = Sander(amplitude_n=SANDER_AMPLITUDE_N, enabled=self.sander)
        # reset() builds the environment and then the target: the target reads this clock.
        self._clock = PhaseClock(timeout_s=self.converge_timeout_s)
        return PolishEnvironment(contact, sander, self._clock)

    def make_sensor(self, rng: np.random.Generator) -> Sensor:
        """F/T sensor of [T] §IV-A (noise off when sensor_noise is False; the filter stays)."""
        if self.sensor_noise:
            return SensorAdapter(FTSensor(rng, cutoff_hz=SENSOR_CUTOFF_HZ))
        return SensorAdapter(
            FTSensor(rng, force_noise_var=0.0, torque_noise_var=0.0, sine_amplitude_n=0.0, cutoff_hz=SENSOR_CUTOFF_HZ)
        )

    def make_target(self, robot: RobotDescription, model: RobotModel, dyn0: Dynamics) -> Callable[[float], TaskTarget]:
        """Hold the start XY with 20 N, then the zig-zag once the clock starts it."""
        clock = self._clock if self._clock is not None else PhaseClock()
        p0, R0 = self.start_pose()
        q_posture = dyn0.q.copy()
        return PolishTarget(p0, R0, q_posture, clock)


class PolishTarget:
    """TaskTarget as a function of time: the zig-zag of Fig. 7 with 20 N along +z."""

    def __init__(self, start_position: np.ndarray, rotation: np.ndarray, q_posture: np.ndarray, clock: PhaseClock):
        self.start = np.asarray(start_position, dtype=float)
        self.rotation = rotation
        self.q_posture = q_posture
        self.clock = clock
        self.corners = segment_waypoints((float(self.start[0]), float(self.start[1])))
        self.wrench = np.array([0.0, 0.0, DESIRED_FORCE_N, 0.0, 0.0, 0.0])

    def __call__(self, t: float) -> TaskTarget:
        """The target at time t."""
        k, tau = self.clock.segment(t)
        pos = self.start.copy()
        vel = np.zeros(6)
        acc = np.zeros(6)
        if k == 0:
            pass
        elif k > N_SEGMENTS:
            pos[:2] = self.corners[-1]
        else:
            a, b = self.corners[k - 1], self.corners[k]
            T = SEGMENT_DURATION_S
            s_p, s_v, s_a = min_jerk(tau / T)
            pos[:2] = a + s_p * (b - a)
            vel[:2] = s_v / T * (b - a)
            acc[:2] = s_a / T**2 * (b - a)
        return TaskTarget(
            position=pos,
            rotation=self.rotation,
            velocity=vel,
            acceleration=acc,
            wrench=self.wrench,
            q_posture=self.q_posture,
        )


SCENARIO = PolishScenario()
