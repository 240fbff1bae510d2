"""Commands the browser side sends to the simulation loop.

GUI and scene callbacks run on viser's thread pool; they never touch the Session. They build one
of these small immutable records and hand it to the loop, which applies it between two steps.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

Vec3 = tuple[float, float, float]


@dataclass(frozen=True)
class DragCommand:
    """Grab, move or release the drag spring on behalf of one browser client.

    grab: `body_name` is the MuJoCo/URDF link name, `point_world` the grabbed point (world frame, m).
    move: `target_world` is where the spring pulls the grabbed point (world frame, m).
    release: drops the spring if `client_id` holds it.
    """

    kind: Literal["grab", "move", "release"]
    client_id: int
    body_name: str = ""
    point_world: Vec3 | None = None
    target_world: Vec3 | None = None


DragSink = Callable[[DragCommand], None]
