"""One definition per metric the lab shows: the page's readouts, the lessons' claims, the plots' markers
and the experiments' reports all compute them here.

- deflection: the distance (mm) of the TCP and of the elbow (the body carrying joint 4) from where they
  stood at the reset (`DeflectionProbe`);
- peak: the largest value inside a stated window (`WindowPeaks`: a push's window is the push and the
  `PUSH_AFTER_S` after it, where the arm's answer to it peaks);
- after a release (`DropFold`): the peak deflection since the release; the settle time, from the release
  to the last return inside `STABLE_BAND_M` (the last sample's time if it is outside); the residual, the
  mean deflection over the last `RESIDUAL_WINDOW_S`;
- per-segment STD: the population standard deviation of the force error over each polish segment, from
  `MIN_SEGMENT_SAMPLES` samples (`segment_std`; `app.core.steplog` keeps the same figure running);
- reversals: sign changes of a joint velocity outside a `REVERSAL_HYSTERESIS_RAD_S` band
  (`velocity_reversals`);
- contact lost: the true normal contact force at or below zero while the strokes run (`contact_lost`),
  counted from each step it drops there (`contact_loss_onsets`); the approach before the strokes, where
  the tool lands and may bounce, is not watched.

The running forms (`DropFold`, `WindowPeaks`) take a run's samples in blocks as they are logged, so a
figure "since the reset" covers the whole run however long it is; fed a whole run at once they give
the experiments' numbers.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Protocol

import numpy as np

PUSH_AFTER_S = 0.5  # a push's peak is taken over the push and this long after it
STABLE_BAND_M = 1e-3  # settled: the TCP back within 1 mm of where it stood
RESIDUAL_WINDOW_S = 0.5  # the residual error is the mean deflection over the last 0.5 s
MIN_SEGMENT_SAMPLES = 5  # a segment's STD needs at least this many samples
REVERSAL_HYSTERESIS_RAD_S = 0.02  # velocity reversals smaller than this are not counted
ELBOW_JOINT = 3  # 0-based: the body carrying joint 4 is the elbow of a 7-DOF arm


class Fold(Protocol):
    """A metric kept running over a run's samples: `names` are the logged columns it reads ("t" comes
    with them), `add` takes the next block of rows, `value` gives the figures so far."""

    names: tuple[str, ...]

    def add(self, columns: Mapping[str, np.ndarray]) -> None: ...

    def value(self) -> dict[str, float]: ...


# ---- deflection ------------------------------------------------------------------------------------
class DeflectionProbe:
    """The TCP's and the elbow's distance (mm) from where they stood when the probe was made (the reset),
    in the world frame. `session` has `dyn`, `world` and `robot` (a `Session`)."""

    def __init__(self, session: Any):
        model = session.world.model
        self.elbow_body = int(model.jnt_bodyid[model.joint(session.robot.joint_names[ELBOW_JOINT]).id])
        self.tcp0 = np.array(session.dyn.tcp_position_world, dtype=float)
        self.elbow0 = session.world.data.xpos[self.elbow_body].copy()

    def read(self, session: Any) -> tuple[float, float]:
        """(TCP, elbow) deflection in mm at the session's current state."""
        tcp = 1e3 * float(np.linalg.norm(session.dyn.tcp_position_world - self.tcp0))
        elbow = 1e3 * float(np.linalg.norm(session.world.data.xpos[self.elbow_body] - self.elbow0))
        return tcp, elbow


# ---- peaks in windows --------------------------------------------------------------------------------
class WindowPeaks:
    """The largest value of each signal in `names` inside each named window [t0, t1) (s since the reset):
    key "{window}_{signal}" with the signal's "_dev_mm" written "_mm" ("elbow_push_elbow_mm"). A window
    appears once it has a sample."""

    def __init__(self, windows: Mapping[str, tuple[float, float]], names: tuple[str, ...]):
        self.windows = dict(windows)
        self.names = names
        self._peaks: dict[str, float] = {}

    @staticmethod
    def key(window: str, name: str) -> str:
        return f"{window}_{name.replace('_dev_mm', '_mm')}"

    def add(self, columns: Mapping[str, np.ndarray]) -> None:
        t = columns["t"]
        for window, (t0, t1) in self.windows.items():
            inside = (t >= t0 - 1e-9) & (t < t1 - 1e-9)
            if not np.any(inside):
                continue
            for name in self.names:
                values = columns[name][inside]
                values = values[np.isfinite(values)]
                if values.size:
                    key = self.key(window, name)
                    self._peaks[key] = max(self._peaks.get(key, -np.inf), float(values.max()))

    def value(self) -> dict[str, float]:
        return dict(self._peaks)


def push_windows(pushes: tuple[tuple[str, float, float], ...]) -> dict[str, tuple[float, float]]:
    """(where, start, end) pushes → "{where}_push": (start, end + PUSH_AFTER_S)."""
    return {f"{where}_push": (start, end + PUSH_AFTER_S) for where, start, end in pushes}


# ---- after a release -------------------------------------------------------------------------------
class DropFold:
    """Peak deflection, settle time and residual error of signal `name` (mm) after `release_s` (see the
    module docstring): "peak_deflection_mm", "stabilization_time_s", "residual_error_mm"; nothing
    before the release."""

    def __init__(self, release_s: float, name: str = "tcp_dev_mm"):
        self.release_s = release_s
        self.names: tuple[str, ...] = (name,)
        self._peak = -np.inf
        self._settle = 0.0  # s after the release
        self._outside = False  # the last sample was outside the band
        self._t_last = np.nan
        self._tail_t = np.zeros(0)
        self._tail_d = np.zeros(0)

    def add(self, columns: Mapping[str, np.ndarray]) -> None:
        t, d = columns["t"], columns[self.names[0]]
        after = (t >= self.release_s - 1e-9) & np.isfinite(d)
        if not np.any(after):
            return
        ta, da = t[after] - self.release_s, d[after]
        self._peak = max(self._peak, float(da.max()))
        outside = np.flatnonzero(da > 1e3 * STABLE_BAND_M)
        if outside.size:
            last = outside[-1]
            self._outside = last + 1 >= ta.size
            if not self._outside:
                self._settle = float(ta[last + 1])
        elif self._outside:  # the first sample of this block is the first one back inside
            self._settle = float(ta[0])
            self._outside = False
        self._t_last = float(ta[-1])
        tail_t, tail_d = np.concatenate([self._tail_t, ta]), np.concatenate([self._tail_d, da])
        keep = tail_t >= self._t_last - RESIDUAL_WINDOW_S
        self._tail_t, self._tail_d = tail_t[keep], tail_d[keep]

    def value(self) -> dict[str, float]:
        if not np.isfinite(self._peak):
            return {}
        return {
            "peak_deflection_mm": self._peak,
            "stabilization_time_s": self._t_last if self._outside else self._settle,
            "residual_error_mm": float(np.mean(self._tail_d)),
        }


def run_fold(fold: Fold, columns: Mapping[str, np.ndarray]) -> dict[str, float]:
    """A fold over a whole run's columns at once (the experiments' use)."""
    fold.add(columns)
    return fold.value()


# ---- per-segment STD and reversals ---------------------------------------------------------------------
def force_error_std(values: np.ndarray) -> float:
    """Population STD (N) of a stroke's force error over its finite samples (NaN without one)."""
    finite = np.asarray(values, dtype=float)
    finite = finite[np.isfinite(finite)]
    return float(np.std(finite)) if finite.size else float("nan")


def segment_std(segment: np.ndarray, error: np.ndarray, segments: range = range(1, 7)) -> dict[int, float]:
    """`force_error_std` of `error` over each segment k (samples where `segment` == k), for the segments
    with at least MIN_SEGMENT_SAMPLES finite samples."""
    out: dict[int, float] = {}
    for k in segments:
        values = error[segment == k]
        if np.count_nonzero(np.isfinite(values)) >= MIN_SEGMENT_SAMPLES:
            out[k] = force_error_std(values)
    return out


def velocity_reversals(dq: np.ndarray, hysteresis: float = REVERSAL_HYSTERESIS_RAD_S) -> int:
    """Sign changes of a joint velocity with a hysteresis band: a reversal counts once the velocity is
    beyond ±`hysteresis` rad/s the other way; 0 for a fall that stops without rebounding."""
    sign = 0
    reversals = 0
    for v in dq:
        if v > hysteresis and sign <= 0:
            reversals += sign < 0
            sign = 1
        elif v < -hysteresis and sign >= 0:
            reversals += sign > 0
            sign = -1
    return int(reversals)


# ---- contact ----------------------------------------------------------------------------------------
def contact_watched(segment: float) -> bool:
    """True while the strokes run (polish signal "segment" 1…N, or after them): contact is expected."""
    return bool(segment >= 1.0)


def contact_lost(contact_force_n: np.ndarray, segment: np.ndarray) -> np.ndarray:
    """Per sample: the true normal contact force (N) is at or below zero while contact is watched
    (`contact_watched`; the experiments' "contact lost" steps)."""
    force = np.asarray(contact_force_n, dtype=float)
    watched = np.asarray(segment, dtype=float) >= 1.0
    return watched & (force <= 0.0)


def contact_loss_onsets(contact_force_n: np.ndarray, segment: np.ndarray) -> np.ndarray:
    """Indices of the samples where contact is lost (`contact_lost`) and was not at the sample before."""
    lost = contact_lost(contact_force_n, segment)
    if lost.size == 0:
        return np.zeros(0, dtype=np.intp)
    before = np.concatenate([[False], lost[:-1]])
    return np.flatnonzero(lost & ~before)
