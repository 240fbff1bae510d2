"""Read the current tunables of an executor, environment or sensor as a flat {name: value} dict.

An object may say it itself with a `settings()` method. Otherwise every dataclass instance held in
a public attribute (e.g. `executor.gains`) contributes its fields, and public scalar attributes
(numbers, booleans, strings) contribute themselves. The GUI builds and refreshes its panels from
this, so a new field in a gains dataclass appears without hand-written code.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

_SKIP = frozenset({"name", "title", "description"})


def plain(value: Any) -> Any:
    """A value as JSON-friendly Python data (arrays → lists of floats, tuples → lists)."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    if isinstance(value, dict):
        return {str(k): plain(v) for k, v in value.items()}
    return value


def settings_of(obj: object) -> dict[str, Any]:
    """The tunables `obj` exposes, by field name (see the module docstring)."""
    method = getattr(obj, "settings", None)
    if callable(method):
        try:
            return {str(k): plain(v) for k, v in dict(method()).items()}
        except Exception:  # a broken settings() must not take the app down
            return {}
    out: dict[str, Any] = {}
    attrs = getattr(obj, "__dict__", {})
    for key, value in attrs.items():
        if key.startswith("_") or key in _SKIP:
            continue
        if dataclasses.is_dataclass(value) and not isinstance(value, type):
            for f in dataclasses.fields(value):
                if not f.name.startswith("_"):
                    out.setdefault(f.name, plain(getattr(value, f.name)))
        elif isinstance(value, (bool, int, float, str)):
            out.setdefault(key, value)
    return out


def finite_number(value: object) -> float | None:
    """A finite float, or None for anything else (strings, NaN, None, booleans)."""
    if isinstance(value, bool):
        return None
    try:
        out = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return None
    return out if math.isfinite(out) else None
