"""The polish preset's environment: the table contact, the sander, the phase clock and the live
force-loop figures (σ, the K_f^d margin and the stroke headroom of `polish_margin`) of the run."""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Mapping
from concurrent.futures import Future
from dataclasses import dataclass
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
LIVE_PENDING_MAX = 10  # live figures under way in the offload at most (1 s of σ): beyond, samples wait
# samples waiting for the offload at most (100 s of σ; the six strokes take 150 samples): beyond, the oldest go
LIVE_BACKLOG_MAX = 1000
# the strokes' σ samples still waiting this long (simulated) after the last stroke are computed inline
# (a worker that stopped answering): the strokes' headroom is whole soon after they end in any case
LIVE_WAIT_AFTER_S = 1.0
MAX_LIFTS = 200  # contact-loss marks kept per run


@dataclass
class LiveSample:
    """One live figure to compute: its kind ("rate": σ, "kd": the K_f^d margin), the simulated time and
    segment it was sampled at, the headroom budget then, the job (a module-level function and its
    arguments, Λx copied at the sample's step) and its future once the offload took it."""

    kind: str
    t: float
    segment: int
    budget: float
    fn: Callable[..., float] | None = None
    args: tuple = ()
    future: Future | None = None

    @property
    def on_stroke(self) -> bool:
        """A σ sample taken on one of the six strokes (never skipped)."""
        return self.kind == "rate" and 1 <= self.segment <= N_SEGMENTS


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
        # live figures sampled and not yet handed to the offload (it is starting, or behind), and those
        # under way in it, oldest first; a stroke's σ samples wait here rather than being skipped
        self._backlog: deque[LiveSample] = deque()
        self._pending: deque[LiveSample] = deque()
        self._polled_at = -np.inf
        self._answered_at = -np.inf  # when the latest σ answer was stored
        self._stroke_waiting = 0  # stroke σ samples in the backlog or under way
        self.dropped_stroke_samples = 0  # stroke σ samples dropped from a full backlog (the offload never came up)

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
        waiting = bool(self._pending or self._backlog)
        if waiting and t - self._polled_at >= LIVE_POLL_EVERY_S - 1e-9:
            due = True  # look for answers now and then, not at every step
        if self._world is not None and live and due:
            self._polled_at = t
            self._live_figures(t)
        headroom, headroom_min, headroom_segment = self._headroom_now(t)
        target = self.target
        return {
            "swivel_deg": swivel,
            "swivel_plan_deg": target.planned_swivel_deg(t) if target is not None else float("nan"),
            "margin_kd": self._margin,
            "margin_rate": self._rate,
            # the worst σ of the stroke the headroom is of (NaN while that stroke's first σ is not in)
            "margin_rate_stroke_min": self._rate_stroke_min if self._rate_segment == headroom_segment else math.nan,
            "margin_headroom_np": headroom,
            "margin_headroom_stroke_min_np": headroom_min,
            "margin_headroom_segment": headroom_segment,
            "margin_waiting": float(self.stroke_samples_waiting()),
            "settle_s": max(t - CONTACT_TIME_S, 0.0) if settling else float(clock.convergence_time_s or 0.0),
            "settle_converged": float("nan") if settling else float(clock.converged),
            "settle_quiet_s": quiet if settling else float("nan"),
            "settle_dW_rel": dw if settling else float("nan"),
        }

    def _live_figures(self, t: float) -> None:
        """Take the live figures the offload has finished; sample σ every `live_rate_every_s` and the
        K_f^d margin every `live_margin_every_s`: inline without an offload, else as jobs for the
        offload with a copy of the posture's Λx and the groups (`LiveSample`). A stroke's σ samples are
        never skipped: while the offload is starting or behind they wait in order, so the stroke
        headroom is the one the same run computes inline; other samples are taken only while nothing
        waits (they are for the display)."""
        self._take_answers(t)
        due_kd = t - self._margin_at >= self.live_margin_every_s
        due_rate = t - self._rate_at >= self.live_rate_every_s - 1e-9
        if due_kd:
            self._margin_at = t
        if due_rate:
            self._rate_at = t
        offload = self._offload
        if (due_kd or due_rate) and offload is None:
            segment, _ = self.clock.segment(t)
            if due_kd:
                self._margin = self.live_margin(t)
            if due_rate:
                self._store(LiveSample("rate", t, segment, self._budget()), self.live_rate(t), t)
            return
        if due_kd or due_rate:
            self._sample(t, due_kd, due_rate)
        segment, into = self.clock.segment(t)
        if self._stroke_waiting and segment > N_SEGMENTS and into >= LIVE_WAIT_AFTER_S:
            self._take_answers(t, inline=True)  # the offload stopped answering: finish the strokes here
        elif offload is not None:
            self._submit_backlog(offload, t)

    def _sample(self, t: float, due_kd: bool, due_rate: bool) -> None:
        """Queue the figures due at t for the offload (`LiveSample`): a stroke's σ always, the others
        only while nothing waits (none without motion/force gains: `_figure`)."""
        groups = self._groups()
        Lambda = self._lambda()
        if Lambda is None:
            return
        Lambda = np.array(Lambda)  # the step's snapshot is overwritten by the next step: the sample keeps its own
        segment, _ = self.clock.segment(t)
        budget = self._budget(groups)
        behind = bool(self._backlog) or len(self._pending) >= LIVE_PENDING_MAX
        rate_due = due_rate and (1 <= segment <= N_SEGMENTS or not behind)  # a stroke's σ always
        for kind, due in (("kd", due_kd and not behind), ("rate", rate_due)):
            figure = self._figure(kind, t, groups, Lambda) if due else None
            if figure is not None:
                self._queue(LiveSample(kind, t, segment, budget, *figure))
        while len(self._backlog) > LIVE_BACKLOG_MAX:  # an offload that never comes up: keep the latest
            gone = self._backlog.popleft()
            if gone.on_stroke:
                self._stroke_waiting -= 1
                self.dropped_stroke_samples += 1

    def _queue(self, sample: LiveSample) -> None:
        self._backlog.append(sample)
        self._stroke_waiting += sample.on_stroke

    def _submit_backlog(self, offload: Offload, t: float) -> None:
        """Hand waiting samples to the offload, oldest first, while fewer than LIVE_PENDING_MAX are
        under way there; inline when it gave up (no worker process will start)."""
        if offload.gave_up is not None:
            self._take_answers(t, inline=True)
            return
        while self._backlog and len(self._pending) < LIVE_PENDING_MAX:
            sample = self._backlog[0]
            assert sample.fn is not None  # (only a sample stored inline has none)
            future = offload.submit(sample.fn, *sample.args)
            if future is None:  # starting, or just died: try again at the next poll
                return
            sample.future = future
            self._pending.append(self._backlog.popleft())

    def _take_answers(self, t: float, inline: bool = False) -> None:
        """Store the answers that are in, in order (with `inline`, every waiting sample: the offload's
        answer when it is in, else computed here), stopping before the first σ of another stroke than
        the σ stored before it, so that each stroke's final headroom is a logged step of its own."""
        stored: int | None = None
        while True:
            queue = self._pending or (self._backlog if inline else None)
            if not queue:
                return
            sample = queue[0]
            future = sample.future
            answered = future is not None and future.done()
            if not (answered or inline) or (sample.kind == "rate" and stored not in (None, sample.segment)):
                return
            queue.popleft()
            failed = future.exception() if future is not None and answered else None
            if answered and failed is None:
                value = float(future.result())  # type: ignore[union-attr]
            elif inline and sample.fn is not None:
                value = float(sample.fn(*sample.args))
            else:
                value = float("nan")  # the worker died under it
            self._take(sample, value, t)
            if sample.kind == "rate":
                stored = sample.segment

    def _take(self, sample: LiveSample, value: float, t: float) -> None:
        """An answered sample, at step time t."""
        self._stroke_waiting -= sample.on_stroke
        if sample.kind == "kd":
            self._margin = value
        else:
            self._store(sample, value, t)

    def stroke_samples_waiting(self) -> int:
        """The strokes' σ samples taken and not yet answered (0 inline): a stroke's headroom is whole
        once none of its samples waits."""
        return self._stroke_waiting

    def _store(self, sample: LiveSample, value: float, t: float) -> None:
        """σ computed for the sample's time, stored at step time t: the worst σ of its stroke and the
        stroke headroom (NaN outside the six strokes)."""
        self._answered_at = t
        self._rate = value
        segment = sample.segment
        if segment != self._rate_segment:
            self._rate_segment = segment
            self._rate_stroke_min = float("nan")
        if 1 <= segment <= N_SEGMENTS and math.isfinite(value):
            prev = self._rate_stroke_min
            self._rate_stroke_min = value if not math.isfinite(prev) else min(prev, value)
        if self._headroom is None:
            self._headroom = StrokeHeadroom(sample.budget, self.live_rate_every_s)
        self._headroom.budget_np = sample.budget
        self._headroom.add(sample.t, segment, value)

    def _headroom_now(self, t: float) -> tuple[float, float, float]:
        """The stroke headroom (Np), its least value on its stroke so far, and that stroke: the stroke
        of the latest σ answered while its samples are still coming in or it is the stroke under way
        (answers come a little after their step: a stroke's last figures may arrive in the next one);
        the whole budget of the stroke under way from its start until its first σ is in; NaN outside."""
        h = self._headroom
        nan = math.nan
        if h is None:
            return nan, nan, nan
        segment, _ = self.clock.segment(t)
        waiting = self._oldest_waiting_segment()
        on = waiting if waiting is not None and 1 <= waiting <= N_SEGMENTS else segment
        if h.segment == on or (self._answered_at >= t and 1 <= h.segment <= N_SEGMENTS):
            if math.isfinite(h.headroom_np):
                return h.headroom_np, h.headroom_min_np, float(h.segment)
        if not 1 <= on <= N_SEGMENTS:
            return nan, nan, nan
        return h.budget_np, h.budget_np, float(on)

    def _oldest_waiting_segment(self) -> int | None:
        """The segment of the oldest σ sample not yet answered (None: none waits)."""
        if not self._stroke_waiting and not self._pending and not self._backlog:
            return None
        for queue in (self._pending, self._backlog):
            for x in queue:
                if x.kind == "rate":
                    return x.segment
        return None

    def _budget(self, groups: Mapping[str, Any] | None = None) -> float:
        """ln(F̂ / noise floor) (Np) of the session's sensor group: each stroke's headroom at its start."""
        if groups is None:
            groups = self._groups()
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
            groups = self._groups()
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
        figure = self._figure("rate", t, self._groups())
        return float("nan") if figure is None else figure[0](*figure[1])

    def live_margin(self, t: float) -> float:
        """Force-loop margin (N s/m, `kd_margin_at`) of the current posture with the run's latency."""
        figure = self._figure("kd", t, self._groups()) if self._world is not None else None
        return float("nan") if figure is None else figure[0](*figure[1])

    def _groups(self) -> Mapping[str, Any]:
        """The session's parameter groups now (none without a session)."""
        return self._params() if self._params is not None else {}

    def _figure(
        self, kind: str, t: float, groups: Mapping[str, Any], Lambda: np.ndarray | None = None
    ) -> tuple[Callable[..., float], tuple] | None:
        """A live figure at t as a function and its arguments (run inline, or in the offload's worker):
        "kd" the force-loop margin (`kd_margin_at`, at the strokes' peak speed), "rate" the decay rate
        (`rate_at`, at the trajectory's time at t); of the posture's Λx (`Lambda`, else the step's own)
        and the groups' gains and sensor. None without motion/force gains or Λx."""
        gains = groups.get("motion_force")
        Lambda = self._lambda() if Lambda is None else Lambda
        if Lambda is None or not isinstance(gains, MotionForceGains):
            return None
        if kind == "kd":
            return kd_margin_at, (Lambda, gains, self._contact_loop(PEAK_SPEED_M_S, groups))
        return rate_at, (Lambda, gains, self._contact_loop(0.0, groups), self._tau(t))

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
