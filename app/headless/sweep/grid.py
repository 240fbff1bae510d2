"""Grid axes from the command line: `NAME=a:b:n` (linspace), `NAME=a,b,c` (list) or `NAME=v`.

Values stay text here; each experiment's knob table (`app.headless.sweep.knobs`) types and validates them.
Errors are `SweepError` with a one-line message naming the offending item. A grid of more than
MAX_CELLS cells (axes × seeds) is refused before anything is allocated.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

MAX_CELLS = 100_000  # cells a sweep may have (each one a simulated run of seconds: more is a typo)


class SweepError(ValueError):
    """Bad sweep input (a grid item, a value, an engine address): a one-line message."""


@dataclass(frozen=True)
class Axis:
    """One grid axis: a parameter name and its values (typed once validated)."""

    name: str
    values: tuple

    def __len__(self) -> int:
        return len(self.values)


def _linspace(name: str, text: str) -> list[str]:
    parts = text.split(":")
    if len(parts) != 3:
        raise SweepError(f"{name}={text}: a range is a:b:n (start, stop, number of values)")
    try:
        a, b = float(parts[0]), float(parts[1])
    except ValueError:
        raise SweepError(f"{name}={text}: range ends must be numbers") from None
    try:
        n = int(parts[2])
    except ValueError:
        raise SweepError(f"{name}={text}: the number of values n must be a whole number") from None
    if n < 1:
        raise SweepError(f"{name}={text}: the number of values n must be at least 1")
    if n > MAX_CELLS:
        raise SweepError(f"{name}={text}: {n:,} values is more than a sweep's {MAX_CELLS:,} cells")
    if not (np.isfinite(a) and np.isfinite(b)):
        raise SweepError(f"{name}={text}: range ends must be finite")
    return [repr(float(x)) for x in np.linspace(a, b, n)]


def parse_item(item: str) -> tuple[str, list[str]]:
    """`NAME=VALUES` → (name, value texts)."""
    name, sep, text = item.partition("=")
    name = name.strip()
    text = text.strip()
    if not sep or not name:
        raise SweepError(f"grid item {item!r} must be NAME=VALUES (e.g. mu=0.25,0.5 or swivel=-180:180:24)")
    if not text:
        raise SweepError(f"{name}= has no values")
    if ":" in text:
        return name, _linspace(name, text)
    values = [v.strip() for v in text.split(",")]
    if any(not v for v in values):
        raise SweepError(f"{name}={text}: empty value in the list")
    return name, values


def parse_grid(items: list[str]) -> list[tuple[str, list[str]]]:
    """All `--grid` items in order; a name given twice is an error."""
    if not items:
        raise SweepError("give at least one --grid NAME=VALUES")
    out: list[tuple[str, list[str]]] = []
    seen: set[str] = set()
    for item in items:
        name, values = parse_item(item)
        if name in seen:
            raise SweepError(f"{name} is given twice in --grid")
        seen.add(name)
        out.append((name, values))
    return out


def cells(axes: list[Axis], seeds: int) -> list[tuple[dict, int]]:
    """The Cartesian product of the axes (first axis slowest) × seeds 0 … seeds−1; SweepError beyond
    MAX_CELLS cells (counted before the list is built)."""
    check_size(axes, seeds)
    combos = itertools.product(*(a.values for a in axes))
    return [(dict(zip((a.name for a in axes), combo, strict=True)), seed) for combo in combos for seed in range(seeds)]


def check_size(axes: list[Axis], seeds: int) -> int:
    """The number of cells of a grid; SweepError (one line) when it exceeds MAX_CELLS."""
    n = math.prod(len(a) for a in axes) * max(int(seeds), 0)
    if n > MAX_CELLS:
        sizes = " × ".join(str(len(a)) for a in axes)
        raise SweepError(f"the grid has {n:,} cells ({sizes} × {seeds} seeds): at most {MAX_CELLS:,}")
    return n
