"""External joint-torque estimation [C25–26]: momentum observer, F/T mapping, complementary fusion.

- Momentum observer [C25]: r = K_I [p − ∫(τ + Cᵀq̇ − g + r) ds − p(0)], p = M q̇, i.e.
  ṙ = K_I (τ_e − r). Discretised exactly (zero-order hold of τ_e over each control period):
  r_k = a r_{k−1} + (1 − a) Δ_k/δt, a = exp(−K_I δt), with Δ_k = ∫τ_e over the period
  = p_k − p_{k−1} − ∫(τ + Cᵀq̇ − g). Since Cᵀq̇ = Ṁq̇ − Cq̇ ([C1]: Ṁ = C + Cᵀ),
  ∫(τ + Cᵀq̇ − g) = ∫(τ − h) + ∫Ṁq̇, and ∫Ṁq̇ over one period is (M_k − M_{k−1}) q̇_k; so
  Δ_k = M_{k−1}(q̇_k − q̇_{k−1}) − (τ_{k−1} − h_{k−1}) δt. No Coriolis matrix is needed.
- F/T mapping: τ_s = J_sᵀ F_s (a wrench moved to the TCP gives the same τ_s with the TCP Jacobian).
- Fusion [C26]: τ̂_e = r + s/(K_I + s) τ_s: the sensor's high-pass part fills in what the observer,
  a first-order low-pass of τ_e with the same pole, has not caught up with yet.
- Sources: none, residual, fusion, oracle (simulation truth: labelled as such in every output).
"""

from __future__ import annotations

import math

import numpy as np

from control.gains import EstimatorGains
from control.kernels.cqp import estimator_record_dtype
from control.kernels.estimation import momentum_observer_fused, sensor_high_pass_fused
from control.kernels.records import fill_record
from control.model import Dynamics


class MomentumObserver:
    """Generalised-momentum residual [C25] with exact discrete integration."""

    def __init__(self, n: int, gain: float, dt: float):
        if not gain > 0 or not dt > 0:
            raise ValueError(f"observer gain and dt must be positive, got {gain!r}, {dt!r}")
        self.n = n
        self.gain = float(gain)
        self.dt = float(dt)
        self.a = math.exp(-self.gain * self.dt)
        self.r = np.zeros(n)
        self._M_prev: np.ndarray | None = None
        self._dq_prev = np.zeros(n)
        self._h_prev = np.zeros(n)

    def reset(self, dyn: Dynamics | None = None) -> None:
        """r = 0 and p(0) taken at the given state (or at the next update)."""
        self.r = np.zeros(self.n)
        if dyn is None:
            self._M_prev = None
        else:
            self._store(dyn)

    def _store(self, dyn: Dynamics) -> None:
        self._M_prev = dyn.M
        self._dq_prev = dyn.dq
        self._h_prev = dyn.h

    @property
    def previous(self) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """(M, q̇, h) of the last stored state, what the next step integrates from; None before the
        first update (then the next update only stores)."""
        return None if self._M_prev is None else (self._M_prev, self._dq_prev, self._h_prev)

    def take_step(self, dyn: Dynamics, r: np.ndarray) -> None:
        """Take the residual r that a compiled step computed from `previous` and `dyn` (as `update`
        would), and store `dyn` for the next step."""
        self.r = r
        self._store(dyn)

    def continue_from(self, other: MomentumObserver) -> None:
        """Carry another observer's residual and stored state over (a new gain keeps running)."""
        self.r = other.r.copy()
        previous = other.previous
        if previous is None:
            self._M_prev = None
        else:
            self._M_prev, self._dq_prev, self._h_prev = previous

    def update(self, dyn: Dynamics, tau_prev: np.ndarray) -> np.ndarray:
        """`update_reference` in one compiled call (`control.kernels.estimation.momentum_observer_fused`)."""
        if self._M_prev is None:
            self._store(dyn)
            return self.r
        tau_prev = np.asarray(tau_prev, dtype=float)
        M_prev, dq_prev, h_prev = self._M_prev, self._dq_prev, self._h_prev
        self.r = momentum_observer_fused(M_prev, dyn.dq, dq_prev, tau_prev, h_prev, self.dt, self.a, self.r)
        self._store(dyn)
        return self.r

    def update_reference(self, dyn: Dynamics, tau_prev: np.ndarray) -> np.ndarray:
        """Advance to the state in `dyn`, given the torque applied over the last period; return r."""
        if self._M_prev is None:
            self._store(dyn)
            return self.r
        # Δ = ∫τ_e over the last period (see module docstring)
        delta = self._M_prev @ (dyn.dq - self._dq_prev) - (tau_prev - self._h_prev) * self.dt
        self.r = self.a * self.r + (1.0 - self.a) * (delta / self.dt)  # [C25], exact ZOH solution
        self._store(dyn)
        return self.r


class HighPass:
    """s/(K + s) per channel, discretised as x − LP(x) with the same exact pole as the observer."""

    def __init__(self, n: int, gain: float, dt: float):
        self.a = math.exp(-float(gain) * float(dt))
        self.lp: np.ndarray | None = None
        self.n = n

    def reset(self) -> None:
        """Forget the state (the next input starts the low-pass at that value)."""
        self.lp = None

    def update(self, x: np.ndarray) -> np.ndarray:
        """Filter one sample."""
        if self.lp is None:  # start in steady state: a constant reading has no high-pass part
            self.lp = np.array(x, dtype=float)
        else:
            self.lp = self.a * self.lp + (1.0 - self.a) * x
        return x - self.lp


def sensor_joint_torque(J_sensor: np.ndarray, wrench: np.ndarray) -> np.ndarray:
    """τ_s = J_sᵀ F_s: joint torque of a wrench [f; m] (world axes) read at the frame of J_sensor."""
    return J_sensor.T @ wrench


class ExternalTorqueEstimator:
    """τ̂_e from the selected source: none, residual [C25], fusion [C26] or oracle (sim truth)."""

    def __init__(self, n: int, gains: EstimatorGains | None = None, dt: float = 1e-3):
        self.n = n
        self.dt = float(dt)
        self.gains = gains or EstimatorGains()
        self._build()

    def _build(self) -> None:
        self.observer = MomentumObserver(self.n, self.gains.observer_gain, self.dt)
        self.high_pass = HighPass(self.n, self.gains.observer_gain, self.dt)
        self.tau_s = np.zeros(self.n)
        self.estimate = np.zeros(self.n)
        # the [C] executor's fused step's record (`kernels.cqp.estimator_record_dtype`): K_I by name, the
        # pole a, δt, the source code (−1: the oracle, not computed there)
        self.source_code = {"none": 0.0, "residual": 1.0, "fusion": 2.0}.get(self.gains.source, -1.0)
        self.kernel_record = fill_record(
            estimator_record_dtype(), (self.gains,), a=self.observer.a, dt=self.dt, source_code=self.source_code
        )

    def configure(self, gains: EstimatorGains) -> None:
        """New source or K_I; the observer keeps running from its current residual."""
        old = self.observer
        self.gains = gains
        self._build()
        self.observer.continue_from(old)

    def reset(self, dyn: Dynamics | None = None) -> None:
        """Clear observer and filter states."""
        self.observer.reset(dyn)
        self.high_pass.reset()
        self.estimate = np.zeros(self.n)

    @property
    def is_oracle(self) -> bool:
        """True when the estimate is simulation truth, not an estimate."""
        return self.gains.source == "oracle"

    def update(
        self,
        dyn: Dynamics,
        tau_prev: np.ndarray,
        wrench_tcp: np.ndarray | None = None,
        tau_oracle: np.ndarray | None = None,
    ) -> np.ndarray:
        """One estimation step; the observer always runs so switching sources is bumpless."""
        r = self.observer.update(dyn, tau_prev)
        source = self.gains.source
        high_pass = self.high_pass
        if wrench_tcp is not None and high_pass.lp is not None:  # τ_s = J_sᵀ F_s (wrench at the TCP), high-passed
            wrench = np.asarray(wrench_tcp, dtype=float)
            self.tau_s, hp = sensor_high_pass_fused(dyn.J, wrench, high_pass.lp, high_pass.a)
        else:
            if wrench_tcp is not None:
                self.tau_s = sensor_joint_torque(dyn.J, wrench_tcp)
            hp = high_pass.update(self.tau_s)
        if source == "residual":
            self.estimate = r.copy()
        elif source == "fusion":
            self.estimate = r + hp  # [C26]
        elif source == "oracle":
            self.estimate = np.zeros(self.n) if tau_oracle is None else np.array(tau_oracle, dtype=float)
        else:
            self.estimate = np.zeros(self.n)
        return self.estimate
