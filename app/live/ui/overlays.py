"""Overlays at the tool: coupling ellipse, P Pᵀ ellipsoid, task inertia, force arrows, trail, path, contact.

`Overlays` owns a dozen viser nodes created once and afterwards only moved, rescaled, recoloured or
hidden; their geometry is `app.live.ui.overlay_shapes` (pure functions of arrays).

Contact (a table preset): a dot at the contact point, the normal force and the friction force as arrows
from it (the force scale, m per N, of the other force arrows), a ring on the table around the tool, green
in contact and red while contact is lost (`metrics.contact_lost`) and `LOST_RING_HOLD_S` after, and a red
cross on the table where the tool lifted at each loss of this run (`metrics.contact_loss_onsets`),
labelled at the latest.
"""

from __future__ import annotations

import numpy as np
import viser
import viser.transforms as vtf

from app.live.ui.node_writes import set_position, set_prop, set_wxyz
from app.live.ui.overlay_shapes import (
    CONTACT_RING_RADIUS_M,
    COUPLING_OPACITY,
    FRICTION_COLOR,
    GREEN,
    IN_CONTACT_COLOR,
    LABEL_GAP_M,
    LIFT_M,
    LIFT_MARK_HALF_M,
    LOST_COLOR,
    LOST_RING_HOLD_S,
    MAX_AXIS_M,
    MIN_AXIS_M,
    NORMAL_COLOR,
    PAYLOAD_RADIUS_M,
    Trail,
    arrow_points,
    capped_semi_axes,
    coupling_cap,
    coupling_center,
    coupling_map,
    cross_segments,
    ellipsoid_of_map,
    inertia_ellipsoid,
    magnitude_color,
    measured_coupled_response,
    on_table,
    polyline_segments,
    ring_segments,
    tilt_rad,
    translational_force_ellipsoid,
    wxyz_of,
)
from app.live.ui.snapshot import SceneSnapshot
from app.live.ui.visuals import VisualSettings
from control.coupling import coupling_ellipse


class Overlays:
    """The overlay nodes under /overlays; `update` sets only light properties."""

    def __init__(self, server: viser.ViserServer, settings: VisualSettings, root: str = "/overlays"):
        self.server = server
        self.settings = settings
        self.root = root
        self.trail = Trail()
        self.coupling_center: np.ndarray | None = None  # where the coupling ellipse was last drawn
        sc = server.scene
        self.coupling_disc = sc.add_icosphere(
            f"{root}/coupling_disc", radius=1.0, color=GREEN, subdivisions=3, opacity=COUPLING_OPACITY, side="double"
        )
        self.coupling_outline = sc.add_line_segments(
            f"{root}/coupling_outline", np.zeros((1, 2, 3)), colors=(30, 30, 30), thickness=0.003
        )
        self.coupling_label = sc.add_label(f"{root}/coupling_label", "", font_screen_scale=0.9, anchor="bottom-left")
        self.ppt = sc.add_icosphere(f"{root}/ppt", radius=1.0, color=(150, 90, 220), subdivisions=2, opacity=0.5)
        self.inertia = sc.add_icosphere(
            f"{root}/inertia", radius=1.0, color=(80, 140, 230), subdivisions=2, opacity=0.25, visible=False
        )
        self.drag_arrow = _add_arrow(sc, f"{root}/drag_force", (240, 140, 20))
        self.measured_arrow = _add_arrow(sc, f"{root}/measured_force", (220, 30, 200))
        self.response_arrow = _add_arrow(sc, f"{root}/coupled_response", (230, 40, 40))
        self.spring = sc.add_line_segments(
            f"{root}/drag_spring", np.zeros((1, 2, 3)), colors=(240, 140, 20), thickness=0.004
        )
        self.grab_point = sc.add_icosphere(f"{root}/grab_point", radius=0.012, color=(240, 140, 20), visible=False)
        self.trail_line = sc.add_line_segments(
            f"{root}/trail", np.zeros((1, 2, 3)), colors=(40, 120, 220), thickness=0.003
        )
        self.path_line = sc.add_line_segments(
            f"{root}/path", np.zeros((1, 2, 3)), colors=(120, 120, 120), thickness=0.002
        )
        self.target = sc.add_icosphere(f"{root}/target", radius=0.008, color=(120, 120, 120), visible=False)
        self.target_label = sc.add_label(
            f"{root}/target_label", "task target", font_screen_scale=0.7, visible=False, anchor="bottom-center"
        )
        self.contact_dot = sc.add_icosphere(f"{root}/contact_point", radius=0.008, color=(20, 20, 20), visible=False)
        self.normal_arrow = _add_arrow(sc, f"{root}/contact_normal", NORMAL_COLOR)
        self.friction_arrow = _add_arrow(sc, f"{root}/contact_friction", FRICTION_COLOR)
        self.contact_ring = sc.add_line_segments(
            f"{root}/contact_ring", np.zeros((1, 2, 3)), colors=IN_CONTACT_COLOR, thickness=0.004, visible=False
        )
        self.lost_ring = sc.add_line_segments(
            f"{root}/contact_lost_ring", np.zeros((1, 2, 3)), colors=LOST_COLOR, thickness=0.008, visible=False
        )
        self.lift_marks = sc.add_line_segments(
            f"{root}/contact_lifts", np.zeros((1, 2, 3)), colors=LOST_COLOR, thickness=0.006, visible=False
        )
        self.lift_label = sc.add_label(
            # under its cross, where the task target's label (above the target, at the tool) cannot cover it
            f"{root}/contact_lift_label",
            "",
            font_screen_scale=0.8,
            visible=False,
            anchor="top-center",
        )
        self.payload = sc.add_icosphere(f"{root}/payload", radius=PAYLOAD_RADIUS_M, color=(70, 70, 75), visible=False)
        # below the ball, to its left: clear of the coupling label, which sits above the tool, to its right
        self.payload_label = sc.add_label(
            f"{root}/payload_label", "", font_screen_scale=0.8, visible=False, anchor="top-right"
        )

    def update(self, snap: SceneSnapshot) -> None:
        """Move/rescale/recolour every overlay for one frame; hides them all on a non-finite state."""
        s = self.settings
        if not _finite(snap):  # a diverged simulation: show nothing rather than fail every frame
            for node in self._nodes():
                node.visible = False
            return
        try:
            self._update_coupling(snap, s)
            self._update_ppt(snap, s)
            self._update_inertia(snap, s)
        except (np.linalg.LinAlgError, ValueError):
            self.coupling_disc.visible = self.coupling_outline.visible = self.coupling_label.visible = False
            self.ppt.visible = self.inertia.visible = False
        self._update_arrows(snap, s)
        self._update_lines(snap, s)
        self._update_payload(snap, s)
        self._update_contact(snap, s)

    def _update_contact(self, snap: SceneSnapshot, s: VisualSettings) -> None:
        """Contact point, normal and friction arrows, the ring at the tool and the marks where it lifted."""
        point, force = snap.contact_point, snap.contact_force
        has = s.contact and point is not None and force is not None
        touching = has and force is not None and float(force[2]) > 0.0
        self.contact_dot.visible = bool(touching)
        if touching and point is not None:
            set_position(self.contact_dot, point)
        normal = None if force is None else np.array([0.0, 0.0, float(force[2])])
        friction = None if force is None else np.array([float(force[0]), float(force[1]), 0.0])
        _set_arrow(self.normal_arrow, bool(touching), point, normal, s.force_m_per_n)
        _set_arrow(self.friction_arrow, bool(touching), point, friction, s.force_m_per_n)
        ring_at = None if not has or point is None else on_table(point, snap.table)
        times = snap.contact_lift_times
        lost = bool(has and (snap.contact_lost or (len(times) > 0 and 0.0 <= snap.t - times[-1] <= LOST_RING_HOLD_S)))
        self.contact_ring.visible = bool(touching) and not lost
        self.lost_ring.visible = lost
        if ring_at is not None and (touching or lost):
            ring = ring_segments(ring_at, CONTACT_RING_RADIUS_M).astype(np.float32)
            set_prop(self.lost_ring if lost else self.contact_ring, "points", ring)
        lifts = snap.contact_lifts
        shown = s.contact and len(lifts) > 0
        self.lift_marks.visible = shown
        self.lift_label.visible = shown and s.labels
        if shown:
            marks = on_table(lifts, snap.table)
            set_prop(self.lift_marks, "points", cross_segments(marks).astype(np.float32))
            set_position(self.lift_label, marks[-1] - np.array([0.0, 0.0, LIFT_MARK_HALF_M]))
            set_prop(self.lift_label, "text", f"contact lost ×{len(lifts)}" if len(lifts) > 1 else "contact lost")

    def coupling_extent(self) -> np.ndarray | None:
        """(8, 3) corners of a box around the coupling disc as last drawn (None while it is hidden): what
        framing the camera keeps in view besides the arm."""
        if self.coupling_center is None or not self.coupling_disc.visible:
            return None
        R = vtf.SO3(np.asarray(self.coupling_disc.wxyz)).as_matrix()
        half = np.abs(R * np.asarray(self.coupling_disc.scale)).sum(axis=1)  # along world x, y, z
        signs = np.array([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)], dtype=float)
        return self.coupling_center + signs * half

    def _update_payload(self, snap: SceneSnapshot, s: VisualSettings) -> None:
        p = snap.payload_position
        shown = p is not None and bool(np.all(np.isfinite(p)))
        self.payload.visible = shown
        self.payload_label.visible = shown and s.labels
        if p is not None and shown:
            set_position(self.payload, p)
            set_position(self.payload_label, p - np.array([0.0, 0.0, 1.5 * PAYLOAD_RADIUS_M]))
            set_prop(self.payload_label, "text", f"{snap.payload_mass_kg:.2f} kg")

    def _nodes(self) -> tuple[viser.SceneNodeHandle, ...]:
        return (
            self.coupling_disc,
            self.coupling_outline,
            self.coupling_label,
            self.ppt,
            self.inertia,
            self.drag_arrow,
            self.measured_arrow,
            self.response_arrow,
            self.spring,
            self.grab_point,
            self.trail_line,
            self.path_line,
            self.target,
            self.target_label,
            self.payload,
            self.payload_label,
            self.contact_dot,
            self.normal_arrow,
            self.friction_arrow,
            self.contact_ring,
            self.lost_ring,
            self.lift_marks,
            self.lift_label,
        )

    def _update_coupling(self, snap: SceneSnapshot, s: VisualSettings) -> None:
        sub = snap.subspaces
        kind = s.projection_name(snap.objective)
        P = snap.P[kind]
        scale = s.coupling_scale(snap.objective)
        L = coupling_map(P, sub, scale)
        # with no translational force axis the image is the unit sphere whatever P is: nothing to show,
        # and a sphere at the tool would hide the wrist and the payload
        lifts = any(a < 3 for a in sub.force_axes)
        show = s.coupling and L.shape[1] > 0 and lifts and not snap.near_singular
        self.coupling_disc.visible = show
        self.coupling_outline.visible = show
        self.coupling_label.visible = s.coupling and s.labels and L.shape[1] > 0 and (lifts or snap.near_singular)
        if snap.near_singular:
            set_position(self.coupling_label, snap.tcp_position + LIFT_M)
            set_prop(self.coupling_label, "text", "near a singularity: Λx ill-conditioned")
        if not show:
            return
        radius = s.coupling_radius_m
        axes, R = ellipsoid_of_map(L)
        semi, factor = capped_semi_axes(radius * axes, coupling_cap(radius))
        center = coupling_center(snap.tcp_position, R, semi)
        self.coupling_center = center
        set_position(self.coupling_disc, center)
        set_wxyz(self.coupling_disc, wxyz_of(R))
        set_prop(self.coupling_disc, "scale", _triple(semi))
        set_prop(self.coupling_disc, "color", magnitude_color(np.tan(tilt_rad(P, sub, scale))))
        outline = coupling_ellipse(P, sub, scale=scale, points=48)
        outline = radius * factor * outline  # the disc's rim: scaled with it
        set_prop(self.coupling_outline, "points", polyline_segments(center + outline).astype(np.float32))
        W = snap.W.get("W" + kind[1:], float("nan"))
        top = float(np.linalg.norm(R[2, :] * semi))  # the disc's half-height along world z
        set_position(self.coupling_label, center + np.array([0.0, 0.0, top + LABEL_GAP_M]))
        set_prop(self.coupling_label, "text", f"W{kind[1:]} = {W:.3g}")

    def _update_ppt(self, snap: SceneSnapshot, s: VisualSettings) -> None:
        kind = s.projection_name(snap.objective)
        wanted = s.ppt_ellipsoid and not snap.near_singular
        shape = translational_force_ellipsoid(snap.P[kind], snap.subspaces) if wanted else None
        self.ppt.visible = shape is not None
        if shape is None:
            return
        axes, R = shape
        size = s.coupling_radius_m * s.coupling_scale(snap.objective)
        semi, _ = capped_semi_axes(size * axes, coupling_cap(s.coupling_radius_m))
        set_position(self.ppt, coupling_center(snap.tcp_position, R, semi))
        set_wxyz(self.ppt, wxyz_of(R))
        set_prop(self.ppt, "scale", _triple(semi))

    def _update_inertia(self, snap: SceneSnapshot, s: VisualSettings) -> None:
        self.inertia.visible = s.inertia_ellipsoid and not snap.near_singular
        if not self.inertia.visible:
            return
        masses, R = inertia_ellipsoid(snap.Lambda_translational)
        set_position(self.inertia, snap.tcp_position)
        set_wxyz(self.inertia, wxyz_of(R))
        set_prop(self.inertia, "scale", _triple(np.clip(s.inertia_m_per_kg * masses, MIN_AXIS_M, MAX_AXIS_M)))

    def _update_arrows(self, snap: SceneSnapshot, s: VisualSettings) -> None:
        _set_arrow(self.drag_arrow, s.drag_force, snap.drag_point, snap.drag_force, s.force_m_per_n)
        _set_arrow(self.measured_arrow, s.measured_force, snap.tcp_position, snap.wrench_measured[:3], s.force_m_per_n)
        response = measured_coupled_response(snap) if s.coupled_response else None
        _set_arrow(self.response_arrow, s.coupled_response, snap.tcp_position, response, s.response_m_per_mps2)

    def _update_lines(self, snap: SceneSnapshot, s: VisualSettings) -> None:
        point, target = snap.drag_point, snap.drag_target
        dragging = point is not None and target is not None
        self.spring.visible = dragging
        self.grab_point.visible = dragging
        if point is not None and target is not None:
            set_prop(self.spring, "points", np.stack([point, target])[None].astype(np.float32))
            set_position(self.grab_point, point)
        self.trail.add(snap.t, snap.tcp_position, s.trail_seconds)
        trail = self.trail.array()
        self.trail_line.visible = s.trail and len(trail) >= 2
        if self.trail_line.visible:
            set_prop(self.trail_line, "points", polyline_segments(trail).astype(np.float32))
        has_path = s.path and len(snap.path) >= 2
        self.path_line.visible = has_path
        if has_path:
            set_prop(self.path_line, "points", polyline_segments(snap.path).astype(np.float32))
        self.target.visible = s.path and snap.target_position is not None
        self.target_label.visible = self.target.visible and s.labels
        if snap.target_position is not None and s.path:
            set_position(self.target, snap.target_position)
            set_position(self.target_label, snap.target_position + np.array([0.0, 0.0, 0.015]))

    def remove(self) -> None:
        """Remove every overlay node."""
        for node in self._nodes():
            node.remove()


def _finite(snap: SceneSnapshot) -> bool:
    """True when everything the overlays compute with is finite."""
    arrays = [snap.tcp_position, snap.Lambda_translational, snap.wrench_measured, *snap.P.values()]
    return all(bool(np.all(np.isfinite(a))) for a in arrays)


def _set_arrow(
    handle: viser.ArrowsHandle, enabled: bool, origin: np.ndarray | None, vector: np.ndarray | None, scale: float
) -> None:
    """Show an arrow of scale·vector at origin, or hide it when off, absent or shorter than 2 mm."""
    show = enabled and origin is not None and vector is not None and float(np.linalg.norm(vector)) * scale > 2e-3
    handle.visible = bool(show)
    if show:
        assert origin is not None and vector is not None
        set_prop(handle, "points", arrow_points(origin, vector, scale).astype(np.float32))


def _add_arrow(scene: viser.SceneApi, name: str, color: tuple[int, int, int]) -> viser.ArrowsHandle:
    return scene.add_arrows(
        name, np.zeros((1, 2, 3)), colors=color, shaft_radius=0.006, head_radius=0.016, head_length=0.035
    )


def _triple(a: np.ndarray) -> tuple[float, float, float]:
    return (float(a[0]), float(a[1]), float(a[2]))
