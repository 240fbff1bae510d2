"""F/T sensor model at the flange ([T] §IV-A).

reading = LPF(true wrench + Gaussian noise + sinusoid), all in world axes at the sensor origin:
- zero-mean Gaussian noise on each force channel with variance `force_noise_var` (5 N²), and on
  each torque channel with `torque_noise_var` (default 0.05 (N m)², the force noise referred to
  the 0.1 m tool lever);
- a sinusoid of `sine_amplitude_n` (2 N) at `sine_hz` (1 Hz) on every force channel;
- a first-order low-pass of cutoff `cutoff_hz` (25 Hz), discretised exactly for a zero-order
  hold: y ← y + α (x − y), α = 1 − exp(−2π f_c Δt). cutoff_hz = 0 disables the filter.
The random generator is passed in (seeded by the caller), so runs reproduce exactly.
"""

from __future__ import annotations

import numpy as np


class FTSensor:
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
    ):
        self.rng = rng
        self.dt = float(dt)
        self.force_noise_var = 0.0
        self.torque_noise_var = 0.0
        self.sine_amplitude_n = 0.0
        self.sine_hz = 0.0
        self.cutoff_hz = 0.0
        self.configure(
            force_noise_var=force_noise_var,
            torque_noise_var=torque_noise_var,
            sine_amplitude_n=sine_amplitude_n,
            sine_hz=sine_hz,
            cutoff_hz=cutoff_hz,
        )
        self.reset()

    def configure(self, **changes: object) -> None:
        """Change noise/filter settings; ValueError on negative or non-finite values."""
        for key, value in changes.items():
            if key not in ("force_noise_var", "torque_noise_var", "sine_amplitude_n", "sine_hz", "cutoff_hz"):
                raise ValueError(f"F/T sensor has no setting {key!r}")
            x = float(value)  # type: ignore[arg-type]
            if not np.isfinite(x) or x < 0:
                raise ValueError(f"F/T sensor {key} must be a finite non-negative number, got {value!r}")
            setattr(self, key, x)
        self._std = np.array([np.sqrt(self.force_noise_var)] * 3 + [np.sqrt(self.torque_noise_var)] * 3)
        self.alpha = 1.0 - np.exp(-2.0 * np.pi * self.cutoff_hz * self.dt) if self.cutoff_hz > 0 else 1.0

    def reset(self) -> None:
        """Clear the filter state (the first reading initialises it)."""
        self._y: np.ndarray | None = None

    def measure(self, true_wrench: np.ndarray, t: float) -> np.ndarray:
        """The filtered reading for this step's true wrench [f; m] at time t."""
        x = self.rng.standard_normal(6)  # the same arithmetic as true + std·noise, y + α(x − y), in place
        x *= self._std
        x += true_wrench
        if self.sine_amplitude_n > 0:
            x[:3] += self.sine_amplitude_n * np.sin(2.0 * np.pi * self.sine_hz * t)
        if self._y is not None:
            x -= self._y
            x *= self.alpha
            x += self._y
        self._y = x
        return x.copy()
