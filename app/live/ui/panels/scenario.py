"""Scenario panel: preset, robot, executor, play/pause/step/reset, speed, drag force limit, status."""

from __future__ import annotations

import contextlib
import math
import time
from collections import deque
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import viser

import robots
from app.core.commands import Pause, Play, Reset, SetSpeed, SettleNow, StepOnce, SwitchSession
from app.core.executors import EXECUTORS
from app.live.loop import Frame, LoopStatus, SimLoop
from app.live.run_flags import UNPACED_SPEED
from app.live.ui.panels.base import KnobPanel, notify
from app.live.ui.panels.settings import SettingsButtons
from app.live.ui.phase import PhaseReader, starts_paused
from app.scenarios import SCENARIOS
from control.qp import RELAXED

DEFAULT_ROBOT = "scenario default"


def robot_labels(specs: Iterable[str], taken: Iterable[str] = ()) -> dict[str, str]:
    """label -> spec for the page's robot list: each URDF's short name (`robots.short_name`); one that
    a label already holds (`taken`: the shipped robots, or an earlier URDF) gets, in brackets, its chain
    options (--base/--tip) if it has any, else its file name, then its folder and file, then a number."""
    used = set(taken)
    out: dict[str, str] = {}
    for spec in specs:
        name = robots.short_name(spec)
        path_text, _, query = spec.partition("#")
        path = Path(path_text)
        where = f"{path.parent.name}/{path.name}"
        tries = [name, *([f"{name} ({query})"] if query else []), f"{name} ({path.name})", f"{name} ({where})"]
        if query:
            tries.append(f"{name} ({where} {query})")
        label = next((t for t in tries if t not in used), "")
        k = 2
        while not label:
            label = f"{name} ({k})" if f"{name} ({k})" not in used else ""
            k += 1
        used.add(label)
        out[label] = spec
    return out


NO_CASE = "–"
SETTLE_LABEL = "Settle now"
SETTLING_LABEL = "Settling unpaced…"
STEPS = {"1 ms": 1, "10 ms": 10, "100 ms": 100}
UNPACED = "as fast as possible"
SPEEDS = {"0.01×": 0.01, "0.03×": 0.03, "0.1×": 0.1, "0.3×": 0.3, "0.5×": 0.5, "1×": 1.0, "2×": 2.0, "5×": 5.0}
SPEEDS[UNPACED] = UNPACED_SPEED
RTF_WINDOW_S = 2.0  # the status line's real-time factor: simulated over wall time across this many seconds
SLOW_WARNING = 0.95  # say so when the real-time factor stays below this share of the requested speed
FALLBACK_SHOW_S = 2.0  # keep the fallback badge up this long after the last fallback step
NOTICE_SHOW_S = 20.0  # the status line repeats the newest notice this long
NOTICE_CHARS = 160


def fallback_text(qp_status: str) -> str:
    """The badge's one line for a step whose QP solution was replaced: a relaxed step (the
    constraints had no common point: `control.qp.RELAXED`) says what was infeasible and what the arm
    does instead; anything else says the QP failed and a fallback torque was used."""
    if qp_status.startswith(RELAXED):
        why = qp_status.removeprefix(RELAXED).lstrip(": ")
        return f"**QP relaxed:** {why[:1].upper()}{why[1:]}."
    return f"**QP fallback!** A QP failed in the last seconds ({qp_status}); a fallback torque was used."


SUMMARY = "Preset, case, arm and controller; run, step, reset, speed. Drag any link to push it."
INTRO = (
    "Pick a preset and its case, the arm and the controller. The simulation runs at 1 kHz paced to wall "
    "time; drag any link with the mouse to push it (spring force, clamped to the limit below)."
)

FIELDS: tuple[str, ...] = ("drag.max_force_n",)


class ScenarioPanel(KnobPanel):
    """The Scenario folder (see the module docstring)."""

    def __init__(
        self,
        server: viser.ViserServer,
        loop: SimLoop,
        extra_robots: tuple[str, ...] = (),
        order=None,
        status_box: Any = None,
    ):
        self._extra_robots = extra_robots
        self._status_box = status_box  # where the status line goes (the top of the plots); None: this folder
        self.replay_t: float | None = None  # the instant the replay shows (None: live)
        self._last_frame: Frame | None = None
        self._last_fallback_wall = -1e9
        self._seen_fallback_steps = 0
        self._rtf = AveragedRate()
        self._phase = PhaseReader()
        self._notice: Any = None
        self._notice_wall = 0.0
        super().__init__(server, loop, "Scenario", INTRO, FIELDS, order=order, summary=SUMMARY)

    def has_content(self, settings: Any) -> bool:
        """Always shown: the preset, the run buttons and the status."""
        return True

    def build_extra_top(self) -> None:
        """Preset, robot, executor, run buttons, speed and status lines."""
        gui = self.server.gui
        status = self.loop.status
        scenarios = tuple(SCENARIOS) or (status.scenario,)
        self.preset = gui.add_dropdown(
            "Preset", scenarios, initial_value=status.scenario if status.scenario in scenarios else scenarios[0]
        )
        self.case = gui.add_dropdown(
            "Case", status.variants or (NO_CASE,), initial_value=status.variant or NO_CASE, disabled=not status.variants
        )
        self.description = gui.add_markdown(_describe(status))
        names = (DEFAULT_ROBOT, *robots.available())
        self._robot_specs = {**{n: n for n in names}, **robot_labels(self._extra_robots, names)}  # label -> spec
        self._robot_labels = {spec: label for label, spec in self._robot_specs.items()}
        paths = [f"{label}: {spec}" for label, spec in self._robot_specs.items() if label not in names]
        self.robot = gui.add_dropdown(
            "Robot",
            tuple(self._robot_specs),
            initial_value=DEFAULT_ROBOT,
            hint="The arm to run the preset on" + ("; " + "; ".join(paths) if paths else ""),
        )
        executors = tuple(EXECUTORS)
        self.executor = gui.add_dropdown(
            "Executor", executors, initial_value=status.executor if status.executor in executors else executors[0]
        )
        self.run = gui.add_button("Pause", icon=viser.Icon.PLAYER_PAUSE, hint="Play / pause (Space)")
        self._shown_running: bool | None = None
        self.step = gui.add_button_group("Single step", tuple(STEPS), hint="→: 1 ms, Shift+→: 10 ms")
        self.reset = gui.add_button("Reset", icon=viser.Icon.REFRESH, hint="Start the preset again (R)")
        self.settle = gui.add_button(
            SETTLE_LABEL,
            icon=viser.Icon.PLAYER_TRACK_NEXT,
            hint="Run the settle phase as fast as this machine allows until the posture has converged, "
            "then go on at the chosen speed (Pause or Reset stop it)",
            visible=False,
        )
        self.frame_button = gui.add_button(
            "Frame the robot", icon=viser.Icon.FOCUS_CENTERED, hint="Point the camera at the arm (F)"
        )
        self.on_frame: Any = None  # set by the app: frames the camera of the client that clicked
        self.frame_button.on_click(lambda e: self.on_frame(e.client) if self.on_frame is not None else None)
        self.speed = gui.add_dropdown(
            "Speed", tuple(SPEEDS), initial_value="1×", hint="Simulated time per wall second; the last runs unpaced"
        )
        self.settings = SettingsButtons(self.server, self.loop)
        with self._status_box if self._status_box is not None else contextlib.nullcontext():
            self.status_md = gui.add_markdown("")
            self.fallback_md = gui.add_markdown(
                "**QP fallback!** A QP failed in the last seconds; a fallback torque was used.", visible=False
            )
            self.halted_md = gui.add_markdown("", visible=False)

        self.preset.on_update(self._on_preset)
        self.case.on_update(self._on_case)
        self.robot.on_update(self._on_robot)
        self.executor.on_update(self._on_executor)
        self.run.on_click(lambda e: self.toggle_run())
        self.reset.on_click(lambda e: self.reset_preset())
        self.step.on_click(self._on_step)
        self.settle.on_click(lambda e: self.loop.submit(SettleNow(e.client_id)))
        self.speed.on_update(self._on_speed)

    # ---- callbacks: only commands -----------------------------------------------------------------
    def _on_preset(self, event: viser.GuiEvent) -> None:
        if event.client_id is None:
            return
        name = event.target.value
        if name not in SCENARIOS:
            notify(self.server, event.client_id, "Refused", f"unknown preset {name!r}")
            return
        self.loop.submit(SwitchSession(scenario=name))
        if starts_paused(name):
            self.loop.submit(Pause())  # over in seconds: wait for Play

    def reset_preset(self) -> None:
        """Reset (the button and R); a preset that is over in seconds waits for Play after it."""
        self.loop.submit(Reset())
        if starts_paused(self.loop.status.scenario):
            self.loop.submit(Pause())

    def _on_case(self, event: viser.GuiEvent) -> None:
        if event.client_id is None:
            return
        status = self.loop.status
        if event.target.value not in status.variants:
            notify(self.server, event.client_id, "Refused", f"{status.scenario} has no case {event.target.value!r}")
            return
        self.loop.submit(SwitchSession(scenario=status.scenario, variant=event.target.value))

    def _on_robot(self, event: viser.GuiEvent) -> None:
        if event.client_id is None:
            return
        name = event.target.value
        spec = self._robot_specs.get(name)
        if spec is None:
            notify(self.server, event.client_id, "Refused", f"unknown robot {name!r}")
            return
        self.loop.submit(SwitchSession(robot="" if spec == DEFAULT_ROBOT else spec))

    def _on_executor(self, event: viser.GuiEvent) -> None:
        if event.client_id is None:
            return
        name = event.target.value
        if name not in EXECUTORS:
            notify(self.server, event.client_id, "Refused", f"unknown executor {name!r}")
            return
        self.loop.submit(SwitchSession(executor=name))

    def toggle_run(self) -> None:
        """Pause when running, play when paused (the button and Space)."""
        self.loop.submit(Pause() if self.loop.status.running else Play())

    def _on_step(self, event: viser.GuiEvent) -> None:
        steps = STEPS.get(event.target.value)
        if steps is not None:
            self.loop.submit(StepOnce(steps))

    def _on_speed(self, event: viser.GuiEvent) -> None:
        if event.client_id is None:
            return
        value = SPEEDS.get(str(event.target.value))
        if value is None:
            notify(self.server, event.client_id, "Value refused", f"speed must be one of {', '.join(SPEEDS)}")
            return
        self.loop.submit(SetSpeed(value))

    # ---- live view ------------------------------------------------------------------------------
    def show_replay(self, t: float | None) -> None:
        """The status line for a replayed instant t (None: live again), written at once."""
        self.replay_t = t
        if self._last_frame is not None:
            self.live(self._last_frame)

    def live(self, frame: Frame) -> None:
        """Status line, fallback badge, divergence message and the dropdowns in force."""
        self._last_frame = frame
        st = frame.status
        _set(self.preset, st.scenario)
        options = st.variants or (NO_CASE,)
        if tuple(self.case.options) != options:
            self.case.options = options
        _set(self.case, st.variant or NO_CASE)
        if self.case.disabled == bool(st.variants):
            self.case.disabled = not st.variants
        if st.executor in self.executor.options:
            _set(self.executor, st.executor)
        choice = self._robot_labels.get(self.loop.robot_choice or DEFAULT_ROBOT)
        if choice is not None:
            _set(self.robot, choice)
        if time.time() - self.speed.update_timestamp > 0.6:
            _set(self.speed, speed_label(st.speed))
        text = _describe(st)
        if self.description.content != text:
            self.description.content = text
        self._show_running(st.running)
        self._show_settle(st)
        rtf = self._rtf.update(time.monotonic(), st.t, st.running)
        unpaced = st.speed >= UNPACED_SPEED
        state = "▶ running" if st.running else "❚❚ paused"
        rate = f"real-time factor **{rtf:.2f}×**" if st.running and rtf is not None else "real-time factor –"
        if st.settling:
            pace = "Settle now: unpaced until the posture has converged"
        else:
            pace = "unpaced: as fast as possible" if unpaced else f"speed {st.speed:g}×"
        status = (
            f"t = {st.t:.3f} s · {state} · {rate} ({pace}, compute {100 * st.load:.0f} %)  \n{st.robot} · {st.executor}"
        )
        if self.replay_t is not None:
            status = (
                f"**Replay** at t = {self.replay_t:.3f} s (the run is paused at t = {st.t:.3f} s; "
                f"turn Replay off to go back)  \n{st.robot} · {st.executor}"
            )
        step = getattr(frame.scene, "step", None)  # the controller's view of its latest step
        if step is not None and step.qp_status is not None:
            solve = "closed form in the law" if math.isnan(step.qp_solve_us) else f"{step.qp_solve_us:.0f} µs"
            status += f" · QP {step.qp_backend} {solve}"
        phase = self._phase.text(st, frame.scene)
        if phase:
            status += f"  \n**Phase:** {phase}"
        if not st.running and st.t < 1e-6 and not st.halted:  # any preset paused at its start (Pause carries over)
            status += "  \n**Press Play** (or Space) to start."
        if st.drag_client is not None:
            status += f" · dragging ({st.signals.get('drag_force_n', 0.0):.0f} N)"
        if st.overpowered:
            status += f"  \n**Overpowered:** {st.overpowered}."
        paced = st.running and not unpaced and not st.settling
        slow = paced and rtf is not None and 0.0 < rtf < SLOW_WARNING * st.speed
        if slow:
            status += "  \n**Slower than requested:** this machine cannot keep up right now."
        notice = self._latest_notice()
        if notice:
            status += f"  \n**Latest notice:** {notice}"
        if self.status_md.content != status:
            self.status_md.content = status
        now = time.time()
        if st.fallback or st.fallback_steps > self._seen_fallback_steps:
            self._last_fallback_wall = now
        self._seen_fallback_steps = st.fallback_steps
        show = now - self._last_fallback_wall < FALLBACK_SHOW_S
        if step is not None and step.qp_fallback and step.qp_status:
            text = fallback_text(step.qp_status)
            if self.fallback_md.content != text:
                self.fallback_md.content = text
        if self.fallback_md.visible != show:
            self.fallback_md.visible = show
        halted = f"**Paused:** {st.halted}. Press **Reset**." if st.halted else ""
        if self.halted_md.content != halted:
            self.halted_md.content = halted
        if self.halted_md.visible != bool(halted):
            self.halted_md.visible = bool(halted)

    def _latest_notice(self) -> str:
        """The newest notice of the last NOTICE_SHOW_S wall seconds, as "title: body" (shown in the status
        line, so it stays readable after its pop-up has closed)."""
        try:
            newest = self.loop.lab.notice_log[-1]
        except (IndexError, RuntimeError):
            return ""
        now = time.monotonic()
        if newest is not self._notice:
            self._notice, self._notice_wall = newest, now
        if now - self._notice_wall > NOTICE_SHOW_S:
            return ""
        body = newest.body if len(newest.body) <= NOTICE_CHARS else newest.body[: NOTICE_CHARS - 1] + "…"
        return f"{newest.title}: {body}"

    def _show_settle(self, st: LoopStatus) -> None:
        """ "Settle now" shows while the preset has a settle phase to run; it reads "Settling unpaced…"
        (and waits) while it runs."""
        visible = st.can_settle or st.settling
        label = SETTLING_LABEL if st.settling else SETTLE_LABEL
        if self.settle.visible != visible:
            self.settle.visible = visible
        if self.settle.label != label:
            self.settle.label = label
        if self.settle.disabled != st.settling:
            self.settle.disabled = st.settling

    def _show_running(self, running: bool) -> None:
        """The run button offers what a click does: Pause while running, Play while paused."""
        if self._shown_running == running:
            return
        self._shown_running = running
        self.run.label = "Pause" if running else "Play"
        self.run.icon = viser.Icon.PLAYER_PAUSE if running else viser.Icon.PLAYER_PLAY
        self.run.color = None if running else "green"


class AveragedRate:
    """Real-time factor over the last `window_s` wall seconds from (wall, simulated time) samples, so a
    catch-up burst after a stall does not read as faster than real time; None until it has a window."""

    def __init__(self, window_s: float = RTF_WINDOW_S):
        self.window_s = window_s
        self._samples: deque[tuple[float, float]] = deque()

    def update(self, wall: float, sim_t: float, running: bool) -> float | None:
        """Add a sample; returns the factor over the window (None while paused or just restarted)."""
        s = self._samples
        if not running or (s and sim_t < s[-1][1]):
            s.clear()
            if not running:
                return None
        s.append((wall, sim_t))
        while len(s) > 2 and wall - s[1][0] >= self.window_s:
            s.popleft()
        elapsed = wall - s[0][0]
        if elapsed < 0.5 * self.window_s:
            return None
        return (sim_t - s[0][1]) / elapsed


def speed_label(speed: float) -> str:
    """The Speed dropdown's entry nearest to a requested speed."""
    return min(SPEEDS, key=lambda k: abs(math.log(SPEEDS[k]) - math.log(max(speed, 1e-9))))


def _describe(status: LoopStatus) -> str:
    return f"**{status.scenario_title}** — {status.scenario_text}"


def _set(handle: Any, value: Any) -> None:
    if handle.value != value:
        handle.value = value
