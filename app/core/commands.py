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


@dataclass(frozen=True)
class Play:
    """Run the simulation paced to wall time."""


@dataclass(frozen=True)
class Pause:
    """Stop stepping; the state is kept."""


@dataclass(frozen=True)
class StepOnce:
    """While paused: advance `steps` control periods (1 ms each) at once."""

    steps: int = 1


@dataclass(frozen=True)
class SettleNow:
    """Run the preset's settle phase unpaced (as fast as the machine allows) until the posture has
    converged, then go on paced. Pause, Reset or a single step stop it; a preset with nothing left to
    settle refuses it (a notice to `client_id`)."""

    client_id: int | None = None


@dataclass(frozen=True)
class Reset:
    """Back to t = 0 of the current scenario (drag released, settings kept)."""


@dataclass(frozen=True)
class SetSpeed:
    """Simulated seconds per wall second requested: 0.01 … 1000 (`app.live.run_flags.SPEED_RANGE`; 1000 means
    as fast as the machine allows, every wake-up a full burst); the Lab refuses a value outside."""

    factor: float


@dataclass(frozen=True)
class SwitchSession:
    """Rebuild the session: `None` keeps the current choice; robot "" means the scenario's default;
    `variant` picks the scenario's case (mass drop: position / torque-residual / torque-fusion...)."""

    scenario: str | None = None
    robot: str | None = None
    executor: str | None = None
    variant: str | None = None


@dataclass(frozen=True)
class SetParam:
    """Set one parameter (`control.params`) of the session between two steps: field `field` of group
    `group` (see `Session.params()`), or only element `index` of a vector field — applied on the
    loop thread, so two element changes in one frame both land. The group's dataclass validates
    the value; a refused one changes nothing and is reported to `client_id`."""

    group: str
    field: str
    value: object
    index: int | None = None
    client_id: int | None = None


def label(o: SetParam) -> str:
    """How a notice names a change: "damper.lambda_ = 300.0", "posture_task.compliance[3] = 1.0"."""
    index = "" if o.index is None else f"[{o.index}]"
    return f"{o.group}.{o.field}{index} = {o.value!r}"


@dataclass(frozen=True)
class RestoreDefaults:
    """Every parameter of the preset back to its defaults (overrides forgotten; the run restarts)."""

    client_id: int | None = None


@dataclass(frozen=True)
class SetTwin:
    """Run a twin arm with nullspace objective `objective` ("j", "f", "a", "d") beside the main one,
    or none (None). Switching a twin on restarts the scenario so both arms start together."""

    objective: str | None
    client_id: int | None = None


Command = (
    DragCommand
    | Play
    | Pause
    | StepOnce
    | SettleNow
    | Reset
    | SetSpeed
    | SwitchSession
    | SetParam
    | RestoreDefaults
    | SetTwin
)
