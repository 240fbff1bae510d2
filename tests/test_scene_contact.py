"""Contact in the 3D scene, live and in replay, read from the scene nodes' own properties: the contact
point and its force arrows, the ring turning red and the marks left where the tool lifted, and every
object of a replayed instant where the live scene had it at that instant."""

from __future__ import annotations

import numpy as np
import pytest

from app.core.commands import SetParam
from app.live.lab import Lab
from app.live.ui.overlay_shapes import on_table
from app.live.ui.overlays import Overlays
from app.live.ui.replay import ArmPoser, instant_snapshot
from app.live.ui.snapshot import capture
from app.live.ui.visuals import VisualSettings
from app.scenarios.metrics import contact_loss_onsets

FRAME_STEPS = 33  # a 30 Hz frame at real time: 33 simulated ms between two scene updates
MARK_WITHIN_S = 0.05


def arrow_vector(handle) -> np.ndarray:
    pts = np.asarray(handle.points, dtype=float).reshape(-1, 2, 3)
    return pts[0, 1] - pts[0, 0]


@pytest.fixture(scope="module")
def slipping_run():
    """Polish with μ = 1 and W_j, 12 s: the tool loses contact on strokes S2 and S4. The scene is drawn
    from a snapshot every FRAME_STEPS steps, as the live page draws it; the snapshots are kept."""
    lab = Lab("polish")
    lab.apply(SetParam("contact", "mu", 1.0))
    lab.apply(SetParam("nullspace", "objective", "j"))
    snaps = []
    for _ in range(12000 // FRAME_STEPS):
        lab.advance(FRAME_STEPS)
        snaps.append(capture(lab.session))
    return lab, snaps


def test_the_contact_loss_mark_appears_live_within_50_ms_of_the_contact_force_reaching_zero(server, slipping_run):
    lab, snaps = slipping_run
    full = lab.log.window(60.0, lab.dt, 1)
    onsets = contact_loss_onsets(full["contact_force_n"], full["segment"])
    assert len(onsets) >= 2  # the run loses contact (else this test proves nothing)
    first_t = float(full["t"][onsets[0]])
    overlays = Overlays(server, VisualSettings(), root="/test_live_contact")
    shown_t, marks = None, 0
    for snap in snaps:
        overlays.update(snap)
        if shown_t is None and overlays.lost_ring.visible and overlays.lift_marks.visible:
            shown_t = snap.t
            marks = len(np.asarray(overlays.lift_marks.points)) // 2
    assert shown_t is not None
    assert 0.0 <= shown_t - first_t <= MARK_WITHIN_S
    assert marks >= 1
    # the cross lies on the table top where the tool was at the onset
    final = snaps[-1]
    tcp_at = np.array([full[f"target_{a}_m"][onsets[0]] for a in "xyz"])  # (a sanity bound only)
    cross = np.asarray(overlays.lift_marks.points, dtype=float)[:2].reshape(-1, 3)
    center = cross.mean(axis=0)
    assert final.table is not None
    top = float(final.table[0][2] + final.table[1][2])
    assert center[2] == pytest.approx(top, abs=3e-3)
    assert np.linalg.norm(center[:2] - final.contact_lifts[0][:2]) < 1e-6
    assert np.linalg.norm(center[:2] - tcp_at[:2]) < 0.05  # beside the target it tracked


def test_contact_arrows_are_the_contact_force_at_the_force_scale_and_visuals_turns_them_off(server, slipping_run):
    _, snaps = slipping_run
    settings = VisualSettings()
    overlays = Overlays(server, settings, root="/test_contact_arrows")
    snap = next(s for s in snaps if s.contact_force is not None and s.contact_force[2] > 15.0)
    overlays.update(snap)
    assert overlays.normal_arrow.visible and overlays.contact_ring.visible and not overlays.lost_ring.visible
    assert snap.contact_force is not None and snap.contact_point is not None
    np.testing.assert_allclose(
        arrow_vector(overlays.normal_arrow), [0, 0, settings.force_m_per_n * snap.contact_force[2]], atol=1e-5
    )
    friction = np.array([snap.contact_force[0], snap.contact_force[1], 0.0])
    if np.linalg.norm(friction) * settings.force_m_per_n > 2e-3:
        np.testing.assert_allclose(arrow_vector(overlays.friction_arrow), settings.force_m_per_n * friction, atol=1e-5)
    np.testing.assert_allclose(np.asarray(overlays.contact_dot.position), snap.contact_point, atol=1e-6)
    settings.update(contact=False)
    overlays.update(snaps[-1])
    assert not any(
        n.visible for n in (overlays.normal_arrow, overlays.friction_arrow, overlays.contact_dot, overlays.lift_marks)
    )
    assert not overlays.contact_ring.visible and not overlays.lost_ring.visible


def test_replay_draws_every_object_where_the_live_scene_had_it_and_the_mark_at_the_loss(server, slipping_run):
    """At logged instants, the replayed snapshot's links, tool, target and contact force equal the live
    snapshot's of that instant; around each loss the ring turns red within 50 ms and the marks count the
    losses so far."""
    lab, snaps = slipping_run
    columns = lab.log.window(60.0, lab.dt, 1)
    poser = ArmPoser(lab.session.world, tuple(lab.session.robot.link_names))
    live_now = snaps[-1]
    overlays = Overlays(server, VisualSettings(), root="/test_replay_contact")
    for snap in snaps[:-1:25]:
        # a live frame captured after the step from t - dt to t mixes two rows a step apart: the bodies where
        # MuJoCo has them at t (the row logged at t), the TCP of the controller's model, the contact and the
        # target of the step's start (the row logged at t - dt); a replayed instant shows one row throughout
        at_t = instant_snapshot(live_now, columns, poser, snap.t)
        assert at_t.t == pytest.approx(snap.t, abs=1e-9)
        np.testing.assert_allclose(at_t.link_positions, snap.link_positions, atol=1e-6)
        row_t = snap.t - lab.dt
        replayed = instant_snapshot(live_now, columns, poser, row_t)
        assert replayed.t == pytest.approx(row_t, abs=1e-9)
        np.testing.assert_allclose(replayed.tcp_position, snap.tcp_position, atol=1e-6)
        assert snap.contact_point is not None
        np.testing.assert_allclose(replayed.contact_point, snap.contact_point, atol=1e-6)
        np.testing.assert_allclose(replayed.target_position, snap.target_position, atol=1e-9)
        np.testing.assert_allclose(replayed.contact_force, snap.contact_force, atol=1e-9)
        np.testing.assert_allclose(replayed.contact_lifts, snap.contact_lifts, atol=1e-6)
        np.testing.assert_allclose(replayed.contact_lift_times, snap.contact_lift_times, atol=1e-9)
        overlays.update(replayed)
        np.testing.assert_allclose(np.asarray(overlays.target.position), snap.target_position, atol=1e-6)
    onsets = contact_loss_onsets(columns["contact_force_n"], columns["segment"])
    for k, i in enumerate(onsets[:4]):
        t0 = float(columns["t"][i])
        overlays.update(instant_snapshot(live_now, columns, poser, t0 - 0.005))
        assert len(np.asarray(overlays.lift_marks.points)) // 2 == k if k else not overlays.lift_marks.visible
        overlays.update(instant_snapshot(live_now, columns, poser, t0))
        assert overlays.lost_ring.visible and overlays.lift_marks.visible
        assert len(np.asarray(overlays.lift_marks.points)) // 2 == k + 1
        center = np.asarray(overlays.lift_marks.points, dtype=float)[2 * k : 2 * k + 2].reshape(-1, 3).mean(axis=0)
        assert live_now.table is not None
        np.testing.assert_allclose(center, on_table(live_now.contact_lifts[k], live_now.table), atol=1e-6)


def test_replay_poses_the_payload_with_the_arm(server):
    """Limit-drop's payload hangs at the tool: replayed at a logged instant it is where the live scene drew it."""
    lab = Lab("limit-drop")
    kept = []
    for _ in range(6):
        lab.advance(100)
        kept.append(capture(lab.session))
    lab.advance(10)  # the row of the last kept frame's instant is logged by the next step
    columns = lab.log.window(60.0, lab.dt, 1)
    poser = ArmPoser(lab.session.world, tuple(lab.session.robot.link_names))
    live_now = capture(lab.session)
    assert live_now.payload_position is not None
    overlays = Overlays(server, VisualSettings(), root="/test_replay_payload")
    moved = 0.0
    for snap in kept:
        replayed = instant_snapshot(live_now, columns, poser, snap.t)
        overlays.update(replayed)
        assert overlays.payload.visible
        np.testing.assert_allclose(np.asarray(overlays.payload.position), snap.payload_position, atol=1e-6)
        moved = max(moved, float(np.linalg.norm(snap.payload_position - live_now.payload_position)))
    assert moved > 0.01  # the payload moved during the run: a payload left at the live place would fail


def test_replay_draws_the_falling_mass_where_it_was_logged(server):
    """Mass-drop's mass hangs on a rope, not on the arm: replayed, it is where the run logged it."""
    lab = Lab("mass-drop")
    lab.advance(2500)  # released at 1.5 s, falls and swings
    columns = lab.log.window(60.0, lab.dt, 1)
    poser = ArmPoser(lab.session.world, tuple(lab.session.robot.link_names))
    live_now = capture(lab.session)
    assert live_now.payload_position is not None
    overlays = Overlays(server, VisualSettings(), root="/test_replay_mass")
    for t in (1.0, 1.7, 2.0, 2.3):
        i = int(np.searchsorted(columns["t"], t))
        logged = np.array([columns[f"payload_{a}_m"][i] for a in "xyz"])
        overlays.update(instant_snapshot(live_now, columns, poser, t))
        np.testing.assert_allclose(np.asarray(overlays.payload.position), logged, atol=1e-6)
    fell = columns["payload_z_m"][np.searchsorted(columns["t"], 1.0)] - columns["payload_z_m"][-1]
    assert fell > 0.02  # the mass fell: left at the live place, it would be at the same place every instant


def test_replay_poses_the_twin_arm_at_its_logged_posture(server):
    """Polish with a W_a twin: replayed at a logged instant, the twin's links stand where the live scene
    had them at that instant (the twin's own posture, not the main arm's nor the live one)."""
    from app.core.commands import SetTwin
    from app.live.frames import _with_twin

    lab = Lab("polish")
    lab.apply(SetParam("nullspace", "objective", "j"))
    lab.apply(SetTwin("a"))
    kept = []
    for _ in range(4):
        lab.advance(1500)
        kept.append(_with_twin(capture(lab.session), lab.twin))
    lab.advance(10)
    columns = lab.log.window(60.0, lab.dt, 1)
    assert lab.twin is not None
    columns |= {f"twin_{k}": v for k, v in lab.twin.columns_at(columns["t"]).items() if k.startswith("q_")}
    poser = ArmPoser(lab.session.world, tuple(lab.session.robot.link_names))
    live_now = _with_twin(capture(lab.session), lab.twin)
    for snap in kept:
        replayed = instant_snapshot(live_now, columns, poser, snap.t)
        np.testing.assert_allclose(replayed.twin_link_positions, snap.twin_link_positions, atol=1e-6)
        np.testing.assert_allclose(replayed.link_positions, snap.link_positions, atol=1e-6)
    assert float(np.max(np.abs(kept[0].twin_link_positions - live_now.twin_link_positions))) > 1e-3
    assert max(float(np.max(np.abs(s.twin_link_positions - s.link_positions))) for s in kept) > 1e-3  # its own posture
