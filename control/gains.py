"""Every tunable of the controllers as frozen, validated parameter groups (`control.params`).

Each field carries its metadata (label, unit, range, step, help, paper tag) once; construction
coerces and validates every field and raises `ParamError` (a ValueError) naming the field.
Use `control.params.replaced(gains, "field", value)` (or `dataclasses.replace`) to change one
value: the result is validated again and the old group stays as it was.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from control.params import ParamError, ParamGroup, param

TASK_AXES = ("px", "py", "pz", "rx", "ry", "rz")
JOINTS7 = tuple(f"joint {i + 1}" for i in range(7))
GAMMA_MAX = 1.2  # Γ 0 … 1.2 like the authors' own GUI (DESIGN §3)
QP_BACKENDS = ("dense", "osqp")  # the QP backends of `control.qp` (a choice of `SolverParams`)
DEFAULT_QP_BACKEND = "dense"
CONTROL_PERIOD_S = (
    1e-3  # s, the controller's sampling period (1 kHz: one MuJoCo step), e.g. of the [T12] force integral
)


# ---- [T] projection executor: motion/force law and nullspace QP -------------------------------
TANG_OBJECTIVES = ("j", "f", "a", "d")
FORCE_AXES_CHOICES = ("pz", "px", "py", "px py", "pz rz", "px py pz")


@dataclass(frozen=True)
class MotionForceGains(ParamGroup):
    """Gains of the [T] motion/force law (Table II, "Simulation" column); K_m^d = 2ζ√(K_m^p A_ii)."""

    title = "Motion–force law [T11–12]"

    force_axes: str = param(
        "pz",
        label="Force axes",
        choices=FORCE_AXES_CHOICES,
        help="task axes under force control; the rest are motion axes",
        tag="[T19]",
    )
    force_kp: float = param(0.5, label="K_f^p", lo=0.0, hi=5.0, step=0.05, help="proportional force gain", tag="[T12]")
    force_kd: float = param(
        200.0,
        label="K_f^d",
        unit="N s/m",
        lo=0.0,
        hi=2000.0,
        step=10.0,
        help="velocity damping along the force axes",
        tag="[T12]",
    )
    force_ki: float = param(
        0.0, label="K_f^i", unit="1/s", lo=0.0, hi=50.0, step=0.5, help="integral force gain (clamped)", tag="[T12]"
    )
    force_integral_limit_n: float = param(
        20.0,
        label="K_f^i ∫e_f clamp",
        unit="N",
        lo=0.0,
        hi=100.0,
        step=1.0,
        help="anti-windup clamp of the integral term",
    )
    motion_kp: tuple[float, ...] = param(
        (4000.0, 4000.0, 4000.0, 400.0, 400.0, 400.0),
        label="K_m^p",
        unit=("N/m",) * 3 + ("N m/rad",) * 3,
        lo=0.0,
        hi=(10000.0,) * 3 + (1000.0,) * 3,
        step=(50.0,) * 3 + (10.0,) * 3,
        axes=TASK_AXES,
        help="motion stiffness per task axis",
        tag="[T11]",
    )
    motion_zeta: tuple[float, ...] = param(
        (0.7,) * 6,
        label="ζ",
        lo=0.0,
        hi=2.0,
        step=0.05,
        axes=TASK_AXES,
        help="damping ratio per task axis",
        tag="[T11]",
    )
    nullspace_kd: tuple[float, ...] = param(
        (50.0,) * 7,
        label="K_n^d",
        unit="1/s",
        lo=0.0,
        hi=200.0,
        step=1.0,
        axes=JOINTS7,
        help="nullspace velocity gain per joint (Table II K_q^p)",
        tag="[T13]",
    )
    shaping: bool = param(
        True, label="Inertia shaping Λ̂x", help="on: partially decoupled Λ̂x in F_x; off: natural Λx", tag="[T7, T9]"
    )

    @property
    def force_axis_names(self) -> tuple[str, ...]:
        """The force axes as names ("pz", ...)."""
        return tuple(self.force_axes.split())


# k0 of each objective: W_j rad², W_f 1/kg², W_a kg², W_d 1 have different units, so each has its
# own k0, chosen once by one rule: k0 times the RMS of the nullspace-projected gradient
# ‖(I − J⁺J)∇W‖ over the feasible self-motion loop at the polish start pose is 0.3 rad/s
# (`control.coupling.k0_for_speed`); k0_j = 1/s is a 1 s posture time constant. The slider spans
# 0 … 20 × the default.
K0_DEFAULTS = {"j": 1.0, "f": 25.0, "a": 0.05, "d": 0.25}
K0_UNITS = {"j": "1/s", "f": "kg² rad/s", "a": "rad/(kg² s)", "d": "rad/s"}
K0_RANGE_FACTOR = 20.0


def _k0(objective: str) -> float:
    d = K0_DEFAULTS[objective]
    return param(
        d,
        label=f"k0 (W_{objective})",
        unit=K0_UNITS[objective],
        lo=0.0,
        hi=K0_RANGE_FACTOR * d,
        step=K0_RANGE_FACTOR * d / 1000.0,
        help=f"gradient gain of W_{objective}",
        tag="[T15]",
    )


@dataclass(frozen=True)
class NullspaceGains(ParamGroup):
    """Nullspace velocity QP [T15-17] and its first-order joint-limit dampers
    q̂̇ ≥ −ξ (d − d_s)/(d_i − d_s) near a limit."""

    title = "Nullspace QP [T15–17]"

    objective: str = param(
        "a",
        label="Objective",
        choices=TANG_OBJECTIVES,
        choice_labels=tuple(f"W_{o}" for o in TANG_OBJECTIVES),
        help="W the nullspace QP minimises: j posture, f/a/d coupling",
        tag="[T18, T22]",
    )
    k0_j: float = _k0("j")
    k0_f: float = _k0("f")
    k0_a: float = _k0("a")
    k0_d: float = _k0("d")
    velocity_scale: float = param(
        0.5,
        label="Nullspace velocity limit",
        unit="× q̇max",
        lo=0.05,
        hi=1.0,
        step=0.01,
        help="fraction of the joint velocity limits used as q̇min/q̇max",
        tag="[T17]",
    )
    unit_length_m: float = param(
        0.0,
        label="Characteristic length L_c",
        unit="m",
        lo=0.0,
        hi=10.0,
        step=0.01,
        help="W_f, W_a, W_d in task coordinates with rotations as arcs of radius L_c, so their terms "
        "share units (0: off, SI units as [T])",
        tag="[T22]",
    )
    unit_mass_kg: float = param(
        1.0,
        label="Characteristic mass m_c",
        unit="kg",
        lo=0.01,
        hi=100.0,
        step=0.1,
        help="W_f, W_a, W_d with Λx divided by m_c (W_f × m_c², W_a ÷ m_c², W_d unchanged); 1 kg: as [T]",
        tag="[T22]",
    )
    damper_speed: float = param(
        0.5, label="ξ", unit="rad/s", lo=0.0, hi=2.0, step=0.05, help="approach speed of the nullspace damper at d_i"
    )
    damper_influence: float = param(
        0.25,
        label="d_i",
        unit="rad",
        lo=0.01,
        hi=1.0,
        step=0.01,
        help="nullspace QP: distance where the damper starts acting",
    )
    damper_safety: float = param(
        0.03,
        label="d_s",
        unit="rad",
        lo=0.0,
        hi=0.5,
        step=0.005,
        help="nullspace QP: distance where the approach velocity is zero",
    )

    def check(self) -> None:
        if not self.damper_safety < self.damper_influence:
            raise ParamError(
                f"damper_safety (d_s = {self.damper_safety:g}) must be smaller than "
                f"damper_influence (d_i = {self.damper_influence:g})"
            )

    @staticmethod
    def k0_field(objective: str) -> str:
        """The field holding k0 of an objective ("a" → "k0_a")."""
        if objective not in TANG_OBJECTIVES:
            raise ParamError(f"objective must be one of {', '.join(TANG_OBJECTIVES)}, got {objective!r}")
        return f"k0_{objective}"

    @property
    def k0(self) -> float:
        """k0 of the selected objective [T15]."""
        return float(getattr(self, self.k0_field(self.objective)))


# ---- [C] explicit-compliance QP executor ---------------------------------------------------------

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


@dataclass(frozen=True)
class PoseTaskGains(ParamGroup):
    """TCP pose task [C3, C6]: ë* = −K_d ė − K_p e, weight w_k, compliance Γ_k [C9]."""

    title = "Pose task [C3, C6, C9]"

    stiffness: float | tuple = param(
        100.0,
        kind="scalar_or_vector",
        size=6,
        label="K_p",
        unit="1/s²",
        lo=0.0,
        hi=2000.0,
        step=10.0,
        axes=TASK_AXES,
        help="pose task stiffness (one value or per axis)",
        tag="[C6]",
    )
    damping: float | tuple = param(
        20.0,
        kind="scalar_or_vector",
        size=6,
        label="K_d",
        unit="1/s",
        lo=0.0,
        hi=200.0,
        step=1.0,
        axes=TASK_AXES,
        help="pose task damping (one value or per axis)",
        tag="[C6]",
    )
    weight: float = param(1e4, label="w", lo=1e-3, hi=1e6, help="task weight in the QP objective", tag="[C9]")
    compliance: float | tuple = param(
        0.0,
        kind="gamma",
        size=6,
        label="Γ task",
        lo=0.0,
        hi=GAMMA_MAX,
        step=0.05,
        axes=TASK_AXES,
        help="how much of q̈_e the TCP task lets through (0 stiff, 1 compliant)",
        tag="[C9]",
    )


@dataclass(frozen=True)
class PostureTaskGains(ParamGroup):
    """Posture (null-space) task, task 0 of [C7, C9]:
    q̈*₀ = −K_d (q̇ − q̇_ref) − K_p (q − q_ref) − K_i ∫(q − q_ref); metric "identity" (‖·‖², [C9])
    or "inertia" (‖·‖²_M, the dynamically consistent nullspace, DESIGN §8)."""

    title = "Posture task [C7, C9]"

    stiffness: float | tuple = param(
        1.0,
        kind="scalar_or_vector",
        size=7,
        label="K_p posture",
        unit="1/s²",
        lo=0.0,
        hi=2000.0,
        step=1.0,
        axes=JOINTS7,
        help="posture stiffness (one value or per joint)",
        tag="[C7]",
    )
    damping: float | tuple = param(
        2.0,
        kind="scalar_or_vector",
        size=7,
        label="K_d posture",
        unit="1/s",
        lo=0.0,
        hi=200.0,
        step=1.0,
        axes=JOINTS7,
        help="posture damping (one value or per joint)",
        tag="[C7]",
    )
    integral: float | tuple = param(
        0.0,
        kind="scalar_or_vector",
        size=7,
        label="K_i posture",
        unit="1/s³",
        lo=0.0,
        hi=10000.0,
        step=10.0,
        axes=JOINTS7,
        help="posture integral gain (one value or per joint)",
    )
    weight: float = param(1.0, label="w₀", lo=1e-3, hi=1e6, help="posture weight in the QP objective", tag="[C9]")
    compliance: float | tuple = param(
        0.0,
        kind="gamma",
        size=7,
        label="Γ₀",
        lo=0.0,
        hi=GAMMA_MAX,
        step=0.05,
        axes=JOINTS7,
        help="how much of q̈_e the posture lets through (0 stiff, 1 compliant)",
        tag="[C9]",
    )
    metric: str = param(
        "identity", label="Posture metric", choices=POSTURE_METRICS, help="‖·‖² [C9] or ‖·‖²_M (dynamically consistent)"
    )


@dataclass(frozen=True)
class DamperGains(ParamGroup):
    """Joint position/velocity limit dampers [C13–24].

    form "proposed" [C24] uses lambda_ and overdamping M; "classic" [C17–19] uses the control
    period δt and the intermediary velocity limit [C15] with d_i = influence_fraction·range and
    ξ = λ(d_i − d_s)/(4M²) [C23] (the same velocity envelope as the proposed form, so the two
    differ only in the gain 1/δt versus λ).
    """

    title = "Joint-limit dampers [C13–24]"

    form: str = param(
        "proposed", label="Damper form", choices=DAMPER_FORMS, help="proposed [C24] or classic [C17–19]", tag="[C24]"
    )
    lambda_: float = param(100.0, label="λ", unit="1/s", lo=1.0, hi=1000.0, step=1.0, help="damper gain", tag="[C24]")
    M: float = param(2.0, label="M", lo=0.5, hi=10.0, step=0.1, help="overdamping (M > 1 overdamped)", tag="[C24]")
    safety_fraction: float = param(
        0.01,
        label="d_s",
        unit="× range",
        lo=0.0,
        hi=0.2,
        step=0.005,
        help="distance kept from the limit ([C]: 1 %)",
        tag="[C17]",
    )
    influence_fraction: float = param(
        0.1,
        label="d_i",
        unit="× range",
        lo=0.01,
        hi=0.45,
        step=0.01,
        help="distance where the damper starts acting",
        tag="[C17]",
    )
    velocity_scale: float = param(
        1.0,
        label="Velocity limit",
        unit="× q̇max",
        lo=0.05,
        hi=1.0,
        step=0.01,
        help="share of the joint velocity limits the controller may use",
        tag="[C15]",
    )

    def check(self) -> None:
        if self.influence_fraction <= self.safety_fraction:
            raise ParamError(
                f"influence_fraction (d_i = {self.influence_fraction:g}) must exceed "
                f"safety_fraction (d_s = {self.safety_fraction:g})"
            )


@dataclass(frozen=True)
class EstimatorGains(ParamGroup):
    """External-torque estimation [C25–26]: "none", "residual" (momentum observer), "fusion"
    (observer + F/T through the complementary filter [C26]) or "oracle" (simulation truth,
    labelled as such in outputs); observer_gain K_I (also the fusion crossover)."""

    title = "External-torque estimate [C25–26]"

    source: str = param(
        "fusion",
        label="τ̂_e source",
        choices=ESTIMATE_SOURCES,
        help="none, momentum observer [C25], fusion with the F/T sensor [C26], or simulation truth",
        tag="[C25, C26]",
    )
    observer_gain: float = param(
        50.0,
        label="K_I",
        unit="1/s",
        lo=1.0,
        hi=1000.0,
        step=1.0,
        help="observer gain and fusion crossover (≤ 1/Δt at the 1 kHz step)",
        tag="[C25]",
    )


@dataclass(frozen=True)
class ComplianceQPSettings(ParamGroup):
    """Switches of the [C] QP executor; eps: the QP tolerance (OSQP's absolute/relative one, DAQP's
    primal one); polish: OSQP solution polishing (slower, exact active set); max_iter: OSQP's
    iteration cap per step (the iterate at the cap is used, flagged by its status; DAQP's active
    set ends on its own). Changing eps, polish or max_iter rebuilds the QP."""

    title = "QP executor [C8, C10]"

    feedback: bool = param(
        True,
        label="External-force feedback",
        help="keep τ̂_e in the inverse dynamics [C8] and torque limits [C10]",
        tag="[C8]",
    )
    torque_limits: bool = param(
        True, label="Torque limits", help="torque limits on τ_d including τ̂_e as constraints", tag="[C10]"
    )
    eps: float = param(1e-6, label="QP tolerance", lo=1e-12, hi=1e-2, help="OSQP abs./rel. tolerance, DAQP primal")
    polish: bool = param(False, label="OSQP polishing", help="exact active set, slower")
    max_iter: int = param(400, label="OSQP iteration cap", lo=1, hi=100000, step=1, help="iterations per step")


@dataclass(frozen=True)
class SolverParams(ParamGroup):
    """Which QP backend an executor's QPs use (`control.qp`); a change builds new QPs."""

    title = "QP solver"

    qp_backend: str = param(
        DEFAULT_QP_BACKEND,
        label="QP solver",
        choices=QP_BACKENDS,
        help="dense: DAQP active set (exact, a few µs); osqp: the ADMM reference; both executors' QPs",
    )
