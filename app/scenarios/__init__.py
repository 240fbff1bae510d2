"""Scenarios: the presets of DESIGN §5 (polish, free, limit-drop, mass-drop, compliance).

A scenario says which robot and executor it wants by default, how the world is built (table,
payloads), where the arm starts, what the task target is over time, which environment forces
act (contact, sander, payload release) and which sensor model reads them. The `Session` runs it;
the web app and the headless experiments both use the same Session, so they agree step for step.

Each scenario module adds itself to `SCENARIOS` (name -> module under app.scenarios that defines
`SCENARIO`, an instance of a `Scenario` subclass). What a runner needs from a preset comes through
the hooks `Scenario` declares (each with a default, so a preset overrides only those it has), and
the runner names no preset and looks up no hook by name: the parameter groups it brings
(`Scenario.groups`), the robot's preparation (`prepare_robot`), the executor's tasks and limits
(`prepare_executor`) and the parameter changes it makes to the executor's groups
(`executor_changes`, applied by the Session like any other group change), a costly computation to
do first (`pending_work`), the strokes of its task (`segments`), the limit a joint falls to
(`fall`), its deflection readouts and their words (`readout_text`), its phase in words (`phase_text`),
its charts, phase marks and panels (`plot_layout`, `phase_marks`, `tune_first`) and the parameters its
lessons' claims rest on (`claim_keys`), and on
the environment `Environment.settle_pending` (a settle phase is under way) and
`Environment.connect` (the session's parameter groups, to read, and an `Offload` where the runner
has one: a place off its loop thread for costly page signals).
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from concurrent.futures import Future
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar, Protocol

import mujoco
import numpy as np

from app.scenarios.metrics import Fold
from app.sim.sensor import Sensor
from app.sim.world import World
from control.executor import Executor, TaskTarget
from control.model import Dynamics, RobotModel
from control.params import ParamGroup, expect
from robots import RobotDescription

if TYPE_CHECKING:
    from app.scenarios.drop_postures import Fall

# name -> module under app.scenarios (or a full module path) with a module-level SCENARIO
SCENARIOS: dict[str, str] = {
    "free": "free",
    "limit-drop": "limit_drop",
    "mass-drop": "mass_drop",
    "compliance": "compliance",
    "polish": "polish",
}
APP_PRESET = "polish"  # the web app opens on it (`torquelab serve`)
PLAIN_PRESET = "free"  # a lab or session built without naming one runs it


@dataclass(frozen=True)
class Work:
    """A computation a preset needs before its session is built (e.g. a planned swivel path):
    `compute(*args)` may run in another process (a module-level function, picklable arguments);
    `store(result)` then caches the result here, and building the session again finds it."""

    what: str  # in words, for a notice
    compute: Callable[..., Any]
    args: tuple
    store: Callable[[Any], None]


@dataclass(frozen=True)
class Chart:
    """A chart a preset brings to the page's Plots tab: its logged `series` (signal, label) against time,
    under `title`, on a y axis `y_label` (with its unit) of `y_range` before any widening. A preset lists
    it in its `plot_layout` beside the charts the page has of its own ("force", "torque", ...)."""

    key: str  # unique among the page's charts
    title: str
    series: tuple[tuple[str, str], ...]
    y_label: str
    y_range: tuple[float, float] = (0.0, 1.0)


@dataclass(frozen=True)
class PhaseMark:
    """A phase change of a preset worth a vertical line in the charts and an event in the replay: where
    the logged `signal` crosses 0.5 upward (`rising`) or downward, named `label`."""

    signal: str
    label: str
    rising: bool = True


class Offload(Protocol):
    """Where an environment's costly page signals are computed away from the loop thread (the app's
    loop gives one; tests and headless runs give none and the environment computes inline)."""

    gave_up: str | None  # why it will never take work (the caller then computes inline); None while it may

    def submit(self, fn: Callable[..., Any], /, *args: Any) -> Future | None:
        """Compute fn(*args) elsewhere (a module-level function, picklable arguments); None when it
        cannot take work now (still starting, or just died): the caller tries again later."""
        ...


class Environment:
    """Forces the surroundings apply each step (contact, sander, released masses...).

    `apply` is called once per step before the controller runs, with the world at the current
    state; it applies forces via `world.apply_force` and returns scalar signals for the logs.
    """

    def connect(
        self,
        params: Callable[[], Mapping[str, ParamGroup]],
        offload: Offload | None = None,
        dynamics: Callable[[], Dynamics] | None = None,
    ) -> None:
        """Called by the session once it has built the environment (and again when its runner gives
        an `offload`): `params()` gives the session's parameter groups in force (read only), for an
        environment whose signals depend on the controller's gains; `dynamics()` the step's snapshot
        of the arm's dynamics (during `apply`: of this step). Ignored by default."""

    def settle_pending(self) -> bool:
        """True while the preset's settle phase (before the task starts) has not ended; a preset
        without one: False. "Settle now" runs while this holds."""
        return False

    def apply(self, world: World, t: float) -> dict[str, float]:
        return {}

    def observe(self, signals: dict[str, float], t: float) -> None:
        """Called after the controller each step with its signals (e.g. to detect convergence)."""

    def params(self) -> dict[str, ParamGroup]:
        """Its parameter groups by name (friction, sander...); none by default."""
        return {}

    def set_params(self, name: str, group: Any) -> None:
        """Take a new validated group; ParamError for a group it lacks."""
        expect(name, group, None)

    def overlay(self) -> dict[str, np.ndarray]:
        """Vectors the UI may draw (e.g. 'contact_force' at 'contact_point'), world frame."""
        return {}


class Scenario:
    """Base scenario: hold the home posture, no environment, ideal sensor."""

    name = "base"
    title = "Base"
    description = ""
    default_robot = "rizon4s"
    default_executor = "joint-hold"
    table_height: float | None = None
    focus_joint: int | None = None  # 0-based joint the phase plot should show when the preset starts
    starts_paused = False  # over in seconds: the app starts it paused (and after Reset) until Play
    cases: tuple[str, ...] = ()  # the cases the preset can run in (app.core.variants), () if it has none
    case_arg = ""  # the constructor argument (and attribute) that picks the case
    # a preset whose lesson is how far the arm is pushed off its pose: its session's steps carry the TCP's and
    # the elbow's distance from where they stood at t = 0 ("tcp_dev_mm", "elbow_dev_mm"), live and headless
    logs_deflection = False
    # the parameter groups this preset brings beyond the controller's and the simulator's, by name: its own
    # "scenario" group and its environment's (the panels and settings files read them before a session has them)
    groups: ClassVar[Mapping[str, type[ParamGroup]]] = {}
    # the strokes of its task, counted by the environment's "segment" signal (1…segments while they run,
    # segments + 1 after, 0 before): 0 for a preset without strokes
    segments: int = 0
    # the page's view of it: the charts of the Plots tab in order (the page's own by name, `app.live.ui.charts`,
    # or a `Chart` of its own), the phase changes its charts and replay mark, the Tune tab's folders shown
    # first, and the parameters ("group.field") every lesson claim on it rests on
    plot_layout: tuple[str | Chart, ...] = ("coupling", "torque", "force")
    phase_marks: tuple[PhaseMark, ...] = ()
    tune_first: tuple[str, ...] = ("Nullspace", "Motion–force")
    claim_keys: tuple[str, ...] = ()

    @property
    def chosen_case(self) -> str:
        """The case it runs in (one of `cases`; "" for a preset without cases)."""
        return ""

    def prepare_robot(self, robot: RobotDescription) -> None:
        """Adapt to the robot before the model and the world are built (e.g. place the table for an arm
        without sidecar postures, or find its start); nothing by default."""

    def prepare_executor(self, executor: Executor, robot: RobotDescription) -> None:
        """Set up what is not a parameter of the executor it runs with (its tasks, its limits) when the
        session builds or switches the executor; nothing by default. Its gains come from `executor_changes`."""

    def executor_changes(self, groups: Mapping[str, ParamGroup], robot: RobotDescription) -> dict[str, ParamGroup]:
        """The executor's parameter groups this preset sets, from its groups in force (`groups`): the
        Session hands them to the executor after `prepare_executor` and at every reset, before the
        changes made with `set_param`, which stay in force. None by default."""
        return {}

    def phase_text(self, status: Any, scene: Any, memory: dict[str, Any]) -> str:
        """The phase it is in, in words, for the status line ("" when it has none): from the loop's
        `status` (t, signals, variant, focus_joint) and the frame's `scene` (q, objective, W; None
        without one); `memory` is the reader's own, kept between frames of one run."""
        return ""

    def fall(self, robot: RobotDescription) -> Fall | None:
        """Where a joint of the arm falls from the start (joint, direction, the limit it falls toward),
        for a preset that drops one; None by default."""
        return None

    def params(self) -> dict[str, ParamGroup]:
        """The scenario's own parameters (e.g. the polish start swivel) as group "scenario", if any;
        they take effect at the next reset. The Session works on its own copy of the scenario."""
        return {}

    def set_params(self, name: str, group: Any) -> None:
        """Take a new validated "scenario" group; ParamError for a group it lacks."""
        expect(name, group, None)

    def readout_fold(self) -> Fold | None:
        """A fresh running metric of the preset's deflection readouts (`app.scenarios.metrics`: the mass
        drop's peak, settle time and residual, the compliance pushes' peaks), fed every logged step since
        the reset; None: it has none."""
        return None

    def readout_text(self, values: Mapping[str, float]) -> list[str]:
        """The lines the page's readout shows for the values of `readout_fold` (every logged step since
        the reset); none by default."""
        return []

    def pending_work(self, robot: RobotDescription) -> Work | None:
        """A costly computation this preset needs on `robot` (the session's, prepared) that is not
        done yet, or None (the default). A session built without it computes it in place."""
        return None

    def armature(self, nominal: np.ndarray) -> np.ndarray:
        """The rotor armature (kg m², per joint) the controller model and the simulated arm run with,
        from the robot's `nominal` one; the Session sets it at every reset. Default: the nominal."""
        return nominal

    def initial_q(self, robot: RobotDescription) -> np.ndarray:
        """Joint positions at t = 0."""
        return robot.home

    def named_posture(self, robot: RobotDescription, name: str) -> np.ndarray:
        """A copy of the robot's posture `name` (from its sidecar); ValueError saying which robot has it."""
        if name not in robot.postures:
            raise ValueError(
                f"the {self.name} scenario starts from the posture {name!r}, which {robot.name} does not define; "
                f"run it on {self.default_robot}"
            )
        return np.array(robot.postures[name], dtype=float)

    def customize_world(self, spec: mujoco.MjSpec, robot: RobotDescription) -> None:
        """Edit the MuJoCo spec before compile (payloads...)."""

    def make_environment(self, world: World, rng: np.random.Generator) -> Environment:
        return Environment()

    def make_sensor(self, rng: np.random.Generator) -> Sensor:
        return Sensor()

    def make_target(
        self, robot: RobotDescription, model: RobotModel, dyn0: Dynamics, gains: Mapping[str, ParamGroup]
    ) -> Callable[[float], TaskTarget]:
        """The task target as a function of time, built at each reset with the executor's groups in
        force (`gains`); default: hold the initial TCP pose and posture."""
        hold = TaskTarget(
            position=dyn0.tcp_position_world.copy(), rotation=dyn0.tcp_rotation_world.copy(), q_posture=dyn0.q.copy()
        )
        return lambda t: hold


def get_scenario(name: str) -> Scenario:
    """The registered scenario `name`; ValueError listing the known ones otherwise."""
    if name not in SCENARIOS:
        raise ValueError(f"unknown scenario {name!r}; choose one of {', '.join(SCENARIOS)}")
    where = SCENARIOS[name]  # a module under app.scenarios, or a full module path (a preset of the tests)
    module = importlib.import_module(where if "." in where else f"app.scenarios.{where}")
    return module.SCENARIO
