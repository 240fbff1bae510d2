"""Settings: a session's parameter groups in force as one frozen, versioned snapshot, and small helpers
for settings-like data (plain JSON-friendly values and finite numbers).

The tunables themselves are parameter groups (`control.params`, `Session.params()`); saving and
loading them is `app.settings_file`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from control.params import ParamGroup


@dataclass(frozen=True)
class Settings:
    """A session's parameter groups in force (`Session.params()`, frozen); `version` grows."""

    version: int
    groups: dict[str, ParamGroup]

    @property
    def values(self) -> dict[str, dict[str, Any]]:
        """Group → field → value as plain data (for exports and tests)."""
        return {name: group.values() for name, group in self.groups.items()}


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


def finite_number(value: object) -> float | None:
    """A finite float, or None for anything else (strings, NaN, None, booleans)."""
    if isinstance(value, bool):
        return None
    try:
        out = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return None
    return out if math.isfinite(out) else None
