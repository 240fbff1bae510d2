"""Every tunable of the controllers as frozen, validated dataclasses.

Construction validates: a negative or non-finite gain raises `ValueError` naming the field.
Use `dataclasses.replace(gains, field=value)` to change one value (validated again).
"""

from __future__ import annotations

import math
from dataclasses import fields

import numpy as np


def validate_non_negative(obj: object) -> None:
    """Raise ValueError naming the first field that is NaN/inf or negative (scalars and arrays)."""
    for f in fields(obj):  # type: ignore[arg-type]
        value = getattr(obj, f.name)
        if isinstance(value, bool) or isinstance(value, str) or value is None:
            continue
        arr = np.asarray(value, dtype=float)
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"{type(obj).__name__}.{f.name} must be finite, got {value!r}")
        if np.any(arr < 0):
            raise ValueError(f"{type(obj).__name__}.{f.name} must be non-negative, got {value!r}")


def validate_positive(obj: object, *names: str) -> None:
    """Raise ValueError if any named field is not strictly positive."""
    for name in names:
        arr = np.asarray(getattr(obj, name), dtype=float)
        if np.any(arr <= 0) or not np.all(np.isfinite(arr)):
            raise ValueError(f"{type(obj).__name__}.{name} must be positive, got {getattr(obj, name)!r}")


def as_tuple(value, n: int, name: str) -> tuple[float, ...]:
    """A scalar or length-n sequence as a tuple of n floats (frozen dataclasses hold tuples)."""
    arr = np.broadcast_to(np.asarray(value, dtype=float), (n,)) if np.ndim(value) == 0 else np.asarray(value, float)
    if arr.shape != (n,):
        raise ValueError(f"{name} needs {n} values, got {len(arr)}")
    return tuple(float(x) for x in arr)


def is_finite_number(x) -> bool:
    """True for a real, finite number."""
    try:
        return math.isfinite(float(x))
    except (TypeError, ValueError):
        return False
