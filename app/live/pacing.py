"""Pacing simulated time to wall time, and measuring how well that works.

`Pacer` says how many 1 ms steps are due at a wall-clock instant: the step count is anchored to a
wall instant, so sleeping too long (or a hiccup: garbage collection, another process) is caught up
in bursts and nothing drifts. If the loop falls further behind than `max_lag_s`, the extra debt is
dropped (the anchor moves) and the simulation runs slower than requested; `RateMeter` reports the
real-time factor that was actually achieved.
"""

from __future__ import annotations

import math


class Pacer:
    """Steps due at wall time `now` for a simulation with period `dt` run at `speed`× real time.

    A debt of up to `max_lag_s` is caught up (in bursts of at most `max_burst` steps per call, so
    the caller can apply commands and publish between bursts); beyond it, the extra steps are
    dropped and the simulation runs slower than requested.
    """

    def __init__(self, dt: float = 1e-3, speed: float = 1.0, max_lag_s: float = 0.25, max_burst: int = 50):
        if not (dt > 0 and speed > 0 and max_lag_s > 0 and max_burst >= 1):
            raise ValueError("dt, speed, max_lag_s and max_burst must be positive")
        self.dt = dt
        self.speed = speed
        self.max_lag_steps = max(1, round(max_lag_s / dt))
        self.max_burst = int(max_burst)
        self._anchor_wall = 0.0
        self._anchor_steps = 0
        self.dropped_steps = 0  # steps given up because the loop could not keep up

    def restart(self, now: float, steps_done: int) -> None:
        """Anchor: step `steps_done` happens at wall time `now` (after a pause, switch or speed change)."""
        self._anchor_wall = now
        self._anchor_steps = steps_done

    def set_speed(self, speed: float, now: float, steps_done: int) -> None:
        """Change the requested speed from now on."""
        if not (math.isfinite(speed) and speed > 0):
            raise ValueError(f"speed must be positive, got {speed!r}")
        self.speed = speed
        self.restart(now, steps_done)

    def due(self, now: float, steps_done: int) -> int:
        """How many steps to run now (≤ max_burst); a debt beyond max_lag_steps is dropped."""
        target = self._anchor_steps + math.floor((now - self._anchor_wall) * self.speed / self.dt + 1e-9)
        behind = target - steps_done
        if behind > self.max_lag_steps:
            dropped = behind - self.max_lag_steps
            self.dropped_steps += dropped
            self._anchor_steps -= dropped
            behind = self.max_lag_steps
        return max(0, min(behind, self.max_burst))

    def next_due(self, steps_done: int) -> float:
        """Wall time at which step `steps_done + 1` is due."""
        return self._anchor_wall + (steps_done + 1 - self._anchor_steps) * self.dt / self.speed


class RateMeter:
    """Real-time factor (simulated seconds per wall second) over windows of `window_s` wall seconds."""

    def __init__(self, window_s: float = 0.5):
        self.window_s = window_s
        self._wall0: float | None = None
        self._sim0 = 0.0
        self._busy = 0.0
        self.rtf = 0.0
        self.load = 0.0  # fraction of wall time spent computing steps

    def restart(self) -> None:
        """Start a new window at the next sample (after a pause or a switch)."""
        self._wall0 = None
        self._busy = 0.0

    def add_busy(self, seconds: float) -> None:
        """Account compute time spent in steps."""
        self._busy += seconds

    def sample(self, now: float, sim_time: float) -> bool:
        """Feed the clocks; returns True when a new `rtf` value was computed."""
        if self._wall0 is None:
            self._wall0, self._sim0, self._busy = now, sim_time, 0.0
            return False
        elapsed = now - self._wall0
        if elapsed < self.window_s:
            return False
        self.rtf = (sim_time - self._sim0) / elapsed
        self.load = self._busy / elapsed
        self._wall0, self._sim0, self._busy = now, sim_time, 0.0
        return True


def next_frame_due(due: float, now: float, period: float) -> float:
    """When the frame after the one due at `due` (sent at `now` ≥ due) is due: one `period` after
    `due`, so a late wake-up does not stretch the period and frames keep their rate on average; after
    a stall longer than a period, one period from `now` (missed frames are not sent in a burst)."""
    following = due + period
    return following if following > now else now + period
