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
    contact = np.where((t > 7.0) & (t < 7.2), 0.0, 20.0)  # the true normal contact force (N)
    contact[(t > 0.05) & (t < 0.1)] = 0.0  # a bounce while landing, before the strokes: not watched
    events = find_events(
        {"t": t, "segment": seg, "fallback": fallback, "contact_force_n": contact}, halted="diverged", segments=6
    )
    got = [(e.label, round(e.t, 2)) for e in events]
    assert got == [("S1", 2.0), ("S2", 4.0), ("QP fallback", 5.01), ("contact lost", 7.01), ("halt", 9.99)]


def test_every_event_is_listed_and_fallback_onsets_close_together_are_one_burst():
    """40 fallbacks 0.2 s apart are 40 events (no cap at 20); 5 onsets 10 ms apart are one burst of 5."""
    t = np.arange(0.0, 12.0, 0.005)
    fallback = np.zeros(len(t))
    for k in range(40):
        fallback[(t >= 0.2 * k + 0.1) & (t < 0.2 * k + 0.12)] = 1.0
    for k in range(5):
        fallback[(t >= 10.0 + 0.01 * k) & (t < 10.005 + 0.01 * k)] = 1.0
    events = find_events({"t": t, "fallback": fallback})
    assert len(events) == 41
    assert events[-1].label == "QP fallback ×5" and events[-1].t == pytest.approx(10.0, abs=0.006)


def test_polish_lists_no_contact_loss_while_the_tool_lands_and_holds():
    """The tool lands, bounces once and presses through the first 1.5 s of polish: the F/T reading is
    below 1 N at 0.02 s and the true force is zero around 0.08 s, but the strokes have not begun and the
    contact is not lost (the old rule, F/T reading < 1 N with the setpoint > 5 N, listed 0.02 s)."""
    lab = Lab("polish")
    lab.advance(1500)
    columns = lab.log.window(60.0, lab.dt, 5)
    assert float(np.min(columns["contact_force_n"])) <= 0.0  # the landing's bounce is in the log
    assert [e for e in find_events(columns) if e.label == "contact lost"] == []


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
