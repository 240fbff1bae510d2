"""When the surroundings (the drag) overpower a joint: the status says which, and a notice says when it starts."""

from __future__ import annotations

import math
from collections.abc import Callable

from app.core.session import Session

OVERPOWERED_NOTICE_S = 2.0  # simulated time between two "overpowered" notices
OVERPOWERED_CHECK_STEPS = 10  # steps between two looks for an overpowered joint (a look costs ~10 µs)


class OverpoweredWatch:
    """`text`: the joints the surroundings overpower, in words (`World.overpowered`), "" when none;
    `say(text)` tells the person when that starts."""

    def __init__(self, say: Callable[[str], None]) -> None:
        self._say = say
        self.clear()

    def clear(self) -> None:
        """A new run: nothing overpowered, nothing said yet, the next look at once."""
        self.text = ""
        self._notice_t = -math.inf
        self._check_at = 0

    def due(self, total_steps: int) -> bool:
        """True once every OVERPOWERED_CHECK_STEPS steps (`total_steps` run so far), and at once after `clear`."""
        if total_steps < self._check_at:
            return False
        self._check_at = total_steps + OVERPOWERED_CHECK_STEPS
        return True

    def check(self, session: Session) -> None:
        """Which joints `session`'s surroundings overpower now; said when that starts, at most every
        OVERPOWERED_NOTICE_S of simulated time."""
        last = session.last
        was, self.text = self.text, session.world.overpowered(last.tau_ext if last else None)
        t = session.world.time
        if self.text and not was and t - self._notice_t >= OVERPOWERED_NOTICE_S:
            self._notice_t = t
            self._say(f"{self.text}: more than the motors can resist, so no controller can hold the arm here")
