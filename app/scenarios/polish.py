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
from collections import deque
from collections.abc import Callable, Mapping
from concurrent.futures import Future
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from app.scenarios import Environment, Offload, Scenario, Sensor, Work, reach
from app.sim.contact import TableContact
from app.sim.disturbances import Sander
from app.sim.sensor import FTSensor
from app.sim.world import World
from control.coupling import POLISH_SUBSPACES, move_to_swivel, project_to_pose
from control.executor import TaskTarget, float_array
from control.gains import MotionForceGains
from control.kernels.geometry import swivel_of_anchors_fused
from control.margin import ContactLoop, posture_margin
from control.model import Dynamics, RobotModel
from control.params import ParamGroup, expect, param, replaced
from control.planner import PLAN_COSTS, Plan, cost_map, loops_along
from control.planner import plan as make_plan
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
PEAK_SPEED_M_S = 1.875 * float(np.hypot(SEGMENT_DX_M, SEGMENT_DY_M)) / SEGMENT_DURATION_S  # minimum-jerk peak
HOLD_AFTER_S = 0.5  # rest at the end so the last segment's transient is recorded

# an arm without sidecar postures: the paper's table and start scaled by the first of these it reaches
PLACEMENT_SCALES = (1.0, 0.9, 1.1, 0.8, 1.2, 0.7, 1.3, 0.6, 1.4, 0.5)
MIRROR_START_DEG = -30.0  # just across the W_a ridge (≈ −31° on the scan) from the Fig. 6a start: the other basin
# The app's cases: the gradient flow of the chosen objective from the Fig. 6a start, the same from the
# mirror start, or the globally planned swivel path with cost W_a or the directional coupling where its sign
# destabilises the force loop, max(P_d·f̂, 0)² (control.planner "signed").
MODES = ("flow", "mirror start", "planned W_a", "planned max(P_d·f̂, 0)²")

# ---- phases ---------------------------------------------------------------------------------
CONTACT_TIME_S = 1.0  # approach + 20 N settle (force loop settles in ~0.1 s)
CONVERGE_MIN_S = 1.0  # the posture converges at least this long (one W window)
# The settle phase ends when the posture has converged ([T] §IV-B "until the robot configuration
# converged"), judged on the QP's goal nullspace velocity and on W over the last second:
SETTLE_WINDOW_S = 1.0  # both tests look at the last second
SETTLE_SPEED_RAD_S = (
    1e-3  # max ‖q̂̇n‖ over the window: ≤ 0.9° of drift over the 15 s trajectory, 8× below the W_a plateau flow
)
SETTLE_W_RTOL = 1e-3  # |W(t) − W(t − 1 s)| ≤ rtol·|W| + atol: W changes < 1.5 % over the trajectory at that rate
SETTLE_W_ATOL = 1e-6  # absolute floor for W → 0 (W_j, rad²: ‖q − q_d‖ ≈ 1.4 mrad)
CONVERGE_TIMEOUT_S = 120.0  # safety cap of the settle phase; a run that reaches it is reported as not converged
LIVE_MARGIN_EVERY_S = 1.0  # the live force-loop margin signal is recomputed once a simulated second
LIVE_RATE_EVERY_S = 0.1  # the live decay rate σ at the step's posture and stroke state: 10 Hz of simulated time
LIVE_POLL_EVERY_S = 0.01  # the offload's answers are looked for every 10 ms of simulated time (a 100 Hz display)
LIVE_PENDING_MAX = 10  # live figures under way in the offload at most (1 s of σ): beyond, a sample is skipped

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


class SettleCriterion:
    """Convergence of the posture while the TCP is held: over the last `SETTLE_WINDOW_S` the goal
    nullspace speed ‖q̂̇n‖ of the QP stayed below `SETTLE_SPEED_RAD_S` and W changed by at most
    `SETTLE_W_RTOL`·|W| + `SETTLE_W_ATOL`. A slow flow over a plateau fails the speed test; a
    flow whose speed is small but whose W still falls fails the W test."""

    def __init__(
        self,
        speed_tol: float = SETTLE_SPEED_RAD_S,
        w_rtol: float = SETTLE_W_RTOL,
        w_atol: float = SETTLE_W_ATOL,
        window_s: float = SETTLE_WINDOW_S,
        dt: float = 1e-3,
    ):
        self.speed_tol, self.w_rtol, self.w_atol = float(speed_tol), float(w_rtol), float(w_atol)
        self.window = max(1, round(window_s / dt))
        self._w: deque[float] = deque(maxlen=self.window + 1)
        self._last_fast = -1  # sample index of the last speed above the tolerance
        self._n = 0

    def reset(self) -> None:
        """Forget the history (a new settle phase, or the objective changed)."""
        self._w.clear()
        self._last_fast = -1
        self._n = 0

    def update(self, nullspace_speed: float, w: float) -> bool:
        """Add one step's ‖q̂̇n‖ (rad/s) and W; True when the posture counts as converged."""
        if not (math.isfinite(nullspace_speed) and math.isfinite(w)):
            self.reset()
            return False
        if nullspace_speed > self.speed_tol:
            self._last_fast = self._n
        self._w.append(w)
        self._n += 1
        if len(self._w) <= self.window or self._n - 1 - self._last_fast < self.window:
            return False
        return abs(self._w[-1] - self._w[0]) <= self.w_rtol * abs(self._w[-1]) + self.w_atol

    def progress(self) -> tuple[float, float]:
        """(seconds the speed has been below its tolerance, relative W change over the window)."""
        quiet = (self._n - 1 - self._last_fast) / self.window * SETTLE_WINDOW_S if self._n else 0.0
        if len(self._w) < 2:
            return quiet, float("nan")
        return quiet, abs(self._w[-1] - self._w[0]) / max(abs(self._w[-1]), 1e-12)


@dataclass
class PhaseClock:
    """When the trajectory starts: set once the posture has converged (or at the cap)."""

    trajectory_start: float | None = None
    timeout_s: float = CONVERGE_TIMEOUT_S
    converged: bool = False  # the settle phase ended on the criterion, not at the cap
    earliest_end_s: float = CONTACT_TIME_S + CONVERGE_MIN_S  # e.g. a planned transfer's end
    criterion: SettleCriterion = field(default_factory=SettleCriterion)
    last_speed: float = float("nan")
    last_w: float = float("nan")

    @property
    def settle_start(self) -> float:
        """Time the settle phase begins (the TCP is on the table)."""
        return CONTACT_TIME_S

    @property
    def convergence_time_s(self) -> float | None:
        """Seconds from the settle start to the trajectory start (None while settling)."""
        return None if self.trajectory_start is None else self.trajectory_start - CONTACT_TIME_S

    def observe(self, t: float, nullspace_speed: float, w: float) -> None:
        """Feed one step's goal nullspace speed ‖q̂̇n‖ and W (the TCP is held, so this is the self-motion)."""
        if self.trajectory_start is not None:
            return
        self.last_speed, self.last_w = nullspace_speed, w
        if t < CONTACT_TIME_S:
            return
        done = self.criterion.update(nullspace_speed, w)
        if t >= CONTACT_TIME_S + self.timeout_s:
            self.trajectory_start = t
            return
        if done and t >= self.earliest_end_s:
            self.converged = True
            self.trajectory_start = t

    def start_now(self, t: float) -> None:
        """Start the trajectory at t whatever the criterion says (not converged)."""
        if self.trajectory_start is None:
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


def rate_at(Lambda: np.ndarray, gains: MotionForceGains, loop: ContactLoop, tau: float) -> float:
    """σ (1/s) of the force loop at a posture's Λx at trajectory time tau (`polish_margin.sample`), NaN
    where the model cannot be formed; a module-level function, so the app's loop can compute it in
    its worker process."""
    from app.scenarios.polish_margin import sample

    try:
        return sample(Lambda, gains, loop, tau, find_kd=False).rate_per_s
    except (ValueError, np.linalg.LinAlgError):
        return float("nan")


def kd_margin_at(Lambda: np.ndarray, gains: MotionForceGains, loop: ContactLoop) -> float:
    """Force-loop margin (N s/m, `control.margin`) of a posture's Λx: K_f^d minus the critical K_f^d
    over the stretching and retracting friction directions, at rest and at the segments' peak speed
    (`loop` at that speed), with the loop's latency (a coarse version of the report's, for once a
    second); NaN where the model cannot be formed."""
    dirs = [friction_direction(1.5 * SEGMENT_DURATION_S), friction_direction(0.5 * SEGMENT_DURATION_S)]
    try:
        pm = posture_margin(
            Lambda, POLISH_SUBSPACES, gains, loop, dirs, speeds=(0.0, 0.3 * PEAK_SPEED_M_S, PEAK_SPEED_M_S)
        )
    except (ValueError, np.linalg.LinAlgError):
        return float("nan")
    return pm.kd_margin


class PolishEnvironment(Environment):
    """Table contact, optional sander, and the phase clock of the protocol."""

    def __init__(self, contact: TableContact, sander: Sander, clock: PhaseClock):
        self.contact = contact
        self.sander = sander
        self.clock = clock
        self._sander_force = np.zeros(3)
        self._world: World | None = None
        self._joints: list[int] = []
        self.target: PolishTarget | None = None  # set by the scenario once the target exists
        self._params: Callable[[], Mapping[str, Any]] | None = None  # the session's groups (the margin's gains)
        self._margin = float("nan")
        self._margin_at = -np.inf
        # seconds between live margin signals (the page's Nullspace panel reads them); inf: none, for
        # headless runs that do not read them (each costs about as much as a thousand steps)
        self.live_margin_every_s = LIVE_MARGIN_EVERY_S
        # the decay rate σ (1/s) of the force loop at the step's posture and stroke state, every
        # live_rate_every_s while live_margin_every_s is finite, its worst value on this stroke so far,
        # and the stroke headroom those samples leave (`polish_margin.StrokeHeadroom`)
        self.live_rate_every_s = LIVE_RATE_EVERY_S
        self._rate = float("nan")
        self._rate_at = -np.inf
        self._rate_segment = -1
        self._rate_stroke_min = float("nan")
        self._headroom: Any = None  # a `polish_margin.StrokeHeadroom` from the first σ on
        self._offload: Offload | None = None
        self._dynamics: Callable[[], Dynamics] | None = None
        # live figures under way in the offload, oldest first: (kind, t, segment, budget, future)
        self._pending: deque[tuple[str, float, int, float, Future]] = deque()
        self._polled_at = -np.inf

    def connect(
        self,
        params: Callable[[], Mapping[str, Any]],
        offload: Offload | None = None,
        dynamics: Callable[[], Dynamics] | None = None,
    ) -> None:
        """Read the controller's gains for the live margin from the session's groups and Λx from the
        step's dynamics; compute the live figures in `offload` when given (off the loop thread), else
        inline."""
        self._params = params
        self._offload = offload
        self._dynamics = dynamics

    def settle_pending(self) -> bool:
        """True until the posture has converged (or the cap) and the zig-zag starts."""
        return self.clock.trajectory_start is None

    def apply(self, world: World, t: float) -> dict[str, float]:
        """Contact and sander forces for this step, and the settle progress."""
        if self._world is not world:  # joint anchors (shoulder, elbow, wrist = joints 2, 4, 6) for the swivel
            self._world = world
            self._joints = [world.model.joint(n).id for n in world.robot.joint_names]
        state = self.contact.apply(world)
        self._sander_force = self.sander.apply(world, t)
        friction = state.friction_force if state.friction_force is not None else np.zeros(3)
        friction_x, friction_y, _ = friction.tolist()
        segment, _ = self.clock.segment(t)
        return {
            "contact_force_n": state.normal_force_n,
            "friction_x_n": friction_x,
            "friction_y_n": friction_y,
            "tcp_speed_m_s": state.tangential_speed,
            "segment": float(segment),
            **self.settle_signals(t),
        }

    def settle_signals(self, t: float) -> dict[str, float]:
        """Settle progress for the status line and plots: seconds settling, converged (1/0, NaN while
        settling), seconds the nullspace speed has been quiet, relative W change over the last second."""
        clock = self.clock
        settling = clock.trajectory_start is None
        quiet, dw = clock.criterion.progress() if settling else (float("nan"), float("nan"))
        joints = self._joints
        swivel = (  # `swivel_of_points` of the shoulder, elbow and wrist anchors, compiled
            math.degrees(swivel_of_anchors_fused(self._world.data.xanchor, joints[1], joints[3], joints[5]))
            if self._world is not None
            else float("nan")
        )
        live = self.live_margin_every_s < np.inf  # inf: no live margin at all (at t = 0 neither)
        due = t - self._rate_at >= self.live_rate_every_s - 1e-9 or t - self._margin_at >= self.live_margin_every_s
        if self._pending and t - self._polled_at >= LIVE_POLL_EVERY_S - 1e-9:
            due = True  # look for answers now and then, not at every step
        if self._world is not None and live and due:
            self._polled_at = t
            self._live_figures(t)
        headroom, headroom_min = self._headroom_now(t)
        target = self.target
        return {
            "swivel_deg": swivel,
            "swivel_plan_deg": target.planned_swivel_deg(t) if target is not None else float("nan"),
            "margin_kd": self._margin,
            "margin_rate": self._rate,
            "margin_rate_stroke_min": self._rate_stroke_min,
            "margin_headroom_np": headroom,
            "margin_headroom_stroke_min_np": headroom_min,
            "settle_s": max(t - CONTACT_TIME_S, 0.0) if settling else float(clock.convergence_time_s or 0.0),
            "settle_converged": float("nan") if settling else float(clock.converged),
            "settle_quiet_s": quiet if settling else float("nan"),
            "settle_dW_rel": dw if settling else float("nan"),
        }

    def _live_figures(self, t: float) -> None:
        """Take the live figures the offload has finished; start σ every `live_rate_every_s` and the
        K_f^d margin every `live_margin_every_s`: inline without an offload, else submitted with a
        snapshot of the posture (Λx) and the groups, and skipped while LIVE_PENDING_MAX are under way."""
        while self._pending and self._pending[0][4].done():
            kind, at, segment, budget, future = self._pending.popleft()
            value = float("nan") if future.exception() is not None else float(future.result())
            self._store(kind, at, segment, budget, value)
        due_kd = t - self._margin_at >= self.live_margin_every_s
        due_rate = t - self._rate_at >= self.live_rate_every_s - 1e-9
        if not (due_kd or due_rate):
            return
        if due_kd:
            self._margin_at = t
        if due_rate:
            self._rate_at = t
        segment, _ = self.clock.segment(t)
        offload = self._offload
        if offload is None:
            if due_kd:
                self._margin = self.live_margin(t)
            if due_rate:
                self._store("rate", t, segment, self._budget(), self.live_rate(t))
            return
        groups = self._params() if self._params is not None else {}
        Lambda = self._lambda()
        gains = groups.get("motion_force")
        if Lambda is None or not isinstance(gains, MotionForceGains):
            return
        jobs: list[tuple[str, Callable[..., float], tuple]] = []
        if due_kd:
            jobs.append(("kd", kd_margin_at, (Lambda, gains, self._contact_loop(PEAK_SPEED_M_S, groups))))
        if due_rate:
            tau = self._tau(t)
            jobs.append(("rate", rate_at, (Lambda, gains, self._contact_loop(0.0, groups), tau)))
        budget = self._budget(groups)
        for kind, fn, args in jobs:
            submitted = offload.submit(fn, *args) if len(self._pending) < LIVE_PENDING_MAX else None
            if submitted is not None:
                self._pending.append((kind, t, segment, budget, submitted))

    def _store(self, kind: str, t: float, segment: int, budget: float, value: float) -> None:
        """A live figure computed for time t: the K_f^d margin, or σ with the worst σ of its stroke and
        the stroke headroom (NaN outside the six strokes)."""
        if kind == "kd":
            self._margin = value
            return
        self._rate = value
        if segment != self._rate_segment:
            self._rate_segment = segment
            self._rate_stroke_min = float("nan")
        if 1 <= segment <= N_SEGMENTS and math.isfinite(value):
            prev = self._rate_stroke_min
            self._rate_stroke_min = value if not math.isfinite(prev) else min(prev, value)
        if self._headroom is None:
            from app.scenarios.polish_margin import StrokeHeadroom

            self._headroom = StrokeHeadroom(budget, self.live_rate_every_s)
        self._headroom.budget_np = budget
        self._headroom.add(t, segment, value)

    def _headroom_now(self, t: float) -> tuple[float, float]:
        """The stroke headroom now and its least value on this stroke so far (Np): the whole budget
        from the stroke's start until its first σ is in, NaN outside the strokes."""
        h = self._headroom
        if h is None:
            return math.nan, math.nan
        segment, _ = self.clock.segment(t)
        if not 1 <= segment <= N_SEGMENTS:
            return math.nan, math.nan
        if h.segment != segment or not math.isfinite(h.headroom_np):
            return h.budget_np, h.budget_np
        return h.headroom_np, h.headroom_min_np

    def _budget(self, groups: Mapping[str, Any] | None = None) -> float:
        """ln(F̂ / noise floor) (Np) of the session's sensor group: each stroke's headroom at its start."""
        from app.scenarios.polish_margin import headroom_budget_np, sensor_floor_n

        if groups is None:
            groups = self._params() if self._params is not None else {}
        sensor = groups.get("sensor")
        if sensor is None or self._world is None:
            return math.nan
        floor = sensor_floor_n(sensor, float(self._world.model.opt.timestep))
        return headroom_budget_np(DESIRED_FORCE_N, floor)

    def _tau(self, t: float) -> float:
        """Trajectory time at t (0 before the strokes: at rest)."""
        start = self.clock.trajectory_start
        return 0.0 if start is None else t - start

    def _contact_loop(self, speed_m_s: float, groups: Mapping[str, Any] | None = None) -> ContactLoop:
        """The run's `ContactLoop`: this contact, the session's sensor group (cutoff, reading age) and
        the world's torque delay (`app.scenarios.polish_margin.contact_loop`)."""
        from app.scenarios.polish_margin import contact_loop

        if groups is None:
            groups = self._params() if self._params is not None else {}
        return contact_loop(self.contact, groups.get("sensor"), self._world, speed_m_s)

    def _lambda(self) -> np.ndarray | None:
        """Λx of the posture now: the step's dynamics snapshot's (the controller's model, computed this
        step anyway), or from the simulated arm without a session."""
        if self._dynamics is not None:
            return self._dynamics().Lambda
        world = self._world
        if world is None:
            return None
        J = world.tcp_jacobian()
        try:
            return np.linalg.inv(J @ np.linalg.solve(world.mass_matrix(), J.T))
        except np.linalg.LinAlgError:
            return None

    def live_rate(self, t: float) -> float:
        """Decay rate σ (1/s, `app.scenarios.polish_margin`) of the force loop at the current posture,
        linearised about the stroke's commanded speed and friction direction at t (at rest before
        the strokes), with the run's latency: < 0 when a mode grows."""
        groups = self._params() if self._params is not None else {}
        gains = groups.get("motion_force")
        Lambda = self._lambda()
        if Lambda is None or not isinstance(gains, MotionForceGains):
            return float("nan")
        return rate_at(Lambda, gains, self._contact_loop(0.0, groups), self._tau(t))

    def live_margin(self, t: float) -> float:
        """Force-loop margin (N s/m, `kd_margin_at`) of the current posture with the run's latency."""
        gains = self._params().get("motion_force") if self._params is not None else None
        if self._world is None or not isinstance(gains, MotionForceGains):
            return float("nan")
        Lambda = self._lambda()
        if Lambda is None:
            return float("nan")
        return kd_margin_at(Lambda, gains, self._contact_loop(PEAK_SPEED_M_S))

    def observe(self, signals: dict[str, float], t: float) -> None:
        """After the controller: feed the clock with the QP's goal nullspace speed and W."""
        speed = signals.get("nullspace_speed")
        self.clock.observe(t, float("nan") if speed is None else speed, signals.get("W", float("nan")))

    def params(self) -> dict[str, Any]:
        """ "contact" (μ, stiffness, v_ε) and "sander"."""
        return {**self.contact.params(), **self.sander.params()}

    def set_params(self, name: str, group: Any) -> None:
        """Hand a new group to the contact or the sander."""
        (self.sander if name == "sander" else self.contact).set_params(name, group)

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


def _chain_length(robot: RobotDescription) -> float:
    """Sum of the distances between the joints from joint 2 to the TCP (m): the arm's size."""
    model = robot.model
    length = sum(float(np.linalg.norm(model.jointPlacements[j].translation)) for j in range(2, model.njoints))
    return length + float(np.linalg.norm(model.frames[model.getFrameId("tcp")].placement.translation))


def ik_seed(robot: RobotDescription) -> np.ndarray:
    """Where the start pose's IK begins: the robot's `polish_start` posture if its sidecar names one,
    else its home posture."""
    return np.array(robot.postures.get("polish_start", robot.home), dtype=float)


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
    cases = MODES
    case_arg = "mode"

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
        self._plan_lead_s = 0.0
        self._executor: object | None = None
        self._environment: PolishEnvironment | None = None

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
        ratio = _chain_length(robot) / _chain_length(robots.load(PolishScenario.default_robot))
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

    def configure_executor(self, executor: object, robot: RobotDescription) -> None:
        """Holding a swivel or following a plan runs the W_j objective [T18] on the target's posture."""
        groups: dict = getattr(executor, "params", dict)()
        if (self.hold_swivel_deg is not None or self.plan_cost is not None) and "nullspace" in groups:
            executor.set_params("nullspace", replaced(groups["nullspace"], "objective", "j"))  # type: ignore[attr-defined]
        self._executor = executor
        k0_j = getattr(getattr(executor, "nullspace", None), "k0_j", 0.0)
        # W_j [T18] follows a moving q_d with the lag 1/k0_j: the target leads the plan by that much
        self._plan_lead_s = 1.0 / k0_j if k0_j > 0 else 0.0

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
        if self.hold_swivel_deg is not None and self._executor is not None:
            self.configure_executor(self._executor, None)  # type: ignore[arg-type]  # holding runs W_j

    def pending_work(self, robot: RobotDescription) -> Work | None:
        """The planned swivel path of a planned case, while it is not cached."""
        if self.plan_cost is None:
            return None
        key = _plan_key(robot, self.start_swivel_used_deg, self.plan_cost, self.armature_scale)
        if key in _PLAN_CACHE:
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

    def make_target(self, robot: RobotDescription, model: RobotModel, dyn0: Dynamics) -> Callable[[float], TaskTarget]:
        """Hold the start XY with 20 N, then the zig-zag once the clock starts it."""
        clock = self._clock if self._clock is not None else PhaseClock()
        p0, R0 = self.start_pose()
        q_posture = dyn0.q.copy()
        self.plan = None
        if self.plan_cost is not None:
            if self.table_height != TABLE_HEIGHT_M or self.start_xy != START_XY_M:
                raise ValueError("the planned cases plan on the paper's table; this arm's table was moved to its reach")
            self.plan = planned_path(robot, model, self.start_swivel_used_deg, self.plan_cost, self.armature_scale)
            clock.earliest_end_s = CONTACT_TIME_S + self.plan.transfer_s
        target = PolishTarget(p0, R0, q_posture, clock, self.plan, self._plan_lead_s)
        if self._environment is not None:
            self._environment.target = target
        return target


# ---- the planned nullspace path (control.planner) --------------------------------------------------
PLAN_SAMPLE_S = 0.5  # trajectory samples of the plan: 31 over the 15 s zig-zag
PLAN_GRID_DEG = 4.0  # swivel grid of the plan: 90 postures per self-motion loop
PLAN_RATE_MAX_DEG_S = 20.0  # swivel-rate bound: the W_j flow (k0_j = 1/s) follows it within a few degrees
_PLAN_CACHE: dict[tuple, Plan] = {}


def trajectory_state(
    tau: float, start_xy: tuple[float, float] = START_XY_M
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(xy, velocity xy, acceleration xy) of the zig-zag at time tau since the trajectory start."""
    corners = segment_waypoints(start_xy)
    if tau <= 0.0:
        return corners[0].copy(), np.zeros(2), np.zeros(2)
    k = int(tau // SEGMENT_DURATION_S)
    if k >= N_SEGMENTS:
        return corners[-1].copy(), np.zeros(2), np.zeros(2)
    a, b = corners[k], corners[k + 1]
    T = SEGMENT_DURATION_S
    s_p, s_v, s_a = min_jerk((tau - k * T) / T)
    return a + s_p * (b - a), s_v / T * (b - a), s_a / T**2 * (b - a)


def friction_direction(tau: float) -> np.ndarray:
    """Unit friction direction in world xy at trajectory time tau (opposite the segment's motion;
    at a corner, that of the segment starting there)."""
    corners = segment_waypoints()
    k = min(max(int(tau // SEGMENT_DURATION_S), 0), N_SEGMENTS - 1)
    d = corners[k + 1] - corners[k]
    return -d / np.linalg.norm(d)


def _plan_key(robot: RobotDescription, start_swivel_deg: float, cost: str, armature_scale: float) -> tuple:
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


def store_plan(key: tuple, plan: Plan) -> None:
    """Cache a plan computed elsewhere under its key (`PolishScenario.pending_work`)."""
    _PLAN_CACHE[key] = plan


def planned_path(
    robot: RobotDescription, model: RobotModel, start_swivel_deg: float, cost: str, armature_scale: float = 1.0
) -> Plan:
    """The swivel path planned over the zig-zag (cached per robot, start, cost and armature); `model`
    is `RobotModel(robot.model)`."""
    key = _plan_key(robot, start_swivel_deg, cost, armature_scale)
    if key not in _PLAN_CACHE:
        _PLAN_CACHE[key] = compute_plan(robot, start_swivel_deg, cost, model)
    return _PLAN_CACHE[key]


class PolishTarget:
    """TaskTarget as a function of time: the zig-zag of Fig. 7 with 20 N along +z.

    Its inputs (start, rotation, posture, the plan's postures) are checked here, once, as the
    executors' type (`control.executor.float_array`); each step's target is built from them by
    arithmetic that keeps that type, so it takes `TaskTarget.trusted` (no check per step)."""

    def __init__(
        self,
        start_position: np.ndarray,
        rotation: np.ndarray,
        q_posture: np.ndarray,
        clock: PhaseClock,
        plan: Plan | None = None,
        plan_lead_s: float = 0.0,
    ):
        self.start = float_array("PolishTarget", "start_position", start_position, (3,))
        self.rotation = float_array("PolishTarget", "rotation", rotation, (3, 3))
        self.q_posture = float_array("PolishTarget", "q_posture", q_posture, None)
        self.clock = clock
        if plan is not None:
            n = self.q_posture.shape[0]
            float_array("PolishTarget", "plan.q", plan.q, (plan.t.shape[0], n))
            float_array("PolishTarget", "plan.t", plan.t, None)
        self.plan = plan
        self.plan_lead_s = float(plan_lead_s)
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
        q_d = self.q_posture if self.plan is None else self.planned_posture(t)
        return TaskTarget.trusted(pos, self.rotation, vel, acc, self.wrench, q_d)  # checked in __init__

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
