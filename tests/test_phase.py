"""The status line's phase, from the scenario's own signals."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from app.live.ui.phase import PhaseReader


def _status(scenario: str, t: float, focus_joint: int | None = None, **signals: float) -> SimpleNamespace:
    return SimpleNamespace(scenario=scenario, t=t, signals=signals, focus_joint=focus_joint)


def test_polish_phase_names_contact_settling_with_w_swivel_seconds_then_each_stroke_and_the_end():
    reader = PhaseReader()
    scene = SimpleNamespace(objective="a", W={"W_a": 12.5})
    assert reader.text(_status("polish", 0.5, segment=0.0), scene).startswith("contact")
    settling = reader.text(_status("polish", 4.2, segment=0.0, swivel_deg=-31.6, settle_s=3.2), scene)
    assert settling == "settling: W_a = 12.5, swivel -32°, 3.2 s"
    assert reader.text(_status("polish", 20.0, segment=2.0), scene) == "S2 (forward stroke)"
    assert reader.text(_status("polish", 21.0, segment=3.0), scene) == "S3 (back stroke)"
    assert reader.text(_status("polish", 40.0, segment=7.0), scene).startswith("done")


def test_a_planned_case_says_it_follows_the_planned_path_not_an_objectives_settling():
    reader = PhaseReader()
    scene = SimpleNamespace(objective="j", W={"W_j": 0.4})  # the planned case runs W_j's gains underneath
    status = _status("polish", 4.2, segment=0.0, swivel_deg=-12.4, swivel_plan_deg=-20.2, settle_s=3.2)
    status.variant = "planned W_a"
    text = reader.text(status, scene)
    assert text == "moving to the planned W_a path's start: swivel -12° (planned -20°), 3.2 s"
    assert "W_j" not in text and "settling" not in text


def test_mass_drop_phase_follows_the_release_signal():
    reader = PhaseReader()
    assert reader.text(_status("mass-drop", 1.0, mass_released=0.0)) == "holding the mass"
    assert reader.text(_status("mass-drop", 2.0, mass_released=1.0)).startswith("dropped")


def test_limit_drop_phase_is_the_drop_while_the_joint_moves_and_done_once_it_rests():
    reader = PhaseReader()
    q = np.zeros(7)
    texts = []
    for k, q4 in enumerate([0.0, 0.05, 0.15, 0.25, 0.3, 0.3, 0.3]):  # frames 0.1 s apart
        q = q.copy()
        q[3] = q4
        texts.append(reader.text(_status("limit-drop", 0.1 * k, focus_joint=3), SimpleNamespace(q=q)))
    assert all(t.startswith("drop") for t in texts[:5])
    assert texts[-1] == "done: joint 4 at rest"
    assert reader.text(_status("free", 1.0)) == ""


def test_the_drops_start_paused_by_their_own_flag_and_an_unknown_preset_does_not():
    """The app starts a preset paused when the scenario says it is over in seconds (the two drops)."""
    from app.live.ui.phase import starts_paused
    from app.scenarios import SCENARIOS

    assert {name for name in SCENARIOS if starts_paused(name)} == {"limit-drop", "mass-drop"}
    assert not starts_paused("no-such-preset")
