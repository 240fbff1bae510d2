"""What the 3D scene shows, copied out of a running Session between two simulation steps.

The loop thread calls `capture(session)` at 30–60 Hz; the publisher hands the result to
`SceneView.update`. A `SceneSnapshot` holds plain copies only (no view into MjData or the
Dynamics arrays), so the scene can read it on another thread while the simulation steps on.
The controller's part (objective, split, coupling terms, damper zone, QP status) comes from its
`view()` of the latest step; the coupling terms are computed here only for a controller that has
none (or when another split is asked for). Cost: about 0.1 ms (link poses, a few target samples).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import mujoco
import numpy as np

from control.bridge import GammaXSummary, gamma_x_matrix, gamma_x_summary
from control.coupling import POLISH_SUBSPACES, Subspaces, coupling_terms, coupling_values
from control.executor import StepView

PATH_HORIZON_S = 5.0  # how far ahead the commanded path is sampled
PATH_SAMPLES = 40
# Below this smallest eigenvalue of J M⁻¹ Jᵀ (an effective mass or inertia above 1000 kg or kg m²)
# the coupling projections blow up; the scene says "near a singularity" instead of drawing them.
NEAR_SINGULAR_EIG = 1e-3


@dataclass(frozen=True)
class SceneSnapshot:
    """Everything the scene and its overlays draw for one visual frame (world frame, SI units)."""

    t: float  # s, simulation time
    link_names: tuple[str, ...]
    link_positions: np.ndarray  # (L, 3) m, body origins
    link_wxyz: np.ndarray  # (L, 4) body orientations as quaternions (w, x, y, z)
    tcp_position: np.ndarray  # (3,)
    tcp_rotation: np.ndarray  # (3, 3) world ← tcp
    joint_margins: np.ndarray  # (7,) rad to the nearer position limit; inf for endless joints
    force_axes: tuple[int, ...]  # task indices of the force subspace [T19]
    motion_axes: tuple[int, ...]
    P: dict[str, np.ndarray]  # "P_f", "P_a", "P_d": (n_f, n_m) coupling projections (Table I)
    W: dict[str, float]  # "W_f", "W_a", "W_d" = ‖P‖²_F [T22]
    Lambda_translational: np.ndarray  # (3, 3) kg, translational block of Λx
    wrench_measured: np.ndarray  # (6,) F/T reading mapped to the TCP [f; m] (what the controller saw)
    drag_point: np.ndarray | None = None  # (3,) grabbed point
    drag_target: np.ndarray | None = None  # (3,) where the spring pulls it
    drag_force: np.ndarray | None = None  # (3,) N, applied spring force
    contact_point: np.ndarray | None = None  # (3,)
    contact_force: np.ndarray | None = None  # (3,) N, true contact force on the robot (normal + friction)
    contact_lost: bool = False  # the contact is lost now while the strokes run (`metrics.contact_lost`)
    # (k, 3) m: where the tool was at each contact loss of this run so far (`metrics.contact_loss_onsets`)
    contact_lifts: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    contact_lift_times: np.ndarray = field(default_factory=lambda: np.zeros(0))  # (k,) s, the losses' onsets
    target_position: np.ndarray | None = None  # (3,) current task target
    path: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # (k, 3) target over the next seconds
    table: tuple[np.ndarray, np.ndarray] | None = None  # (center, half sizes) of the table box
    objective: str | None = None  # nullspace objective of the controller: "j", "f", "a", "d" or None
    limit_zone: np.ndarray | None = None  # (7,) rad: the controller's damper distance d_i, if it has one
    near_singular: bool = False  # Λx damped or ill-conditioned (NEAR_SINGULAR_EIG): no coupling shapes
    payload_position: np.ndarray | None = None  # (3,) attached payload mass (mass-drop, limit-drop), if any
    payload_mass_kg: float = 0.0
    payload_body: int | None = None  # the payload's MuJoCo body id (the replay poses it with the arm)
    # what Γ_x = Λ̂x⁻¹Λx of the running [T] projection executor is computed from, on the first read of
    # `gamma_x_sym_eigs` / `gamma_x_skew` (by the reader, not on the loop thread): (Λx copy (6, 6), the
    # split its step used, shaping); None for other executors
    gamma_x_input: tuple[np.ndarray, Subspaces, bool] | None = None
    q: np.ndarray | None = None  # (7,) rad, joint positions (the self-motion preview starts from them)
    planned_q: np.ndarray | None = None  # (7,) rad: the planned posture now, when the scenario tracks a plan
    twin_link_positions: np.ndarray | None = None  # (L, 3) m: the twin arm's bodies (app.core.twin), if one runs
    twin_link_wxyz: np.ndarray | None = None  # (L, 4)
    twin_objective: str | None = None  # "j", "f", "a" or "d"
    twin_W: dict[str, float] = field(default_factory=dict)  # the twin's "W" (its own objective), W_f, W_a, W_d
    step: StepView | None = None  # the controller's view of its latest step (QP status, backend, …)

    @cached_property
    def subspaces(self) -> Subspaces:
        """The force/motion split of this frame."""
        return split_of(self.force_axes)

    @cached_property
    def _gamma_x(self) -> GammaXSummary | None:
        """Γ_x of the projection executor on the split its step used, summarised (control.bridge)."""
        if self.gamma_x_input is None:
            return None
        Lambda, sub, shaping = self.gamma_x_input
        try:
            return gamma_x_summary(gamma_x_matrix(Lambda, sub, shaping=shaping))
        except np.linalg.LinAlgError:
            return None

    @property
    def gamma_x_sym_eigs(self) -> np.ndarray | None:
        """(6,) real eigenvalues of ½(Γ_x + Γ_xᵀ), projection executor only."""
        summary = self._gamma_x
        return None if summary is None else summary.sym_eigenvalues

    @property
    def gamma_x_skew(self) -> float | None:
        """‖½(Γ_x − Γ_xᵀ)‖₂ of Γ_x = Λ̂x⁻¹Λx, projection executor only."""
        summary = self._gamma_x
        return None if summary is None else summary.skew_norm

    def link_index(self, name: str) -> int:
        """Row of a link in `link_positions`."""
        return self.link_names.index(name)


_SPLITS: dict[tuple, Subspaces] = {}  # force axes → their Subspaces (a handful of splits ever occur)


def split_of(force_axes: tuple) -> Subspaces:
    """`Subspaces.from_force_axes(force_axes)`, built once per distinct tuple of axes."""
    sub = _SPLITS.get(force_axes)
    if sub is None:
        sub = _SPLITS[force_axes] = Subspaces.from_force_axes(force_axes)
    return sub


def subspaces_of(session, view: StepView | None = None) -> Subspaces:
    """The force/motion split the running controller's step used (its view), else pz only."""
    if view is not None and view.force_axes is not None:
        return split_of(tuple(view.force_axes))
    return POLISH_SUBSPACES


def capture(session, subspaces: Subspaces | None = None) -> SceneSnapshot:
    """Copy the scene state out of a `Session` (call between steps, on the loop thread)."""
    world = session.world
    robot = session.robot
    model, data = world.model, world.data
    names = tuple(robot.link_names)
    ids = world.body_ids(names)
    positions = data.xpos[ids].reshape(-1, 3)  # fancy indexing: copies
    wxyz = data.xquat[ids].reshape(-1, 4)

    q = world.q
    margins = np.minimum(q - robot.q_lower, robot.q_upper - q)
    margins = np.where(robot.endless, np.inf, margins)

    view = session.executor.view()  # what the step computed (built now, at the frame rate)
    sub = subspaces or subspaces_of(session, view)
    dyn = session.dyn
    if view.P is not None and view.force_axes == sub.force_axes and {"W_f", "W_a", "W_d"} <= set(view.W):
        P = {k: np.array(v) for k, v in view.P.items()}  # the step's own terms: not computed again
        W = {k: float(view.W[k]) for k in ("W_f", "W_a", "W_d")}
    else:  # the controller has no split (or another one is asked for): compute them here
        try:
            # near a singularity Λx⁻¹ is not the inverse of the damped Λx: the block identities would
            # divide by its zero force-axis entry (Gen3 stretched straight up, loaded without its sidecar)
            terms = coupling_terms(dyn.Lambda, dyn.Lambda_inv, sub, exact_inverse=not dyn.near_singular)
            P = {"P_f": terms.P_f.copy(), "P_a": terms.P_a.copy(), "P_d": terms.P_d.copy()}
            W = coupling_values(terms)
        except (np.linalg.LinAlgError, ZeroDivisionError):  # a singular block (diverged state): nothing to draw
            nan = np.full((sub.n_f, sub.n_m), np.nan)
            P = {"P_f": nan, "P_a": nan.copy(), "P_d": nan.copy()}
            W = {"W_f": float("nan"), "W_a": float("nan"), "W_d": float("nan")}

    last = session.last
    wrench = np.array(last.wrench_tcp, dtype=float) if last is not None else np.zeros(6)
    target_position = np.array(last.target.position, dtype=float) if last is not None else None

    drag = session.drag.state if session.drag.active else None
    overlay = _environment_overlay(session)
    return SceneSnapshot(
        t=float(world.time),
        link_names=names,
        link_positions=positions,
        link_wxyz=wxyz,
        tcp_position=np.array(dyn.tcp_position_world, dtype=float),
        tcp_rotation=np.array(dyn.tcp_rotation_world, dtype=float),
        joint_margins=margins,
        force_axes=sub.force_axes,
        motion_axes=sub.motion_axes,
        P=P,
        W=W,
        Lambda_translational=np.array(dyn.Lambda[:3, :3], dtype=float),
        wrench_measured=wrench,
        drag_point=None if drag is None else np.array(drag.point_world, dtype=float),
        drag_target=None if drag is None else np.array(drag.target_world, dtype=float),
        drag_force=None if drag is None else np.array(drag.force_world, dtype=float),
        contact_point=overlay.get("contact_point"),
        contact_force=overlay.get("contact_force"),
        **_contact_marks(session),
        target_position=target_position,
        path=_sample_path(session, float(world.time)),
        table=_table_box(model),
        objective=view.objective,
        limit_zone=_limit_zone(view, len(robot.joint_names)),
        step=view,
        near_singular=bool(dyn.near_singular or dyn.min_eig_Lambda_inv < NEAR_SINGULAR_EIG),
        q=q,
        planned_q=_planned_posture(last),
        **_payload(session),
        gamma_x_input=_gamma_x_input(view, dyn.Lambda),
    )


def _planned_posture(last) -> np.ndarray | None:
    """The posture the nullspace tracks when the scenario follows a planned path (its signal
    "swivel_plan_deg" is finite): the step target's q_posture; None otherwise."""
    if last is None or last.target.q_posture is None:
        return None
    plan = last.signals.get("swivel_plan_deg")
    if plan is None or not np.isfinite(plan):
        return None
    return np.array(last.target.q_posture, dtype=float)


def _gamma_x_input(view: StepView, Lambda: np.ndarray) -> tuple[np.ndarray, Subspaces, bool] | None:
    """What Γ_x of the running [T] projection executor is computed from (a copy of Λx, the split its
    step used, shaping); None for other executors."""
    if view.executor != "projection" or view.force_axes is None:
        return None
    shaping = True if view.shaping is None else view.shaping
    return np.array(Lambda, dtype=float), split_of(tuple(view.force_axes)), bool(shaping)


def _payload(session) -> dict:
    """Position and mass of an attached payload body of the environment (empty when none/released)."""
    env = getattr(session, "environment", None)
    body_id = getattr(env, "body_id", None)
    if not getattr(env, "attached", False) or not isinstance(body_id, int):
        return {}
    return {
        "payload_position": np.array(session.world.data.xipos[body_id], dtype=float),
        "payload_mass_kg": float(getattr(env, "mass_kg", 0.0)),
        "payload_body": body_id,
    }


def _contact_marks(session) -> dict:
    """Whether the environment's contact is lost now and where it was lost so far (empty without a contact)."""
    env = getattr(session, "environment", None)
    lifts = getattr(env, "lifts", None)
    if lifts is None:
        return {}
    kept = list(lifts)
    points = np.array([p for _, p in kept], dtype=float).reshape(-1, 3)
    times = np.array([t for t, _ in kept], dtype=float)
    lost = bool(getattr(env, "contact_lost", False))
    return {"contact_lost": lost, "contact_lifts": points, "contact_lift_times": times}


def _limit_zone(view: StepView, n: int) -> np.ndarray | None:
    """d_i per joint (rad) of the running controller's joint-limit damper (from its view)."""
    if view.limit_zone is None or view.limit_zone.shape != (n,) or not np.all(np.isfinite(view.limit_zone)):
        return None
    return np.array(view.limit_zone)


def _environment_overlay(session) -> dict[str, np.ndarray]:
    env = getattr(session, "environment", None)
    if env is None:
        return {}
    try:
        raw = env.overlay()
    except Exception:  # the overlay is decoration; never let it stop the scene
        return {}
    out = {}
    for key, value in raw.items():
        arr = np.array(value, dtype=float)
        if arr.shape == (3,) and np.all(np.isfinite(arr)):
            out[key] = arr
    return out


def _sample_path(session, t: float) -> np.ndarray:
    """The commanded TCP path: the target's own `path()` (k, 3) when it has one, else the target
    sampled over the next PATH_HORIZON_S seconds (empty if it does not move)."""
    target_fn = getattr(session, "target_fn", None)
    if target_fn is None:
        return np.zeros((0, 3))
    planned = getattr(target_fn, "path", None)
    if callable(planned):
        try:
            pts = np.array(planned(), dtype=float)
        except Exception:  # fall back to sampling
            pts = np.zeros((0, 3))
        if pts.ndim == 2 and pts.shape[1] == 3 and len(pts) >= 2 and np.all(np.isfinite(pts)):
            return pts
    try:
        times = t + np.linspace(0.0, PATH_HORIZON_S, PATH_SAMPLES)
        pts = np.array([np.asarray(target_fn(float(ti)).position, dtype=float) for ti in times])
    except Exception:  # a target that cannot be sampled ahead simply has no path drawn
        return np.zeros((0, 3))
    if pts.shape != (PATH_SAMPLES, 3) or not np.all(np.isfinite(pts)):
        return np.zeros((0, 3))
    if float(np.max(np.linalg.norm(pts - pts[0], axis=1))) < 1e-4:
        return np.zeros((0, 3))
    return pts


def _table_box(model: mujoco.MjModel) -> tuple[np.ndarray, np.ndarray] | None:
    gid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "table")
    if gid < 0:
        return None
    return np.array(model.geom_pos[gid], dtype=float), np.array(model.geom_size[gid], dtype=float)
