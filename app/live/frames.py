"""What the loop publishes: one `Frame` (status, settings, scene snapshot, plot data) built from a Lab.

The status line, the plot data and the scene capture are built here, between two steps on the
loop thread, as copies the browser side can read without touching the Session. The scene capture
is a function handed in by the server (`app.live.ui.snapshot.capture`); without one, frames carry no
scene (tests, headless runs). The capture, the twin's poses and the rest of the build are each an error
boundary (`app.live.supervise`): a failing one is skipped for that frame, reported once per distinct
error per minute (again at once after a preset switch), and tried again with the next frame.
"""

from __future__ import annotations

import dataclasses
import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from app.core.session import Session
from app.core.settings import Settings
from app.core.steplog import StepLog
from app.core.variants import variant_of
from app.live.lab import Lab
from app.live.run_flags import RunFlags
from app.live.run_identity import describe, identity_from
from app.live.supervise import Stages
from app.scenarios import PhaseMark, Scenario
from app.scenarios.stroke_outcomes import MARGIN_COLUMNS, StrokeOutcome, stroke_outcomes
from control.executor import StepView

PLOT_WINDOW_S = 10.0
PLOT_POINTS = 500  # points per plotted series
# signals whose chart must reach the peak its readout states (metrics.deflection's): decimated by peak
PEAK_SIGNALS = ("tcp_dev_mm", "elbow_dev_mm")
STAGE_TEXT = {  # what each loop-side stage of a frame does, for the notice
    "capture": "capturing the scene",
    "twin poses": "placing the twin arm",
    "build": "building the frame",
}


@dataclass(frozen=True)
class LoopStatus:
    """What the loop is doing, for the status line and the tests."""

    running: bool = False
    settling: bool = False  # "Settle now" runs the settle phase unpaced
    can_settle: bool = False  # the preset is in a settle phase that "Settle now" can run
    t: float = 0.0  # s, simulated time of the session
    steps: int = 0  # steps since the last reset
    speed: float = 1.0  # requested simulated seconds per wall second
    rtf: float = 0.0  # achieved real-time factor over the last window
    load: float = 0.0  # fraction of wall time spent computing steps
    scenario: str = ""
    scenario_title: str = ""
    scenario_text: str = ""  # what the preset shows, one paragraph
    variant: str = ""  # the scenario's case, "" if it has none
    variants: tuple[str, ...] = ()  # the cases it can run in
    focus_joint: int | None = None  # 0-based joint the scenario is about (phase plot), if any
    twin: str = ""  # nullspace objective of the twin arm ("j", "f", "a", "d"), "" when there is none
    twin_segment: float = math.nan  # the twin's stroke (its signal "segment"), NaN without one
    robot: str = ""
    executor: str = ""
    halted: str = ""  # why the loop auto-paused (divergence), "" otherwise
    overpowered: str = ""  # joints the surroundings overpower (torque beyond the motors', or at a stop)
    fallback: bool = False  # the last step used a fallback solution (QP failed)
    fallback_steps: int = 0  # fallback steps since the last reset
    drag_client: int | None = None  # client holding the drag spring
    step_cpu_s: float = 0.0  # CPU time the loop thread spent in steps since it started
    signals: dict[str, float] = field(default_factory=dict)  # last step's scalar signals


@dataclass(frozen=True)
class PlotData:
    """The last seconds of logged signals, decimated, plus the slower monitor series."""

    columns: dict[str, np.ndarray]  # StepLog columns
    monitor: dict[str, np.ndarray]  # "t", "rtf", "W_f", "W_a", "W_d" sampled at the publish rate
    q_lower: np.ndarray
    q_upper: np.ndarray
    dq_max: np.ndarray
    tau_max: np.ndarray
    peak_abs_tau: np.ndarray | None = None  # max |τ_i| per joint over every step since the reset
    peak_q: np.ndarray | None = None  # max q_i per joint over every step since the reset
    segment_std: dict[int, float] | None = None  # force-error STD per polish segment, every step since the reset
    twin_segment_std: dict[int, float] | None = None  # the same for the twin arm, over its own segments
    deflection: dict[str, float] | None = None  # the deflection readouts over every step (`deflection_readouts`)
    low_q: np.ndarray | None = None  # min q_i per joint over every step since the reset
    fall_direction: int = 0  # a falling joint falls toward its upper (+1) or lower (−1) limit; 0: none falls
    segments: int = 0  # the strokes of the preset (`Scenario.segments`): signal "segment" counts them
    marks: tuple[PhaseMark, ...] = ()  # the preset's phase changes its charts mark (`Scenario.phase_marks`)
    readout_text: tuple[str, ...] = ()  # the preset's lines for its `deflection` readouts (`Scenario.readout_text`)
    run: str = ""  # the run the readouts were measured on, in words (`run_text`)
    strokes: tuple[StrokeOutcome, ...] = ()  # the polish strokes over since the reset: prediction and verdict


@dataclass(frozen=True)
class Frame:
    """One publication of the loop to the browser side."""

    seq: int
    session_id: int  # grows when the session (robot, scenario) is rebuilt
    robot: Any  # RobotDescription of the current session
    status: LoopStatus
    settings: Settings
    scene: Any = None  # SceneSnapshot, if a capture function was handed in
    plot: PlotData | None = None  # the newest plot data (kept in later frames until replaced)
    plot_seq: int = 0  # grows when `plot` is new data
    restarts: int = 0  # grows at every reset or rebuild of the lab (a new run: its plots start empty)


def make_status(
    lab: Lab, rtf: float = 0.0, load: float = 0.0, view: StepView | None = None, flags: RunFlags | None = None
) -> LoopStatus:
    """The status of a lab run by the loop's `flags` (None: paused at speed 1); `rtf` and `load` come from
    the runner's rate meter; `view` is the executor's view of its latest step when the caller has built it
    already (the scene capture has)."""
    s = lab.session
    running = flags is not None and flags.running
    last = s.last
    variant = variant_of(s.scenario)
    return LoopStatus(
        running=running,
        settling=flags is not None and flags.settling,
        can_settle=s.settle_pending(),
        t=s.world.time,
        steps=s.steps,
        speed=flags.speed if flags is not None else 1.0,
        rtf=rtf if running else 0.0,
        load=load if running else 0.0,
        scenario=s.scenario.name,
        scenario_title=s.scenario.title,
        scenario_text=s.scenario.description,
        variant=variant.current if variant else "",
        variants=variant.options if variant else (),
        focus_joint=s.scenario.focus_joint,
        twin=lab.twin.objective if lab.twin is not None else "",
        twin_segment=_twin_segment(lab),
        robot=s.robot.name + (f" (guessed: {', '.join(s.robot.guessed)})" if s.robot.guessed else ""),
        executor=s.executor_name,
        halted=lab.halted,
        overpowered=lab.overpowered,
        fallback=bool(last.fallback) if last is not None else False,
        fallback_steps=lab.fallback_steps,
        drag_client=lab.drag_client,
        step_cpu_s=lab.step_cpu_s,
        signals=_with_posture_objective(s, dict(last.signals) if last is not None else {}, view),
    )


def _twin_segment(lab: Lab) -> float:
    """The twin arm's stroke (signal "segment" of its last step), NaN without a twin or the signal."""
    last = lab.twin.session.last if lab.twin is not None else None
    return float(last.signals.get("segment", math.nan)) if last is not None else math.nan


class FrameBuilder:
    """Builds frames from a lab: the scene every frame, the plot data at `plot_period` while the lab
    runs (the frame closest to each plot time: frames come on a fixed schedule but a little late, up
    to half a frame early counts) and in every frame while it does not (then frames go out only when
    something changed, and the last one must show the last step)."""

    def __init__(self, publish_period: float, plot_period: float, capture: Callable[[Session], Any] | None = None):
        self.plot_period = plot_period
        self._plot_slack = 0.5 * publish_period
        self.capture = capture
        self._monitor: deque[tuple[float, float, float, float, float]] = deque(
            maxlen=round(PLOT_WINDOW_S / publish_period) + 2
        )
        self._restarts = -1
        self._edits_at_restart = 0  # the lab's edit count when this run started (`run_text`)
        # (restarts, segment, the margin figures' stroke) the strokes were judged at
        self._strokes_key: tuple[int, float, float] | None = None
        self._strokes: tuple[StrokeOutcome, ...] = ()
        self._seq = 0
        self._next_plot = 0.0
        self._plot: PlotData | None = None
        self._plot_seq = 0
        self._lab: Lab | None = None
        self._session_id = -1
        self.stages = Stages(self._report)  # capture, twin poses, build: one error boundary each

    def _report(self, stage: str, text: str) -> None:
        """A notice for a failing stage (the budget lets through one per distinct error per minute)."""
        if self._lab is not None:
            what = STAGE_TEXT.get(stage, stage)
            self._lab.notify(
                "warning",
                "Display problem",
                f"{what} failed ({text}); it is skipped until it works again, the simulation keeps running",
            )

    def publish(
        self, lab: Lab, now: float, rtf: float = 0.0, load: float = 0.0, flags: RunFlags | None = None
    ) -> Frame | None:
        """`build` inside its error boundary: the frame, or None when building it failed."""
        self._lab = lab
        if lab.session_id != self._session_id:  # a preset switch re-arms every stage's report
            self._session_id = lab.session_id
            self.stages.rearm()
        return self.stages.run("build", self.build, lab, now, rtf, load, flags)

    def build(self, lab: Lab, now: float, rtf: float = 0.0, load: float = 0.0, flags: RunFlags | None = None) -> Frame:
        """The next frame of `lab` run by `flags` (`now`: wall time, for the plot rate)."""
        if lab.restarts != self._restarts:
            self._monitor.clear()  # a reset or a new session: the monitor series start over
            self._restarts = lab.restarts
            self._edits_at_restart = lab.edits
        scene = self._scene(lab)
        status = make_status(lab, rtf, load, getattr(scene, "step", None), flags)
        self._monitor.append(_monitor_row(status, scene))
        if now >= self._next_plot or not status.running:
            self._next_plot = now + self.plot_period - self._plot_slack
            run = run_text(lab, status, self._edits_at_restart)
            strokes = self._strokes_over(lab, status)
            self._plot = dataclasses.replace(plot_data(lab, self._monitor), run=run, strokes=strokes)
            self._plot_seq += 1
        self._seq += 1
        return Frame(
            seq=self._seq,
            session_id=lab.session_id,
            robot=lab.session.robot,
            status=status,
            settings=lab.settings,
            scene=scene,
            plot=self._plot,
            plot_seq=self._plot_seq,
            restarts=lab.restarts,
        )

    def _strokes_over(self, lab: Lab, status: LoopStatus) -> tuple[StrokeOutcome, ...]:
        """The polish strokes the zig-zag has left since the reset, each with the margin's prediction and
        its verdict (`stroke_outcomes`), judged again only when a stroke ends or the margin's figures move
        to another stroke; () in other presets."""
        segment, segments = status.signals.get("segment"), lab.session.scenario.segments
        if not segments or segment is None or segment != segment:
            return ()
        # judged again when a stroke ends and when the margin's figures move on to another stroke (the
        # last figures of a stroke come from the offload a little after its end)
        tag = status.signals.get("margin_headroom_segment", -1.0)
        key = (lab.restarts, float(segment), -1.0 if tag != tag else float(tag))  # NaN: no stroke's figures
        if key != self._strokes_key:
            self._strokes_key = key
            c = lab.log.signal((*MARGIN_COLUMNS, "F_z", "contact_force_n"))
            sensor = lab.settings.groups.get("sensor")
            found = stroke_outcomes(c, sensor, lab.dt, segments) if c is not None else []
            self._strokes = tuple(x for x in found if x.verdict is not None)
        return self._strokes

    def _scene(self, lab: Lab) -> Any:
        if self.capture is None:
            return None
        self._lab = lab
        scene = self.stages.run("capture", self.capture, lab.session)  # None (no scene) while it fails
        twin = lab.twin
        if scene is not None and twin is not None:
            scene = self.stages.run("twin poses", _with_twin, scene, twin, default=scene)  # the arm without its twin
        return scene


def _with_twin(scene: Any, twin: Any) -> Any:
    """The scene snapshot with the twin arm's link poses, objective and W."""
    positions, wxyz = twin.link_poses(scene.link_names)
    return dataclasses.replace(
        scene,
        twin_link_positions=positions,
        twin_link_wxyz=wxyz,
        twin_objective=twin.objective,
        twin_W=twin.W,
    )


def plot_data(lab: Lab, monitor: deque[tuple[float, float, float, float, float]]) -> PlotData:
    """The last PLOT_WINDOW_S of the lab's log, decimated to ≈ PLOT_POINTS per series."""
    every = max(1, round(PLOT_WINDOW_S / lab.dt / PLOT_POINTS))
    columns = lab.log.window(PLOT_WINDOW_S, lab.dt, every, peaks=PEAK_SIGNALS)
    if lab.twin is not None and "t" in columns:
        # the twin's own segment column: with another objective its zig-zag starts at another time
        twin = lab.twin.columns_at(columns["t"])
        missing = np.full(len(columns["t"]), np.nan)
        columns["twin_force_error_n"] = twin["Fd_z"] - twin["F_z"] if "Fd_z" in twin else missing
        if "segment" in twin:
            columns["twin_segment"] = twin["segment"]
    peak_abs_tau, peak_q = lab.log.extremes()
    fall = lab.session.scenario.fall(lab.session.robot)  # a drop preset's: which limit its joint falls toward
    fall_direction = fall.direction if fall is not None else 0
    segment_std = lab.log.segment_force_error_std()
    twin_segment_std = lab.twin.log.segment_force_error_std() if lab.twin is not None else None
    deflection = deflection_readouts(lab.log, lab.session.scenario)
    mon = np.array(monitor) if monitor else np.zeros((0, 5))
    series = {k: mon[:, i].copy() for i, k in enumerate(("t", "rtf", "W_f", "W_a", "W_d"))}
    r = lab.session.robot
    return PlotData(
        columns,
        series,
        r.q_lower.copy(),
        r.q_upper.copy(),
        r.dq_max.copy(),
        r.tau_max.copy(),
        peak_abs_tau,
        peak_q,
        segment_std,
        twin_segment_std,
        deflection,
        low_q=lab.log.q_min(),
        fall_direction=fall_direction,
        segments=lab.session.scenario.segments,
        marks=lab.session.scenario.phase_marks,
        readout_text=tuple(lab.session.scenario.readout_text(deflection)) if deflection else (),
    )


def run_text(lab: Lab, status: LoopStatus, edits_at_restart: int) -> str:
    """The run the readouts are about: preset, case, robot, controller and every value the person changed
    from the preset's defaults; and, when a setting changed since the reset, that the figures since the
    reset mix the set-ups before and after it."""
    keys = list(dict.fromkeys(f"{o.group}.{o.field}" for o in lab.overrides))
    text = describe(identity_from(status, lab.settings), keys)
    text += "" if keys else " (the preset's defaults)"
    if lab.edits != edits_at_restart:
        text += (
            f"; changed during this run ({lab.last_edit}): the figures since the reset mix the set-ups before and "
            "after it (Reset starts a run with one)"
        )
    return text


def deflection_readouts(log: StepLog, scenario: Scenario) -> dict[str, float] | None:
    """The scenario's deflection readouts (mass drop: peak, stabilisation time, residual error of the TCP;
    compliance: TCP and elbow under each push) over every logged step since the reset, kept running in the
    log (`StepLog.fold`: the whole run, not only the rows the log still holds); None for a preset without
    a `readout_fold`."""
    fold = log.fold("readout", scenario.readout_fold)
    return fold.value() if fold is not None else None


def _with_posture_objective(
    session: Session, signals: dict[str, float], view: StepView | None = None
) -> dict[str, float]:
    """Add W_j = ½‖q − q_posture‖² [T18] when the executor did not report it."""
    if "W_j" not in signals:
        view_W = (view or session.executor.view()).W  # the executor's own W_j, when it has a posture
        if "W_j" in view_W:
            signals["W_j"] = float(view_W["W_j"])
            return signals
        q_posture = session.last.target.q_posture if session.last is not None else None
        if q_posture is not None:
            e = session.world.q - np.asarray(q_posture, dtype=float)
            signals["W_j"] = 0.5 * float(e @ e)
    return signals


def _monitor_row(status: LoopStatus, scene: Any) -> tuple[float, float, float, float, float]:
    """(t, real-time factor, W_f, W_a, W_d); the W are NaN near a singularity, where Λx is ill-conditioned
    and W_a runs into the 1e8s (the overlays hide there too)."""
    W = getattr(scene, "W", None) or {}
    sig = status.signals
    singular = bool(getattr(scene, "near_singular", False))

    def pick(key: str) -> float:
        value = W.get(key, sig.get(key, math.nan))
        return math.nan if singular else float(value)

    return (status.t, status.rtf, pick("W_f"), pick("W_a"), pick("W_d"))
