"""The polish protocol's facts [T §IV-B]: the table, the zig-zag of Fig. 7 and the phase clock.

The geometry, the six minimum-jerk strokes, the contact and sensor constants and when each phase
begins and ends, shared by the preset (`app.scenarios.polish`), its target (`polish_plan`), its
environment (`polish_environment`) and the force-loop margin along the strokes (`polish_margin`).
Every constant is chosen once from the paper's description and physical sense (reason on the same
line) and is not re-tuned to match the paper's tables.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

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
