"""Notices: the messages a run has for the browser, queued for the publisher and kept for tests and logs,
and the words they name a change or a refusal with."""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

from app.core.params import field_spec
from control.params import ParamError

KEPT_NOTICES = 100  # notices each queue holds (the oldest go first)


@dataclass(frozen=True)
class Notice:
    """A message for the browser: to one client (`client_id`) or to all (None)."""

    level: str  # "info", "warning" or "error"
    title: str
    body: str
    client_id: int | None = None


class Notices:
    """The notices not yet taken by the publisher (`queue`) and every notice (`log`). Appends and pops of
    a deque are atomic: another thread may `say` while the loop thread takes."""

    def __init__(self) -> None:
        self.queue: deque[Notice] = deque(maxlen=KEPT_NOTICES)
        self.log: deque[Notice] = deque(maxlen=KEPT_NOTICES)

    def say(self, notice: Notice) -> None:
        """Queue `notice` for the browser and keep it in `log`."""
        self.queue.append(notice)
        self.log.append(notice)

    def __len__(self) -> int:
        """Notices not yet taken."""
        return len(self.queue)

    def take(self) -> list[Notice]:
        """The notices queued since the last call, oldest first."""
        out = []
        while True:
            try:
                out.append(self.queue.popleft())
            except IndexError:
                return out


def refusal_words(exc: BaseException) -> str:
    """Why a command was refused, from its exception, in words."""
    text = str(exc) or type(exc).__name__
    if isinstance(exc, TypeError) and "unexpected keyword" in text:
        return f"this controller has no such setting ({text})"
    return text


def in_knob_words(message: str, group: str, field: str) -> str:
    """A refusal as the page's knob says it: "λ must be between 1 and 1000 1/s, got -5" for the
    parameter's "damper.lambda_ must be …" (the knob's label instead of the group and field names)."""
    try:
        label_text = field_spec(group, field).label
    except ParamError:
        return message
    prefix = f"{group}.{field}"
    if not label_text or not message.startswith(prefix):
        return message
    return label_text + message[len(prefix) :]
