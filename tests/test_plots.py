"""Live plots: finite ranges whatever the data, titles that say what is plotted, history, markers, readouts."""

from __future__ import annotations

import dataclasses
import time
from collections import deque

import numpy as np
import pytest

from app.core.commands import StepOnce
from app.live.loop import SimLoop
from app.live.ui.chart_draws import (
    COUPLING_TITLE,
    FORCE_RANGE_N,
    FORCE_TITLE,
    NEUTRAL_FORCE_TITLE,
    NO_SETPOINT_TITLE,
)
from app.live.ui.plot_axes import nice_ceiling
from app.live.ui.plot_history import SignalHistory, phase_markers, segment_std
from app.live.ui.plots import Plots
from app.live.ui.snapshot import capture
from app.scenarios.limit_drop import LimitDropScenario


def _has_rate(plot) -> bool:
    """The frame's columns hold a live σ (the offload's figures arrive a few steps after their step)."""
    return bool(np.any(np.isfinite(plot.columns.get("margin_rate", np.zeros(0)))))


def _plot_data(scenario: str, steps: int = 300):
    loop = SimLoop(scenario, capture=capture)
    assert loop.offload.ready(120.0)  # the live margin's worker process: its figures from the first step on
    loop.start(running=False)
    try:
        loop.submit(StepOnce(steps))
        loop.sync()
        frame = loop.wait_frame(0, timeout=10.0)
        deadline = 50
        until = time.monotonic() + 60.0  # polish: until its first live σ is in (a loaded machine may take seconds)

        def wanting(frame) -> bool:
            if frame is None or frame.plot is None or len(frame.plot.monitor["t"]) < 2:
                return True
            return scenario == "polish" and not _has_rate(frame.plot)

        while wanting(frame) and (deadline or (scenario == "polish" and time.monotonic() < until)):
            loop.submit(StepOnce(100))
            loop.sync()
            frame = loop.wait_frame(frame.seq if frame else 0, timeout=5.0)
            deadline -= 1
        assert frame is not None and frame.plot is not None
        return frame.plot
    finally:
        loop.stop()


@pytest.fixture(scope="module")
def polish():
    return _plot_data("polish")


@pytest.fixture(scope="module")
def drop():
    return _plot_data("limit-drop")


def test_a_run_paused_at_its_start_is_not_said_to_have_no_force_setpoint(server, polish, drop):
    """After limit-drop (no setpoint), polish reset and paused at t = 0 (one row, no setpoint yet) is titled
    neither way; its first samples with the setpoint name it."""
    import dataclasses

    plots = Plots(server)
    plots.update(drop, session=1)
    assert plots.handles["force"].title == NO_SETPOINT_TITLE
    start = {k: v[:1].copy() for k, v in polish.columns.items()}
    start["Fd_z"][:] = 0.0
    plots.update(dataclasses.replace(polish, columns=start), session=2)
    assert plots.handles["force"].title == NEUTRAL_FORCE_TITLE
    plots.update(polish, session=2)
    assert plots.handles["force"].title == FORCE_TITLE


def test_force_plot_says_when_there_is_no_force_setpoint(server, polish, drop):
    plots = Plots(server)
    plots.update(polish, session=1)
    assert np.any(polish.columns["Fd_z"] != 0) and plots.handles["force"].title == FORCE_TITLE
    plots.update(drop, session=2)
    assert np.all(drop.columns["Fd_z"] == 0) and plots.handles["force"].title == NO_SETPOINT_TITLE
    # the L-shape is near a singularity: W is not plotted there and the heading says why
    assert np.all(np.isnan(drop.monitor["W_a"])) and COUPLING_TITLE + ":" in plots.headings["coupling"].content
    plots.update(polish, session=3)
    assert plots.headings["coupling"].content == f"**{COUPLING_TITLE}**" and np.all(np.isfinite(polish.monitor["W_a"]))


def test_every_plot_has_a_finite_y_range_and_data_with_no_twin(server, polish, drop):
    """The twin's series is all NaN without a twin: the force plot keeps a fixed finite range and is
    sent finite samples of the main arm (uPlot's auto range turned that into a blank plot)."""
    plots = Plots(server)
    for session, plot in enumerate((polish, drop)):
        plots.update(plot, session=session)
        for handle in (plots.handles[k] for k in ("force", "rate", "torque", "rtf", "W_f", "W_a", "W_d")):
            lo, hi = handle.scales["y"]["range"]
            assert np.isfinite(lo) and np.isfinite(hi) and hi > lo
        lo, hi = plots.handles["force"].scales["y"]["range"]
        err = plots.handles["force"].data[1]
        top = float(np.nanmax(np.abs(err)))
        assert lo == -hi and top <= hi <= 2.5 * max(1.1 * top, FORCE_RANGE_N)  # covers the data, not much more
        assert np.count_nonzero(np.isfinite(plots.handles["force"].data[1])) >= 3  # every plotted sample is finite
        assert plots.handles["force"].series[2].get("show") is False  # no twin: its legend entry is hidden
        assert plots.handles["force"].data[0][-1] == pytest.approx(0.0)  # x is the time before now


def test_y_range_widens_in_one_two_five_steps_and_comes_back(server, polish):
    assert [nice_ceiling(v, 10.0) for v in (3.0, 10.0, 10.5, 27.0, 51.0, 180.0)] == [10, 10, 20, 50, 100, 200]
    plots = Plots(server)
    big = dict(polish.columns)
    big["force_error_n"] = polish.columns["force_error_n"] + 0.0
    plots.update(polish, session=1)
    hi = nice_ceiling(1.1 * float(np.nanmax(np.abs(polish.columns["force_error_n"]))), FORCE_RANGE_N)
    assert plots.handles["force"].scales["y"]["range"] == (-hi, hi)
    big["force_error_n"][-3] = 3.0 * hi
    plots.update(dataclasses.replace(polish, columns=big), session=2)
    wide = nice_ceiling(3.3 * hi, FORCE_RANGE_N)
    assert plots.handles["force"].scales["y"]["range"] == (-wide, wide)
    plots.update(polish, session=3)
    assert plots.handles["force"].scales["y"]["range"] == (-hi, hi)


def test_history_keeps_sixty_seconds_appends_new_rows_and_restarts_on_a_reset():
    h = SignalHistory(seconds=60.0)
    for start in np.arange(0.0, 80.0, 5.0):  # overlapping 10 s windows every 5 s, 50 samples per second
        t = np.arange(start, start + 10.0, 0.02)
        h.add({"t": t, "x": np.sin(t)})
    assert np.all(np.diff(h.t) > 0)
    assert h.t[-1] == pytest.approx(84.98) and h.t[0] >= 84.98 - 60.0 - 1e-9
    assert h.t[0] == pytest.approx(24.98, abs=0.03)
    np.testing.assert_allclose(h.columns["x"], np.sin(h.t))
    assert len(h.window(10.0)["t"]) == pytest.approx(501, abs=1)
    h.add({"t": np.arange(0.0, 1.0, 0.02), "y": np.ones(50)})  # a reset: time starts again
    assert h.t[0] == 0.0 and len(h.t) == 50 and "x" not in h.columns


def test_markers_and_segment_std_from_the_segment_signal():
    t = np.arange(0.0, 20.0, 0.02)
    seg = np.clip(np.floor((t - 2.0) / 2.5) + 1, 0, 7)
    rng = np.random.default_rng(0)
    err = rng.normal(0.0, 1.0, len(t)) * np.where(seg % 2 == 0, 3.0, 1.0)
    columns = {"t": t, "segment": seg, "e": err, "payload_attached": (t < 5.0).astype(float)}
    marks = phase_markers(columns, 6, LimitDropScenario.phase_marks)
    labels = [m.label for m in marks]
    assert labels == ["S1", "S2", "release", "S3", "S4", "S5", "S6", "end"]
    s1 = next(m for m in marks if m.label == "S1")
    assert s1.t == pytest.approx(2.0, abs=0.021)
    std = segment_std(columns, "e", 6)
    assert sorted(std) == [1, 2, 3, 4, 5, 6]
    assert std[2] / std[1] == pytest.approx(3.0, rel=0.25) and std[4] / std[3] == pytest.approx(3.0, rel=0.25)


def test_freeze_holds_the_picture_while_the_history_fills(server, polish):
    plots = Plots(server)
    plots.update(polish, session=1)
    shown = plots.handles["force"].data
    plots.freeze.value = True
    later = {k: v.copy() for k, v in polish.columns.items()}
    later["t"] = later["t"] + 5.0
    plots.update(dataclasses.replace(polish, columns=later), session=1)
    assert plots.handles["force"].data is shown and plots.history.t[-1] == pytest.approx(later["t"][-1])
    plots.freeze.value = False
    plots.update(dataclasses.replace(polish, columns=later), session=1)
    assert plots.handles["force"].data is not shown


def test_window_choice_sets_the_x_range(server, polish):
    plots = Plots(server)
    plots.update(polish, session=1)
    assert plots.handles["force"].scales["x"]["range"] == (-10.0, 0.0)
    plots.window.value = "60 s"
    plots._on_window()
    assert plots.handles["force"].scales["x"]["range"] == (-60.0, 0.0)
    assert all(h.scales["x"]["range"] == (-60.0, 0.0) for h in (plots.handles[k] for k in ("W_f", "W_a", "W_d")))


def test_limit_drop_readout_names_the_peak_torque_of_the_falling_joint(server, drop):
    plots = Plots(server)
    plots.focus(3)
    plots.update(drop, session=1)
    assert drop.peak_abs_tau is not None
    assert plots.readouts["peak_torque_nm"] == pytest.approx(float(drop.peak_abs_tau[3]))
    assert plots.readouts["peak_torque_nm"] >= float(np.nanmax(np.abs(drop.columns["tau_4"])))  # ≥ the plotted samples
    assert "peak |τ|" in plots.readout.content


def test_peak_torque_comes_from_every_step_not_the_plotted_samples():
    """The limit drop's peak |τ₄| and max q₄, folded in 100 steps at a time, equal those of every
    logged 1 ms step; the ≈ 50 samples per second the plots get miss the peak's exact step."""
    from app.live.frames import plot_data
    from app.live.lab import Lab

    lab = Lab("limit-drop")
    for _ in range(20):
        lab.advance(100)
        peak_tau, peak_q = lab.log.extremes()
    every = lab.log.window(60.0, lab.dt)
    assert peak_tau[3] == np.max(np.abs(every["tau_4"])) and peak_q[3] == np.max(every["q_4"])
    plot = plot_data(lab, deque())
    assert plot.peak_abs_tau is not None and plot.peak_abs_tau[3] == peak_tau[3]
    assert np.max(np.abs(plot.columns["tau_4"])) <= peak_tau[3]
    lab.reset()
    assert np.all(np.isnan(lab.log.extremes()[0]))  # a reset starts the peak again


def test_twin_force_error_std_is_taken_over_the_twins_own_segments(server, polish):
    """A W_j twin starts its zig-zag ~20 s before a W_d main arm: its per-segment STD uses its own
    segment signal, so a ±3 N square wave in the twin's S2 reads 3.0 N there and 0 in its S1."""
    t = np.arange(0.0, 40.0, 0.02)
    main_seg = np.clip(np.floor((t - 22.0) / 2.5) + 1, 0, 7)
    twin_seg = np.clip(np.floor((t - 2.0) / 2.5) + 1, 0, 7)
    err = np.where(twin_seg == 2, np.where(np.arange(len(t)) % 2 == 0, 3.0, -3.0), 0.0)
    base = {k: np.zeros(len(t)) for k in polish.columns}
    columns = base | {"t": t, "segment": main_seg, "twin_segment": twin_seg, "twin_force_error_n": err}
    plots = Plots(server)
    plots.update(dataclasses.replace(polish, columns=columns, segment_std=None, twin_segment_std=None), session=1)
    assert plots.readouts["twin_force_error_std_S2"] == pytest.approx(3.0, abs=1e-3)
    assert plots.readouts["twin_force_error_std_S1"] == pytest.approx(0.0)
    assert plots.readouts["force_error_std_S2"] == pytest.approx(0.0)


def test_segment_std_comes_from_every_step_for_the_main_arm_and_the_twin():
    """Polish with a W_j arm and a W_j twin (both settle within about a second): the per-segment
    force-error STD the loop folds in 100 steps at a time equals that of every logged step (1e-9 N),
    for each arm from its own log and segments."""
    from app.core.commands import SetParam, SetTwin
    from app.live.frames import plot_data
    from app.live.lab import Lab

    lab = Lab("polish", robot="rizon4s", executor="projection")
    lab.apply(SetParam("nullspace", "objective", "j"))
    lab.apply(SetTwin("j"))
    while lab.session.last is None or lab.session.last.signals.get("segment", 0.0) < 3:
        lab.advance(100)
        main, twin = lab.log.segment_force_error_std(), lab.twin.log.segment_force_error_std()
        assert lab.session.world.time < 30.0
    for log, got in ((lab.log, main), (lab.twin.log, twin)):
        every = log.window(60.0, lab.dt)
        want = segment_std({"segment": every["segment"], "e": every["force_error_n"]}, "e", 6)
        assert set(got) == set(want)
        for k in want:
            assert got[k] == pytest.approx(want[k], abs=1e-9)
    assert {1, 2} <= set(main) and {1, 2} <= set(twin)
    plot = plot_data(lab, deque())
    assert plot.segment_std == main and plot.twin_segment_std == twin


def test_the_margin_plot_shows_the_logged_stroke_headroom_and_decay_rate_of_the_polish_force_loop(server, polish, drop):
    """Polish logs σ every 100 steps (finite, within the plot's range) and the stroke headroom h, NaN
    before the strokes; a headroom far below 0 widens the range to hold it; the limit drop has neither
    and its margin plot stays empty with its fixed range."""
    import dataclasses

    plots = Plots(server)
    plots.update(polish, session=1)
    headroom, rate = (np.asarray(plots.handles["rate"].data[k], dtype=float) for k in (1, 2))
    logged = polish.columns["margin_rate"]
    assert np.any(np.isfinite(rate)) and np.all(np.isin(rate[np.isfinite(rate)], logged))
    assert np.all(np.isnan(polish.columns["margin_headroom_np"])) and np.all(np.isnan(headroom))  # still settling
    lo, hi = plots.handles["rate"].scales["y"]["range"]
    assert lo == -hi and np.nanmax(np.abs(rate)) <= hi
    # a short plot: two or three ticks (−max, 0), ≥ 40 px apart in a 330 px wide panel at its aspect
    splits = plots.handles["rate"].axes[1]["splits"]
    assert 2 <= len(splits) <= 3 and 0.0 in splits
    assert (330 / plots.handles["rate"].aspect - 60) / len(splits) >= 40  # minus the title and the x axis
    deep = np.linspace(-30.0, 2.5, len(polish.columns["t"]))
    stroke = dataclasses.replace(polish, columns={**polish.columns, "margin_headroom_np": deep})
    plots.update(stroke, session=2)
    headroom = np.asarray(plots.handles["rate"].data[1], dtype=float)
    lo, hi = plots.handles["rate"].scales["y"]["range"]
    assert (
        np.nanmin(headroom) == pytest.approx(-30.0)
        and -hi <= -30.0
        and np.all(np.isin(headroom[np.isfinite(headroom)], deep))
    )
    plots.update(drop, session=3)
    assert not np.any(np.isfinite(np.asarray(plots.handles["rate"].data[1], dtype=float)))
    assert not np.any(np.isfinite(np.asarray(plots.handles["rate"].data[2], dtype=float)))


def test_a_redraw_with_nothing_new_sends_no_chart_options_again(server, polish, drop):
    """Options (scales, axes, title) rebuild a chart in the browser: a second redraw of the same data,
    with or without a damper group (NaN d_s, d_i), must not send any of them again."""
    for plot in (polish, drop):
        plots = Plots(server)
        plots.update(plot, session=1)
        handles = dict(plots.handles)
        before = {k: (h.scales, h.axes, h.title) for k, h in handles.items()}
        plots.redraw()
        after = {k: (h.scales, h.axes, h.title) for k, h in handles.items()}
        assert all(before[k][i] is after[k][i] for k in handles for i in range(3)), plot


@pytest.mark.skipif(not __import__("robots").external.installed("panda"), reason="needs the robots extra")
def test_the_limit_drop_readout_measures_the_pandas_fall_toward_its_lower_limit(server):
    """On the Panda joint 4 falls toward its lower limit: the plot data says so and carries min q₄ over
    every step, and the readout's distance beyond d_s is taken from the lower limit's side
    ((q⁻ + d_s) − min q₄); the Gen3's stays on its upper side."""
    from app.live.frames import plot_data
    from app.live.lab import Lab

    lab = Lab("limit-drop", robot="panda")
    lab.advance(400)
    plot = plot_data(lab, deque())
    every = lab.log.window(60.0, lab.dt)
    assert plot.fall_direction == -1 and plot.low_q is not None and plot.low_q[3] == np.min(every["q_4"])
    lo, hi = lab.session.robot.q_lower[3], lab.session.robot.q_upper[3]
    plots = Plots(server)
    plots.focus(3)
    plots.update(plot, session=1)
    expected = (lo + 0.01 * (hi - lo)) - float(np.min(every["q_4"]))
    assert plots.readouts["overshoot_beyond_ds_rad"] == pytest.approx(expected, abs=1e-12)
    assert plot_data(Lab("limit-drop"), deque()).fall_direction == 1


def _finite(values) -> int:
    return int(np.count_nonzero(np.isfinite(np.asarray(values, dtype=float))))


def test_the_signals_chosen_for_a_plot_are_the_ones_it_draws_across_a_switch_and_a_reset(server, polish, drop):
    """Torque plot: joints 2 and 5 only: every other joint's series is hidden and sent without a finite sample,
    and the y range covers only the shown joints; a checkbox unticked in the page hides its series the same
    way; a preset switch (new session) and a blank new run keep the choice; W_d's plot and the margin plot hide;
    an unknown series is refused in one line and changes nothing."""
    plots = Plots(server)
    plots.update(drop, session=1)
    n = plots.n
    big = max(range(n), key=lambda i: float(np.nanmax(np.abs(drop.columns[f"tau_{i + 1}"] / drop.tau_max[i]))))
    keep = [k for k in (1, 4) if k != big][:2]  # two joints, not the one with the largest torque share
    plots.choose_signals("torque", [f"tau_{k + 1}" for k in keep] + ["limits"])
    series = plots.handles["torque"].series
    for i in range(n):
        assert series[i + 1].get("show", True) is (i in keep), i
        assert (_finite(plots.handles["torque"].data[i + 1]) > 0) is (i in keep), i
    top = max(float(np.nanmax(np.abs(100 * drop.columns[f"tau_{k + 1}"] / drop.tau_max[k]))) for k in keep)
    hi = plots.handles["torque"].scales["y"]["range"][1]
    assert hi == (nice_ceiling(1.05 * top, 110.0) if top > 110.0 else 110.0)  # the shown joints' range only
    assert plots.signal_boxes[("torque", f"tau_{big + 1}")].value is False  # the checkbox follows
    # what a checkbox the page unticks calls (the browser test clicks the real one)
    plots._on_signal_box("deflection", "elbow", False)
    assert plots.handles["deflection"].series[2]["show"] is False
    plots._on_signal_box("coupling", "W_d", False)
    plots._on_signal_box("force", "rate", False)
    assert not plots.handles["W_d"].visible and plots.handles["W_a"].visible and not plots.handles["rate"].visible
    # a preset switch and a new run's blank charts keep the choice
    plots.update(polish, session=2)
    plots.update(dataclasses.replace(polish, columns={k: v[:1] for k, v in polish.columns.items()}), session=3)
    plots.update(polish, session=4)
    assert [i for i in range(n) if plots.handles["torque"].series[i + 1].get("show", True)] == keep
    assert all(_finite(plots.handles["torque"].data[i + 1]) == 0 for i in range(n) if i not in keep)
    assert plots.handles["deflection"].series[2]["show"] is False and not plots.handles["W_d"].visible
    before = plots.signals.as_dict()
    with pytest.raises(ValueError, match="no series 'tau_99'"):
        plots.choose_signals("torque", ["tau_1", "tau_99"])
    assert plots.signals.as_dict() == before


def test_the_readouts_name_the_run_they_were_measured_on_and_a_change_during_it(server):
    """The readout line's first line names the run (preset, case, robot, controller, the values changed
    from the preset's defaults); a parameter changed after the reset is named as mixing two set-ups."""
    from app.core.commands import SetParam
    from app.live.frames import FrameBuilder
    from app.live.lab import Lab

    lab = Lab("limit-drop")
    builder = FrameBuilder(publish_period=1 / 30, plot_period=0.1)
    lab.advance(300)
    plots = Plots(server)
    plots.focus(3)
    plot = builder.build(lab, now=0.0).plot
    assert plot is not None and plot.run.startswith("limit-drop (case position) on gen3, compliance-qp")
    assert "(the preset's defaults)" in plot.run and "changed during this run" not in plot.run
    plots.update(plot, session=1)
    first = plots.readout.content.split("  \n")[0]
    assert first == f"*Run:* {plot.run}" and "peak |τ|" in plots.readout.content
    lab.apply(SetParam("damper", "lambda_", 400.0))
    lab.advance(100)
    plot = builder.build(lab, now=1.0).plot
    assert plot is not None and "λ (damper.lambda_) = 400 1/s" in plot.run
    assert "changed during this run (damper.lambda_ = 400.0)" in plot.run
    lab.reset()
    lab.advance(100)
    plot = builder.build(lab, now=2.0).plot
    assert plot is not None and "λ (damper.lambda_) = 400 1/s" in plot.run and "changed during" not in plot.run


@pytest.mark.parametrize("top_mm", [0.0, 1e-7, 2e-4, 0.003, 0.04, 0.3, 4.9, 27.0, 480.0])
def test_the_deflection_ticks_are_distinct_numbers_with_their_unit_at_any_scale(top_mm):
    """The deflection range holds the data (never below 10 µm: an arm at rest) and its ticks' texts, which
    the page writes as sent, are distinct and read back as the ticks (uPlot's three decimals wrote "0 0 0 0"
    for a range of a few µm)."""
    from app.live.ui.chart_draws import DEFLECTION_MIN_MM, deflection_range
    from app.live.ui.plot_axes import y_axis

    lo, hi = deflection_range(top_mm)
    assert lo == 0.0 and hi >= max(top_mm, DEFLECTION_MIN_MM) and hi <= max(2.5 * 1.1 * top_mm, 10.0)
    axis = y_axis("deflection (mm)", lo, hi)
    splits, texts = axis["splits"], axis["values"]  # type: ignore[typeddict-item]
    assert len(splits) >= 2 and len(set(texts)) == len(texts) and axis["label"].endswith("(mm)")
    step = splits[1] - splits[0]
    np.testing.assert_allclose([float(t.replace(",", "")) for t in texts], splits, rtol=0, atol=1e-9 * step)
    assert axis["size"] >= 16 + 7 * max(len(t) for t in texts)


def test_an_untitled_plot_gets_its_top_tick_and_a_titled_one_keeps_its_top_clear():
    from app.live.ui.plot_axes import y_axis

    assert y_axis("W_a (kg²)", 0.0, 1.0, top=True)["splits"] == (0.0, 0.5, 1.0)
    assert y_axis("F̂ − F (N)", -20.0, 20.0)["splits"] == (-20.0, -10.0, 0.0, 10.0)


@pytest.mark.parametrize("spike_at", [1, 2998, 2999, 1503])
def test_a_chart_thinned_for_the_browser_still_reaches_the_peak_between_the_rows_it_sends(server, polish, spike_at):
    """A window of more rows than a chart sends (here 3000: every 5th is sent) keeps the deflection's peak
    at the row sent for it (peak detect), wherever the one-row spike falls, the newest row included; the
    other series are thinned plainly."""
    n = 3000
    t = polish.columns["t"]
    dense = {k: np.repeat(v, -(-n // len(v)))[:n] for k, v in polish.columns.items()}
    dense["t"] = np.linspace(t[-1] - 10.0, t[-1], n)
    for name, height in (("tcp_dev_mm", 3.25), ("elbow_dev_mm", 29.4)):
        dense[name] = np.zeros(n)
        dense[name][spike_at] = height
    dense["elbow_dev_mm"][spike_at - 1] = -40.0 if spike_at % 5 else 0.0  # the largest magnitude wins, its sign kept
    plots = Plots(server)
    plots.update(dataclasses.replace(polish, columns=dense), session=1)
    data = plots.handles["deflection"].data
    sent = np.isfinite(data[1])
    assert 500 <= np.count_nonzero(sent) <= 600  # thinned: ≤ MAX_POINTS rows sent of 3000
    assert np.nanmax(data[1]) == 3.25
    assert np.nanmax(np.abs(data[2])) == (40.0 if spike_at % 5 else 29.4)
    force = plots.handles["force"].data[1]
    assert np.count_nonzero(np.isfinite(force)) == np.count_nonzero(sent)
