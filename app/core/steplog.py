"""A ring buffer of the last seconds of logged signals, one row per 1 kHz step.

The loop thread appends every `StepRecord`; plots read a decimated window and Record/Export reads
the last N seconds. Only the loop thread touches a `StepLog`; readers get copies.
Columns: t, q_1..n, dq_1..n, tau_1..n, F_x..M_z (sensor reading at the TCP), Fd_x..Md_z (desired
F^e), target_x_m..target_z_m (the task target's position), fallback, then every scalar signal the
executor and environment report, added as they appear (NaN before a signal first appears).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from app.core.session import StepRecord
from app.scenarios.metrics import MIN_SEGMENT_SAMPLES, Fold

WRENCH = ("x", "y", "z", "rx", "ry", "rz")


def base_columns(n_joints: int) -> list[str]:
    """Names of the fixed columns for an arm with `n_joints` joints."""
    cols = ["t"]
    cols += [f"q_{i + 1}" for i in range(n_joints)]
    cols += [f"dq_{i + 1}" for i in range(n_joints)]
    cols += [f"tau_{i + 1}" for i in range(n_joints)]
    cols += [f"F_{a}" for a in WRENCH]
    cols += [f"Fd_{a}" for a in WRENCH]
    cols += [f"target_{a}_m" for a in "xyz"]  # the task target's position (the replay's scene draws it)
    cols += ["fallback"]
    return cols


def largest_magnitude(rows: np.ndarray) -> np.ndarray:
    """Per row of `rows` (samples × the values each sample stands for), the value of largest magnitude,
    its sign kept; NaN only where a whole row is NaN (a scope's peak detect)."""
    magnitude = np.where(np.isnan(rows), -np.inf, np.abs(rows))
    return rows[np.arange(len(rows)), np.argmax(magnitude, axis=1)]


def session_log(session: Any, seconds: float) -> StepLog:
    """An empty log of `seconds` of `session`'s steps (a `Session`: its arm, control period and strokes)."""
    dt = float(session.world.model.opt.timestep)
    return StepLog(session.robot.nq, capacity=round(seconds / dt), segments=session.scenario.segments)


class StepLog:
    """Fixed-capacity ring buffer of step rows with growable signal columns."""

    def __init__(self, n_joints: int, capacity: int = 60_000, max_signals: int = 64, segments: int = 0):
        """A log of `capacity` rows for an arm of `n_joints`; `segments`: the strokes of the preset run
        (`Scenario.segments`, signal "segment"), over which `segment_force_error_std` folds the force error."""
        self.n = n_joints
        self.segments = int(segments)
        self.capacity = int(capacity)
        self.columns = base_columns(n_joints)
        self._n_base = len(self.columns)
        self._max_cols = self._n_base + max_signals
        self._data = np.full((self.capacity, self._max_cols), np.nan)
        self._signal_col: dict[str, int] = {}
        # the columns of the last step's signal names, in their order: a step that reports the same
        # names (every step but the first, in practice) writes its values with one indexed store
        self._last_keys: tuple[str, ...] = ()
        self._last_idx = np.zeros(0, dtype=np.intp)
        self.count = 0  # rows ever appended (the newest row is count - 1)
        n = n_joints
        self._sl_q = slice(1, 1 + n)
        self._sl_dq = slice(1 + n, 1 + 2 * n)
        self._sl_tau = slice(1 + 2 * n, 1 + 3 * n)
        self._sl_f = slice(1 + 3 * n, 7 + 3 * n)
        self._sl_fd = slice(7 + 3 * n, 13 + 3 * n)
        self._sl_target = slice(13 + 3 * n, 16 + 3 * n)
        self._i_fallback = 16 + 3 * n
        self._scanned = 0  # rows already folded into the extremes
        self._abs_tau_max = np.full(n, np.nan)
        self._q_max = np.full(n, np.nan)
        self._q_min = np.full(n, np.nan)
        self._seg_scanned = 0  # rows already folded into the per-segment force-error moments
        self._seg_moments = np.zeros((self.segments + 1, 3))  # per segment: count, mean, sum of squared deviations
        self._folds: dict[str, tuple[Fold, int]] = {}  # running metrics (`fold`) and the rows each has taken

    def clear(self) -> None:
        """Forget every row (columns are kept)."""
        self._data.fill(np.nan)
        self.count = 0
        self._scanned = 0
        self._abs_tau_max.fill(np.nan)
        self._q_max.fill(np.nan)
        self._q_min.fill(np.nan)
        self._seg_scanned = 0
        self._seg_moments.fill(0.0)
        self._folds.clear()

    def extremes(self) -> tuple[np.ndarray, np.ndarray]:
        """(max |τ_i|, max q_i) per joint over every row since the last clear — every 1 ms step, not a
        decimated window (NaN before the first row). Each call folds in only the rows appended since
        the previous one; rows overwritten before a call (more than `capacity` in between) are missed."""
        new = self.count - self._scanned
        if new > 0:
            rows = min(new, self.capacity)
            idx = np.arange(self.count - rows, self.count) % self.capacity
            block = self._data[idx]
            np.fmax(self._abs_tau_max, np.max(np.abs(block[:, self._sl_tau]), axis=0), out=self._abs_tau_max)
            np.fmax(self._q_max, np.max(block[:, self._sl_q], axis=0), out=self._q_max)
            np.fmin(self._q_min, np.min(block[:, self._sl_q], axis=0), out=self._q_min)
            self._scanned = self.count
        return self._abs_tau_max.copy(), self._q_max.copy()

    def fold(self, key: str, make: Callable[[], Fold | None]) -> Fold | None:
        """The running metric `key` over every row since the last clear (`app.scenarios.metrics`): made by
        `make()` at its first use, then fed the rows appended since its previous call — so it covers the
        whole run, not only the rows the ring still holds (rows overwritten before a call are missed, as in
        `extremes()`). None when `make` gives none; it waits while one of its columns was never logged."""
        entry = self._folds.get(key)
        if entry is None:
            fold = make()
            if fold is None:
                return None
            entry = (fold, 0)
        fold, taken = entry
        new = self.count - taken
        if new > 0:
            c = self.signal(fold.names, rows=new)
            if c is None:
                self._folds[key] = (fold, taken)
                return fold
            fold.add(c)
        self._folds[key] = (fold, self.count)
        return fold

    def q_min(self) -> np.ndarray:
        """min q_i per joint over the rows `extremes()` has folded in (NaN before the first)."""
        return self._q_min.copy()

    def append(self, rec: StepRecord) -> None:
        """Store one step (called by the loop thread after every step)."""
        row = self._data[self.count % self.capacity]
        row.fill(np.nan)
        row[0] = rec.t
        row[self._sl_q] = rec.q
        row[self._sl_dq] = rec.dq
        row[self._sl_tau] = rec.tau
        row[self._sl_f] = rec.wrench_tcp
        target = rec.target
        row[self._sl_fd] = target.wrench
        row[self._sl_target] = target.position
        row[self._i_fallback] = 1.0 if rec.fallback else 0.0
        signals = rec.signals
        keys = tuple(signals)
        if keys != self._last_keys:
            self._last_keys, self._last_idx = keys, self._signal_columns(keys)
        if len(self._last_idx) == len(keys):
            row[self._last_idx] = list(signals.values())
        else:  # more distinct signals than columns: the extra ones are not logged
            for key, value in signals.items():
                idx = self._signal_col.get(key)
                if idx is not None:
                    row[idx] = value
        self.count += 1

    def _signal_columns(self, keys: tuple[str, ...]) -> np.ndarray:
        """The columns of these signals (added as they first appear, while there is room)."""
        cols = []
        for key in keys:
            idx = self._signal_col.get(key)
            if idx is None:
                idx = self._add_signal(key)
            if idx is not None:
                cols.append(idx)
        return np.array(cols, dtype=np.intp)

    def segment_force_error_std(self) -> dict[int, float]:
        """STD (N) of the force error over each stroke S1…S`segments` (signal "segment") from every row
        since the last clear — the executor's own "force_error_n" when it reports one, else F̂_z − F_z.
        Incremental like `extremes()` (the running form of `metrics.segment_std`); a segment with fewer
        than MIN_SEGMENT_SAMPLES rows is left out."""
        new = self.count - self._seg_scanned
        seg_col = self._signal_col.get("segment")
        if new > 0 and seg_col is not None:
            rows = min(new, self.capacity)
            idx = np.arange(self.count - rows, self.count) % self.capacity
            block = self._data[idx]
            err_col = self._signal_col.get("force_error_n")
            err = block[:, err_col] if err_col is not None else np.full(rows, np.nan)
            fd_z, f_z = block[:, self._sl_fd.start + 2], block[:, self._sl_f.start + 2]
            err = np.where(np.isfinite(err), err, fd_z - f_z)
            seg = block[:, seg_col]
            for k in range(1, self.segments + 1):
                values = err[(seg == k) & np.isfinite(err)]
                if values.size:
                    self._merge_moments(k, values)
        if new > 0:
            self._seg_scanned = self.count
        m = self._seg_moments
        return {
            k: float(np.sqrt(m[k, 2] / m[k, 0])) for k in range(1, self.segments + 1) if m[k, 0] >= MIN_SEGMENT_SAMPLES
        }

    def _merge_moments(self, k: int, values: np.ndarray) -> None:
        """Fold a batch into segment k's (count, mean, M2) (Chan et al.'s parallel update)."""
        n_a, mean_a, m2_a = self._seg_moments[k]
        n_b, mean_b = float(values.size), float(values.mean())
        m2_b = float(((values - mean_b) ** 2).sum())
        n = n_a + n_b
        delta = mean_b - mean_a
        self._seg_moments[k] = (n, mean_a + delta * n_b / n, m2_a + m2_b + delta**2 * n_a * n_b / n)

    def _add_signal(self, key: str) -> int | None:
        idx = self._n_base + len(self._signal_col)
        if idx >= self._max_cols:
            return None  # too many distinct signals: the extra ones are not logged
        self._signal_col[key] = idx
        self.columns.append(key)
        return idx

    def signal(self, names: tuple[str, ...], rows: int | None = None) -> dict[str, np.ndarray] | None:
        """Every row since the last clear (as far as the capacity holds; the newest `rows` with it) of the
        columns `names` and "t"; None when one of them was never logged."""
        cols = [0]
        for name in names:
            idx = self._signal_col.get(name)
            if idx is None and name in self.columns[: self._n_base]:  # a fixed column (q_1, F_z, …)
                idx = self.columns.index(name)
            if idx is None:
                return None
            cols.append(idx)
        rows = min(self.count, self.capacity, self.count if rows is None else rows)
        idx_rows = np.arange(self.count - rows, self.count) % self.capacity
        block = self._data[np.ix_(idx_rows, np.array(cols, dtype=np.intp))]
        return {name: block[:, i] for i, name in enumerate(("t", *names))}

    def window(self, seconds: float, dt: float, every: int = 1, peaks: tuple[str, ...] = ()) -> dict[str, np.ndarray]:
        """The last `seconds` of rows by column, every `every`-th row on a grid fixed to the log's rows
        (row indices every−1, 2·every−1, …: the samples of a trace do not shift from one window to the
        next) and the newest row last. A column named in `peaks` keeps, at each sample, its value of
        largest magnitude over the rows the sample stands for (those after the previous sample, up to
        it: a scope's peak detect, so a decimated plot still reaches the peak a readout measures on
        every row)."""
        rows = min(self.count, self.capacity, max(1, round(seconds / dt)))
        if rows <= 0 or self.count == 0:
            return {c: np.zeros(0) for c in self.columns}
        newest = self.count - 1
        first = newest - rows + 1
        every = max(1, every)
        ends = np.arange(first + (every - 1 - first) % every, newest + 1, every)
        if len(ends) == 0 or ends[-1] != newest:
            ends = np.append(ends, newest)
        block = self._data[ends % self.capacity, : len(self.columns)]
        out = {c: block[:, i].copy() for i, c in enumerate(self.columns)}
        if every > 1 and peaks:
            starts = np.maximum(np.concatenate([[ends[0] - every + 1], ends[:-1] + 1]), first)
            span = np.minimum(starts[:, None] + np.arange(every)[None, :], ends[:, None]) % self.capacity
            for name in peaks:
                if name not in out:
                    continue
                out[name] = largest_magnitude(self._data[span, list(self.columns).index(name)])
        return out
