"""Who holds the drag spring: the client whose grab took it, the only one whose moves and release count."""

from __future__ import annotations

from typing import Any

import numpy as np

from app.core.commands import DragCommand


class DragOwner:
    """The client holding a session's drag spring (`client`, None when nobody does)."""

    def __init__(self) -> None:
        self.client: int | None = None

    def apply(self, session: Any, cmd: DragCommand) -> None:
        """Grab, move or release `session`'s spring (`app.sim.drag.DragSpring`) for `cmd.client_id`:
        a grab takes it, a move or release by another client is ignored; ValueError or KeyError for a
        grab without a finite point, of the world body or of an unknown body, and for an unknown kind."""
        drag = session.drag
        if cmd.kind == "grab":
            point = vec3(cmd.point_world)
            if point is None:
                raise ValueError("grab needs a finite 3-D point")
            body_id = session.world.model.body(cmd.body_name).id  # KeyError for unknown names
            if body_id == 0:
                raise ValueError("the world body cannot be dragged")
            drag.grab(session.world, body_id, point)
            self.client = cmd.client_id
        elif cmd.kind == "move":
            target = vec3(cmd.target_world)
            if target is not None and drag.active and cmd.client_id == self.client:
                drag.move(target)
        elif cmd.kind == "release":
            if cmd.client_id == self.client:
                drag.release()
                self.client = None
        else:
            raise ValueError(f"unknown drag command {cmd.kind!r}")


def vec3(value: object) -> np.ndarray | None:
    """A finite 3-vector, or None."""
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        return None
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        return None
    return arr
