"""The Lessons tab: pick a lesson, take its steps one by one, read what this run showed.

"Set up" sends the step's commands (as the panels would: preset, parameters, Settle now or Play) and
binds the step to the run they made (`app.live.lesson_run`). While the step runs the panel watches
the loop's status; a change of the preset, case, robot, controller or a parameter cancels the step
with one line saying what changed. When the step has run far enough it measures the run on the loop
thread, pauses the simulation there (the picture freezes at the end of the step, for a look and a
replay) and shows the step's claim, built from those numbers and naming the run they were measured
on. The numbers of each step are kept (`results`), so a later step can compare. While the step's run
is on, the Plots panel shows the charts the step names on top and, drawn faint, the run it compares
with: the lesson's step before, else this step's earlier run (`view`, `app.live.ui.lesson_view`).
"""

from __future__ import annotations

import threading
from typing import Any

import viser

from app.core.commands import Pause
from app.live.curriculum import LESSONS
from app.live.lesson_run import BoundStep, bind, cancel_line, finish
from app.live.lessons import Lesson, Memo, Step
from app.live.loop import Frame, SimLoop
from app.live.run_identity import identity_from
from app.live.ui.lesson_view import LessonView, Trace

INTRO = (
    "**Start here.** Each lesson sets up a preset for you, says what to do and watch, and after each step "
    "says what you saw, with this run's numbers. The plots on the left show the step's signal on top."
)
WAITING = "*Running… the result appears here when the step is over (the simulation then pauses).*"


class LessonsPanel:
    """The Lessons tab's content (see the module docstring); the publisher calls it like a panel."""

    def __init__(self, server: viser.ViserServer, loop: SimLoop, order: float | None = None):
        self.server = server
        self.loop = loop
        gui = server.gui
        self.lesson: Lesson = LESSONS[0]
        self.index = 0
        self.armed: BoundStep | None = None  # the step set up and not yet measured, bound to its run
        self.results: dict[str, Memo] = {}  # lesson key → step key → numbers
        self.claims: dict[tuple[str, str], str] = {}  # what each step showed (tests read them)
        self.last_claim = ""  # the latest claim or cancel line (the classroom's teacher view shows it)
        self._lock = threading.Lock()
        self.view: LessonView | None = None  # the Plots panel arranged for the step's run (set by the app)
        self.traces: dict[tuple[str, str], Trace] = {}  # each step's last run as the plots drew it
        self.folder = gui.add_folder("Lessons", order=order)
        with self.folder:
            gui.add_markdown(INTRO)
            self.choice: Any = gui.add_dropdown("Lesson", tuple(lesson.title for lesson in LESSONS))
            self.purpose = gui.add_markdown("")
            self.step_md = gui.add_markdown("")
            self.setup = gui.add_button("Set up this step", icon=viser.Icon.PLAYER_PLAY, color="green")
            self.nav = gui.add_button_group("Step", ("◀ Back", "Next ▶"))
            self.result_md = gui.add_markdown("")
        self.choice.on_update(self._on_choice)
        self.setup.on_click(lambda e: self.start_step())
        self.nav.on_click(self._on_nav)
        self._show()

    # ---- callbacks --------------------------------------------------------------------------------
    def _on_choice(self, event: viser.GuiEvent) -> None:
        lesson = next((x for x in LESSONS if x.title == event.target.value), None)
        if lesson is None or lesson is self.lesson:
            return
        self.select(lesson.key)

    def _on_nav(self, event: viser.GuiEvent) -> None:
        step = self.index + (1 if str(event.target.value).startswith("Next") else -1)
        self.select(self.lesson.key, step)

    def select(self, lesson_key: str, step: int = 0) -> None:
        """Show step `step` of lesson `lesson_key` (nothing is set up until "Set up this step")."""
        lesson = next(x for x in LESSONS if x.key == lesson_key)
        self.lesson = lesson
        self.index = max(0, min(step, len(lesson.steps) - 1))
        if self.choice.value != lesson.title:
            self.choice.value = lesson.title
        self._show()

    @property
    def step(self) -> Step:
        """The step shown."""
        return self.lesson.steps[self.index]

    def start_step(self) -> None:
        """Send the shown step's set-up commands and watch for its end."""
        step = self.step
        compare = self.compared(self.lesson, self.index)
        for cmd in step.setup(self.loop.lab):
            self.loop.submit(cmd)
        lesson = self.lesson.key
        # after every set-up command (a preset switch may take a while)
        bound = self.loop.call(lambda s: bind(self.loop.lab, lesson, step.key), timeout=60.0)
        with self._lock:
            self.armed = bound
        if self.view is not None:
            self.view.show(bound.restarts, step.plots, compare)
        self.claims.pop(bound.key, None)
        self.result_md.content = WAITING

    # ---- live -------------------------------------------------------------------------------------
    def refresh(self, settings: Any) -> None:
        """Nothing: the lessons follow the run, not the parameters."""

    def live(self, frame: Frame) -> None:
        """When the armed step's run changed: cancel it with one line; when it has run far enough:
        measure it, pause there and show the claim."""
        if self.view is not None:
            self.view.follow(frame)
        with self._lock:
            armed = self.armed
            if armed is None or frame.restarts < armed.restarts:
                return
            lesson = next(x for x in LESSONS if x.key == armed.lesson)
            step = next(s for s in lesson.steps if s.key == armed.step)
            cancelled = cancel_line(armed, identity_from(frame.status, frame.settings))
            if cancelled is None and not step.ready(frame.status):
                return
            self.armed = None
        memo = self.results.setdefault(lesson.key, {})
        if cancelled is None:
            self.loop.submit(Pause())
            fresh: Memo = dict(memo)
            obs, cancelled_or_claim = self.loop.call(lambda s: finish(self.loop.lab, armed, step, fresh), timeout=30.0)
            if obs is not None:
                memo[step.key] = obs
                trace = self.view.capture() if self.view is not None else None
                if trace is not None:
                    self.traces[armed.key] = trace
            text = cancelled_or_claim
        else:
            text = cancelled
        if text.startswith("Cancelled: ") and self.view is not None:
            self.view.clear()  # the run is not the step's any more
        self.claims[armed.key] = text
        self.last_claim = text
        if self.lesson is lesson and self.step is step:
            self.result_md.content = result_text(text)

    def compared(self, lesson: Lesson, index: int) -> Trace | None:
        """The run step `index` of `lesson` compares with (`Step.compared`): the named step's last run, by
        default the step before's, else the step's own earlier run; None for a step that compares with none."""
        step = lesson.steps[index]
        if step.compared is None:
            return None
        other = step.compared or (lesson.steps[index - 1].key if index > 0 else step.key)
        keys = (other, step.key)
        return next((self.traces[(lesson.key, k)] for k in keys if (lesson.key, k) in self.traces), None)

    def _show(self) -> None:
        lesson, step = self.lesson, self.step
        self.purpose.content = f"*{lesson.purpose}*"
        self.step_md.content = f"**Step {self.index + 1} of {len(lesson.steps)}: {step.title}.** {step.todo}"
        claim = self.claims.get((lesson.key, step.key))
        waiting = self.armed is not None and self.armed.key == (lesson.key, step.key)
        self.result_md.content = result_text(claim) if claim else (WAITING if waiting else "")


def _sentence(text: str) -> str:
    """`text` opening as a sentence does (its first letter in capitals)."""
    return text[:1].upper() + text[1:]


def result_text(claim: str) -> str:
    """A step's result as shown: the claim, or the line saying why the step was cancelled."""
    return (
        f"**Step cancelled.** {_sentence(claim.removeprefix('Cancelled: '))}"
        if claim.startswith("Cancelled: ")
        else (f"**What you saw.** {claim}")
    )
