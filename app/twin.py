"""The twin arm: the same scenario run a second time, in lockstep, with another nullspace objective.

The twin is a second `Session` (its own MuJoCo world, controller model, executor and sensor noise
with the same seed) that the loop steps right after the main session. It gets every setting the
person changes except the objective, never the drag spring. With the same objective it repeats the
main arm step for step (a test checks this), so any difference on screen comes from the objective.
It costs a second control step per millisecond: the status line shows when that is too much.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from app.scenarios import Scenario
from app.session import Session

TWIN_OBJECTIVES = ("j", "f", "a", "d")
FORCE_LOG_S = 12.0  # s of the twin's force error kept for the plot (the plot shows 10 s)


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
        overrides: Mapping[str, Mapping[str, Any]],
    ):
        if objective not in TWIN_OBJECTIVES:
            raise ValueError(f"the twin's objective must be one of {', '.join(TWIN_OBJECTIVES)}, got {objective!r}")
        self.session = Session(scenario, robot=robot, executor=executor, seed=seed)
        if "objective" not in _settings(self.session):
            raise ValueError(f"the {executor} executor has no nullspace objective: the twin needs the projection one")
        self.objective = objective
        for target, changes in overrides.items():
            self.configure(target, changes)
        self.session.executor.configure(objective=objective)
        capacity = round(FORCE_LOG_S / dt)
        self._t = np.full(capacity, np.nan)
        self._err = np.full(capacity, np.nan)
        self._count = 0

    def configure(self, target: str, changes: Mapping[str, Any]) -> None:
        """Apply a person's change to the twin too, one setting at a time; its own objective and
        the drag spring stay its own, and a setting the twin refuses is left out (the main session
        has already accepted it)."""
        if target == "drag":
            return
        for key, value in changes.items():
            if target == "executor" and key == "objective":
                continue
            try:
                self.session.configure(target, {key: value})
            except (ValueError, TypeError, KeyError):
                pass

    def set_executor(self, name: str, executor_overrides: Mapping[str, Any]) -> None:
        """Follow the main session's executor switch (state kept); ValueError if it has no objective."""
        self.session.set_executor(name)
        if "objective" not in _settings(self.session):
            raise ValueError(f"the {name} executor has no nullspace objective")
        self.configure("executor", executor_overrides)
        self.session.executor.configure(objective=self.objective)

    def reset(self, overrides: Mapping[str, Mapping[str, Any]]) -> None:
        """Back to t = 0 with the main session (environment, sensor and target settings re-applied)."""
        self.session.reset()
        for target in ("environment", "sensor", "target"):
            self.configure(target, overrides.get(target, {}))
        self._t[:] = np.nan
        self._err[:] = np.nan
        self._count = 0

    def step(self) -> None:
        """One control period, in lockstep with the main session."""
        rec = self.session.step()
        i = self._count % len(self._t)
        self._t[i] = rec.t
        self._err[i] = float(rec.target.wrench[2] - rec.wrench_tcp[2])  # F̂_z − F_z, as the main plot
        self._count += 1

    def diverged(self) -> bool:
        """NaN or runaway state in the twin's simulation."""
        return self.session.diverged()

    def force_error_at(self, t: np.ndarray) -> np.ndarray:
        """The twin's F̂_z − F_z at the main log's times (NaN where the twin has no sample)."""
        out = np.full(len(t), np.nan)
        n = min(self._count, len(self._t))
        if n == 0 or len(t) == 0:
            return out
        order = np.argsort(self._t[:n])
        ts, errs = self._t[:n][order], self._err[:n][order]
        idx = np.clip(np.searchsorted(ts, t), 0, n - 1)
        hit = np.abs(ts[idx] - t) < 1e-9
        out[hit] = errs[idx[hit]]
        return out

    def link_poses(self, names: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
        """World positions (L, 3) and quaternions (L, 4, wxyz) of the twin's bodies."""
        world = self.session.world
        ids = [world.model.body(name).id for name in names]
        return world.data.xpos[ids].copy(), world.data.xquat[ids].copy()

    @property
    def W(self) -> dict[str, float]:
        """The twin's last objective values as its executor reported them: "W" (its own objective)
        and whichever of W_j, W_f, W_a, W_d it reports."""
        last = self.session.last
        sig = last.signals if last is not None else {}
        return {k: float(sig[k]) for k in ("W", "W_j", "W_f", "W_a", "W_d") if k in sig}


def _settings(session: Session) -> dict[str, Any]:
    from app.settings import settings_of

    return settings_of(session.executor)
