"""The stability map's tolerated latency along the self-motion loop, for the preview's colours.

`torquelab sweep polish-map` writes `stability_map.json` (docs/map.md): per friction μ and held swivel,
the total latency (F/T reading + drive, control periods) the held posture tolerates by the one verdict.
The page reads the copy kept in the package (`MAP_PATH`, written from the map's run) and the
self-motion preview colours the loop with it at the session's current μ (`SelfMotionPreview`). The
swivels are the held postures' at the polish start pose, so the colours are the map's, read at the
swivel angle of each posture of the loop now.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

import static

MAP_PATH = Path(static.__file__).parent / "stability_map.json"
FORMAT = "torquelab stability map 1"
LEVELS = (-1, 0, 1, 2, 3, 4)  # tolerated total latency in periods; -1: not even without latency
LEVEL_COLOURS = ("#b71c1c", "#e65100", "#f9a825", "#c0ca33", "#7cb342", "#1b5e20")


def level_label(level: int) -> str:
    """The legend's words for a tolerated latency."""
    if level < 0:
        return "map: unstable without latency"
    return f"map: tolerates {level} period{'s' if level != 1 else ''}" + (" or more" if level == LEVELS[-1] else "")


@dataclass(frozen=True)
class LatencyMap:
    """Per μ, the held swivels (deg) and the total latency each tolerates (NaN: unknown)."""

    robot: str | None
    mu: tuple[float, ...]
    swivel_deg: tuple[np.ndarray, ...]
    tolerated: tuple[np.ndarray, ...]

    def at(self, mu: float, swivel_deg: np.ndarray) -> np.ndarray:
        """The tolerated latency (periods, NaN where the map has no cell) at each swivel, at the map's μ
        nearest `mu`, from the map's swivel nearest each one (within half its spacing, around the loop)."""
        psi = np.asarray(swivel_deg, dtype=float)
        if not self.mu:
            return np.full(psi.shape, np.nan)
        row = int(np.argmin(np.abs(np.asarray(self.mu) - float(mu))))
        grid, values = self.swivel_deg[row], self.tolerated[row]
        if grid.size == 0:
            return np.full(psi.shape, np.nan)
        gap = np.abs((psi[:, None] - grid[None, :] + 180.0) % 360.0 - 180.0)
        nearest = np.argmin(gap, axis=1)
        spacing = float(np.min(np.diff(np.sort(grid)))) if grid.size > 1 else 360.0
        out = values[nearest].astype(float)
        out[gap[np.arange(psi.size), nearest] > spacing / 2 + 1e-9] = np.nan
        return out


def load(path: Path = MAP_PATH) -> LatencyMap | None:
    """The map in `path`, or None when there is none (or it is not a stability map)."""
    try:
        doc = json.loads(Path(path).read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        return None
    rows = sorted(doc.get("tolerated", []), key=lambda r: float(r["mu"]))
    return LatencyMap(
        doc.get("robot"),
        tuple(float(r["mu"]) for r in rows),
        tuple(np.asarray(r["swivel_deg"], dtype=float) for r in rows),
        tuple(np.array([np.nan if v is None else float(v) for v in r["tolerated_periods"]]) for r in rows),
    )


def level_series(W: np.ndarray, tolerated: np.ndarray) -> list[np.ndarray]:
    """One series per `LEVELS` entry: W where the posture tolerates that latency (the last level: that
    or more), NaN elsewhere."""
    W = np.asarray(W, dtype=float)
    tol = np.asarray(tolerated, dtype=float)
    capped = np.where(np.isfinite(tol), np.minimum(tol, LEVELS[-1]), np.nan)
    return [np.where(capped == level, W, np.nan) for level in LEVELS]
