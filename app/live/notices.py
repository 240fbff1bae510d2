"""Notices: the messages a run has for the browser, queued for the publisher and kept for tests and logs."""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

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
