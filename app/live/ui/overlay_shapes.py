"""The overlays' geometry as pure functions of arrays (tested in tests/test_scene.py): the coupling
ellipse and its cap, the P Pᵀ and task-inertia ellipsoids, colours by magnitude and margin, arrows, the
contact ring and lift crosses on the table, and the TCP trail; `app.live.ui.overlays` draws them.

Coupling ellipse (DESIGN §6): the unit circle (sphere) of the translational motion axes is
mapped by v ↦ (v, s·P v) — the motion components stay, the translational force axes get s·P v.
It is a flat disc in the motion plane when P = 0 and tilts by atan(s·|P|) as coupling grows.
"""

from __future__ import annotations

from collections import deque

import numpy as np
import viser.transforms as vtf

from app.live.ui.snapshot import SceneSnapshot
from control.coupling import Subspaces, coupled_response, principal_axes

FLAT_THICKNESS = 0.02  # relative thickness of a flat ellipsoid (so it stays visible edge-on)
MIN_AXIS_M = 1e-3
# semi-axis cap: no overlay is more than 1 m across (a huge P near a singularity would engulf the camera)
MAX_AXIS_M = 0.5
PAYLOAD_RADIUS_M = 0.04  # drawn size of an attached payload mass (the sphere its inertia assumes)
# Coupling shapes sit 5 cm above the TCP (a surface under the tool cannot hide them), beside the tool.
LIFT_M = np.array([0.0, 0.0, 0.05])
COUPLING_OPACITY = 0.3  # the wrist and the tool stay visible through the disc
# the coupling shapes' largest semi-axis is at most this many times the unit circle's radius (the shape is
# scaled down as a whole, so its tilt stays): a strongly coupled posture stays beside the tool and in view
# instead of growing over the arm; the tilt, the colour and the label still say how strong it is
COUPLING_MAX_SPAN = 2.0
SIDE_GAP_M = 0.03  # gap between a coupling shape and a payload at the tool
LABEL_GAP_M = 0.01  # the coupling label sits this far above the disc's top (it moves with the disc)

CONTACT_RING_RADIUS_M = 0.035  # the ring on the table around the tool
CONTACT_RING_SEGMENTS = 32
LOST_RING_HOLD_S = 0.5  # the ring stays red this long (simulated) after a loss, however short the loss was
LIFT_MARK_HALF_M = 0.025  # half the span of a lift mark's cross
TABLE_GAP_M = 0.002  # contact marks sit this far above the table top (not hidden in its surface)
NORMAL_COLOR = (20, 160, 170)  # contact normal force
FRICTION_COLOR = (240, 200, 20)  # friction force
LOST_COLOR = (230, 30, 30)
IN_CONTACT_COLOR = (40, 190, 80)

GREEN = np.array([60, 200, 90], dtype=float)
YELLOW = np.array([240, 200, 40], dtype=float)
RED = np.array([230, 50, 40], dtype=float)


# ---- geometry ----------------------------------------------------------------------------------
def coupling_map(P: np.ndarray, sub: Subspaces, scale: float) -> np.ndarray:
    """(3, k) linear map from the k translational motion axes to world space: v ↦ (v, s·P v).

    Columns are unit vectors of the motion axes plus s times the P entries on the translational
    force axes. k = 0 (empty map) when no translational axis is in the motion subspace.
    """
    lin_m = [i for i, a in enumerate(sub.motion_axes) if a < 3]
    L = np.zeros((3, len(lin_m)))
    for col, i in enumerate(lin_m):
        L[sub.motion_axes[i], col] = 1.0
        for j, a in enumerate(sub.force_axes):
            if a < 3:
                L[a, col] = scale * P[j, i]
    return L


def ellipsoid_of_map(L: np.ndarray, thickness: float = FLAT_THICKNESS) -> tuple[np.ndarray, np.ndarray]:
    """Semi-axes (3,) and rotation (3, 3, det +1) of the image of the unit ball under L (3, k).

    Semi-axes are the singular values of L along its left singular vectors; missing axes
    (k < 3) get `thickness` times the largest one so a flat ellipse stays a thin disc.
    """
    if L.shape[1] == 0:
        return np.zeros(3), np.eye(3)
    U, sv, _ = np.linalg.svd(L, full_matrices=True)
    axes = np.zeros(3)
    axes[: sv.size] = sv
    largest = float(np.max(axes)) if np.max(axes) > 0 else 1.0
    axes = np.maximum(axes, thickness * largest)
    R = U.copy()
    if np.linalg.det(R) < 0:
        R[:, 2] = -R[:, 2]
    return axes, R


def tilt_rad(P: np.ndarray, sub: Subspaces, scale: float) -> float:
    """Largest angle between the coupling ellipse's span and the motion subspace it lifts.

    The largest principal angle between range(v ↦ (v, s·P v)) and range(v ↦ (v, 0)); for one
    translational force axis it is atan(s·|P_t|), the tilt of the disc (0 when decoupled).
    """
    L = coupling_map(P, sub, scale)
    if L.shape[1] == 0:
        return 0.0
    E = coupling_map(P, sub, 0.0)
    Q, _ = np.linalg.qr(L)
    cosines = np.linalg.svd(E.T @ Q, compute_uv=False)
    return float(np.arccos(np.clip(np.min(cosines), -1.0, 1.0)))


def translational_force_ellipsoid(P: np.ndarray, sub: Subspaces) -> tuple[np.ndarray, np.ndarray] | None:
    """Semi-axes (3,) and rotation of the P Pᵀ ellipsoid [T21] on the translational force axes.

    Uses the rows of P on translational force axes; semi-axes are √σ_i of P Pᵀ. None when fewer
    than two translational force axes exist (one axis is a segment, drawn by the ellipse tilt).
    """
    rows = [j for j, a in enumerate(sub.force_axes) if a < 3]
    if len(rows) < 2:
        return None
    sigma, V = principal_axes(P[rows, :])
    E = np.zeros((3, len(rows)))  # embeds the force rows in world xyz
    for col, j in enumerate(rows):
        E[sub.force_axes[j], col] = 1.0
    L = E @ V @ np.diag(np.sqrt(sigma))
    return ellipsoid_of_map(L)


def inertia_ellipsoid(Lambda_t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Principal masses (kg, descending) and axes of the translational task inertia (3×3)."""
    w, V = np.linalg.eigh(0.5 * (Lambda_t + Lambda_t.T))
    order = np.argsort(w)[::-1]
    R = V[:, order]
    if np.linalg.det(R) < 0:
        R[:, 2] = -R[:, 2]
    return np.clip(w[order], 0.0, None), R


def measured_coupled_response(snap: SceneSnapshot) -> np.ndarray:
    """World vector (m/s²) of P_f F_m: force-axis acceleration from the measured motion wrench."""
    sub = snap.subspaces
    F_m = snap.wrench_measured[list(sub.motion_axes)]
    accel = coupled_response(snap.P["P_f"], F_m)
    out = np.zeros(3)
    for j, a in enumerate(sub.force_axes):
        if a < 3:
            out[a] = accel[j]
    return out


def magnitude_color(x: float) -> tuple[int, int, int]:
    """Green at 0, yellow at 0.5, red at ≥ 1 (x is a normalised magnitude)."""
    x = float(np.clip(x, 0.0, 1.0)) if np.isfinite(x) else 1.0
    c = GREEN + (YELLOW - GREEN) * (2 * x) if x < 0.5 else YELLOW + (RED - YELLOW) * (2 * x - 1)
    return (round(float(c[0])), round(float(c[1])), round(float(c[2])))


def margin_color(margin_rad: float, zone_rad: float) -> tuple[int, int, int]:
    """Link colour for a joint `margin_rad` from its nearer limit: green outside d_i, red at the limit."""
    if not np.isfinite(margin_rad) or zone_rad <= 0:
        return magnitude_color(0.0)
    return magnitude_color(1.0 - margin_rad / zone_rad)


def coupling_cap(radius: float) -> float:
    """The largest semi-axis a coupling shape gets with this unit-circle radius (m)."""
    return min(COUPLING_MAX_SPAN * radius, MAX_AXIS_M)


def capped_semi_axes(semi: np.ndarray, cap: float) -> tuple[np.ndarray, float]:
    """(semi-axes, factor): `semi` scaled as a whole so that the largest is at most `cap` (the factor ≤ 1
    applies to the outline too: the shape and its tilt stay), each ≥ MIN_AXIS_M."""
    semi = np.asarray(semi, dtype=float)
    top = float(np.max(semi)) if semi.size else 0.0
    factor = cap / top if top > cap else 1.0
    return np.maximum(factor * semi, MIN_AXIS_M), factor


def coupling_center(tcp: np.ndarray, R: np.ndarray, semi: np.ndarray) -> np.ndarray:
    """Where a coupling shape (rotation R, semi-axes `semi`) is drawn: LIFT_M above the tool and moved
    out sideways, away from the arm's base (at the world origin), by its own horizontal half-extent plus
    a payload's radius and a gap, so that it covers neither the wrist nor a payload at the tool."""
    out = np.array([tcp[0], tcp[1], 0.0])
    norm = float(np.linalg.norm(out))
    out = out / norm if norm > 1e-6 else np.array([1.0, 0.0, 0.0])
    half = float(np.linalg.norm((out @ R) * semi))  # half-extent of the ellipsoid along `out`
    return tcp + LIFT_M + (half + PAYLOAD_RADIUS_M + SIDE_GAP_M) * out


def wxyz_of(R: np.ndarray) -> np.ndarray:
    """Quaternion (w, x, y, z) of a rotation matrix."""
    return vtf.SO3.from_matrix(R).wxyz


def arrow_points(origin: np.ndarray, vector: np.ndarray, scale: float) -> np.ndarray:
    """(1, 2, 3) start/end of an arrow of `scale`·vector at origin."""
    origin = np.asarray(origin, dtype=float)
    return np.stack([origin, origin + scale * np.asarray(vector, dtype=float)])[None]


def polyline_segments(points: np.ndarray) -> np.ndarray:
    """(k-1, 2, 3) segments joining consecutive points."""
    pts = np.asarray(points, dtype=float).reshape(-1, 3)
    if len(pts) < 2:
        return np.zeros((1, 2, 3))
    return np.stack([pts[:-1], pts[1:]], axis=1)


def ring_segments(center: np.ndarray, radius: float, n: int = CONTACT_RING_SEGMENTS) -> np.ndarray:
    """(n, 2, 3) segments of a horizontal circle of `radius` around `center`."""
    a = np.linspace(0.0, 2 * np.pi, n + 1)
    pts = np.asarray(center, dtype=float) + radius * np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], axis=1)
    return polyline_segments(pts)


def cross_segments(points: np.ndarray, half: float = LIFT_MARK_HALF_M) -> np.ndarray:
    """(2k, 2, 3) segments of a horizontal cross (an X) at each of k points."""
    pts = np.asarray(points, dtype=float).reshape(-1, 3)
    d1, d2 = np.array([half, half, 0.0]), np.array([half, -half, 0.0])
    segs = [np.stack([p - d, p + d]) for p in pts for d in (d1, d2)]
    return np.array(segs).reshape(-1, 2, 3)


def on_table(point: np.ndarray, table: tuple[np.ndarray, np.ndarray] | None) -> np.ndarray:
    """The point moved onto the table's top (plus TABLE_GAP_M); unchanged without a table."""
    out = np.array(point, dtype=float)
    if table is not None:
        center, half = table
        out[..., 2] = float(center[2] + half[2]) + TABLE_GAP_M
    return out


# ---- the TCP trail ------------------------------------------------------------------------------
class Trail:
    """Recent TCP positions, thinned to one point per 2 mm or 50 ms, at most `seconds` old."""

    def __init__(self, max_points: int = 400):
        self.points: deque[tuple[float, np.ndarray]] = deque(maxlen=max_points)

    def add(self, t: float, p: np.ndarray, seconds: float) -> None:
        """Append a sample (clears on a time jump backwards, i.e. a reset)."""
        if self.points and t < self.points[-1][0]:
            self.points.clear()
        if not self.points or t - self.points[-1][0] > 0.05 or np.linalg.norm(p - self.points[-1][1]) > 2e-3:
            self.points.append((t, np.array(p, dtype=float)))
        while self.points and t - self.points[0][0] > seconds:
            self.points.popleft()

    def array(self) -> np.ndarray:
        """(k, 3) positions, oldest first."""
        return np.array([p for _, p in self.points]).reshape(-1, 3)
