"""Replay without a browser: the events found in logged columns, and the arm posed from a logged posture."""

from __future__ import annotations

import numpy as np
import pytest

from app.live.lab import Lab
from app.live.ui.replay import ArmPoser, find_events


def test_events_are_the_phase_changes_fallback_onsets_contact_losses_and_a_halt():
    t = np.arange(0.0, 10.0, 0.01)
    seg = np.where(t < 2.0, 0.0, np.where(t < 4.0, 1.0, 2.0))
    fallback = ((t > 5.0) & (t < 5.5)).astype(float)
    fd = np.full(len(t), 20.0)
    fz = np.where((t > 7.0) & (t < 7.2), 0.0, 20.0)
    events = find_events(
        {"t": t, "segment": seg, "fallback": fallback, "F_z": fz, "Fd_z": fd}, halted="diverged", segments=6
    )
    got = [(e.label, round(e.t, 2)) for e in events]
    assert got == [("S1", 2.0), ("S2", 4.0), ("QP fallback", 5.01), ("contact lost", 7.01), ("halt", 9.99)]


def test_the_poser_puts_the_links_where_the_simulation_had_them():
    lab = Lab("limit-drop")
    lab.advance(800)
    world, robot = lab.session.world, lab.session.robot
    names = tuple(robot.link_names)
    poser = ArmPoser(world, names)
    q_now = world.q.copy()
    expected = world.data.xpos[world.body_ids(names)].copy()
    lab.advance(400)  # the arm moves on; the poser works on its own data
    positions, wxyz, tcp, _ = poser.pose(q_now)
    np.testing.assert_allclose(positions, expected, atol=1e-9)
    assert np.allclose(np.linalg.norm(wxyz, axis=1), 1.0)
    margins = np.where(robot.endless, np.inf, np.minimum(q_now - robot.q_lower, robot.q_upper - q_now))
    assert poser.margins(q_now) == pytest.approx(margins)
    np.testing.assert_allclose(tcp, lab.session.dyn.tcp_position_world, atol=0.5)  # on the arm, roughly


def test_the_poser_computes_the_coupling_terms_at_the_replayed_posture():
    """The replayed instant's P and W are those of the model at that posture (as the live scene's are
    at the live one), not the live instant's."""
    from app.live.ui.snapshot import capture

    lab = Lab("limit-drop")
    lab.advance(200)
    poser = ArmPoser(lab.session.world, tuple(lab.session.robot.link_names))
    before = capture(lab.session)
    q_then = lab.session.world.q.copy()
    lab.advance(600)  # joint 4 falls on
    now = capture(lab.session)
    got = poser.coupling(q_then, before.subspaces)
    assert got is not None
    P, W = got
    np.testing.assert_allclose(P["P_a"], before.P["P_a"], rtol=1e-2)  # one step apart at most, near-singular
    assert W["W_a"] == pytest.approx(before.W["W_a"], rel=1e-2)
    assert not np.allclose(P["P_a"], now.P["P_a"], rtol=0.1)  # the live instant's differ by more than 10 %
