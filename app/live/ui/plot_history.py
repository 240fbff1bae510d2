"""What the charts draw from: the last 60 s of plot samples (`SignalHistory`), the phase changes in them
(`phase_markers`: a preset's strokes and the marks it declares, `Scenario.phase_marks`) and the figures
taken over them (force error per stroke)."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from app.scenarios import PhaseMark, metrics

HISTORY_S = 60.0


class SignalHistory:
    """The last `seconds` of plot samples, by column, grown from overlapping `PlotData` windows.

    Rows newer than the newest kept one are appended; a window that ends earlier than the history
    (a reset, a new session) starts the history again."""

    def __init__(self, seconds: float = HISTORY_S):
        self.seconds = seconds
        self.columns: dict[str, np.ndarray] = {}

    @property
    def t(self) -> np.ndarray:
        return self.columns.get("t", np.zeros(0))

    def clear(self) -> None:
        """Forget every sample."""
        self.columns = {}

    def add(self, columns: dict[str, np.ndarray]) -> None:
        """Take in a window of samples (column "t" increasing)."""
        t = columns.get("t")
        if t is None or len(t) == 0:
            return
        old = self.t
        if len(old) and t[-1] < old[-1] - 1e-9:
            self.clear()
            old = self.t
        new = t > old[-1] + 1e-9 if len(old) else np.ones(len(t), dtype=bool)
        if not np.any(new):
            return
        n_old = len(old)
        merged: dict[str, np.ndarray] = {}
        for key in set(self.columns) | set(columns):
            before = self.columns.get(key, np.full(n_old, np.nan))
            after = columns[key][new] if key in columns else np.full(int(new.sum()), np.nan)
            merged[key] = np.concatenate([before, after])
        keep = merged["t"] >= merged["t"][-1] - self.seconds
        self.columns = {k: v[keep] for k, v in merged.items()}

    def window(self, seconds: float) -> dict[str, np.ndarray]:
        """The samples of the last `seconds` (views)."""
        t = self.t
        if len(t) == 0:
            return {}
        start = int(np.searchsorted(t, t[-1] - seconds))
        return {k: v[start:] for k, v in self.columns.items()}

    def shown(self, seconds: float, replay_t: float | None) -> dict[str, np.ndarray]:
        """The window a chart shows: the last `seconds` up to now, or while replaying up to `replay_t`
        (read once per redraw by the caller: Replay may clear it from another thread meanwhile)."""
        if replay_t is None:
            return self.window(seconds)
        t = self.t
        end = int(np.searchsorted(t, replay_t, side="right"))
        start = int(np.searchsorted(t, replay_t - seconds))
        return {k: v[start:end] for k, v in self.columns.items()}


@dataclass(frozen=True)
class Marker:
    """A phase change worth a vertical line: simulated time and a short name."""

    t: float
    label: str


def phase_markers(columns: dict[str, np.ndarray], segments: int, marks: Iterable[PhaseMark] = ()) -> list[Marker]:
    """Where the scenario's phase changes in these samples: the strokes S1…S`segments` of a preset
    that has them (`Scenario.segments`, signal "segment") and their end, and each of the preset's
    `marks` (`Scenario.phase_marks`) where its signal crosses 0.5 upward (or downward)."""
    t = columns.get("t", np.zeros(0))
    out: list[Marker] = []
    seg = columns.get("segment")
    if seg is not None and len(seg) == len(t):
        idx = np.flatnonzero(np.diff(np.nan_to_num(seg, nan=-1.0)) != 0) + 1
        for i in idx:
            k = seg[i]
            if np.isfinite(k) and 1 <= k <= segments:
                out.append(Marker(float(t[i]), f"S{int(k)}"))
            elif np.isfinite(k) and k > segments:
                out.append(Marker(float(t[i]), "end"))
    for mark in marks:
        values = columns.get(mark.signal)
        if values is None or len(values) != len(t):
            continue
        v = np.nan_to_num(values, nan=0.0 if mark.rising else 1.0)
        crossed = (v[:-1] < 0.5) & (v[1:] > 0.5) if mark.rising else (v[:-1] > 0.5) & (v[1:] < 0.5)
        out.extend(Marker(float(t[i]), mark.label) for i in np.flatnonzero(crossed) + 1)
    return sorted(out, key=lambda m: m.t)


def segment_std(columns: dict[str, np.ndarray], key: str, segments: int) -> dict[int, float]:
    """STD of column `key` over each stroke 1…`segments` present (segment index → N; `metrics.segment_std`)."""
    seg, values = columns.get("segment"), columns.get(key)
    if seg is None or values is None:
        return {}
    return metrics.segment_std(seg, values, range(1, segments + 1))


def force_error(columns: dict[str, np.ndarray]) -> np.ndarray:
    """F̂_z − F_z: the executor's own force error if it reports one, else from the logged wrenches."""
    err = columns.get("force_error_n")
    if err is None or not np.any(np.isfinite(err)):
        err = columns["Fd_z"] - columns["F_z"]
    return err


def previous_at(previous: dict[str, np.ndarray] | None, key: str, t: np.ndarray) -> np.ndarray:
    """The previous run's signal `key` at the simulated times t (NaN where it has none)."""
    if previous is None or key not in previous or "t" not in previous or not len(t):
        return np.full(len(t), np.nan)
    pt, pv = previous["t"], previous[key]
    ok = np.isfinite(pv)
    if np.count_nonzero(ok) < 2:
        return np.full(len(t), np.nan)
    out = np.interp(t, pt[ok], pv[ok])
    out[(t < pt[ok][0]) | (t > pt[ok][-1])] = np.nan
    return out
