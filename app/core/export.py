"""A run's logged signals with what produced them, and as CSV and JSON files (the Record/Export panel's
downloads)."""

from __future__ import annotations

import io
import json
import math
from typing import Any

import numpy as np

from app.core.session import Session
from app.core.settings import plain
from app.core.steplog import StepLog
from app.core.twin import Twin

MAX_EXPORT_S = 60.0


def run_export(session: Session, log: StepLog, twin: Twin | None, seconds: float) -> dict[str, Any]:
    """The last `seconds` of `log` (every step; the twin's columns beside them as "twin_*", same rows)
    plus what produced it: scenario, robot, executor, dt, seed and the settings in force."""
    dt = float(session.world.model.opt.timestep)
    columns = log.window(seconds, dt)
    if twin is not None and "t" in columns:
        columns |= {f"twin_{k}": v for k, v in twin.columns_at(columns["t"]).items() if k != "t"}
    return {
        "columns": columns,
        "twin_objective": twin.objective if twin is not None else None,
        "scenario": session.scenario.name,
        "robot": session.robot.name,
        "executor": session.executor_name,
        "dt": dt,
        "seed": session.seed,
        "settings": plain({name: group.values() for name, group in session.params().items()}),
    }


def to_csv(columns: dict[str, np.ndarray]) -> bytes:
    """One header line of column names, then one line per step (empty cell for a missing value)."""
    names = list(columns)
    if not names:
        return b""
    table = np.column_stack([np.asarray(columns[n], dtype=float) for n in names])
    out = io.StringIO()
    np.savetxt(out, table, fmt="%.9g", delimiter=",", header=",".join(names), comments="")
    return out.getvalue().replace("nan", "").encode()  # no other cell can contain "nan"


def to_json(export: dict[str, Any]) -> bytes:
    """The export as JSON: metadata, settings in force, and each column as a list (null = missing)."""
    cols = {
        name: [None if math.isnan(x) else float(x) for x in np.asarray(values, dtype=float)]
        for name, values in export["columns"].items()
    }
    meta = {k: plain(v) for k, v in export.items() if k != "columns"}
    return json.dumps({**meta, "columns": cols}, allow_nan=False).encode()
