"""Logged signals as CSV and JSON files (the Record/Export panel's downloads)."""

from __future__ import annotations

import io
import json
import math
from typing import Any

import numpy as np

from app.core.settings import plain

MAX_EXPORT_S = 60.0


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
