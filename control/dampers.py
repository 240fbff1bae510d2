"""Joint position and velocity limits as acceleration bounds: velocity dampers [C13–24].

Per joint and per side, with e the distance to the limit (upper: e = q⁺ − q, ė = −q̇; lower:
e = q − q⁻, ė = q̇), both limits become a lower bound on ë:
- position, proposed [C24]: ë_p = −λ ė − λ²/(4M²)(e − d_s), active everywhere (no d_i needed);
- position, classic [C15, C17]: ë_p = −(ė − ė_d)/δt, ė_d = −ξ(e − d_s)/(d_i − d_s), only when e < d_i;
- velocity [C14, C18]: ë_v = −g(ė − ė_min) with g = λ (proposed) or 1/δt (classic), ė_min = −q̇⁺;
merged [C19]: ë ≥ max(ë_p, ë_v). Upper side: q̈ ≤ −max(ë_p, ë_v); lower side: q̈ ≥ max(ë_p, ë_v).
Endless joints get no position bound. Saturated at the limit the proposed bound gives
ë + λė + λ²/(4M²)(e − d_s) = 0 [C21–22]: natural frequency λ/(2M), damping ratio M.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from control.gains import DamperGains
from control.kernels.compliance import acceleration_bounds_fused
from control.kernels.cqp import damper_record_dtype
from control.kernels.records import fill_record

NO_BOUND = 1e9  # rad/s², stands for "unbounded" in the QP rows (OSQP treats ≥ 1e30 as inf)


class AccelerationBounds(NamedTuple):
    """Box rows lower ≤ q̈ ≤ upper produced by a damper at one state."""

    lower: np.ndarray  # (n,) rad/s²
    upper: np.ndarray  # (n,) rad/s²
    crossed: bool  # lower > upper somewhere (state far outside the limits): both set to the midpoint


class JointLimitDamper:
    """Velocity dampers for every joint of an arm, proposed [C24] or classic [C17–19] form."""

    def __init__(
        self,
        q_lower: np.ndarray,
        q_upper: np.ndarray,
        dq_max: np.ndarray,
        endless: np.ndarray,
        gains: DamperGains | None = None,
        dt: float = 1e-3,
    ):
        self.q_lower = np.asarray(q_lower, dtype=float).copy()
        self.q_upper = np.asarray(q_upper, dtype=float).copy()
        self.dq_max_nominal = np.asarray(dq_max, dtype=float).copy()
        self.endless = np.asarray(endless, dtype=bool).copy()
        n = self.q_lower.shape[0]
        for name, arr in (("q_upper", self.q_upper), ("dq_max", self.dq_max_nominal), ("endless", self.endless)):
            if arr.shape != (n,):
                raise ValueError(f"{name} needs {n} values, got shape {arr.shape}")
        if np.any(self.q_upper <= self.q_lower):
            raise ValueError("every joint needs q_lower < q_upper")
        if np.any(self.dq_max_nominal <= 0):
            raise ValueError("dq_max must be positive")
        if not dt > 0:
            raise ValueError(f"dt must be positive, got {dt!r}")
        self.dt = float(dt)
        self.n = n
        self.gains = gains or DamperGains()
        self.configure(self.gains)

    def configure(self, gains: DamperGains, dq_max: np.ndarray | None = None) -> None:
        """Set the damper parameters (and optionally new per-joint velocity limits, rad/s)."""
        self.gains = gains
        if dq_max is not None:
            arr = np.asarray(dq_max, dtype=float)
            if arr.shape != (self.n,) or np.any(arr <= 0):
                raise ValueError(f"dq_max needs {self.n} positive values")
            self.dq_max_nominal = arr.copy()
        rng = self.q_upper - self.q_lower
        self.d_s = gains.safety_fraction * rng  # [C] §IV-B: 1 % of the range
        self.d_i = gains.influence_fraction * rng
        self.dq_limit = gains.velocity_scale * self.dq_max_nominal
        lam, M = gains.lambda_, gains.M
        self.kp = lam * lam / (4.0 * M * M)  # [C24] λ²/(4M²)
        self.xi = lam * (self.d_i - self.d_s) / (4.0 * M * M)  # [C23] solved for ξ (classic form)
        self.velocity_gain = lam if gains.form == "proposed" else 1.0 / self.dt
        # the fused [C] step's record (`kernels.cqp.damper_record_dtype`): the gains by name, the joint
        # rows (the attributes are views of it) and the derived scalars
        rec = self.kernel_record = fill_record(
            damper_record_dtype(self.n), (gains,), q_lower=self.q_lower, q_upper=self.q_upper, d_s=self.d_s,
            d_i=self.d_i, xi=self.xi, dq_limit=self.dq_limit, endless=self.endless, kp=self.kp,
            velocity_gain=self.velocity_gain, proposed=gains.form == "proposed", dt=self.dt, no_bound=NO_BOUND,
        )  # fmt: skip
        self.q_lower, self.q_upper, self.d_s = rec["q_lower"][0], rec["q_upper"][0], rec["d_s"][0]
        self.d_i, self.xi, self.dq_limit = rec["d_i"][0], rec["xi"][0], rec["dq_limit"][0]
        self.has_position = ~self.endless
        self._d_s2 = np.concatenate([self.d_s, self.d_s])
        self._d_i2 = np.concatenate([self.d_i, self.d_i])
        self._span2 = self._d_i2 - self._d_s2
        self.xi2 = np.concatenate([self.xi, self.xi])
        self._dq_limit2 = np.concatenate([self.dq_limit, self.dq_limit])
        self._no_position2 = np.concatenate([self.endless, self.endless])

    def _both_sides(self, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
        """max(ë_p, ë_v) [C19] for the upper sides (first n) and lower sides (last n), stacked."""
        n = self.n
        e = np.empty(2 * n)
        de = np.empty(2 * n)
        e[:n] = self.q_upper - q  # upper: e = q⁺ − q, ė = −q̇
        e[n:] = q - self.q_lower  # lower: e = q − q⁻, ė = q̇
        de[:n] = -dq
        de[n:] = dq
        g = self.gains
        if g.form == "proposed":
            e_p = -g.lambda_ * de - self.kp * (e - self._d_s2)  # [C24]
        else:
            de_d = -self.xi2 * (e - self._d_s2) / self._span2  # [C15]
            e_p = np.where(e < self._d_i2, -(de - de_d) / self.dt, -NO_BOUND)  # [C17], inserted below d_i
        e_p[self._no_position2] = -NO_BOUND
        e_v = -self.velocity_gain * (de + self._dq_limit2)  # [C18]/[C20] with ė_min = −q̇⁺
        return np.maximum(e_p, e_v)

    def bounds(self, q: np.ndarray, dq: np.ndarray) -> AccelerationBounds:
        """Acceleration bounds lower ≤ q̈ ≤ upper at (q, q̇): `bounds_reference` in one compiled call."""
        lower, upper, crossed = acceleration_bounds_fused(
            np.asarray(q, dtype=float), np.asarray(dq, dtype=float), self.kernel_record
        )
        return AccelerationBounds(lower, upper, bool(crossed))

    def bounds_reference(self, q: np.ndarray, dq: np.ndarray) -> AccelerationBounds:
        """Acceleration bounds lower ≤ q̈ ≤ upper at (q, q̇) (numpy; the reference of `bounds`)."""
        n = self.n
        side = np.minimum(self._both_sides(q, dq), NO_BOUND)
        upper = -side[:n]  # ë = −q̈ on the upper side
        lower = side[n:]
        if (lower > upper).any():
            mid = 0.5 * (lower + upper)
            bad = lower > upper
            lower = np.where(bad, mid, lower)
            upper = np.where(bad, mid, upper)
            return AccelerationBounds(lower, upper, True)
        return AccelerationBounds(lower, upper, False)


def second_order_response(omega_n: float, zeta: float, x0: float, v0: float, t: np.ndarray) -> np.ndarray:
    """Free response x(t) of ẍ + 2ζω ẋ + ω² x = 0 from x(0) = x0, ẋ(0) = v0 [C22]."""
    t = np.asarray(t, dtype=float)
    if abs(zeta - 1.0) < 1e-9:
        return (x0 + (v0 + omega_n * x0) * t) * np.exp(-omega_n * t)
    if zeta > 1.0:
        r = omega_n * np.sqrt(zeta * zeta - 1.0)
        s1, s2 = -zeta * omega_n + r, -zeta * omega_n - r
        c1 = (v0 - s2 * x0) / (s1 - s2)
        c2 = x0 - c1
        return c1 * np.exp(s1 * t) + c2 * np.exp(s2 * t)
    wd = omega_n * np.sqrt(1.0 - zeta * zeta)
    a = zeta * omega_n
    return np.exp(-a * t) * (x0 * np.cos(wd * t) + (v0 + a * x0) / wd * np.sin(wd * t))
