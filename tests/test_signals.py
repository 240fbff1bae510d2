"""Choosing the series a plot draws (app.live.ui.signals): checked on arrival, kept, applied to the charts."""

from __future__ import annotations

import numpy as np
import pytest

from app.live.ui.charts import signal_specs
from app.live.ui.signals import SignalChoice, masked, series_shown


def test_every_series_is_drawn_at_first_and_a_choice_changes_only_its_own():
    choice = SignalChoice(signal_specs(7))
    assert choice.shown_keys("torque") == (*(f"tau_{i}" for i in range(1, 8)), "limits")
    assert choice.set("torque", "tau_3", False) and choice.version == 1
    assert not choice.set("torque", "tau_3", False) and choice.version == 1  # no change, no new version
    assert "tau_3" not in choice.shown_keys("torque") and len(choice.shown_keys("torque")) == 7
    assert choice.shown_keys("deflection") == ("tcp", "elbow", "previous")  # other charts untouched
    assert choice.shown("rtf", "anything")  # a chart with no choice draws what it has


def test_choose_draws_exactly_the_keys_given():
    choice = SignalChoice(signal_specs(7))
    assert choice.choose("torque", ["tau_4", "limits"])
    assert choice.shown_keys("torque") == ("tau_4", "limits")
    assert choice.choose("deflection", {"elbow"}) and choice.shown_keys("deflection") == ("elbow",)
    assert not choice.choose("deflection", ["elbow"])  # the same choice again changes nothing


@pytest.mark.parametrize(
    ("chart", "key", "value", "words"),
    [
        ("torques", "tau_1", False, "no plot 'torques'"),
        ("torque", "tau_8", False, "has no series 'tau_8'"),
        ("torque", "tau_1", "no", "expected true or false"),
        ("torque", "tau_1", 0, "expected true or false"),
        ("torque", "tau_1", None, "expected true or false"),
        ("coupling", "W_x", True, "has no series 'W_x'"),
    ],
)
def test_a_junk_choice_is_refused_in_one_line_and_changes_nothing(chart, key, value, words):
    choice = SignalChoice(signal_specs(7))
    before = choice.as_dict()
    with pytest.raises(ValueError, match=words) as info:
        choice.set(chart, key, value)
    assert "\n" not in str(info.value)
    assert choice.as_dict() == before and choice.version == 0


def test_a_refused_key_in_choose_leaves_the_whole_chart_as_it_was():
    choice = SignalChoice(signal_specs(7))
    with pytest.raises(ValueError, match="tau_9"):
        choice.choose("torque", ["tau_1", "tau_9"])
    assert len(choice.shown_keys("torque")) == 8


def test_a_hidden_series_is_sent_as_nan_and_the_show_flags_only_when_they_change():
    values = np.arange(4.0)
    assert masked(values, True) is values
    assert np.all(np.isnan(masked(values, False))) and len(masked(values, False)) == 4
    series = ({"label": "x"}, {"label": "a"}, {"label": "b", "show": False})
    assert series_shown(series, {1: True, 2: False}) is None  # nothing to send
    out = series_shown(series, {1: False, 2: True})
    assert out is not None and [s.get("show", True) for s in out] == [True, False, True]
    assert out[1]["label"] == "a" and series[1].get("show", True)  # a copy: the old tuple is unchanged
