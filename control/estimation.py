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
from control.kernels.cqp import ESTIMATOR_STATE_FIELDS, estimator_record_dtype
from control.kernels.estimation import momentum_observer_fused, sensor_high_pass_fused
from control.kernels.records import fill_record
from control.model import Dynamics


def _state_record(n: int) -> np.ndarray:
    """A zeroed estimator record (`kernels.cqp.estimator_record_dtype`) for an observer or a filter
    built on its own."""
    return np.zeros(1, estimator_record_dtype(n))


class MomentumObserver:
    """Generalised-momentum residual [C25] with exact discrete integration.

    Its state lives in an estimator record (`record`, shared with the `HighPass` of the same
    estimator and read by the fused [C] step, which advances it in place): `r` and the stored M, q̇, h
    are views of it, and `previous` is None until a state is stored (`observed`)."""

    def __init__(self, n: int, gain: float, dt: float, record: np.ndarray | None = None):
        if not gain > 0 or not dt > 0:
            raise ValueError(f"observer gain and dt must be positive, got {gain!r}, {dt!r}")
        self.n = n
        self.gain = float(gain)
        self.dt = float(dt)
        self.a = math.exp(-self.gain * self.dt)
        self.record = _state_record(n) if record is None else record
        rec = self.record
        self.r = rec["r"][0]
        self._M_prev, self._dq_prev, self._h_prev = rec["M_prev"][0], rec["dq_prev"][0], rec["h_prev"][0]
        self._observed = rec["observed"]  # (1,): a state is stored

    def reset(self, dyn: Dynamics | None = None) -> None:
        """r = 0 and p(0) taken at the given state (or at the next update)."""
        self.r[:] = 0.0
        if dyn is None:
            self._observed[0] = False
        else:
            self._store(dyn)

    def _store(self, dyn: Dynamics) -> None:
        self._M_prev[:] = dyn.M
        self._dq_prev[:] = dyn.dq
        self._h_prev[:] = dyn.h
        self._observed[0] = True

    @property
    def previous(self) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """(M, q̇, h) of the last stored state, what the next step integrates from; None before the
        first update (then the next update only stores)."""
        return (self._M_prev, self._dq_prev, self._h_prev) if self._observed[0] else None

    def continue_from(self, other: MomentumObserver) -> None:
        """Carry another observer's residual and stored state over (a new gain keeps running)."""
        self.r[:] = other.r
        previous = other.previous
        if previous is not None:
            self._M_prev[:], self._dq_prev[:], self._h_prev[:] = previous
        self._observed[0] = previous is not None

    def update(self, dyn: Dynamics, tau_prev: np.ndarray) -> np.ndarray:
        """`update_reference` in one compiled call (`control.kernels.estimation.momentum_observer_fused`)."""
        if not self._observed[0]:
            self._store(dyn)
            return self.r
        tau_prev = np.asarray(tau_prev, dtype=float)
        self.r[:] = momentum_observer_fused(
            self._M_prev, dyn.dq, self._dq_prev, tau_prev, self._h_prev, self.dt, self.a, self.r
        )
        self._store(dyn)
        return self.r

    def update_reference(self, dyn: Dynamics, tau_prev: np.ndarray) -> np.ndarray:
        """Advance to the state in `dyn`, given the torque applied over the last period; return r."""
        if not self._observed[0]:
            self._store(dyn)
            return self.r
        # Δ = ∫τ_e over the last period (see module docstring)
        delta = self._M_prev @ (dyn.dq - self._dq_prev) - (tau_prev - self._h_prev) * self.dt
        self.r[:] = self.a * self.r + (1.0 - self.a) * (delta / self.dt)  # [C25], exact ZOH solution
        self._store(dyn)
        return self.r


class HighPass:
    """s/(K + s) per channel, discretised as x − LP(x) with the same exact pole as the observer.

    Its low-pass state is the `lp` field of an estimator record (`filtered` once started); `lp` is
    None before the first sample."""

    def __init__(self, n: int, gain: float, dt: float, record: np.ndarray | None = None):
        self.a = math.exp(-float(gain) * float(dt))
        self.n = n
        rec = _state_record(n) if record is None else record
        self._lp, self._filtered = rec["lp"][0], rec["filtered"]

    @property
    def lp(self) -> np.ndarray | None:
        """The low-pass state (a view of the record), None before the first sample."""
        return self._lp if self._filtered[0] else None

    def reset(self) -> None:
        """Forget the state (the next input starts the low-pass at that value)."""
        self._filtered[0] = False

    def update(self, x: np.ndarray) -> np.ndarray:
        """Filter one sample."""
        lp = self._lp
        if not self._filtered[0]:  # start in steady state: a constant reading has no high-pass part
            lp[:] = x
            self._filtered[0] = True
        else:
            lp[:] = self.a * lp + (1.0 - self.a) * x
        return x - lp


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
        # the [C] executor's fused step's record (`kernels.cqp.estimator_record_dtype`): K_I by name, the
        # pole a, δt, the source code (−1: the oracle, not computed there), and the state, of which the
        # observer's, the filter's and `tau_s`, `estimate` here are views
        n, gain = self.n, self.gains.observer_gain
        self.source_code = {"none": 0.0, "residual": 1.0, "fusion": 2.0}.get(self.gains.source, -1.0)
        state = dict.fromkeys(ESTIMATOR_STATE_FIELDS, 0)
        rec = self.kernel_record = fill_record(
            estimator_record_dtype(n), (self.gains,), a=math.exp(-gain * self.dt), dt=self.dt,
            source_code=self.source_code, **state,
        )  # fmt: skip
        self.observer = MomentumObserver(n, gain, self.dt, rec)
        self.high_pass = HighPass(n, gain, self.dt, rec)
        self.tau_s, self.estimate = rec["tau_s"][0], rec["tau_hat"][0]
        # what a fused step is given (`control.compliance_qp.ComplianceQPExecutor`): the torque applied
        # over the last period, the F/T wrench at the TCP and whether it computes the estimate
        self.tau_prev, self.wrench, self.estimate_on = rec["tau_prev"][0], rec["wrench"][0], rec["estimate_on"]

    def configure(self, gains: EstimatorGains) -> None:
        """New source or K_I; the observer keeps running from its current residual."""
        old, tau_prev = self.observer, self.tau_prev
        self.gains = gains
        self._build()
        self.observer.continue_from(old)
        self.tau_prev[:] = tau_prev

    def reset(self, dyn: Dynamics | None = None) -> None:
        """Clear observer and filter states."""
        self.observer.reset(dyn)
        self.high_pass.reset()
        self.estimate[:] = 0.0

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
        lp = high_pass.lp
        if wrench_tcp is not None and lp is not None:  # τ_s = J_sᵀ F_s (wrench at the TCP), high-passed
            wrench = np.asarray(wrench_tcp, dtype=float)
            self.tau_s[:], hp = sensor_high_pass_fused(dyn.J, wrench, lp, high_pass.a)
        else:
            if wrench_tcp is not None:
                self.tau_s[:] = sensor_joint_torque(dyn.J, wrench_tcp)
            hp = high_pass.update(self.tau_s)
        if source == "residual":
            self.estimate[:] = r
        elif source == "fusion":
            self.estimate[:] = r + hp  # [C26]
        elif source == "oracle" and tau_oracle is not None:
            self.estimate[:] = tau_oracle
        else:
            self.estimate[:] = 0.0
        return self.estimate
