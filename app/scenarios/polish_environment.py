"""The polish preset's environment: the table contact, the sander, the phase clock and the live
force-loop figures (σ, the K_f^d margin and the stroke headroom of `polish_margin`) of the run."""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Mapping
from concurrent.futures import Future
from typing import TYPE_CHECKING, Any

import numpy as np

from app.scenarios import Environment, Offload
from app.scenarios.metrics import contact_watched
from app.scenarios.polish_margin import (
    StrokeHeadroom,
    contact_loop,
    headroom_budget_np,
    kd_margin_at,
    rate_at,
    sensor_floor_n,
)
from app.scenarios.polish_stroke import (
    CONTACT_TIME_S,
    DESIRED_FORCE_N,
    N_SEGMENTS,
    PEAK_SPEED_M_S,
    PhaseClock,
)
from app.sim.contact import TableContact
from app.sim.disturbances import Sander
from app.sim.world import World
from control.gains import MotionForceGains
from control.kernels.geometry import swivel_of_anchors_fused
from control.margin import ContactLoop
from control.model import Dynamics

if TYPE_CHECKING:
    from app.scenarios.polish_plan import PolishTarget

LIVE_MARGIN_EVERY_S = 1.0  # the live force-loop margin signal is recomputed once a simulated second
LIVE_RATE_EVERY_S = 0.1  # the live decay rate σ at the step's posture and stroke state: 10 Hz of simulated time
LIVE_POLL_EVERY_S = 0.01  # the offload's answers are looked for every 10 ms of simulated time (a 100 Hz display)
LIVE_PENDING_MAX = 10  # live figures under way in the offload at most (1 s of σ): beyond, a sample is skipped
MAX_LIFTS = 200  # contact-loss marks kept per run


class PolishEnvironment(Environment):
    """Table contact, optional sander, and the phase clock of the protocol."""

    def __init__(self, contact: TableContact, sander: Sander, clock: PhaseClock):
        self.contact = contact
        self.sander = sander
        self.clock = clock
        self._sander_force = np.zeros(3)
        # where and when the tool lifted off the table while the strokes ran (`metrics.contact_loss_onsets`,
        # step by step): the scene leaves a mark there; at most MAX_LIFTS, the latest kept
        self.lifts: deque[tuple[float, np.ndarray]] = deque(maxlen=MAX_LIFTS)
        self.contact_lost = False  # the contact is lost now (`metrics.contact_lost`)
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
        lost = contact_watched(segment) and state.normal_force_n <= 0.0
        if lost and not self.contact_lost and state.point is not None:
            self.lifts.append((t, state.point.copy()))
        self.contact_lost = lost
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
