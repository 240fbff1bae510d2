"""A preset, case or robot switch's new session (or a twin arm switched on), built in a thread of its own
while the loop steps on.

Building a session (the robot's model, MuJoCo's world, the executor and its first dynamics) takes tens
of milliseconds, the first build of a preset up to ~110 ms: on the loop thread the arm stood still that
long. The loop hands the build (`app.core.switching.build_switch`) to `SwitchBuilder`, keeps stepping
the current session and applying only urgent commands (drag, Pause: the others keep their order behind
the switch), and makes the built session the lab's once it is done (`Lab.install_switch`). A switch to
a preset that needs a costly computation first ends its build with WorkPending before anything is built:
the loop then hands the work to its planner, as before. A twin arm switched on (`SetTwin`) is built the
same way (`app.core.twin.TwinRecipe`, 14–115 ms on the loop thread before) and installed with
`Lab.install_twin`; a switch with a twin running builds the new twin beside its new session.
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import replace
from typing import TYPE_CHECKING, Any

from app.core.commands import SwitchSession
from app.core.switching import BuiltSwitch, build_switch, plan_switch
from app.core.twin import Twin, TwinRecipe

if TYPE_CHECKING:
    from app.live.lab import Lab

THREAD_NAME = "torquelab-build"


class SwitchBuilder:
    """One build at a time in a thread of its own; `wake()` is called when a build ends."""

    def __init__(self, wake: Callable[[], None]):
        self._wake = wake
        self._threads: ThreadPoolExecutor | None = None
        self._job: tuple[Any, Future] | None = None

    @property
    def busy(self) -> bool:
        """True from `start` until `take_done` hands the result back."""
        return self._job is not None

    def start(self, command: Any, build: Callable[[], Any]) -> None:
        """Run `build()` in the builder's thread; `command` is handed back with its result by `take_done`."""
        if self._threads is None:
            self._threads = ThreadPoolExecutor(max_workers=1, thread_name_prefix=THREAD_NAME)
        future = self._threads.submit(build)
        self._job = (command, future)
        future.add_done_callback(lambda _f: self._wake())

    def take_done(self) -> tuple[Any, Any, BaseException | None] | None:
        """(command, built, None) once the build is done, (command, None, error) if it raised; None while it
        runs or when nothing does."""
        if self._job is None or not self._job[1].done():
            return None
        command, future = self._job
        self._job = None
        error = future.exception()
        return command, None if error is not None else future.result(), error

    def stop(self) -> None:
        """Abandon the build under way (its thread ends with it) and take no more."""
        self._job = None
        if self._threads is not None:
            self._threads.shutdown(wait=False, cancel_futures=True)
            self._threads = None


def switch_build(lab: Lab, command: SwitchSession, log_seconds: float) -> Callable[[], BuiltSwitch]:
    """The build of `command`'s new session (and of the twin beside it, if one runs), with what it needs of
    `lab` read now, on the loop thread: the returned function may run in any thread."""
    session, robot_choice, changes, defaults = lab.session, lab.robot_choice, list(lab.overrides), lab.defaults
    twin_objective = lab.twins.objective

    def build() -> BuiltSwitch:
        plan = plan_switch(session, robot_choice, command)
        assert plan is not None
        built = build_switch(plan, session.seed, changes, defaults, defer_work=True, log_seconds=log_seconds)
        if twin_objective is None:
            return built
        try:  # the twin beside the new session, here too (it is not the loop's yet)
            twin: Any = TwinRecipe.of(built.session, built.robot_choice, twin_objective, log_seconds).build()
        except ValueError as exc:
            twin = exc
        return replace(built, twin=twin)

    return build


def twin_build(lab: Lab, objective: str, log_seconds: float) -> Callable[[], Twin]:
    """The build of a twin with `objective` beside `lab`'s session, read now (ValueError for an objective a
    twin cannot have): the returned function may run in any thread."""
    return TwinRecipe.of(lab.session, lab.robot_choice, objective, log_seconds).build
