"""The twin arm's life beside a lab's session: switched on with an objective, built again on every new
session, following the person's changes and the controller, and switched off, with the reason, when it
cannot follow (`app.core.twin.Twin` is the arm itself)."""

from __future__ import annotations

from collections.abc import Callable

from app.core.commands import SetParam
from app.core.session import Session
from app.core.twin import Twin


class TwinArm:
    """The lab's twin (`twin`, None when off); `say_off(reason)` tells the person it was switched off."""

    def __init__(self, say_off: Callable[[str], None], log_seconds: float):
        self.twin: Twin | None = None
        self._say_off = say_off
        self._log_seconds = log_seconds

    def on(self, session: Session, robot_choice: str, objective: str) -> None:
        """A twin of `session` with `objective` (ValueError for a wrong objective or an executor without one)."""
        self.twin = Twin.beside(session, robot_choice, objective, self._log_seconds)

    def off(self, reason: str = "") -> None:
        """No twin; with a `reason`, the person is told why."""
        self.twin = None
        if reason:
            self._say_off(reason)

    def install(self, twin: Twin) -> None:
        """A twin built elsewhere (off the loop thread: `TwinRecipe.build`) becomes the lab's."""
        self.twin = twin

    @property
    def objective(self) -> str | None:
        """The twin's objective, None when it is off."""
        return None if self.twin is None else self.twin.objective

    def rebuild(self, session: Session, robot_choice: str, ready: Twin | BaseException | None = None) -> None:
        """After a new session: the same objective on it, or no twin if it cannot have one. `ready` is the
        twin (or the error) already built beside `session` off the loop thread, if it was."""
        if self.twin is None:
            return
        try:
            if isinstance(ready, BaseException):
                raise ready
            if ready is not None and ready.objective == self.twin.objective:
                self.twin = ready
            else:
                self.on(session, robot_choice, self.twin.objective)
        except ValueError as exc:
            self.off(f"the twin arm is switched off: {exc}")

    def restore_defaults(self) -> None:
        """The main session went back to its defaults: the twin too, keeping its objective (no new twin)."""
        if self.twin is None:
            return
        try:
            self.twin.restore_defaults()
        except ValueError as exc:
            self.off(f"the twin arm is switched off: {exc}")

    def follow_param(self, cmd: SetParam) -> None:
        """The main arm took `cmd`: the twin takes it too, or is switched off if it cannot."""
        if self.twin is None:
            return
        try:
            self.twin.set_param(cmd.group, cmd.field, cmd.value, cmd.index)
        except Exception as exc:  # a twin that cannot follow compares nothing any more
            self.off(
                f"the twin arm is switched off: it could not take {cmd.group}.{cmd.field} "
                f"({type(exc).__name__}: {exc}); the main arm runs with it"
            )

    def follow_executor(self, name: str) -> None:
        """The main arm switched its controller to `name`: the twin too, or off if it has no objective."""
        if self.twin is None:
            return
        try:
            self.twin.set_executor(name)
        except ValueError as exc:
            self.off(f"the twin arm is switched off: {exc}")

    def reset(self) -> None:
        """Back to t = 0 beside the main arm."""
        if self.twin is not None:
            self.twin.reset()
