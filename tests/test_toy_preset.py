"""A preset that lives only in the tests (tests/toy_preset.py), registered at test time, runs headless with
its readouts taken from the step log, and reaches the live plots with its own chart, its phase mark and
its readout line, with no edit of the app (the page itself: tests/test_browser_toy.py)."""

from __future__ import annotations

import numpy as np
import pytest

from app.core.session import Session
from app.core.steplog import StepLog
from app.live.frames import FrameBuilder
from app.live.lab import Lab
from app.live.ui.phase import PhaseReader
from app.live.ui.plot_history import phase_markers
from app.live.ui.plots import Plots
from app.scenarios import SCENARIOS, get_scenario
from tests import toy_preset as toy

STEPS = 1000  # 1 s at 1 kHz: past the beat (0.4 s) and the wave's first peak (0.357 s)


@pytest.fixture
def registered(monkeypatch):
    toy.register(monkeypatch)
    return get_scenario(toy.NAME)


def test_the_toy_preset_is_found_only_once_registered(monkeypatch):
    assert toy.NAME not in SCENARIOS
    with pytest.raises(ValueError, match="unknown scenario 'toy'"):
        get_scenario(toy.NAME)
    toy.register(monkeypatch)
    assert get_scenario(toy.NAME) is toy.SCENARIO


def test_the_toy_runs_headless_and_its_readout_comes_out_of_the_step_log(registered):
    """Session and StepLog alone: the fold the preset declares gives the wave's peak over every logged step
    (3 N within the 1 ms sampling: 3·cos(2π·0.7·0.5e-3) ≥ 2.99998); the beat is marked at 0.4 s."""
    session = Session(registered, seed=0)
    log = StepLog(session.robot.nq, capacity=STEPS + 10)
    for _ in range(STEPS):
        log.append(session.step())
    every = log.window(10.0, session.world.model.opt.timestep)
    fold = log.fold("readout", registered.readout_fold)
    assert fold is not None
    readout = fold.value()["toy_peak_wave_n"]
    assert readout == pytest.approx(float(np.max(np.abs(every["toy_wave"]))), abs=1e-12)
    assert readout == pytest.approx(toy.WAVE_N, abs=1e-4)
    np.testing.assert_allclose(every["toy_wave"], toy.wave(every["t"]), atol=1e-12)
    marks = phase_markers(every, registered.segments, registered.phase_marks)
    assert [m.label for m in marks] == ["beat"] and marks[0].t == pytest.approx(toy.BEAT_S, abs=1.5e-3)
    assert registered.readout_text(fold.value()) == [f"Toy wave: peak {readout:.3f} N"]


def test_the_toy_reaches_the_live_plots_with_its_chart_phase_and_readout(registered, server):
    """Through the live lab, the frame builder and the Plots panel: its own chart is built and on top with
    the logged wave, the torque chart under it, its beat marked, its readout line shown and its phase said."""
    lab = Lab(toy.NAME)
    builder = FrameBuilder(1 / 30, 0.1)
    lab.advance(STEPS)
    frame = builder.build(lab, now=0.0)
    assert frame.plot is not None and frame.status.scenario == toy.NAME
    plots = Plots(server)
    plots.focus(None, toy.NAME)
    plots.update(frame.plot, session=1)
    assert plots.layout == (toy.CHART.key, "torque")
    shown = sorted((f.order, key) for key, f in plots.folders.items() if f.visible)
    assert [key for _, key in shown] == [toy.CHART.key, "torque"]
    handle = plots.handles[toy.CHART.key]
    assert handle.title == toy.CHART.title and handle.axes[1]["label"] == toy.CHART.y_label
    drawn = np.asarray(handle.data[1], dtype=float)
    logged = frame.plot.columns["toy_wave"]
    assert np.count_nonzero(np.isfinite(drawn)) >= 10 and np.all(np.isin(drawn[np.isfinite(drawn)], logged))
    lo, hi = handle.scales["y"]["range"]
    assert lo == -hi and toy.WAVE_N <= hi <= 2 * 1.1 * toy.WAVE_N  # the (−1, 1) range widened to hold it
    assert [m.label for m in plots.markers] == ["beat"]
    assert plots.readouts["toy_peak_wave_n"] == pytest.approx(toy.WAVE_N, abs=1e-4)
    assert f"Toy wave: peak {plots.readouts['toy_peak_wave_n']:.3f} N" in plots.readout.content
    assert PhaseReader().text(frame.status) == "toy: after the beat"
    plots.choose_signals(toy.CHART.key, [])  # its one series hides: none of its samples is sent
    assert not np.any(np.isfinite(np.asarray(plots.handles[toy.CHART.key].data[1], dtype=float)))
    plots.stop()  # no resend of its axes after the server stops
