"""F/T sensor model at the flange ([T] §IV-A).

reading = LPF(true wrench + Gaussian noise + sinusoid), all in world axes at the sensor origin:
- zero-mean Gaussian noise on each force channel with variance `force_noise_var` (5 N²), and on
  each torque channel with `torque_noise_var` (default 0.05 (N m)², the force noise referred to
  the 0.1 m tool lever);
- a sinusoid of `sine_amplitude_n` (2 N) at `sine_hz` (1 Hz) on every force channel;
- a first-order low-pass of cutoff `cutoff_hz` (25 Hz), discretised exactly for a zero-order
  hold: y ← y + α (x − y), α = 1 − exp(−2π f_c Δt). cutoff_hz = 0 disables the filter;
- the reading's age `reading_delay_steps` (default 1 control period): the controller at step k
  gets the reading of step k − d. A sampled loop reads, computes, then writes, so a torque can
  answer a measurement one period after it was taken at the earliest; the external F/T sensor of
  [C] §V (EtherCAT to a PC, then to the controller) delivers each sample "within 1 ms", one period
  of the 1 kHz loop. 0 gives the ideal same-step reading (bit for bit the undelayed model).
The random generator is passed in (seeded by the caller), so runs reproduce exactly.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numba import njit

from control.params import ParamGroup, expect, param

MAX_READING_DELAY_STEPS = 20  # the longest F/T reading age the simulation accepts, control periods
DEFAULT_READING_DELAY_STEPS = 1  # one period: the reading of step k − 1 answers at step k (module doc)


class Sensor:
    """The scenario's sensor interface, and the ideal sensor: the true wrench at the sensor is what the
    controller reads. `FTSensor` implements it with noise and a filter."""

    def measure(self, true_wrench: np.ndarray, t: float) -> np.ndarray:
        """The reading for this step's true wrench [f; m] at time t (ideal: a copy of it)."""
        return np.array(true_wrench, dtype=float)

    def params(self) -> dict[str, ParamGroup]:
        """Its parameter groups by name; the ideal sensor has none."""
        return {}

    def set_params(self, name: str, group: Any) -> None:
        """Take a new validated group; ParamError for a group it lacks."""
        expect(name, group, None)

    def reset(self) -> None:
        """Clear filter states."""


@dataclass(frozen=True)
class SensorParams(ParamGroup):
    """The F/T sensor model's tunables ([T] §IV-A); `noise` off gives an ideal (filtered) reading."""

    title = "F/T sensor"

    noise: bool = param(
        True, label="Sensor noise", help="Gaussian noise + sinusoid on; off: ideal filtered reading", tag="[T] §IV-A"
    )
    force_noise_var: float = param(
        5.0, label="Force noise variance", unit="N²", lo=0.0, hi=50.0, step=0.5, help="per force channel"
    )
    torque_noise_var: float = param(
        0.05, label="Torque noise variance", unit="(N m)²", lo=0.0, hi=1.0, step=0.01, help="per torque channel"
    )
    sine_amplitude_n: float = param(
        2.0, label="Sinusoid amplitude", unit="N", lo=0.0, hi=10.0, step=0.5, help="on every force channel"
    )
    sine_hz: float = param(
        1.0, label="Sinusoid frequency", unit="Hz", lo=0.0, hi=50.0, step=0.5, help="of the sinusoid"
    )
    cutoff_hz: float = param(
        25.0, label="Low-pass cutoff", unit="Hz", lo=0.0, hi=500.0, step=1.0, help="first-order low-pass (0: no filter)"
    )
    reading_delay_steps: int = param(
        DEFAULT_READING_DELAY_STEPS,
        label="F/T reading age",
        unit="periods",
        lo=0,
        hi=MAX_READING_DELAY_STEPS,
        step=1,
        help="sensing delay: the controller gets the reading of this many 1 ms control periods ago. "
        "Default 1: a sampled loop reads, computes, then writes, so no torque answers a measurement "
        "in the period it is taken ([C] §V: the F/T sample reaches the controller within 1 ms); "
        "0 = the ideal same-step reading",
        tag="[T] §IV-B",
    )


class FTSensor(Sensor):
    """Noisy, filtered 6-axis force/torque sensor."""

    def __init__(
        self,
        rng: np.random.Generator,
        force_noise_var: float = 5.0,
        torque_noise_var: float = 0.05,
        sine_amplitude_n: float = 2.0,
        sine_hz: float = 1.0,
        cutoff_hz: float = 25.0,
        dt: float = 1e-3,
        noise: bool = True,
        reading_delay_steps: int = DEFAULT_READING_DELAY_STEPS,
    ):
        self.rng = rng
        self._noise = np.empty(6)  # this step's draws (read at once by `_reading`)
        self.dt = float(dt)
        self._ring: list[np.ndarray] = []  # the last d + 1 readings (a ring; `_delayed`)
        self._head = 0  # ring slot of the newest reading
        self.set_params(
            "sensor",
            SensorParams(
                noise=noise,
                force_noise_var=force_noise_var,
                torque_noise_var=torque_noise_var,
                sine_amplitude_n=sine_amplitude_n,
                sine_hz=sine_hz,
                cutoff_hz=cutoff_hz,
                reading_delay_steps=reading_delay_steps,
            ),
        )
        self.reset()

    def params(self) -> dict[str, ParamGroup]:
        """Its one group, "sensor"."""
        return {"sensor": self._params}

    def set_params(self, name: str, group: SensorParams) -> None:
        """New noise/filter/delay settings (validated by `SensorParams`); the filter state is kept, and
        a new delay keeps the newest readings it has (a longer one repeats the oldest at first)."""
        self._params = p = expect(name, group, SensorParams if name == "sensor" else None)
        on = 1.0 if p.noise else 0.0
        self.force_noise_var, self.torque_noise_var = on * p.force_noise_var, on * p.torque_noise_var
        self.sine_amplitude_n, self.sine_hz, self.cutoff_hz = on * p.sine_amplitude_n, p.sine_hz, p.cutoff_hz
        self._std = np.array([np.sqrt(self.force_noise_var)] * 3 + [np.sqrt(self.torque_noise_var)] * 3)
        self.alpha = 1.0 - np.exp(-2.0 * np.pi * self.cutoff_hz * self.dt) if self.cutoff_hz > 0 else 1.0
        self.reading_delay_steps = d = p.reading_delay_steps
        if d == 0:  # the line is bypassed; a later delay starts from the reading of its first step
            self._ring = []
        elif self._ring and len(self._ring) != d + 1:  # oldest → newest, then padded (or cut) at the old end
            n = len(self._ring)
            ordered = [self._ring[(self._head + 1 + i) % n] for i in range(n)][-(d + 1) :]
            self._ring = [ordered[0]] * (d + 1 - len(ordered)) + ordered
            self._head = d

    def reset(self) -> None:
        """Clear the filter state and the delay line (the first reading initialises both)."""
        self._y: np.ndarray | None = None
        self._ring = []
        self._head = 0

    def measure(self, true_wrench: np.ndarray, t: float) -> np.ndarray:
        """The filtered reading for this step's true wrench [f; m] at time t."""
        noise = self.rng.standard_normal(out=self._noise)  # the same draws as standard_normal(6)
        add_sine = self.sine_amplitude_n > 0
        sine = self.sine_amplitude_n * math.sin(2.0 * math.pi * self.sine_hz * t) if add_sine else 0.0
        if self._y is None:
            self._y = np.empty(6)
            reading = _reading(noise, self._std, true_wrench, add_sine, sine, False, self.alpha, self._y)
        else:
            reading = _reading(noise, self._std, true_wrench, add_sine, sine, True, self.alpha, self._y)
        return reading if self.reading_delay_steps == 0 else self._delayed(reading)

    def _delayed(self, reading: np.ndarray) -> np.ndarray:
        """The reading of d steps ago, keeping this one (d ≥ 1): a ring of d + 1 arrays that takes
        each new reading in place of the oldest, so nothing is allocated. Before d readings exist
        the first one is repeated (the wrench taken as constant before the run started). The array
        returned stays in the ring for d more steps: read it, do not change it."""
        ring = self._ring
        if not ring:
            ring.extend([reading] * (self.reading_delay_steps + 1))
            self._head = self.reading_delay_steps
            return reading
        n = len(ring)
        self._head = head = (self._head + 1) % n
        ring[head] = reading
        return ring[(head + 1) % n]  # the oldest: d steps before `head`


def reading_reference(noise, std, true_wrench, add_sine, sine, filtered, alpha, y) -> np.ndarray:
    """`_reading` in numpy: x = true + std·noise (+ the sinusoid on the three forces), y ← y + α(x − y)
    when `filtered` (else y ← x), in place; a copy of y."""
    x = noise * std + true_wrench
    if add_sine:
        x[:3] += sine
    y[:] = (x - y) * alpha + y if filtered else x
    return y.copy()


@njit(cache=True)
def _reading(noise, std, true_wrench, add_sine, sine, filtered, alpha, y):
    """One reading: x = true + std·noise (+ the sinusoid on the forces), then the first-order
    low-pass y ← y + α(x − y) when `filtered` (else y ← x); y is updated in place, a copy returned.
    The arithmetic of the numpy version, element by element ((x − y)·α + y), so bit for bit the same."""
    out = np.empty(6)
    for i in range(6):
        x = noise[i] * std[i] + true_wrench[i]
        if add_sine and i < 3:
            x += sine
        if filtered:
            x = (x - y[i]) * alpha + y[i]
        y[i] = x
        out[i] = x
    return out
