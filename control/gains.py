"""Every tunable of the controllers as frozen, validated dataclasses.

Construction validates: a negative or non-finite gain raises `ValueError` naming the field.
Use `dataclasses.replace(gains, field=value)` to change one value (validated again).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np


def validate_non_negative(obj: object) -> None:
    """Raise ValueError naming the first field that is NaN/inf or negative (scalars and arrays)."""
    for f in fields(obj):  # type: ignore[arg-type]
        value = getattr(obj, f.name)
        if isinstance(value, bool) or isinstance(value, str) or value is None:
            continue
        arr = np.asarray(value, dtype=float)
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"{type(obj).__name__}.{f.name} must be finite, got {value!r}")
        if np.any(arr < 0):
            raise ValueError(f"{type(obj).__name__}.{f.name} must be non-negative, got {value!r}")


def validate_positive(obj: object, *names: str) -> None:
    """Raise ValueError if any named field is not strictly positive."""
    for name in names:
        arr = np.asarray(getattr(obj, name), dtype=float)
        if np.any(arr <= 0) or not np.all(np.isfinite(arr)):
            raise ValueError(f"{type(obj).__name__}.{name} must be positive, got {getattr(obj, name)!r}")


def as_tuple(value, n: int, name: str) -> tuple[float, ...]:
    """A scalar or length-n sequence as a tuple of n floats (frozen dataclasses hold tuples)."""
    arr = np.broadcast_to(np.asarray(value, dtype=float), (n,)) if np.ndim(value) == 0 else np.asarray(value, float)
    if arr.shape != (n,):
        raise ValueError(f"{name} needs {n} values, got {len(arr)}")
    return tuple(float(x) for x in arr)


def is_finite_number(x) -> bool:
    """True for a real, finite number."""
    try:
        return math.isfinite(float(x))
    except (TypeError, ValueError):
        return False


# ---- [T] projection executor: motion/force law and nullspace QP -------------------------------
TANG_OBJECTIVES = ("j", "f", "a", "d")


@dataclass(frozen=True)
class MotionForceGains:
    """Gains of the [T] motion/force law (Table II, "Simulation" column).

    force_kp: K_f^p (dimensionless, N per N of force error) [T12]
    force_kd: K_f^d, velocity damping along the force axes, N s/m [T12]
    force_ki: K_f^i, integral gain on the force error, 1/s [T12]
    force_integral_limit_n: anti-windup clamp of K_f^i ∫e_f, N
    motion_kp: K_m^p per task axis [px py pz rx ry rz], N/m and N m/rad [T11]
    motion_zeta: damping ratio ζ per task axis; K_m^d = 2ζ√(K_m^p A_ii) [T11]
    nullspace_kd: K_n^d per joint, 1/s (Table II "K_q^p") [T13]
    shaping: use Λ̂x [T9] (True) or the natural inertia Λx (False, no decoupling) in [T7]
    """

    force_kp: float = 0.5
    force_kd: float = 200.0
    force_ki: float = 0.0
    force_integral_limit_n: float = 20.0
    motion_kp: tuple[float, ...] = (4000.0, 4000.0, 4000.0, 400.0, 400.0, 400.0)
    motion_zeta: tuple[float, ...] = (0.7, 0.7, 0.7, 0.7, 0.7, 0.7)
    nullspace_kd: tuple[float, ...] = (50.0,) * 7
    shaping: bool = True

    def __post_init__(self) -> None:
        object.__setattr__(self, "motion_kp", as_tuple(self.motion_kp, 6, "motion_kp"))
        object.__setattr__(self, "motion_zeta", as_tuple(self.motion_zeta, 6, "motion_zeta"))
        object.__setattr__(self, "nullspace_kd", as_tuple(self.nullspace_kd, 7, "nullspace_kd"))
        validate_non_negative(self)


@dataclass(frozen=True)
class NullspaceGains:
    """Nullspace velocity QP [T15-17] and its joint-limit dampers.

    objective: W to minimise: "j" joint posture [T18], "f", "a", "d" coupling [T22]
    k0_j, k0_f, k0_a, k0_d: gradient scale k0 [T15] per objective. The objectives have
        different units (W_j rad², W_f 1/kg², W_a kg², W_d 1), so each has its own k0, chosen
        once by one rule: k0 times the RMS of the nullspace-projected gradient ‖(I − J⁺J)∇W‖
        over the feasible self-motion loop at the polish start pose is 0.3 rad/s
        (`control.coupling.k0_for_speed`); k0_j = 1/s is a 1 s posture time constant.
    velocity_scale: fraction of the joint velocity limits used as q̇min/q̇max [T17]
    damper_speed: ξ, rad/s: first-order damper q̂̇ ≥ −ξ (d − d_s)/(d_i − d_s) near a limit
    damper_influence: d_i, rad: distance to a position limit where the damper starts acting
    damper_safety: d_s, rad: distance where the allowed approach velocity reaches zero
    """

    objective: str = "a"
    k0_j: float = 1.0
    k0_f: float = 25.0
    k0_a: float = 0.05
    k0_d: float = 0.25
    velocity_scale: float = 0.5
    damper_speed: float = 0.5
    damper_influence: float = 0.25
    damper_safety: float = 0.03

    def __post_init__(self) -> None:
        if self.objective not in TANG_OBJECTIVES:
            raise ValueError(
                f"NullspaceGains.objective must be one of {', '.join(TANG_OBJECTIVES)}, got {self.objective!r}"
            )
        validate_non_negative(self)
        validate_positive(self, "velocity_scale", "damper_influence")
        if not self.damper_safety < self.damper_influence:
            raise ValueError("NullspaceGains.damper_safety must be smaller than damper_influence")

    @property
    def k0(self) -> float:
        """k0 of the selected objective [T15]."""
        return float(getattr(self, f"k0_{self.objective}"))


# ---- [C] explicit-compliance QP executor ---------------------------------------------------------

from dataclasses import dataclass  # noqa: E402

DAMPER_FORMS = ("proposed", "classic")
ESTIMATE_SOURCES = ("none", "residual", "fusion", "oracle")
POSTURE_METRICS = ("identity", "inertia")


def compliance_matrix(value, m: int, name: str = "compliance") -> np.ndarray:
    """Γ [C9] as an (m, m) matrix from a scalar, m diagonal values or an m×m matrix.

    Γ must be symmetric positive semi-definite (eigenvalues ≥ 0); ValueError otherwise.
    """
    arr = np.asarray(value, dtype=float)
    if arr.ndim == 0:
        G = float(arr) * np.eye(m)
    elif arr.shape == (m,):
        G = np.diag(arr)
    elif arr.shape == (m, m):
        G = arr.copy()
    else:
        raise ValueError(f"{name} must be a scalar, {m} diagonal values or a {m}x{m} matrix, got shape {arr.shape}")
    if not np.all(np.isfinite(G)):
        raise ValueError(f"{name} must be finite")
    if not np.allclose(G, G.T, atol=1e-12):
        raise ValueError(f"{name} must be symmetric")
    if np.linalg.eigvalsh(G)[0] < -1e-12:
        raise ValueError(f"{name} must be positive semi-definite")
    return G


def _frozen(value):
    """Hashable copy of a scalar / vector / matrix gain for a frozen dataclass."""
    arr = np.asarray(value, dtype=float)
    if arr.ndim == 0:
        return float(arr)
    if arr.ndim == 1:
        return tuple(float(x) for x in arr)
    return tuple(tuple(float(x) for x in row) for row in arr)


@dataclass(frozen=True)
class PoseTaskGains:
    """TCP pose task [C3, C6]: ë* = −K_d ė − K_p e, weight w_k, compliance Γ_k [C9].

    stiffness K_p in 1/s², damping K_d in 1/s (scalars or 6 values [px py pz rx ry rz]);
    compliance: scalar, 6 diagonal values or a 6×6 symmetric PSD matrix (0 stiff, 1 compliant).
    """

    stiffness: float | tuple = 100.0
    damping: float | tuple = 20.0
    weight: float = 1e4
    compliance: float | tuple = 0.0

    def __post_init__(self) -> None:
        for name in ("stiffness", "damping", "compliance"):
            object.__setattr__(self, name, _frozen(getattr(self, name)))
        as_tuple(self.stiffness, 6, "stiffness")
        as_tuple(self.damping, 6, "damping")
        for name in ("stiffness", "damping", "weight"):
            arr = np.asarray(getattr(self, name), dtype=float)
            if not np.all(np.isfinite(arr)) or np.any(arr < 0):
                raise ValueError(f"PoseTaskGains.{name} must be finite and non-negative, got {getattr(self, name)!r}")
        validate_positive(self, "weight")
        compliance_matrix(self.compliance, 6, "PoseTaskGains.compliance")


@dataclass(frozen=True)
class PostureTaskGains:
    """Posture (null-space) task, task 0 of [C7, C9]: q̈*₀ = −K_d (q̇ − q̇_ref) − K_p (q − q_ref) − K_i ∫(q − q_ref).

    stiffness 1/s², damping 1/s, integral 1/s³ (scalars or 7 values); weight w₀; compliance Γ₀
    (scalar, 7 values or 7×7); metric "identity" (‖·‖², [C9]) or "inertia" (‖·‖²_M, which puts the
    posture in the dynamically consistent nullspace, DESIGN §8).
    """

    stiffness: float | tuple = 1.0
    damping: float | tuple = 2.0
    integral: float | tuple = 0.0
    weight: float = 1.0
    compliance: float | tuple = 0.0
    metric: str = "identity"

    def __post_init__(self) -> None:
        for name in ("stiffness", "damping", "integral", "compliance"):
            object.__setattr__(self, name, _frozen(getattr(self, name)))
        for name in ("stiffness", "damping", "integral", "weight"):
            arr = np.asarray(getattr(self, name), dtype=float)
            if not np.all(np.isfinite(arr)) or np.any(arr < 0):
                raise ValueError(
                    f"PostureTaskGains.{name} must be finite and non-negative, got {getattr(self, name)!r}"
                )
        validate_positive(self, "weight")
        compliance_matrix(self.compliance, 7, "PostureTaskGains.compliance")
        if self.metric not in POSTURE_METRICS:
            raise ValueError(f"PostureTaskGains.metric must be one of {POSTURE_METRICS}, got {self.metric!r}")


@dataclass(frozen=True)
class DamperGains:
    """Joint position/velocity limit dampers [C13–24].

    form "proposed" [C24] uses lambda_ (1/s) and overdamping M; "classic" [C17–19] uses the
    control period δt and the intermediary velocity limit [C15] with influence distance
    d_i = influence_fraction·range and ξ = λ(d_i − d_s)/(4M²) [C23] (the same velocity envelope
    as the proposed form, so the two differ only in the gain 1/δt versus λ).
    safety_fraction: d_s as a fraction of the joint range ([C] §IV-B: 1 %);
    velocity_scale: multiplies the robot's velocity limits (< 1 lowers them).
    """

    form: str = "proposed"
    lambda_: float = 100.0
    M: float = 2.0
    safety_fraction: float = 0.01
    influence_fraction: float = 0.1
    velocity_scale: float = 1.0

    def __post_init__(self) -> None:
        if self.form not in DAMPER_FORMS:
            raise ValueError(f"DamperGains.form must be one of {DAMPER_FORMS}, got {self.form!r}")
        validate_positive(self, "lambda_", "M", "velocity_scale", "influence_fraction")
        if not 0.0 <= self.safety_fraction < 0.5:
            raise ValueError(f"DamperGains.safety_fraction must be in [0, 0.5), got {self.safety_fraction!r}")
        if self.influence_fraction <= self.safety_fraction:
            raise ValueError("DamperGains.influence_fraction must exceed safety_fraction")


@dataclass(frozen=True)
class EstimatorGains:
    """External-torque estimation [C25–26].

    source: "none", "residual" (momentum observer), "fusion" (observer + F/T through the
    complementary filter [C26]) or "oracle" (simulation truth, labelled as such in outputs);
    observer_gain K_I in 1/s (also the fusion crossover).
    """

    source: str = "fusion"
    observer_gain: float = 50.0

    def __post_init__(self) -> None:
        if self.source not in ESTIMATE_SOURCES:
            raise ValueError(f"EstimatorGains.source must be one of {ESTIMATE_SOURCES}, got {self.source!r}")
        validate_positive(self, "observer_gain")


@dataclass(frozen=True)
class ComplianceQPSettings:
    """Switches of the [C] QP executor.

    feedback: keep τ̂_e in the inverse dynamics [C8] and the torque limits [C10];
    torque_limits: add [C10] as constraints; eps: OSQP absolute/relative tolerance;
    polish: OSQP solution polishing (slower, exact active set); max_iter: OSQP iteration cap per
    step (the iterate at the cap is used, flagged by its status).
    """

    feedback: bool = True
    torque_limits: bool = True
    eps: float = 1e-6
    polish: bool = False
    max_iter: int = 400

    def __post_init__(self) -> None:
        validate_positive(self, "eps", "max_iter")
