"""Stability margin of the force loop at one posture, along one friction direction.

"Equal W is not equal coupling" (DESIGN §8) made quantitative: the linearised closed loop of the
[T] projection executor pressing on a table while sliding, stepped exactly as the simulation
steps it (1 ms, semi-implicit Euler, the F/T reading through the first-order low-pass).

Model (perturbations δ about sliding at speed v along the motion direction m̂ with F_n = F̂):

- plant: Λx δẍ = F_cmd + δF^e in task space [T6] (the nullspace term Nᵀ F_n [T14] does not
  accelerate the task, and μx cancels h and J̇q̇ to first order);
- contact: δF_n = −k δz (spring [T] Fig. 4); friction F_t = −μ F_n v/√(‖v‖² + v_ε²), so
  δF_t = μ δF_n f̂·(‖v‖/s) − μ F̂ (I/s − v vᵀ/s³) δv_t with s = √(‖v‖² + v_ε²) and f̂ = −m̂,
  both through the backward-Euler factor (I + Δt C G)⁻¹ of the implicit friction step;
- sensor: y ← y + α (F − y), α = 1 − exp(−2π f_c Δt) ([T] §IV-A, 25 Hz);
- law: u_m = −K_m^p δx_m − K_m^d δẋ_m [T11], u_f = K_f^p δy_f − K_f^d δẋ_f [T12],
  F_m = u_m, F_f = u_f + BᵀA⁻¹(u_m + y_m) with shaping [T7, T9, T10] (F_f = u_f without).

With shaping the force row reads D̂ z̈ = u_f + F_z + BᵀA⁻¹(y_m − F_m^e): the lagged reading of the
friction, which follows the normal force, enters through P_d = BᵀA⁻¹ scaled by P_d·f̂ — the
directional coupling — on top of the lag of the K_f^p feedback itself. The margin is the decay
rate −ln ρ(Φ)/Δt of the one-step map Φ (1/s; negative: the oscillation grows and the TCP
leaves the table), and the K_f^d at which it crosses zero.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from control.coupling import Subspaces, coupling_terms
from control.gains import MotionForceGains


@dataclass(frozen=True)
class ContactLoop:
    """What the force loop sees besides the posture: contact, friction, sensor, step."""

    stiffness_n_per_m: float = 30000.0  # [T] §IV-A
    mu: float = 1.0
    normal_force_n: float = 20.0  # operating point F̂ (Table II)
    speed_m_s: float = 0.16  # sliding speed (the polish segments' peak ≈ 0.16 m/s)
    v_eps_m_per_s: float = 0.01
    sensor_cutoff_hz: float = 25.0  # [T] §IV-A; 0 = no filter
    dt: float = 1e-3


@dataclass(frozen=True)
class Margin:
    """Stability of the linearised force loop at one posture and friction direction."""

    rate_per_s: float  # −ln ρ/Δt: > 0 stable (decay rate), < 0 growing
    spectral_radius: float
    directional_coupling: float  # P_d·f̂ (force-subspace wrench per unit friction wrench) [T10]
    kd_critical: float | None  # K_f^d (N s/m) below which the loop is unstable (None: not found)


def step_matrix(
    Lambda: np.ndarray,
    sub: Subspaces,
    gains: MotionForceGains,
    loop: ContactLoop,
    friction_dir: np.ndarray,
) -> np.ndarray:
    """(15, 15) one-step map Φ of the state (δx, δẋ, y_{k−1}) (task space, filtered force xyz).

    `friction_dir` is the unit friction direction f̂ in world xy (opposite to the sliding motion).
    The force subspace must be a single translational axis along z (the polish task).
    """
    return _step_map(Lambda, sub, gains, loop, friction_dir)(float(gains.force_kd))


def _step_map(
    Lambda: np.ndarray,
    sub: Subspaces,
    gains: MotionForceGains,
    loop: ContactLoop,
    friction_dir: np.ndarray,
) -> Callable[[float], np.ndarray]:
    """Φ as a function of K_f^d (`step_matrix` with the gains' other values): what does not depend
    on K_f^d (Λx⁻¹, the coupling terms, the friction linearisation) is computed once, so a search
    over K_f^d neither recomputes it nor validates a new gains object per trial."""
    if sub.force_axes != (2,):
        raise ValueError("the force-loop margin needs the force subspace pz alone")
    f_hat = np.asarray(friction_dir, dtype=float)
    f_hat = f_hat / np.linalg.norm(f_hat)
    v0 = -loop.speed_m_s * f_hat  # sliding velocity (xy)
    s = math.sqrt(float(v0 @ v0) + loop.v_eps_m_per_s**2)
    dFt_dv = -loop.mu * loop.normal_force_n * (np.eye(2) / s - np.outer(v0, v0) / s**3)
    dFt_dFn = -loop.mu * v0 / s  # = μ f̂ ‖v‖/s
    L_inv = np.linalg.inv(Lambda)
    # the simulation steps friction implicitly (app.sim.contact): F_t = −(I + Δt C G)⁻¹ C v with the
    # damping C = −∂F_t/∂v and G the tangential inverse mass of the TCP (Λx⁻¹, xy block)
    implicit = np.linalg.inv(np.eye(2) - loop.dt * dFt_dv @ L_inv[:2, :2])
    dFt_dv = implicit @ dFt_dv
    dFt_dFn = implicit @ dFt_dFn
    terms = coupling_terms(Lambda, L_inv, sub, exact_inverse=False)
    m_idx, f_idx = np.array(sub.motion_axes), np.array(sub.force_axes)
    kp = np.asarray(gains.motion_kp)[m_idx]
    kd = 2.0 * np.asarray(gains.motion_zeta)[m_idx] * np.sqrt(kp * np.diag(terms.A))
    alpha = 1.0 - math.exp(-2.0 * math.pi * loop.sensor_cutoff_hz * loop.dt) if loop.sensor_cutoff_hz > 0 else 1.0
    # The map is linear: advance all 15 unit states (the columns of I) at once, column j of each
    # block below is the state e_j after one step.
    eye = np.eye(15)
    x, dx, y_prev = eye[:6], eye[6:12], eye[12:15]
    f_env = np.zeros((6, 15))
    dFn = -loop.stiffness_n_per_m * x[2]
    f_env[2] = dFn
    f_env[:2] = dFt_dFn[:, None] * dFn + dFt_dv @ dx[:2]
    y = y_prev + alpha * (f_env[:3] - y_prev)
    u_m = -kp[:, None] * x[m_idx] - kd[:, None] * dx[m_idx]
    F_m = np.zeros((6, 15))
    F_m[m_idx] = u_m
    shaping_m = None
    if gains.shaping:
        # motion-subspace rows that carry the xy forces (the friction reading the shaping term uses)
        y_m = np.zeros((len(m_idx), 15))
        for axis in (0, 1):
            y_m[int(np.flatnonzero(m_idx == axis)[0])] = y[axis]
        shaping_m = terms.P_d @ (u_m + y_m)
    force_kp = gains.force_kp

    def phi(force_kd: float) -> np.ndarray:
        u_f = force_kp * y[2] - force_kd * dx[2]
        F = F_m.copy()
        F[f_idx] = u_f if shaping_m is None else u_f + shaping_m
        dx_new = dx + loop.dt * (L_inv @ (F + f_env))
        x_new = x + loop.dt * dx_new
        return np.vstack([x_new, dx_new, y])

    return phi


def force_loop_margin(
    Lambda: np.ndarray,
    sub: Subspaces,
    gains: MotionForceGains,
    loop: ContactLoop,
    friction_dir: np.ndarray,
    find_kd: bool = True,
) -> Margin:
    """The `Margin` of one posture (its Λx) for one friction direction (module docstring)."""
    rho = _radius(Lambda, sub, gains, loop, friction_dir)
    terms = coupling_terms(Lambda, np.linalg.inv(Lambda), sub, exact_inverse=False)
    f_hat = np.asarray(friction_dir, dtype=float) / np.linalg.norm(friction_dir)
    m_idx = list(sub.motion_axes)
    p_d = float(terms.P_d[0, m_idx.index(0)] * f_hat[0] + terms.P_d[0, m_idx.index(1)] * f_hat[1])
    kd_crit = critical_force_kd(Lambda, sub, gains, loop, friction_dir) if find_kd else None
    return Margin(-math.log(rho) / loop.dt, rho, p_d, kd_crit)


def critical_force_kd(
    Lambda: np.ndarray,
    sub: Subspaces,
    gains: MotionForceGains,
    loop: ContactLoop,
    friction_dir: np.ndarray,
    kd_max: float = 2000.0,
    tol: float = 0.5,
) -> float | None:
    """Lowest K_f^d (N s/m) of the stable interval that holds the gains' own K_f^d (or, when that one
    is unstable, the lowest stable K_f^d above it on a 25 N s/m grid up to kd_max), by bisection;
    0.0 when K_f^d = 0 is already stable, None when no K_f^d up to kd_max is. (Too large a K_f^d
    is unstable again in the 1 ms step, so the stable set is bounded on both sides.)"""
    phi = _step_map(Lambda, sub, gains, loop, friction_dir)

    def stable(kd: float) -> bool:
        return _spectral_radius(phi(float(kd))) < 1.0

    hi: float | None = gains.force_kd if stable(gains.force_kd) else None
    if hi is None:
        hi = next((float(k) for k in np.arange(gains.force_kd, kd_max + 1e-9, 25.0) if stable(float(k))), None)
    if hi is None:
        return None
    if stable(0.0):
        return 0.0
    lo = 0.0
    while hi - lo > tol:
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if stable(mid) else (mid, hi)
    return hi


def _radius(
    Lambda: np.ndarray, sub: Subspaces, gains: MotionForceGains, loop: ContactLoop, friction_dir: np.ndarray
) -> float:
    return _spectral_radius(step_matrix(Lambda, sub, gains, loop, friction_dir))


def _spectral_radius(phi: np.ndarray) -> float:
    return float(np.max(np.abs(np.linalg.eigvals(phi))))


@dataclass(frozen=True)
class PostureMargin:
    """The force-loop margin of one posture over a segment's speed profile, per friction direction."""

    kd_margin: float  # N s/m: K_f^d minus the largest critical K_f^d (> 0 stable, < 0 loses contact)
    kd_critical: float  # the largest critical K_f^d over directions and speeds
    worst_direction: int  # index into the directions given
    worst_speed_m_s: float
    directional_coupling: tuple[float, ...]  # P_d·f̂ per direction [T10]
    kd_critical_per_direction: tuple[float, ...]


def posture_margin(
    Lambda: np.ndarray,
    sub: Subspaces,
    gains: MotionForceGains,
    loop: ContactLoop,
    friction_dirs: list[np.ndarray],
    speeds: tuple[float, ...] | None = None,
) -> PostureMargin:
    """`PostureMargin` over the friction directions (e.g. stretching and retracting) and the speeds a
    segment passes through (default 0 … loop.speed_m_s in 8 steps: a minimum-jerk segment starts and
    ends at rest, where the regularised friction is a stiff viscous damper, and the margin is
    often smallest at a few cm/s)."""
    from dataclasses import replace

    speeds = speeds if speeds is not None else tuple(np.linspace(0.0, loop.speed_m_s, 9))
    crit_dir, pd_dir = [], []
    worst = (-np.inf, 0, 0.0)
    for d_i, f_hat in enumerate(friction_dirs):
        worst_here = -np.inf
        for v in speeds:
            m = force_loop_margin(Lambda, sub, gains, replace(loop, speed_m_s=float(v)), f_hat)
            kd = np.inf if m.kd_critical is None else m.kd_critical
            if kd > worst_here:
                worst_here = kd
            if kd > worst[0]:
                worst = (kd, d_i, float(v))
        crit_dir.append(float(worst_here))
        pd_dir.append(m.directional_coupling)
    return PostureMargin(gains.force_kd - worst[0], float(worst[0]), worst[1], worst[2], tuple(pd_dir), tuple(crit_dir))
