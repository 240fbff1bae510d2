"""Motion/force subspaces and the dynamics coupling between them [T 6, 9, 10, 19-27].

The 6-D task [px py pz rx ry rz] (TCP, LOCAL_WORLD_ALIGNED) is split into a force subspace
(rows picked by S_f) and a motion subspace (S_m) [T19]. With Λx blocked as [[A, B], [Bᵀ, D]] in
(motion, force) order [T6, T20], three projection matrices measure the coupling (Table I):

- P_f = S_f Λx⁻¹ S_mᵀ        force-subspace acceleration per unit motion-subspace wrench,
- P_a = S_f Λx S_mᵀ = Bᵀ     force-subspace wrench per unit motion-subspace acceleration,
- P_d = Bᵀ A⁻¹               disturbance that inertia shaping adds [T10],

and W = ‖P‖²_F [T22] with gradients [T24-27] from ∂Λx/∂q. Everything here is a pure function
of arrays (plus a `Dynamics` snapshot), shared by the controller, the experiments and the UI.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from control.kernels.chain import inertia_contraction_fused
from control.kernels.coupling import coupling_fused, coupling_weights_reference
from control.kernels.gradients import OBJECTIVE_CODES, gradient_contraction_fused, gradient_contraction_reference
from control.model import Dynamics, RobotModel

AXIS_NAMES = ("px", "py", "pz", "rx", "ry", "rz")
OBJECTIVES = ("j", "f", "a", "d")
COUPLING_OBJECTIVES = ("f", "a", "d")


# ---- subspaces [T19] ------------------------------------------------------------------------
@dataclass(frozen=True)
class Subspaces:
    """Selection of force and motion axes of the 6-D task [T19].

    `force_axes` and `motion_axes` are task indices (0..5) in ascending order; together they
    cover all six axes once. `S_f` (n_f×6) and `S_m` (n_m×6) are the selection matrices and
    `perm` = motion_axes + force_axes orders a task vector as [x_m; x_f] [T6].
    """

    force_axes: tuple[int, ...]
    motion_axes: tuple[int, ...]
    S_f: np.ndarray
    S_m: np.ndarray
    perm: np.ndarray
    perm_flat: np.ndarray  # flat indices that permute a 6×6 matrix to (motion, force) order

    @classmethod
    def from_force_axes(cls, axes: Sequence[int | str] = ("pz",)) -> Subspaces:
        """Build from force axes given as indices or names ("px".."rz"); the rest is motion."""
        idx: list[int] = []
        for a in axes:
            if isinstance(a, str):
                if a not in AXIS_NAMES:
                    raise ValueError(f"unknown task axis {a!r}; use one of {', '.join(AXIS_NAMES)}")
                idx.append(AXIS_NAMES.index(a))
            else:
                if not 0 <= int(a) < 6:
                    raise ValueError(f"task axis index {a} outside 0..5")
                idx.append(int(a))
        force = tuple(sorted(set(idx)))
        if len(force) != len(idx):
            raise ValueError(f"force axes repeat: {list(axes)}")
        if not 1 <= len(force) <= 5:
            raise ValueError("the force subspace needs between 1 and 5 axes")
        motion = tuple(i for i in range(6) if i not in force)
        eye = np.eye(6)
        perm = np.array(motion + force)
        perm_flat = (perm[:, None] * 6 + perm[None, :]).ravel()
        return cls(force, motion, eye[list(force)], eye[list(motion)], perm, perm_flat)

    @property
    def n_f(self) -> int:
        """Dimension of the force subspace."""
        return len(self.force_axes)

    @property
    def n_m(self) -> int:
        """Dimension of the motion subspace."""
        return len(self.motion_axes)

    def names(self) -> tuple[tuple[str, ...], tuple[str, ...]]:
        """(motion axis names, force axis names)."""
        return tuple(AXIS_NAMES[i] for i in self.motion_axes), tuple(AXIS_NAMES[i] for i in self.force_axes)


POLISH_SUBSPACES = Subspaces.from_force_axes(("pz",))


# ---- blocks and projections [T6, T9, T10, T20, Table I] ----------------------------------------
class CouplingTerms(NamedTuple):
    """Blocks of Λx and the coupling projections at one posture."""

    A: np.ndarray  # (n_m, n_m) motion-subspace inertia S_m Λx S_mᵀ [T20]
    B: np.ndarray  # (n_m, n_f) coupling block; Bᵀ = S_f Λx S_mᵀ [T20]
    D: np.ndarray  # (n_f, n_f) force-subspace inertia
    A_inv: np.ndarray  # (n_m, n_m)
    D_hat: np.ndarray  # (n_f, n_f) D − Bᵀ A⁻¹ B [T9]
    P_f: np.ndarray  # (n_f, n_m) S_f Λx⁻¹ S_mᵀ (Table I)
    P_a: np.ndarray  # (n_f, n_m) Bᵀ (Table I)
    P_d: np.ndarray  # (n_f, n_m) Bᵀ A⁻¹ (Table I, [T10])


def coupling_terms(
    Lambda: np.ndarray, Lambda_inv: np.ndarray, sub: Subspaces, exact_inverse: bool = True
) -> CouplingTerms:
    """Blocks A, B, D [T6, T20], D̂ [T9] and the projections P_f, P_a, P_d (Table I).

    With `exact_inverse` (Λx⁻¹ really is the inverse of Λx, i.e. away from singularities) the
    block-inverse identities give the rest without a matrix inversion: with L = Λx⁻¹,
    D̂ = L_ff⁻¹, BᵀA⁻¹ = −D̂ L_fm and A⁻¹ = L_mm − L_mf D̂ L_fm.
    """
    A, B, D, A_inv, D_hat, P_f, P_a, P_d, _, _, _ = coupling_fused(
        Lambda, Lambda_inv, sub.perm, sub.n_m, exact_inverse, SI_SCALE
    )  # compiled `control.kernels.coupling.coupling_reference`
    return CouplingTerms(A, B, D, A_inv, D_hat, P_f, P_a, P_d)


SI_SCALE = np.ones(6)  # W in SI units (writeable: the compiled kernels take one array type; never written)


def task_scale(length_m: float = 0.0, mass_kg: float = 1.0) -> np.ndarray:
    """Scale s (6,) of the task coordinates in which W_f, W_a, W_d are taken (`coupling_fused`).

    Λ̃x = diag(s) Λx diag(s) with s = 1/√m_c on [px py pz] and 1/(L_c √m_c) on [rx ry rz]: the
    inertia of the coordinates √m_c [p; L_c r] (a rotation counted as the arc it sweeps at radius
    L_c). Every entry of Λ̃x then has the unit kg·m²/(kg·m²) = 1, so the translational and
    rotational terms of ‖P‖²_F [T22] add like with like. `length_m` = 0 leaves rotations in radians
    (s = 1/√m_c everywhere); (0, 1) gives ones, W as [T22].
    """
    if not (np.isfinite(length_m) and length_m >= 0.0):
        raise ValueError(f"the characteristic length must be ≥ 0 m (0: off), got {length_m}")
    if not (np.isfinite(mass_kg) and mass_kg > 0.0):
        raise ValueError(f"the characteristic mass must be > 0 kg, got {mass_kg}")
    s_lin = 1.0 / np.sqrt(mass_kg)
    s_rot = s_lin / length_m if length_m > 0.0 else s_lin
    return np.array([s_lin, s_lin, s_lin, s_rot, s_rot, s_rot])


def terms_of(dyn: Dynamics, sub: Subspaces) -> CouplingTerms:
    """`coupling_terms` of a `Dynamics` snapshot."""
    return coupling_terms(dyn.Lambda, dyn.Lambda_inv, sub, exact_inverse=not dyn.near_singular)


def terms_and_values(
    dyn: Dynamics, sub: Subspaces, scale: np.ndarray = SI_SCALE
) -> tuple[CouplingTerms, tuple[float, float, float]]:
    """`terms_of` and (W_f, W_a, W_d) = ‖P‖²_F [T22] from the same compiled call, in the task
    coordinates of `scale` (`task_scale`; ones: SI units as [T])."""
    *blocks, W_f, W_a, W_d = coupling_fused(dyn.Lambda, dyn.Lambda_inv, sub.perm, sub.n_m, not dyn.near_singular, scale)
    return CouplingTerms(*blocks), (W_f, W_a, W_d)


def partially_decoupled_inertia(Lambda: np.ndarray, sub: Subspaces) -> np.ndarray:
    """Λ̂x = [[A, B], [0, D − BᵀA⁻¹B]] [T9], returned in task order (6×6)."""
    t = coupling_terms(Lambda, np.linalg.inv(Lambda), sub, exact_inverse=False)
    n_m = sub.n_m
    blocked = np.zeros((6, 6))
    blocked[:n_m, :n_m] = t.A
    blocked[:n_m, n_m:] = t.B
    blocked[n_m:, n_m:] = t.D_hat
    return _unpermute(blocked, sub)


def disturbance_projection(Lambda: np.ndarray, sub: Subspaces) -> np.ndarray:
    """I − Λ̂x Λx⁻¹ = [[0, 0], [BᵀA⁻¹, 0]] [T10], in task order (6×6)."""
    t = coupling_terms(Lambda, np.linalg.inv(Lambda), sub, exact_inverse=False)
    blocked = np.zeros((6, 6))
    blocked[sub.n_m :, : sub.n_m] = t.P_d
    return _unpermute(blocked, sub)


def _unpermute(blocked: np.ndarray, sub: Subspaces) -> np.ndarray:
    """A 6×6 matrix in (motion, force) order back to task order."""
    out = np.empty((6, 6))
    out[np.ix_(sub.perm, sub.perm)] = blocked
    return out


# ---- objectives [T18, T22] and gradients [T24-27] ----------------------------------------------
def projection(terms: CouplingTerms, objective: str) -> np.ndarray:
    """The projection matrix P of a coupling objective "f", "a" or "d" (Table I)."""
    if objective == "f":
        return terms.P_f
    if objective == "a":
        return terms.P_a
    if objective == "d":
        return terms.P_d
    raise ValueError(f"unknown coupling objective {objective!r}; use f, a or d")


def coupling_weights(sub: Subspaces, scale: np.ndarray = SI_SCALE) -> dict[str, np.ndarray]:
    """Per objective "f"/"a"/"d" the weights w (n_f, n_m) with W = Σ w ∘ P² in the task
    coordinates of `scale` (`task_scale`; ones: ‖P‖²_F [T22])."""
    w_f, w_a, w_d = coupling_weights_reference(np.asarray(scale, dtype=float), sub.perm, sub.n_m)
    return {"f": w_f, "a": w_a, "d": w_d}


def coupling_values(
    terms: CouplingTerms, scale: np.ndarray | None = None, sub: Subspaces | None = None
) -> dict[str, float]:
    """W_f, W_a, W_d = ‖P‖²_F [T22] at one posture; with `scale` (and its `sub`) in the task
    coordinates of `task_scale`."""
    w: dict[str, float] | dict[str, np.ndarray] = {"f": 1.0, "a": 1.0, "d": 1.0}
    if scale is not None:
        if sub is None:
            raise ValueError("coupling_values with a scale needs the subspaces")
        w = coupling_weights(sub, scale)
    return {
        "W_f": float(np.sum(w["f"] * terms.P_f * terms.P_f)),
        "W_a": float(np.sum(w["a"] * terms.P_a * terms.P_a)),
        "W_d": float(np.sum(w["d"] * terms.P_d * terms.P_d)),
    }


def joint_objective(q: np.ndarray, q_desired: np.ndarray) -> tuple[float, np.ndarray]:
    """W_j = ½ (q − q_d)ᵀ(q − q_d) and its gradient q − q_d [T18]."""
    e = np.asarray(q, dtype=float) - q_desired
    return 0.5 * float(e @ e), e


def coupling_gradient(
    terms: CouplingTerms,
    Lambda_inv: np.ndarray,
    dLambda: np.ndarray,
    sub: Subspaces,
    objective: str,
    scale: np.ndarray = SI_SCALE,
) -> tuple[float, np.ndarray]:
    """W = ‖P‖²_F [T22] and ∂W/∂q [T23-24] for objective "f", "a" or "d".

    Each ∂P/∂q_k has the form L ∂Λx_k R [T25-27], so ∂W/∂q_k = Σ 2 P ∘ (L ∂Λx_k R)
    = 2 ⟨∂Λx_k, Lᵀ P Rᵀ⟩ [T24]: one (n, 36) @ (36,) product for all joints. With `scale`
    (`task_scale`) W = Σ w ∘ P² and P in the contraction becomes w ∘ P.
    """
    m, f = sub.motion_axes, sub.force_axes
    if objective == "f":  # [T25] ∂P_f = −S_f Λx⁻¹ ∂Λx Λx⁻¹ S_mᵀ
        P = terms.P_f
        left = -Lambda_inv[list(f), :]  # (n_f, 6)
        right = Lambda_inv[:, list(m)]  # (6, n_m)
    elif objective == "a":  # [T26] ∂P_a = S_f ∂Λx S_mᵀ
        P = terms.P_a
        left = sub.S_f
        right = sub.S_m.T
    elif objective == "d":  # [T27] ∂P_d = (S_f − BᵀA⁻¹S_m) ∂Λx S_mᵀ A⁻¹
        P = terms.P_d
        left = sub.S_f - P @ sub.S_m
        right = sub.S_m.T @ terms.A_inv
    else:
        raise ValueError(f"unknown coupling objective {objective!r}; use f, a or d")
    w = coupling_weights(sub, scale)[objective]
    G = left.T @ (w * P) @ right.T  # (6, 6)
    n = dLambda.shape[0]
    grad = 2.0 * (dLambda.reshape(n, 36) @ G.reshape(36))  # [T24]
    return float(np.sum(w * P * P)), grad


def objective_gradient(
    objective: str,
    dyn: Dynamics,
    sub: Subspaces,
    model: RobotModel | None = None,
    q_desired: np.ndarray | None = None,
    terms: CouplingTerms | None = None,
    scale: np.ndarray = SI_SCALE,
) -> tuple[float, np.ndarray]:
    """(W, ∂W/∂q) for objective "j" [T18] or "f"/"a"/"d" [T22-27] at a snapshot.

    "j" needs `q_desired`; the coupling objectives need `model` for the analytic ∂Λx/∂q;
    `scale` (`task_scale`) gives their units.
    """
    if objective == "j":
        if q_desired is None:
            raise ValueError("objective 'j' needs q_desired")
        return joint_objective(dyn.q, q_desired)
    if model is None:
        raise ValueError(f"objective {objective!r} needs the RobotModel for ∂Λx/∂q")
    if terms is None:
        terms = terms_of(dyn, sub)
    return coupling_gradient(terms, dyn.Lambda_inv, model.dLambda_dq(dyn), sub, objective, scale)


def coupled_response(P_f: np.ndarray, force_motion: np.ndarray) -> np.ndarray:
    """Force-subspace acceleration P_f F_m coupled from a motion-subspace wrench F_m (Table I).

    With F_m the friction wrench (or its unit direction) this is the predicted coupled response
    that DESIGN §8 asks to report beside W: two postures with equal W_f can differ several-fold here.
    """
    return P_f @ np.asarray(force_motion, dtype=float)


# ---- geometry for overlays [T21] ---------------------------------------------------------------
def principal_axes(P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues σ_i (descending) and unit eigenvectors (columns) of P Pᵀ [T21].

    The image of the unit sphere under y = P v is the ellipsoid yᵀ(P Pᵀ)⁻¹y = 1 with semi-axes
    √σ_i along the eigenvectors; Σσ_i = ‖P‖²_F = W [T22].
    """
    S = P @ P.T
    w, V = np.linalg.eigh(0.5 * (S + S.T))
    order = np.argsort(w)[::-1]
    return np.clip(w[order], 0.0, None), V[:, order]


@functools.lru_cache(maxsize=16)
def unit_directions(dim: int, points: int = 64) -> np.ndarray:
    """Read-only samples (k, dim) of the unit sphere in 1, 2 or 3 dimensions: the two ends of a
    segment, `points` points around a circle (closed), or a latitude–longitude grid on a sphere."""
    if dim == 1:
        V = np.array([[-1.0], [1.0]])
    elif dim == 2:
        t = np.linspace(0.0, 2 * np.pi, points, endpoint=True)
        V = np.stack([np.cos(t), np.sin(t)], axis=1)
    else:
        rng = np.linspace(0.0, np.pi, max(points // 8, 4))
        az = np.linspace(0.0, 2 * np.pi, max(points // 4, 8))
        th, ph = np.meshgrid(rng, az)
        V = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], axis=-1).reshape(-1, 3)
    V.flags.writeable = False
    return V


def coupling_ellipse(P: np.ndarray, sub: Subspaces, scale: float = 1.0, points: int = 64) -> np.ndarray:
    """Points (k, 3) of the coupling ellipse in translational task space (DESIGN §6).

    The unit circle (or sphere) of the translational motion axes is mapped by v ↦ (v, s·P v):
    the motion components stay on the circle and the translational force axes receive s·P v.
    A decoupled posture gives a flat circle; coupling tilts it out of the motion plane.
    Returns an empty (0, 3) array when the motion subspace has no translational axis.
    """
    lin_m = [i for i, a in enumerate(sub.motion_axes) if a < 3]
    lin_f = [i for i, a in enumerate(sub.force_axes) if a < 3]
    if not lin_m:
        return np.zeros((0, 3))
    V = unit_directions(len(lin_m), points)
    out = np.zeros((V.shape[0], 3))
    for col, i in enumerate(lin_m):
        out[:, sub.motion_axes[i]] = V[:, col]
    if lin_f:
        v_full = np.zeros((V.shape[0], sub.n_m))
        v_full[:, lin_m] = V
        y = scale * (v_full @ P.T)  # (k, n_f)
        for j in lin_f:
            out[:, sub.force_axes[j]] = y[:, j]
    return out


# ---- swivel scan (DESIGN §8) -------------------------------------------------------------------
class SwivelScan(NamedTuple):
    """Coupling objectives along the self-motion loop at a fixed TCP pose."""

    swivel_rad: np.ndarray  # (k,) elbow swivel angle, 0 = elbow straight up, unwrapped from the start
    q: np.ndarray  # (k, n) joint positions along the loop
    W_f: np.ndarray  # (k,)
    W_a: np.ndarray  # (k,)
    W_d: np.ndarray  # (k,)
    within_limits: np.ndarray  # (k,) bool: every joint inside its position limits (angles modulo 2π)
    closed: bool  # the trace came back to its start (a full loop)


def swivel_angle(model: RobotModel, q: np.ndarray) -> float:
    """Elbow swivel angle (rad) about the shoulder–wrist line; 0 = elbow straight up.

    Shoulder, elbow and wrist are the origins of joints 2, 4 and 6. The angle is measured from
    the world +z direction projected on the plane normal to the shoulder→wrist axis, positive
    by the right-hand rule about that axis.
    """

    origins = model.joint_origins(q)
    s, e, w = origins[2], origins[4], origins[6]
    u = w - s
    u = u / np.linalg.norm(u)
    ref = np.array([0.0, 0.0, 1.0]) - u[2] * u
    if np.linalg.norm(ref) < 1e-9:  # shoulder→wrist vertical: use world +x instead
        ref = np.array([1.0, 0.0, 0.0]) - u[0] * u
    ref = ref / np.linalg.norm(ref)
    d = (e - s) - ((e - s) @ u) * u
    return float(np.arctan2(u @ np.cross(ref, d), ref @ d))


def _pose_error(model: RobotModel, q: np.ndarray, target_pos: np.ndarray, target_rot: np.ndarray) -> np.ndarray:
    import pinocchio as pin

    pose = model.frame_pose(q, "tcp")
    err_rot = pin.log3(target_rot @ pose.rotation.T)
    return np.concatenate([target_pos - pose.translation, err_rot])


def project_to_pose(
    model: RobotModel, q: np.ndarray, target_pos: np.ndarray, target_rot: np.ndarray, iters: int = 20
) -> np.ndarray:
    """Gauss-Newton steps with J⁺ that bring the TCP of q onto a pose (a few iterations suffice)."""
    q = np.array(q, dtype=float)
    for _ in range(iters):
        e = _pose_error(model, q, target_pos, target_rot)
        if np.linalg.norm(e) < 1e-10:
            break
        J = model.tcp_jacobian(q)
        step = J.T @ np.linalg.solve(J @ J.T + 1e-8 * np.eye(6), e)  # damped least squares
        norm = float(np.linalg.norm(step))
        q = q + (step if norm < 0.2 else step * (0.2 / norm))
    return q


def swivel_scan(
    model: RobotModel,
    q_start: np.ndarray,
    sub: Subspaces,
    q_lower: np.ndarray,
    q_upper: np.ndarray,
    step_rad: float = np.deg2rad(3.0),
    max_steps: int = 400,
    max_joint_step: float = 0.05,
    scale: np.ndarray | None = None,
) -> SwivelScan:
    """Trace the self-motion loop through q_start at its TCP pose and evaluate W_f, W_a, W_d
    (in the task coordinates of `scale`, `task_scale`, when given; SI units otherwise).

    Predictor–corrector continuation: step along the kernel of J (signed so the swivel angle
    grows), pull back onto the pose with Gauss-Newton, until the swivel angle has advanced by a
    full turn. Joint limits are not enforced; `within_limits` marks the feasible part.
    """
    q = np.array(q_start, dtype=float)
    pose = model.frame_pose(q, "tcp")
    p0, R0 = pose.translation.copy(), pose.rotation.copy()
    psi0 = swivel_angle(model, q)
    qs, psis = [q.copy()], [psi0]
    closed = False
    total = 0.0
    for _ in range(max_steps):
        J = model.tcp_jacobian(q)
        _, _, Vt = np.linalg.svd(J)
        n = Vt[-1]
        # scale the joint step so the swivel advances by about step_rad
        h = 1e-4
        dpsi = _wrap(swivel_angle(model, q + h * n) - psis[-1]) / h
        if abs(dpsi) < 1e-9:
            break
        dq = (step_rad / dpsi) * n
        norm = float(np.linalg.norm(dq))
        if norm > max_joint_step:  # near a shoulder/wrist alignment the swivel moves slowly
            dq *= max_joint_step / norm
        q_new = project_to_pose(model, q + dq, p0, R0)
        total += _wrap(swivel_angle(model, q_new) - psis[-1])
        q = q_new
        if total >= 2 * np.pi - 1e-9:
            closed = True
            break
        qs.append(q.copy())
        psis.append(psi0 + total)
    Q = np.array(qs)
    W = np.empty((len(Q), 3))
    for i, qi in enumerate(Q):
        vals = coupling_values(terms_of(model.compute(qi, np.zeros(len(qi))), sub), scale, sub)
        W[i] = vals["W_f"], vals["W_a"], vals["W_d"]
    inside = np.all(within_limits_mod_2pi(Q, q_lower, q_upper), axis=1)
    return SwivelScan(np.array(psis), Q, W[:, 0], W[:, 1], W[:, 2], inside, closed)


def flow_minimum(values: np.ndarray, feasible: np.ndarray, start: int = 0, closed: bool = True) -> int:
    """Index where a gradient flow from `start` settles along a sampled self-motion loop.

    In one dimension the flow of [T15] walks downhill: towards the neighbour with the smaller W,
    then on while W keeps falling. It stops at a local minimum, or before a sample outside the
    joint limits (the dampers stop it there). `closed`: the last sample neighbours the first.
    """
    W = np.asarray(values, dtype=float)
    ok = np.asarray(feasible, dtype=bool)
    k = len(W)
    assert ok.shape == (k,) and 0 <= start < k

    def neighbour(i: int, d: int) -> int | None:
        j = i + d
        if closed:
            return j % k
        return j if 0 <= j < k else None

    best_dir, best_value = 0, W[start]
    for d in (-1, 1):
        j = neighbour(start, d)
        if j is not None and ok[j] and W[j] < best_value:
            best_dir, best_value = d, W[j]
    i = start
    for _ in range(k):
        if best_dir == 0:
            break
        j = neighbour(i, best_dir)
        if j is None or not ok[j] or W[j] >= W[i] or j == start:
            break
        i = j
    return i


def within_limits_mod_2pi(q: np.ndarray, q_lower: np.ndarray, q_upper: np.ndarray) -> np.ndarray:
    """Per joint: True if q, q − 2π or q + 2π lies inside [q_lower, q_upper].

    A revolute joint's angle is only defined modulo 2π: the continuation of the swivel scan may
    leave the interval of the limits while an equivalent angle lies inside it.
    """
    two_pi = 2.0 * np.pi
    return (
        ((q >= q_lower) & (q <= q_upper))
        | ((q - two_pi >= q_lower) & (q - two_pi <= q_upper))
        | ((q + two_pi >= q_lower) & (q + two_pi <= q_upper))
    )


def _wrap(a: float) -> float:
    return float((a + np.pi) % (2 * np.pi) - np.pi)


def move_to_swivel(
    model: RobotModel, q: np.ndarray, swivel_target_rad: float, iters: int = 200, tol_rad: float = 1e-6
) -> np.ndarray:
    """The posture on the self-motion loop through q (same TCP pose) with the given swivel angle.

    Newton steps on the swivel angle along the kernel of J (at most 0.05 rad per joint step),
    each followed by a pull-back onto the TCP pose. Raises ValueError if it does not converge.
    """
    q = np.array(q, dtype=float)
    pose = model.frame_pose(q, "tcp")
    p0, R0 = pose.translation.copy(), pose.rotation.copy()
    for _ in range(iters):
        err = _wrap(swivel_target_rad - swivel_angle(model, q))
        if abs(err) < tol_rad:
            return q
        _, _, Vt = np.linalg.svd(model.tcp_jacobian(q))
        n = Vt[-1]
        h = 1e-5
        dpsi = _wrap(swivel_angle(model, q + h * n) - swivel_angle(model, q)) / h
        if abs(dpsi) < 1e-9:
            break
        dq = (err / dpsi) * n
        norm = float(np.linalg.norm(dq))
        if norm > 0.05:
            dq *= 0.05 / norm
        q = project_to_pose(model, q + dq, p0, R0)
    raise ValueError(f"could not reach swivel angle {np.rad2deg(swivel_target_rad):.1f}° at this TCP pose")


def k0_for_speed(
    model: RobotModel, scan: SwivelScan, sub: Subspaces, objective: str, speed_rad_s: float = 0.3
) -> float:
    """k0 such that k0 · RMS‖(I − J⁺J)∇W‖ over the feasible part of a swivel scan = speed.

    The rule behind the default k0 of each coupling objective (see `NullspaceGains`): it makes
    the gradient flow of [T15] move the posture at a comparable joint speed for objectives
    whose units differ by orders of magnitude.
    """
    norms = []
    for q, ok in zip(scan.q, scan.within_limits, strict=True):
        if not ok:
            continue
        dyn = model.compute(q, np.zeros(len(q)))
        _, grad = objective_gradient(objective, dyn, sub, model)
        J = dyn.J
        grad_kernel = grad - J.T @ np.linalg.solve(J @ J.T, J @ grad)
        norms.append(float(np.linalg.norm(grad_kernel)))
    if not norms:
        raise ValueError("the swivel scan has no posture inside the joint limits")
    return speed_rad_s / float(np.sqrt(np.mean(np.square(norms))))


def coupling_gradient_direct(
    model: RobotModel,
    dyn: Dynamics,
    terms: CouplingTerms,
    sub: Subspaces,
    objective: str,
    scale: np.ndarray = SI_SCALE,
) -> tuple[float, np.ndarray]:
    """W and ∂W/∂q [T24-27] without forming ∂Λx/∂q: same result as `coupling_gradient`, cheaper.

    With ∂W/∂q_k = 2⟨∂Λx_k, G⟩ and ∂Λx_k = −Λx ∂(Λx⁻¹)_k Λx, ∂(Λx⁻¹)_k = ∂J_k X + Xᵀ∂J_kᵀ − Xᵀ∂M_k X
    (X = M⁻¹Jᵀ), the gradient is −2(⟨∂J_k, (H + Hᵀ)Xᵀ⟩ − ⟨∂M_k, X H Xᵀ⟩) with H = Λx G Λx. G has
    rank ≤ n_f, so X H Xᵀ = Σ_c a_c b_cᵀ and each ⟨∂M_k, a bᵀ⟩ = aᵀ ∂(M b)/∂q_k comes from one
    RNEA-derivative call: n_f calls instead of six. On a serial revolute chain both parts run in
    compiled kernels (`control.kernels`, each tested against its reference: Pinocchio's Hessian and
    RNEA derivatives). `scale` (`task_scale`) gives W's units: W = Σ w ∘ P².
    """

    P = projection(terms, objective)
    w = coupling_weights(sub, scale)[objective]  # [T25-27]: left and right factors are built in the kernel
    if model.revolute_chain:  # compiled, ∂J from J itself
        term_J, A_, B_ = gradient_contraction_fused(
            OBJECTIVE_CODES[objective], dyn.J, dyn.M_inv, dyn.Lambda, dyn.Lambda_inv, P, terms.A_inv, sub.perm, sub.n_m,
            w,
        )  # fmt: skip
    else:
        term_J, A_, B_ = gradient_contraction_reference(
            objective, dyn.J, model.tcp_jacobian_derivative(dyn.q), dyn.M_inv, dyn.Lambda, dyn.Lambda_inv,
            P, terms.A_inv, sub.perm, sub.n_m, w,
        )  # fmt: skip
    term_M = np.zeros(len(dyn.q))
    for c in range(A_.shape[1]):  # [k] = aᵀ ∂(M b)/∂q_k
        if model.revolute_chain:  # compiled, from the chain's kinematics and inertias
            term_M += inertia_contraction_fused(dyn.q, *model.chain, A_[:, c], B_[:, c])  # type: ignore[call-arg]
        else:  # RNEA derivatives at q̇ = 0, no gravity
            term_M += model.mass_matrix_derivative_times(dyn.q, B_[:, c]).T @ A_[:, c]
    return float(np.sum(w * P * P)), -2.0 * (term_J - term_M)
