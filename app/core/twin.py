"""The twin arm: the same scenario run a second time, in lockstep, with another nullspace objective.

The twin is a second `Session` (its own MuJoCo world, controller model, executor and sensor noise
with the same seed) that the main session's `run` steps right after its own (`Lockstep`): a twin
that diverges or raises stops alone, with its own reason. It gets every setting the
person changes except the objective, never the drag spring. With the same objective it repeats the
main arm step for step (a test checks this), so any difference on screen comes from the objective.
It costs a second control step per millisecond: the status line shows when that is too much.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from app.core.session import Session
from app.core.steplog import session_log
from app.scenarios import Scenario
from control.params import ParamError

TWIN_OBJECTIVES = ("j", "f", "a", "d")


class Twin:
    """A second session in lockstep with the main one (see the module docstring)."""

    def __init__(
        self,
        scenario: Scenario,
        robot: str | None,
        executor: str,
        seed: int,
        objective: str,
        dt: float,
        overrides: Sequence[Any],  # the loop's SetParam records: .group, .field, .value, .index
        log_seconds: float = 60.0,
    ):
        if objective not in TWIN_OBJECTIVES:
            raise ValueError(f"the twin's objective must be one of {', '.join(TWIN_OBJECTIVES)}, got {objective!r}")
        self.session = Session(scenario, robot=robot, executor=executor, seed=seed)
        self.objective = objective
        self._own_objective(executor)
        for o in overrides:
            self.set_param(o.group, o.field, o.value, o.index)
        self.dt = dt
        self.log = session_log(self.session, log_seconds)  # as the main log

    @classmethod
    def beside(cls, session: Session, robot_choice: str, objective: str, log_seconds: float = 60.0) -> Twin:
        """A twin of `session`: its preset, robot (`robot_choice`, "" = the preset's default), executor,
        seed, accepted changes and offload, with its own `objective`."""
        return TwinRecipe.of(session, robot_choice, objective, log_seconds).build()

    def _own_objective(self, executor: str) -> None:
        if "nullspace" not in self.session.params():
            raise ValueError(f"the {executor} executor has no nullspace objective: the twin needs the projection one")
        self.session.set_param("nullspace", "objective", self.objective)

    def set_param(self, group: str, field: str, value: Any, index: int | None = None) -> None:
        """Apply a person's change to the twin too; its own objective and the drag spring stay its
        own, and a value the twin refuses is left out (the main session has already accepted it)."""
        if group == "drag" or (group == "nullspace" and field == "objective"):
            return
        try:
            self.session.set_param(group, field, value, index)
        except ParamError:
            pass

    def set_executor(self, name: str) -> None:
        """Follow the main session's executor switch (its overrides re-applied by the session);
        ValueError if the new executor has no objective."""
        self.session.set_executor(name)
        self._own_objective(name)

    def restore_defaults(self) -> None:
        """Every parameter back to the preset's defaults but the twin's own objective; t = 0."""
        self.session.restore_defaults()
        self._own_objective(self.session.executor_name)
        self.session.reset()
        self.log.clear()

    def reset(self) -> None:
        """Back to t = 0 with the main session (the session keeps its parameter overrides)."""
        self.session.reset()
        self.log.clear()

    def columns_at(self, t: np.ndarray) -> dict[str, np.ndarray]:
        """The twin's logged columns at the main log's times `t` (NaN where it has no sample)."""
        out: dict[str, np.ndarray] = {}
        if len(t) == 0:
            return out
        span = float(np.max(t) - np.min(t)) + 2 * self.dt
        cols = self.log.window(span, self.dt)
        ts = cols.get("t", np.zeros(0))
        idx = np.clip(np.searchsorted(ts, t), 0, max(len(ts) - 1, 0))
        hit = (np.abs(ts[idx] - t) < 1e-9) if len(ts) else np.zeros(len(t), dtype=bool)
        for name, values in cols.items():
            column = np.full(len(t), np.nan)
            if len(ts):
                column[hit] = values[idx[hit]]
            out[name] = column
        return out

    def force_error_at(self, t: np.ndarray) -> np.ndarray:
        """The twin's F̂_z − F_z at the main log's times (NaN where it has no sample)."""
        cols = self.columns_at(t)
        if "Fd_z" not in cols:
            return np.full(len(t), np.nan)
        return cols["Fd_z"] - cols["F_z"]

    def link_poses(self, names: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
        """World positions (L, 3) and quaternions (L, 4, wxyz) of the twin's bodies."""
        world = self.session.world
        ids = world.body_ids(names)
        return world.data.xpos[ids], world.data.xquat[ids]  # fancy indexing: copies

    @property
    def W(self) -> dict[str, float]:
        """The twin's last objective values as its executor reported them: "W" (its own objective)
        and whichever of W_j, W_f, W_a, W_d it reports."""
        last = self.session.last
        sig = last.signals if last is not None else {}
        return {k: float(sig[k]) for k in ("W", "W_j", "W_f", "W_a", "W_d") if k in sig}


@dataclass(frozen=True)
class TwinRecipe:
    """What a twin takes from the main session, read where that session runs (cheap); `build()` makes the
    twin anywhere (tens of milliseconds: its own model, world and executor), e.g. off the loop thread."""

    scenario: Scenario
    robot: str | None
    executor: str
    seed: int
    objective: str
    dt: float
    overrides: tuple[Any, ...]
    log_seconds: float
    offload: Any

    @classmethod
    def of(cls, session: Session, robot_choice: str, objective: str, log_seconds: float = 60.0) -> TwinRecipe:
        """The recipe of a twin of `session` (see `Twin.beside`); ValueError for an objective a twin cannot have."""
        if objective not in TWIN_OBJECTIVES:
            raise ValueError(f"the twin's objective must be one of {', '.join(TWIN_OBJECTIVES)}, got {objective!r}")
        dt = float(session.world.model.opt.timestep)
        return cls(
            session.preset,
            robot_choice or None,
            session.executor_name,
            session.seed,
            objective,
            dt,
            tuple(session.changes),
            log_seconds,
            session.offload,
        )

    def build(self) -> Twin:
        """The twin (ValueError when the executor has no objective)."""
        parts = (self.scenario, self.robot, self.executor, self.seed, self.objective, self.dt, self.overrides)
        twin = Twin(*parts, log_seconds=self.log_seconds)
        twin.session.set_offload(self.offload)
        return twin
