"""Stability margin of the force loop at one posture, along one friction direction.

"Equal W is not equal coupling" (DESIGN §8) made quantitative: the linearised closed loop of the
[T] projection executor pressing on a table while sliding, stepped exactly as the simulation
steps it (1 ms, semi-implicit Euler, the F/T reading through the first-order low-pass), with the
latency a sampled controller has: the F/T reading d_s periods old and the torque applied d_a
periods after it was computed (z^−d_s, z^−d_a).

Model (perturbations δ about sliding at speed v along the motion direction m̂ with F_n = F̂):

- plant: Λx δẍ = F_a + δF^e in task space [T6] (the nullspace term Nᵀ F_n [T14] does not
  accelerate the task, and μx cancels h and J̇q̇ to first order), stepped as the simulation
  does: δẋ_{k+1} = δẋ_k + Δt Λx⁻¹ (F_a,k + δF^e_k), δx_{k+1} = δx_k + Δt δẋ_{k+1};
- contact: δF_n = −k δz (spring [T] Fig. 4); friction F_t = −μ F_n v/√(‖v‖² + v_ε²), so
  δF_t = μ δF_n f̂·(‖v‖/s) − μ F̂ (I/s − v vᵀ/s³) δv_t with s = √(‖v‖² + v_ε²) and f̂ = −m̂,
  both through the backward-Euler factor (I + Δt C G)⁻¹ of the implicit friction step;
- sensor: y_k = y_{k−1} + α (F^e_k − y_{k−1}), α = 1 − exp(−2π f_c Δt) ([T] §IV-A), read
  d_s periods late: ŷ_k = y_{k−d_s};
- law: u_m = −K_m^p δx_m − K_m^d δẋ_m [T11], u_f = K_f^p ŷ_f − K_f^d δẋ_f + K_f^i I_k with
  I_k = I_{k−1} + Δt ŷ_f [T12] (the clamp inactive), F_c,m = u_m, F_c,f = u_f + BᵀA⁻¹(u_m + ŷ_m)
  with shaping [T7, T9, T10] (F_c,f = u_f without);
- actuation: F_a,k = F_c,k−d_a (the torque of d_a periods ago, Jᵀ constant to first order).

With shaping the force row reads D̂ z̈ = u_f + F_z + BᵀA⁻¹(ŷ_m − F_m^e): the lagged reading of the
friction, which follows the normal force, enters through P_d = BᵀA⁻¹ scaled by P_d·f̂ — the
directional coupling — on top of the lag of the K_f^p feedback itself. The loop is the discrete
LTI system ξ_{k+1} = Φ ξ_k of the state ξ = (δx, δẋ, y_{k−1}, I_{k−1}, y_{k−2}…y_{k−d_s},
F_c,k−1…F_c,k−d_a) (`delayed_loop`). The margin is the decay rate σ = −ln ρ(Φ)/Δt (1/s; negative:
the oscillation grows as e^{−σt} and the TCP leaves the table), and the K_f^d at which it crosses
zero (Φ is affine in K_f^d, so the search costs one eigenvalue problem per trial).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, fields, replace

import numpy as np

from control.coupling import Subspaces, coupling_terms
from control.gains import MotionForceGains


@dataclass(frozen=True)
class ContactLoop:
    """What the force loop sees besides the posture: contact, friction, sensor, latency, step."""

    stiffness_n_per_m: float = 30000.0  # [T] §IV-A
    mu: float = 1.0
    normal_force_n: float = 20.0  # operating point F̂ (Table II)
    speed_m_s: float = 0.16  # sliding speed (the polish segments' peak ≈ 0.16 m/s)
    v_eps_m_per_s: float = 0.01
    sensor_cutoff_hz: float = 25.0  # [T] §IV-A; 0 = no filter
    dt: float = 1e-3
    sensing_delay_steps: int = 0  # d_s: age of the F/T reading the law uses, in control periods
    actuation_delay_steps: int = 0  # d_a: periods between computing a torque and the motors applying it


@dataclass(frozen=True)
class Margin:
    """Stability of the linearised force loop at one posture and friction direction."""

    rate_per_s: float  # −ln ρ/Δt: > 0 stable (decay rate), < 0 growing
    spectral_radius: float
    directional_coupling: float  # P_d·f̂ (force-subspace wrench per unit friction wrench) [T10]
    kd_critical: float | None  # K_f^d (N s/m) below which the loop is unstable (None: not found)
    frequency_hz: float = math.nan  # the slowest-decaying mode's frequency, |arg λ|/(2π Δt)


# ---- a sampled loop with latency: ξ_{k+1} = Φ ξ_k --------------------------------------------------
@dataclass(frozen=True)
class SampledLoop:
    """A sampled plant and its linear law, each part a matrix (n plant states, p commands, m readings,
    c controller states):

    plant s_{k+1} = A s_k + B a_k; reading m_k = C s_k, used d_s periods late: m̂_k = m_{k−d_s};
    controller state w_k = A_c w_{k−1} + B_c m̂_k; command c_k = K_s s_k + K_m m̂_k + C_c w_k;
    applied a_k = c_{k−d_a}. K_s is the undelayed feedback (joint encoders), K_m the sensed one."""

    A: np.ndarray  # (n, n)
    B: np.ndarray  # (n, p)
    C: np.ndarray  # (m, n)
    K_s: np.ndarray  # (p, n)
    K_m: np.ndarray  # (p, m)
    A_c: np.ndarray  # (c, c)
    B_c: np.ndarray  # (c, m)
    C_c: np.ndarray  # (p, c)


def delayed_loop(parts: SampledLoop, sensing_delay_steps: int, actuation_delay_steps: int) -> np.ndarray:
    """The closed loop's one-step map Φ (z^−d_s on the reading, z^−d_a on the command) of the state
    ξ_k = (s_k, w_{k−1}, m_{k−1} … m_{k−d_s}, c_{k−1} … c_{k−d_a}), size n + c + m d_s + p d_a.
    Parts whose matrices are stacks (k, …) of k loops of the same sizes give the k maps (k, size, size)
    (`stacked`), each as it is alone."""
    ds, da = int(sensing_delay_steps), int(actuation_delay_steps)
    if ds < 0 or da < 0:
        raise ValueError(f"delays must be whole periods ≥ 0, got sensing {ds}, actuation {da}")
    n, p, m, c = parts.A.shape[-2], parts.B.shape[-1], parts.C.shape[-2], parts.A_c.shape[-2]
    size = n + c + m * ds + p * da
    eye = np.eye(size)
    s, w = eye[:n], eye[n : n + c]
    M = [eye[n + c + m * i : n + c + m * (i + 1)] for i in range(ds)]  # M[i] = m_{k−1−i}
    U = [eye[n + c + m * ds + p * i : n + c + m * ds + p * (i + 1)] for i in range(da)]  # U[i] = c_{k−1−i}
    m_now = parts.C @ s
    m_used = m_now if ds == 0 else M[ds - 1]  # z^−d_s
    w_new = parts.A_c @ w + parts.B_c @ m_used
    command = parts.K_s @ s + parts.K_m @ m_used + parts.C_c @ w_new
    applied = command if da == 0 else U[da - 1]  # z^−d_a
    s_new = parts.A @ s + parts.B @ applied
    blocks = [s_new, w_new]
    if ds:
        blocks += [m_now, *M[:-1]]  # the reading buffer shifts by one period
    if da:
        blocks += [command, *U[:-1]]  # so does the command pipeline
    batch = parts.A.shape[:-2]
    return np.concatenate([np.broadcast_to(b, (*batch, *b.shape[-2:])) for b in blocks], axis=-2)


def stacked(parts: list[SampledLoop]) -> SampledLoop:
    """Loops of the same sizes as one `SampledLoop` of stacked matrices (k, …), for `delayed_loop`."""
    return SampledLoop(*(np.stack([getattr(p, f.name) for p in parts]) for f in fields(SampledLoop)))


# ---- the polish force loop --------------------------------------------------------------------------
def force_loop_parts(
    Lambda: np.ndarray,
    sub: Subspaces,
    gains: MotionForceGains,
    loop: ContactLoop,
    friction_dir: np.ndarray,
    force_kd: float | None = None,
) -> SampledLoop:
    """The polish force loop as a `SampledLoop` (module docstring): plant state s = (δx, δẋ, y_{k−1})
    (task space, filtered force xyz), command the task wrench, reading the filtered force xyz, the
    force integral as the controller state when K_f^i > 0. `friction_dir` is the unit friction
    direction f̂ in world xy (opposite to the sliding motion); the force subspace must be the single
    translational axis z (the polish task). `force_kd` overrides the gains' K_f^d."""
    if sub.force_axes != (2,):
        raise ValueError("the force-loop margin needs the force subspace pz alone")
    dt = loop.dt
    f_hat = np.asarray(friction_dir, dtype=float)
    f_hat = f_hat / np.linalg.norm(f_hat)
    v0 = -loop.speed_m_s * f_hat  # sliding velocity (xy)
    s = math.sqrt(float(v0 @ v0) + loop.v_eps_m_per_s**2)
    dFt_dv = -loop.mu * loop.normal_force_n * (np.eye(2) / s - np.outer(v0, v0) / s**3)
    dFt_dFn = -loop.mu * v0 / s  # = μ f̂ ‖v‖/s
    L_inv = np.linalg.inv(Lambda)
    # the simulation steps friction implicitly (app.sim.contact): F_t = −(I + Δt C G)⁻¹ C v with the
    # damping C = −∂F_t/∂v and G the tangential inverse mass of the TCP (Λx⁻¹, xy block)
    implicit = np.linalg.inv(np.eye(2) - dt * dFt_dv @ L_inv[:2, :2])
    dFt_dv, dFt_dFn = implicit @ dFt_dv, implicit @ dFt_dFn
    terms = coupling_terms(Lambda, L_inv, sub, exact_inverse=False)
    m_idx = np.array(sub.motion_axes)
    kp = np.asarray(gains.motion_kp)[m_idx]
    kd = 2.0 * np.asarray(gains.motion_zeta)[m_idx] * np.sqrt(kp * np.diag(terms.A))  # [T11]
    alpha = 1.0 - math.exp(-2.0 * math.pi * loop.sensor_cutoff_hz * dt) if loop.sensor_cutoff_hz > 0 else 1.0
    n = 15
    X, V, Y = np.eye(n)[:6], np.eye(n)[6:12], np.eye(n)[12:15]
    E = np.zeros((6, n))  # δF^e of the state: contact spring and linearised friction
    E[2] = -loop.stiffness_n_per_m * X[2]
    E[:2] = dFt_dFn[:, None] * E[2] + dFt_dv @ V[:2]
    C = Y + alpha * (E[:3] - Y)  # y_k = y_{k−1} + α (F^e_k − y_{k−1})  [T] §IV-A
    V_free = V + dt * L_inv @ E  # semi-implicit Euler without the command
    A = np.vstack([X + dt * V_free, V_free, C])
    B = np.vstack([dt * dt * L_inv, dt * L_inv, np.zeros((3, 6))])
    u_m = -kp[:, None] * X[m_idx] - kd[:, None] * V[m_idx]  # [T11]
    kd_f = float(gains.force_kd if force_kd is None else force_kd)
    K_s = np.zeros((6, n))
    K_s[m_idx] = u_m
    K_s[2] = -kd_f * V[2]  # [T12]
    K_m = np.zeros((6, 3))
    K_m[2, 2] = gains.force_kp  # [T12]
    if gains.shaping:  # F_c,f = u_f + BᵀA⁻¹(u_m + ŷ_m)  [T7, T9, T10]
        P_d = terms.P_d[0]
        K_s[2] += P_d @ u_m
        for axis in (0, 1):
            K_m[2, axis] += P_d[int(np.flatnonzero(m_idx == axis)[0])]
    ki = float(gains.force_ki)
    c = 1 if ki > 0 else 0  # I_k = I_{k−1} + Δt ŷ_f, u_f += K_f^i I_k  [T12]
    A_c, B_c, C_c = np.eye(c), np.zeros((c, 3)), np.zeros((6, c))
    if c:
        B_c[0, 2] = dt
        C_c[2, 0] = ki
    return SampledLoop(A, B, C, K_s, K_m, A_c, B_c, C_c)


def step_matrix(
    Lambda: np.ndarray,
    sub: Subspaces,
    gains: MotionForceGains,
    loop: ContactLoop,
    friction_dir: np.ndarray,
) -> np.ndarray:
    """One-step map Φ of the polish force loop with its latency (`force_loop_parts`, `delayed_loop`):
    (15, 15) without K_f^i and delays, plus 1 state for the integral, 3 per sensing delay period and 6
    per actuation delay period."""
    return _step_map(Lambda, sub, gains, loop, friction_dir)(float(gains.force_kd))


def _step_map(
    Lambda: np.ndarray,
    sub: Subspaces,
    gains: MotionForceGains,
    loop: ContactLoop,
    friction_dir: np.ndarray,
) -> Callable[[float], np.ndarray]:
    """Φ as a function of K_f^d: Φ is affine in K_f^d (it enters the command linearly), so two maps
    give every other, and a search over K_f^d builds nothing more."""
    ds, da = loop.sensing_delay_steps, loop.actuation_delay_steps
    phi0 = delayed_loop(force_loop_parts(Lambda, sub, gains, loop, friction_dir, force_kd=0.0), ds, da)
    phi1 = delayed_loop(force_loop_parts(Lambda, sub, gains, loop, friction_dir, force_kd=1.0), ds, da)
    slope = phi1 - phi0
    return lambda force_kd: phi0 + force_kd * slope


def loop_rate(
    Lambda: np.ndarray, sub: Subspaces, gains: MotionForceGains, loop: ContactLoop, friction_dir: np.ndarray
) -> float:
    """σ = −ln ρ(Φ)/Δt (1/s) of the loop at the gains' own K_f^d: one map and one eigenvalue problem
    (the cheap figure the page recomputes ten times a simulated second)."""
    parts = force_loop_parts(Lambda, sub, gains, loop, friction_dir)
    return decay_rate(delayed_loop(parts, loop.sensing_delay_steps, loop.actuation_delay_steps), loop.dt)


def directional_coupling(Lambda: np.ndarray, sub: Subspaces, friction_dir: np.ndarray) -> float:
    """P_d·f̂ [T10]: the force-subspace wrench shaping adds per unit friction wrench along f̂ (xy)."""
    terms = coupling_terms(Lambda, np.linalg.inv(Lambda), sub, exact_inverse=False)
    f_hat = np.asarray(friction_dir, dtype=float) / np.linalg.norm(friction_dir)
    m_idx = list(sub.motion_axes)
    return float(terms.P_d[0, m_idx.index(0)] * f_hat[0] + terms.P_d[0, m_idx.index(1)] * f_hat[1])


def decay_rate(phi: np.ndarray, dt: float) -> float:
    """σ = −ln ρ(Φ)/Δt (1/s): the slowest mode's decay rate, < 0 when it grows."""
    rho = _spectral_radius(phi)
    return -math.log(rho) / dt if rho > 0 else math.inf


def force_loop_margin(
    Lambda: np.ndarray,
    sub: Subspaces,
    gains: MotionForceGains,
    loop: ContactLoop,
    friction_dir: np.ndarray,
    find_kd: bool = True,
) -> Margin:
    """The `Margin` of one posture (its Λx) for one friction direction (module docstring)."""
    phi = _step_map(Lambda, sub, gains, loop, friction_dir)
    rho, freq = dominant_mode(phi(float(gains.force_kd)), loop.dt)
    kd_crit = _critical_kd(phi, gains.force_kd) if find_kd else None
    return Margin(-math.log(rho) / loop.dt, rho, directional_coupling(Lambda, sub, friction_dir), kd_crit, freq)


def dominant_mode(phi: np.ndarray, dt: float) -> tuple[float, float]:
    """(ρ(Φ), frequency in Hz) of the eigenvalue of largest modulus λ: |λ| and |arg λ|/(2π Δt)."""
    w = np.linalg.eigvals(phi)
    lam = w[int(np.argmax(np.abs(w)))]
    return float(abs(lam)), float(abs(np.angle(lam)) / (2.0 * math.pi * dt))


def _critical_kd(
    phi: Callable[[float], np.ndarray], force_kd: float, kd_max: float = 2000.0, tol: float = 0.5
) -> float | None:
    def stable(kd: float) -> bool:
        return _spectral_radius(phi(float(kd))) < 1.0

    hi: float | None = force_kd if stable(force_kd) else None
    if hi is None:
        hi = next((float(k) for k in np.arange(force_kd, kd_max + 1e-9, 25.0) if stable(float(k))), None)
    if hi is None:
        return None
    if stable(0.0):
        return 0.0
    lo = 0.0
    while hi - lo > tol:
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if stable(mid) else (mid, hi)
    return hi


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
        pd_dir.append(directional_coupling(Lambda, sub, f_hat))
    return PostureMargin(gains.force_kd - worst[0], float(worst[0]), worst[1], worst[2], tuple(pd_dir), tuple(crit_dir))
