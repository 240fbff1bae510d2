"""Scene snapshot and overlay geometry: numbers, not pictures (the browser test checks pictures)."""

from __future__ import annotations

import asyncio
import dataclasses
import itertools
import time
import types

import numpy as np
import pytest

from app.core.commands import DragCommand
from app.core.session import Session
from app.live.ui.overlay_shapes import (
    COUPLING_MAX_SPAN,
    PAYLOAD_RADIUS_M,
    Trail,
    coupling_map,
    ellipsoid_of_map,
    inertia_ellipsoid,
    magnitude_color,
    margin_color,
    measured_coupled_response,
    tilt_rad,
    translational_force_ellipsoid,
)
from app.live.ui.scene import SceneView, link_joint_indices, link_meshes
from app.live.ui.snapshot import capture
from app.live.ui.visuals import VisualSettings, VisualsPanel, field_names
from app.scenarios.mass_drop import MASS_BODY, PAYLOAD_KG, MassDropScenario
from control.coupling import POLISH_SUBSPACES, Subspaces, coupling_ellipse

PZ = POLISH_SUBSPACES  # motion px py rx ry rz, force pz


def _P_pz(px: float, py: float) -> np.ndarray:
    """P (1×5) for the pz force axis with entries on the px, py motion columns only."""
    P = np.zeros((1, 5))
    P[0, 0], P[0, 1] = px, py
    return P


# ---- coupling ellipse ------------------------------------------------------------------------
def test_coupling_ellipse_is_a_flat_unit_disc_in_the_motion_plane_when_decoupled():
    L = coupling_map(np.zeros((1, 5)), PZ, scale=3.0)
    axes, R = ellipsoid_of_map(L)
    assert np.allclose(sorted(axes), [0.02, 1.0, 1.0])
    normal = R[:, int(np.argmin(axes))]
    assert abs(abs(normal[2]) - 1.0) < 1e-12  # disc normal is the force axis z
    assert tilt_rad(np.zeros((1, 5)), PZ, 3.0) == pytest.approx(0.0, abs=1e-12)


def test_coupling_ellipse_tilt_matches_s_times_p():
    P = _P_pz(0.3, -0.4)  # |P_t| = 0.5
    s = 2.0
    assert tilt_rad(P, PZ, s) == pytest.approx(np.arctan(1.0), abs=1e-12)
    axes, R = ellipsoid_of_map(coupling_map(P, PZ, s))
    order = np.argsort(axes)[::-1]
    assert axes[order[0]] == pytest.approx(np.hypot(1.0, 1.0), rel=1e-12)  # stretched along the tilt
    assert axes[order[1]] == pytest.approx(1.0, rel=1e-12)  # the perpendicular motion direction keeps length 1
    normal = R[:, order[2]]
    expected = np.array([-s * 0.3, -s * (-0.4), 1.0])
    expected /= np.linalg.norm(expected)
    assert abs(normal @ expected) == pytest.approx(1.0, abs=1e-12)
    # the steepest direction of the disc is along P_t (0.6, -0.8)
    major = R[:, order[0]]
    assert abs(major[:2] @ np.array([0.6, -0.8])) / np.linalg.norm(major[:2]) == pytest.approx(1.0, abs=1e-12)


def test_rotational_motion_columns_do_not_tilt_the_translational_ellipse():
    P = np.zeros((1, 5))
    P[0, 2:] = [5.0, -3.0, 2.0]  # rx, ry, rz columns
    assert tilt_rad(P, PZ, 1.0) == pytest.approx(0.0, abs=1e-12)


def test_outline_points_of_control_coupling_lie_on_the_drawn_ellipse():
    P = _P_pz(1.75, -0.23)
    s = 0.2
    axes, R = ellipsoid_of_map(coupling_map(P, PZ, s))
    pts = coupling_ellipse(P, PZ, scale=s, points=32)
    local = pts @ R  # coordinates along the principal axes
    big = np.argsort(axes)[::-1][:2]
    thin = int(np.argmin(axes))
    radius = np.sqrt(np.sum((local[:, big] / axes[big]) ** 2, axis=1))
    assert np.allclose(radius, 1.0, atol=1e-12)
    assert np.max(np.abs(local[:, thin])) < 1e-12


def test_coupling_shape_follows_the_number_of_translational_motion_axes():
    rz_only = Subspaces.from_force_axes(("rz",))  # motion px py pz rx ry: nothing to tilt into
    P = np.full((1, 5), 3.0)
    axes, _ = ellipsoid_of_map(coupling_map(P, rz_only, 1.0))
    assert np.allclose(axes, 1.0) and tilt_rad(P, rz_only, 1.0) == pytest.approx(0.0, abs=1e-12)
    pxy = Subspaces.from_force_axes(("px", "py"))  # motion pz rx ry rz: a segment along z, tilted into x, y
    P = np.zeros((2, 4))
    P[:, 0] = [0.6, 0.8]
    L = coupling_map(P, pxy, 1.0)
    assert L.shape == (3, 1) and np.allclose(L[:, 0], [0.6, 0.8, 1.0])
    assert tilt_rad(P, pxy, 1.0) == pytest.approx(np.pi / 4)
    no_translation = Subspaces.from_force_axes(("px", "py", "pz"))
    assert coupling_map(np.zeros((3, 3)), no_translation, 1.0).shape == (3, 0)


def test_ppt_ellipsoid_needs_two_translational_force_axes_and_has_sqrt_sigma_axes():
    assert translational_force_ellipsoid(np.ones((1, 5)), PZ) is None
    sub = Subspaces.from_force_axes(("px", "pz"))  # motion py rx ry rz
    P = np.array([[2.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0]])
    P[1, 1] = 1.0  # pz couples with rx
    shape = translational_force_ellipsoid(P, sub)
    assert shape is not None
    axes, R = shape
    assert sorted(axes)[-2:] == pytest.approx([1.0, 2.0])  # √σ of P Pᵀ = diag(4, 1)
    assert np.sum(np.sort(axes)[-2:] ** 2) == pytest.approx(np.sum(P * P))  # Σσ = W [T22]
    big = R[:, int(np.argmax(axes))]
    assert abs(big[0]) == pytest.approx(1.0)  # the 2-wide axis lies along world x (force axis px)


def test_inertia_ellipsoid_axes_are_principal_masses():
    rot = np.linalg.qr(np.array([[1.0, 2.0, 0.0], [0.5, -1.0, 1.0], [0.2, 0.3, 1.0]]))[0]
    Lambda_t = rot @ np.diag([2.0, 9.0, 5.0]) @ rot.T
    masses, R = inertia_ellipsoid(Lambda_t)
    assert masses == pytest.approx([9.0, 5.0, 2.0])
    assert np.allclose(R @ np.diag(masses) @ R.T, Lambda_t, atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)


# ---- colours and trail -----------------------------------------------------------------------
def test_margin_colour_is_green_outside_the_zone_and_red_at_the_limit():
    assert margin_color(0.5, 0.2) == (60, 200, 90)
    assert margin_color(0.2, 0.2) == (60, 200, 90)
    assert margin_color(0.0, 0.2) == (230, 50, 40)
    redness = [margin_color(m, 0.2)[0] - margin_color(m, 0.2)[1] for m in (0.2, 0.15, 0.1, 0.05, 0.0)]
    assert all(b > a for a, b in itertools.pairwise(redness))  # strictly redder as the margin shrinks
    assert margin_color(float("inf"), 0.2) == magnitude_color(0.0)  # endless joints stay green


def test_trail_thins_samples_forgets_old_ones_and_clears_on_reset():
    trail = Trail()
    for k in range(1000):  # 1 s at 1 kHz moving 1 mm per ms
        trail.add(k * 1e-3, np.array([k * 1e-3, 0.0, 0.0]), seconds=0.5)
    pts = trail.array()
    assert 200 <= len(pts) <= 260  # one point per ≥ 2 mm over the last 0.5 s
    assert pts[0, 0] >= 0.499 and pts[-1, 0] == pytest.approx(0.999, abs=2e-3)
    trail.add(0.0, np.zeros(3), seconds=0.5)
    assert len(trail.array()) == 1


# ---- snapshot from a running session -----------------------------------------------------------
@pytest.fixture(scope="module")
def session():
    s = Session("free")
    s.run(0.05)
    return s


def test_snapshot_link_poses_are_copies_of_the_simulated_bodies(session):
    snap = capture(session)
    data, model = session.world.data, session.world.model
    for i, name in enumerate(snap.link_names):
        bid = model.body(name).id
        assert np.allclose(snap.link_positions[i], data.xpos[bid], atol=0)
        assert np.allclose(snap.link_wxyz[i], data.xquat[bid], atol=0)
    before = snap.link_positions.copy()
    session.drag.grab(session.world, model.body("link7").id, data.xpos[model.body("link7").id] + [0, 0, 0.05])
    session.drag.move(data.xpos[model.body("link7").id] + np.array([0.0, 0.3, 0.05]))
    session.run(0.1)
    assert np.array_equal(snap.link_positions, before)  # not a view into MjData
    moved = capture(session)
    assert np.linalg.norm(moved.link_positions[snap.link_index("link7")] - before[snap.link_index("link7")]) > 1e-3
    assert moved.drag_force is not None and np.linalg.norm(moved.drag_force) > 1.0
    assert np.allclose(moved.drag_point, session.drag.state.point_world)
    session.drag.release()
    assert capture(session).drag_force is None


def test_snapshot_defers_gamma_x_to_its_reader_and_looks_up_bodies_and_splits_once(monkeypatch):
    """The loop thread only copies what Γ_x is computed from (Λx, the split, shaping): Γ_x itself is
    computed when a reader first asks, from the copy (so a later step does not change it), and equals
    control.bridge's on the captured Λx. Body ids and the split are looked up once, not per frame."""
    import mujoco

    from app.live.ui.snapshot import split_of
    from control.bridge import gamma_x_matrix, gamma_x_summary

    s = Session("polish", executor="projection")
    s.run(steps=5)
    snap = capture(s)
    assert "_gamma_x" not in snap.__dict__  # nothing computed on the capturing thread
    Lambda = s.dyn.Lambda.copy()
    s.run(steps=20)  # the arm moves on: the snapshot keeps its own Λx
    expected = gamma_x_summary(gamma_x_matrix(Lambda, split_of(snap.force_axes)))
    np.testing.assert_array_equal(snap.gamma_x_sym_eigs, expected.sym_eigenvalues)
    assert snap.gamma_x_skew == expected.skew_norm
    assert capture(Session("polish", executor="compliance-qp")).gamma_x_sym_eigs is None
    assert split_of((2,)) is split_of((2,)) and split_of((2,)).motion_axes == (0, 1, 3, 4, 5)
    assert snap.subspaces is split_of(snap.force_axes)
    lookups = []
    real = mujoco.mj_name2id
    monkeypatch.setattr(mujoco, "mj_name2id", lambda *a: (lookups.append(a[2]), real(*a))[1])
    again = capture(s)
    assert [n for n in lookups if n in again.link_names] == []
    np.testing.assert_array_equal(
        again.link_positions, [s.world.data.xpos[s.world.model.body(n).id] for n in again.link_names]
    )


def test_snapshot_reads_the_controllers_damper_distance():
    projection = capture(Session("polish", executor="projection"))
    assert projection.objective in ("j", "f", "a", "d")
    assert projection.limit_zone is not None and np.all(projection.limit_zone > 0)
    qp = Session("polish", executor="compliance-qp")
    zone = capture(qp).limit_zone
    assert zone is not None
    assert np.allclose(zone, qp.executor.damper.gains.influence_fraction * (qp.robot.q_upper - qp.robot.q_lower))


def test_snapshot_coupling_terms_match_task_inertia_blocks(session):
    snap = capture(session)
    L = session.dyn.Lambda
    assert snap.force_axes == (2,) and snap.motion_axes == (0, 1, 3, 4, 5)
    assert np.allclose(snap.P["P_a"], L[np.ix_([2], [0, 1, 3, 4, 5])])  # Bᵀ [T20]
    A = L[np.ix_([0, 1, 3, 4, 5], [0, 1, 3, 4, 5])]
    assert np.allclose(snap.P["P_d"], snap.P["P_a"] @ np.linalg.inv(A))
    assert np.allclose(snap.P["P_f"], session.dyn.Lambda_inv[np.ix_([2], [0, 1, 3, 4, 5])])
    for k in ("f", "a", "d"):
        assert snap.W[f"W_{k}"] == pytest.approx(float(np.sum(snap.P[f"P_{k}"] ** 2)))
    assert np.allclose(snap.Lambda_translational, L[:3, :3])
    q = session.world.q
    r = session.robot
    assert np.allclose(snap.joint_margins, np.minimum(q - r.q_lower, r.q_upper - q))


def test_coupled_response_arrow_is_P_f_times_the_measured_motion_wrench(session):
    snap = dataclasses.replace(capture(session), wrench_measured=np.array([10.0, 0, 0, 0, 0, 0]))
    response = measured_coupled_response(snap)
    assert response[:2] == pytest.approx([0.0, 0.0])
    assert response[2] == pytest.approx(10.0 * snap.P["P_f"][0, 0])


# ---- SceneView without a browser ----------------------------------------------------------------


def test_link_meshes_cover_every_visual_link_in_its_own_frame(rizon):
    meshes = link_meshes(str(rizon.urdf_path))
    assert set(meshes) == set(rizon.link_names)
    base = meshes["base_link"]
    assert base.bounds[0][2] == pytest.approx(-0.07, abs=2e-3)  # sphere r = 0.07 at the origin
    assert base.bounds[1][2] == pytest.approx(0.155 + 0.077, abs=2e-3)  # top of the second cylinder
    assert link_joint_indices(rizon) == {n: i - 1 for i, n in enumerate(rizon.link_names[:8])} | {"flange": 6}


def test_scene_view_moves_links_recolours_near_limits_and_sends_drag_commands(server, session):
    sent: list[DragCommand] = []
    settings = VisualSettings(limit_zone_rad=0.2)
    view = SceneView(server, session.robot, sent.append, settings)
    try:
        snap = capture(session)
        margins = snap.joint_margins.copy()
        margins[3] = 0.0  # joint 4 at its limit
        with server.atomic():
            view.update(dataclasses.replace(snap, joint_margins=margins))
        i = snap.link_index("link3")
        assert np.allclose(view.frames["link3"].position, snap.link_positions[i])
        assert np.allclose(view.frames["link3"].wxyz, snap.link_wxyz[i])
        assert tuple(view.meshes["link4"].color) == (230, 50, 40)
        assert tuple(view.meshes["link2"].color) == (60, 200, 90)
        assert view.overlays.coupling_disc.visible
        assert view.overlays.coupling_label.text.startswith("W_a = ")

        cb = view._drag_callback("link5")
        for phase, start, end in (("start", (0.1, 0.2, 0.3), (0.1, 0.2, 0.3)), ("update", (0, 0, 0), (0.4, 0.5, 0.6))):
            asyncio.run(cb(types.SimpleNamespace(phase=phase, client_id=7, start_position=start, end_position=end)))
        asyncio.run(
            cb(types.SimpleNamespace(phase="end", client_id=7, start_position=(0, 0, 0), end_position=(0, 0, 0)))
        )
        assert [c.kind for c in sent] == ["grab", "move", "release"]
        assert sent[0] == DragCommand("grab", 7, body_name="link5", point_world=(0.1, 0.2, 0.3))
        assert sent[1].target_world == (0.4, 0.5, 0.6)

        margins[1] = 0.3  # joint 2: outside the Visuals fallback zone (0.2), inside a controller's d_i = 0.5
        with server.atomic():
            view.update(dataclasses.replace(snap, joint_margins=margins, limit_zone=None))
        assert tuple(view.meshes["link2"].color) == (60, 200, 90)
        with server.atomic():
            view.update(dataclasses.replace(snap, joint_margins=margins, limit_zone=np.full(7, 0.5)))
        assert tuple(view.meshes["link2"].color) == margin_color(0.3, 0.5) != (60, 200, 90)

        settings.update(coupling=False, limit_colors=False)
        with server.atomic():
            view.update(snap)
        assert not view.overlays.coupling_disc.visible
        assert tuple(view.meshes["link4"].color) == (175, 178, 186)
    finally:
        view.remove()


def test_scene_view_survives_a_diverged_snapshot(server, session):
    view = SceneView(server, session.robot, lambda c: None)
    try:
        snap = capture(session)
        with server.atomic():
            view.update(snap)
        before = view.frames["link5"].position.copy()
        positions = snap.link_positions.copy()
        positions[snap.link_index("link5")] = np.nan
        P = {k: np.full_like(v, np.nan) for k, v in snap.P.items()}
        bad = dataclasses.replace(snap, link_positions=positions, P=P, tcp_position=np.full(3, np.nan))
        with server.atomic():
            view.update(bad)  # must not raise
        assert np.array_equal(view.frames["link5"].position, before)  # the last finite pose stays
        assert not view.overlays.coupling_disc.visible and not view.overlays.trail_line.visible
        with server.atomic():
            view.update(snap)
        assert view.overlays.coupling_disc.visible
    finally:
        view.remove()


def test_an_attached_payload_is_drawn_until_it_is_released(server):
    session = Session(MassDropScenario(case="held-release"))
    view = SceneView(server, session.robot, lambda c: None)
    try:
        snap = capture(session)
        assert snap.payload_mass_kg == pytest.approx(session.environment.mass_kg)
        body = session.world.model.body("payload").id
        assert np.allclose(snap.payload_position, session.world.data.xipos[body])
        with server.atomic():
            view.update(snap)
        assert view.overlays.payload.visible and view.overlays.payload_label.text.endswith(" kg")
        session.environment.release()
        released = capture(session)
        assert released.payload_position is None
        with server.atomic():
            view.update(released)
        assert not view.overlays.payload.visible
    finally:
        view.remove()


def test_the_mass_on_its_rope_is_drawn_where_it_hangs(server):
    session = Session("mass-drop")
    snap = capture(session)
    body = session.world.model.body(MASS_BODY).id
    assert snap.payload_mass_kg == pytest.approx(PAYLOAD_KG)
    np.testing.assert_allclose(snap.payload_position, session.world.data.xipos[body])
    np.testing.assert_allclose(snap.payload_position, session.world.site_pose(session.world.tcp_site)[0], atol=1e-9)


def test_gen3_l_shape_of_the_limit_drop_counts_as_near_singular_and_the_polish_start_does_not():
    assert capture(Session("limit-drop")).near_singular
    assert not capture(Session("polish")).near_singular


def test_coupling_shapes_hide_near_a_singularity_and_never_exceed_a_metre(server, session):
    view = SceneView(server, session.robot, lambda c: None, VisualSettings(inertia_ellipsoid=True))
    try:
        snap = capture(session)
        huge = {k: 1e9 * v for k, v in snap.P.items()}
        with server.atomic():
            view.update(dataclasses.replace(snap, P=huge, Lambda_translational=1e9 * snap.Lambda_translational))
        o = view.overlays
        # unit spheres scaled by their semi-axes: at most 0.5 m each way, 1 m across
        assert o.coupling_disc.visible and max(o.coupling_disc.scale) <= 0.5 and max(o.inertia.scale) <= 0.5
        center = o.coupling_center
        assert center is not None and np.allclose(o.coupling_disc.position, center)
        assert np.max(np.linalg.norm(o.coupling_outline.points - center, axis=2)) <= 0.5 + 1e-6
        with server.atomic():
            view.update(dataclasses.replace(snap, near_singular=True))
        assert not o.coupling_disc.visible and not o.inertia.visible
        assert o.coupling_label.visible and "singular" in o.coupling_label.text
    finally:
        view.remove()


def test_visual_settings_refuse_unknown_fields_and_bad_values():
    s = VisualSettings()
    with pytest.raises(ValueError):
        s.update(nonsense=1.0)
    with pytest.raises(ValueError):
        s.update(coupling_kind="P_x")
    with pytest.raises(ValueError):
        s.update(force_m_per_n=float("nan"))
    assert [s.projection_name(o) for o in ("j", "f", "a", "d", None)] == ["P_a", "P_f", "P_a", "P_d", "P_a"]
    s.update(coupling_kind="P_f", coupling_gain=2.0)
    assert s.projection_name("d") == "P_f"  # an explicit choice wins over the objective
    assert s.coupling_scale() == pytest.approx(2.0 / 0.5)


def test_visuals_panel_has_a_control_for_every_setting_and_writes_it(server):
    settings = VisualSettings()
    panel = VisualsPanel(server.gui, settings)
    try:
        assert set(panel.handles) == set(field_names())
        panel.handles["coupling"].value = False
        panel.handles["coupling_kind"].value = "P_d"
        panel.handles["coupling_gain"].value = 3.0
        deadline = time.monotonic() + 5.0  # callbacks run on viser's thread pool
        wanted = (False, "P_d", 3.0)
        while (
            time.monotonic() < deadline
            and (settings.coupling, settings.coupling_kind, settings.coupling_gain) != wanted
        ):
            time.sleep(0.02)
        assert (settings.coupling, settings.coupling_kind, settings.coupling_gain) == wanted
        assert settings.projection_name("a") == "P_d"
    finally:
        panel.remove()


def test_the_twin_arm_is_drawn_where_its_bodies_are_and_hidden_without_a_twin(server, session):
    view = SceneView(server, session.robot, lambda c: None)
    try:
        snap = capture(session)
        offset = np.array([0.0, 0.3, 0.0])
        twin = dataclasses.replace(
            snap,
            twin_link_positions=snap.link_positions + offset,
            twin_link_wxyz=snap.link_wxyz.copy(),
            twin_objective="j",
            twin_W={"W": 0.25},
        )
        with server.atomic():
            view.update(twin)
        assert set(view.twin_meshes) == set(view.meshes)
        for name, handle in view.twin_meshes.items():
            i = snap.link_index(name)
            assert handle.visible
            np.testing.assert_allclose(handle.position, snap.link_positions[i] + offset)
        assert view.twin_label is not None and view.twin_label.text == "twin: W_j = 0.25"
        with server.atomic():
            view.update(snap)
        assert not any(h.visible for h in view.twin_meshes.values()) and not view.twin_label.visible
    finally:
        view.remove()


@pytest.mark.parametrize("preset", ["mass-drop", "limit-drop", "polish"])
def test_the_coupling_ellipse_leaves_the_wrist_and_the_payload_in_view_and_its_label_on_it(server, preset):
    """The disc (an ellipsoid of semi-axes `scale` rotated by its quaternion) contains neither the payload
    ball nor the last two links' origins, and its label sits just above its top (≤ 2 cm)."""
    import viser.transforms as vtf

    session = Session(preset)
    session.run(0.02)
    view = SceneView(server, session.robot, lambda c: None)
    try:
        snap = capture(session)
        if snap.near_singular:  # gen3's L-shaped drop start: no coupling shapes; look at them beside it
            snap = dataclasses.replace(snap, near_singular=False)
        with server.atomic():
            view.update(snap)
        o = view.overlays
        assert o.coupling_disc.visible
        c, semi = np.asarray(o.coupling_disc.position), np.asarray(o.coupling_disc.scale)
        R = vtf.SO3(np.asarray(o.coupling_disc.wxyz)).as_matrix()

        def inside(x: np.ndarray, pad: float = 0.0) -> bool:
            local = R.T @ (np.asarray(x) - c)
            return float(np.sum((local / (semi + pad)) ** 2)) <= 1.0

        points = [snap.link_positions[snap.link_index(n)] for n in session.robot.link_names[-2:]]
        points.append(snap.tcp_position)
        if snap.payload_position is not None:
            assert not inside(snap.payload_position, pad=0.04)  # the ball's radius
        assert not any(inside(p) for p in points)
        top = float(np.linalg.norm(R[2, :] * semi))
        gap = float(o.coupling_label.position[2] - (c[2] + top))
        assert 0.0 <= gap <= 0.02 and np.allclose(o.coupling_label.position[:2], c[:2])
    finally:
        view.remove()


def test_a_strongly_coupled_ellipse_is_scaled_down_whole_beside_the_tool_and_framed_by_its_box(server, session):
    """P 30× the polish start's: the disc's largest semi-axis is capped at COUPLING_MAX_SPAN × the circle's
    radius, its rim (the outline) shrinks by the same factor (the tilt is the unscaled one's), its centre is
    clear of the tool by its half-extent plus a payload's radius, and `coupling_extent` (what the camera
    frames) is the disc's box."""
    settings = VisualSettings()
    view = SceneView(server, session.robot, lambda c: None, settings)
    try:
        snap = capture(session)
        strong = dataclasses.replace(snap, P={k: 30.0 * v for k, v in snap.P.items()})
        with server.atomic():
            view.update(strong)
        o = view.overlays
        radius = settings.coupling_radius_m
        semi = np.array(o.coupling_disc.scale)
        assert o.coupling_disc.visible and max(semi) == pytest.approx(COUPLING_MAX_SPAN * radius, rel=1e-9)
        kind = settings.projection_name(strong.objective)
        L = coupling_map(strong.P[kind], strong.subspaces, settings.coupling_scale(strong.objective))
        axes, R = ellipsoid_of_map(L)
        assert max(radius * axes) > 2 * max(semi)  # it would have been more than twice as large
        rim = o.coupling_outline.points[:, 0, :] - o.coupling_center
        # the rim lies on the disc's plane (its normal R[:, 2]) and within its largest semi-axis: scaled alike
        assert np.max(np.abs(rim @ R[:, 2])) < 1e-3 * max(semi)
        assert np.max(np.linalg.norm(rim, axis=1)) == pytest.approx(max(semi), rel=0.02)
        tcp = strong.tcp_position
        out = np.array([tcp[0], tcp[1], 0.0]) / np.linalg.norm(tcp[:2])
        half = float(np.linalg.norm((out @ R) * semi))
        assert (o.coupling_center - tcp) @ out >= half + PAYLOAD_RADIUS_M - 1e-9
        box = o.coupling_extent()  # what the camera frames: the rim inside it, touching each side
        assert box is not None
        rim_world = o.coupling_outline.points[:, 0, :]
        assert np.all(rim_world >= box.min(axis=0) - 1e-6) and np.all(rim_world <= box.max(axis=0) + 1e-6)
        spans = (rim_world.max(axis=0) - rim_world.min(axis=0), box.max(axis=0) - box.min(axis=0))
        assert np.allclose(*spans, rtol=0.05, atol=2.1 * min(semi))  # but for the disc's thickness
    finally:
        view.remove()
