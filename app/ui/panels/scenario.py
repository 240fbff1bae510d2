"""Scenario panel: preset, robot, executor, play/pause/step/reset, speed, drag force limit, status."""

from __future__ import annotations

import time
from typing import Any

import viser

import robots
from app.commands import Pause, Play, Reset, SetSpeed, StepOnce, SwitchSession
from app.executors import EXECUTORS
from app.loop import SPEED_RANGE, Frame, LoopStatus, SimLoop
from app.scenarios import SCENARIOS
from app.ui.panels.base import KnobPanel, notify, number_in_range

DEFAULT_ROBOT = "scenario default"
NO_CASE = "–"
STEPS = {"1 ms": 1, "10 ms": 10, "100 ms": 100}
SLOW_WARNING = 0.95  # say so when the real-time factor stays below this share of the requested speed
FALLBACK_SHOW_S = 2.0  # keep the fallback badge up this long after the last fallback step

INTRO = (
    "Pick a preset and its case, the arm and the controller. The simulation runs at 1 kHz paced to wall "
    "time; drag any link with the mouse to push it (spring force, clamped to the limit below)."
)

FIELDS: tuple[str, ...] = ("drag.max_force_n",)


class ScenarioPanel(KnobPanel):
    """The Scenario folder (see the module docstring)."""

    def __init__(self, server: viser.ViserServer, loop: SimLoop, extra_robots: tuple[str, ...] = (), order=None):
        self._extra_robots = extra_robots
        self._last_fallback_wall = -1e9
        self._seen_fallback_steps = 0
        super().__init__(server, loop, "Scenario", INTRO, FIELDS, order=order)

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
        robot_options = (DEFAULT_ROBOT, *robots.available(), *self._extra_robots)
        self.robot = gui.add_dropdown("Robot", robot_options, initial_value=DEFAULT_ROBOT)
        executors = tuple(EXECUTORS)
        self.executor = gui.add_dropdown(
            "Executor", executors, initial_value=status.executor if status.executor in executors else executors[0]
        )
        self.play = gui.add_button("Play", icon=viser.Icon.PLAYER_PLAY)
        self.pause = gui.add_button("Pause", icon=viser.Icon.PLAYER_PAUSE)
        self.step = gui.add_button_group("Single step", tuple(STEPS))
        self.reset = gui.add_button("Reset", icon=viser.Icon.REFRESH)
        lo, hi = SPEED_RANGE
        self.speed = gui.add_slider("Speed (× real time)", lo, hi, 0.05, 1.0)
        self.status_md = gui.add_markdown("")
        self.fallback_md = gui.add_markdown(
            "**QP fallback!** A QP failed in the last seconds; a fallback torque was used.", visible=False
        )
        self.halted_md = gui.add_markdown("", visible=False)

        self.preset.on_update(self._on_preset)
        self.case.on_update(self._on_case)
        self.robot.on_update(self._on_robot)
        self.executor.on_update(self._on_executor)
        self.play.on_click(lambda e: self.loop.submit(Play()))
        self.pause.on_click(lambda e: self.loop.submit(Pause()))
        self.reset.on_click(lambda e: self.loop.submit(Reset()))
        self.step.on_click(self._on_step)
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
        if name not in self.robot.options:
            notify(self.server, event.client_id, "Refused", f"unknown robot {name!r}")
            return
        self.loop.submit(SwitchSession(robot="" if name == DEFAULT_ROBOT else name))

    def _on_executor(self, event: viser.GuiEvent) -> None:
        if event.client_id is None:
            return
        name = event.target.value
        if name not in EXECUTORS:
            notify(self.server, event.client_id, "Refused", f"unknown executor {name!r}")
            return
        self.loop.submit(SwitchSession(executor=name))

    def _on_step(self, event: viser.GuiEvent) -> None:
        steps = STEPS.get(event.target.value)
        if steps is not None:
            self.loop.submit(StepOnce(steps))

    def _on_speed(self, event: viser.GuiEvent) -> None:
        if event.client_id is None:
            return
        try:
            value = number_in_range("Speed", event.target.value, SPEED_RANGE[0], SPEED_RANGE[1])
        except ValueError as exc:
            notify(self.server, event.client_id, "Value refused", str(exc))
            return
        self.loop.submit(SetSpeed(value))

    # ---- live view ------------------------------------------------------------------------------
    def live(self, frame: Frame) -> None:
        """Status line, fallback badge, divergence message and the dropdowns in force."""
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
        choice = self.loop.robot_choice or DEFAULT_ROBOT
        if choice in self.robot.options:
            _set(self.robot, choice)
        if time.time() - self.speed.update_timestamp > 0.6:
            _set(self.speed, round(st.speed, 2))
        text = _describe(st)
        if self.description.content != text:
            self.description.content = text
        state = "running" if st.running else "paused"
        rtf = f"real-time factor **{st.rtf:.2f}×**" if st.running else "real-time factor –"
        status = (
            f"t = {st.t:.2f} s · {state} · {rtf} (speed {st.speed:.2f}×, compute {100 * st.load:.0f} %)  \n"
            f"{st.robot} · {st.executor}"
        )
        step = getattr(frame.scene, "step", None)  # the controller's view of its latest step
        if step is not None and step.qp_status is not None:
            status += f" · QP {step.qp_backend} {step.qp_solve_us:.0f} µs"
        if st.drag_client is not None:
            status += f" · dragging ({st.signals.get('drag_force_n', 0.0):.0f} N)"
        if st.overpowered:
            status += f"  \n**Overpowered:** {st.overpowered}."
        if st.running and 0.0 < st.rtf < SLOW_WARNING * st.speed:
            status += "  \n**Slower than requested:** this machine cannot keep up right now."
        if self.status_md.content != status:
            self.status_md.content = status
        now = time.time()
        if st.fallback or st.fallback_steps > self._seen_fallback_steps:
            self._last_fallback_wall = now
        self._seen_fallback_steps = st.fallback_steps
        show = now - self._last_fallback_wall < FALLBACK_SHOW_S
        if step is not None and step.qp_fallback and step.qp_status:
            text = f"**QP fallback!** A QP failed in the last seconds ({step.qp_status}); a fallback torque was used."
            if self.fallback_md.content != text:
                self.fallback_md.content = text
        if self.fallback_md.visible != show:
            self.fallback_md.visible = show
        halted = f"**Paused:** {st.halted}. Press **Reset**." if st.halted else ""
        if self.halted_md.content != halted:
            self.halted_md.content = halted
        if self.halted_md.visible != bool(halted):
            self.halted_md.visible = bool(halted)


def _describe(status: LoopStatus) -> str:
    return f"**{status.scenario_title}** — {status.scenario_text}"


def _set(handle: Any, value: Any) -> None:
    if handle.value != value:
        handle.value = value
