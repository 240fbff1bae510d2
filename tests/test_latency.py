"""The loop's latency chain: the F/T reading's age (`SensorParams.reading_delay_steps`) and the
actuation delay (`WorldParams.torque_delay_ms`, tested in test_world)."""

from __future__ import annotations

import numpy as np
import pytest

from app.sim.sensor import DEFAULT_READING_DELAY_STEPS, MAX_READING_DELAY_STEPS, FTSensor, SensorParams
from control.params import ParamError, replaced


def _quiet(delay: int, seed: int = 0, **kw) -> FTSensor:
    """A noise-free, unfiltered sensor with this reading age."""
    return FTSensor(np.random.default_rng(seed), noise=False, cutoff_hz=0.0, reading_delay_steps=delay, **kw)


def test_the_default_reading_is_one_control_period_old():
    assert SensorParams().reading_delay_steps == DEFAULT_READING_DELAY_STEPS == 1
    assert FTSensor(np.random.default_rng(0)).reading_delay_steps == 1


@pytest.mark.parametrize("delay", [0, 1, 3])
def test_a_step_in_the_wrench_reaches_the_reading_exactly_d_periods_later(delay):
    sensor = _quiet(delay)
    step_at = 5
    z = [sensor.measure(np.array([0, 0, 0.0 if k < step_at else 20.0, 0, 0, 0]), 1e-3 * k)[2] for k in range(15)]
    first = z.index(20.0)
    assert first == step_at + delay
    assert all(v == 0.0 for v in z[:first]) and all(v == 20.0 for v in z[first:])


@pytest.mark.parametrize("delay", [1, 2, 4])
def test_a_delayed_reading_is_the_undelayed_one_d_periods_late_bit_for_bit(delay):
    """Noise, sinusoid and filter as by default: the delayed sensor returns exactly the readings an
    undelayed one (same seed) gave d steps earlier, the first one repeated until then."""
    ideal, late = FTSensor(np.random.default_rng(4), reading_delay_steps=0), FTSensor(np.random.default_rng(4))
    late.set_params("sensor", replaced(late.params()["sensor"], "reading_delay_steps", delay))
    rng = np.random.default_rng(9)
    wrenches = rng.normal(size=(60, 6)) * 10.0
    a = np.array([ideal.measure(w, 1e-3 * k) for k, w in enumerate(wrenches)])
    b = np.array([late.measure(w, 1e-3 * k) for k, w in enumerate(wrenches)])
    assert np.array_equal(b[delay:], a[:-delay])
    assert all(np.array_equal(b[k], a[0]) for k in range(delay))


def test_a_zero_delay_reading_is_the_same_step_filtered_reading():
    """d = 0 is the model without a delay line: reading k is the filtered noisy wrench of step k."""
    sensor = FTSensor(np.random.default_rng(2), sine_amplitude_n=0.0, reading_delay_steps=0)
    draws = np.random.default_rng(2)
    y = None
    alpha = sensor.alpha
    std = np.array([np.sqrt(5.0)] * 3 + [np.sqrt(0.05)] * 3)
    for k in range(30):
        w = np.full(6, float(k))
        x = draws.standard_normal(6) * std + w
        y = x if y is None else (x - y) * alpha + y
        assert np.array_equal(sensor.measure(w, 1e-3 * k), y)


def test_changing_the_delay_mid_run_keeps_the_newest_readings():
    sensor = _quiet(3)
    for k in range(10):
        sensor.measure(np.full(6, float(k)), 1e-3 * k)  # readings 0..9; the last returned is 6
    sensor.set_params("sensor", replaced(sensor.params()["sensor"], "reading_delay_steps", 1))
    assert sensor.measure(np.full(6, 10.0), 0.010)[0] == 9.0
    sensor.set_params("sensor", replaced(sensor.params()["sensor"], "reading_delay_steps", 2))
    # the ring had [9, 10]: the older end repeats once, then the line runs two steps late
    assert [sensor.measure(np.full(6, float(k)), 1e-3 * k)[0] for k in (11, 12, 13)] == [9.0, 10.0, 11.0]
    sensor.set_params("sensor", replaced(sensor.params()["sensor"], "reading_delay_steps", 0))
    assert sensor.measure(np.full(6, 14.0), 0.014)[0] == 14.0
    sensor.set_params("sensor", replaced(sensor.params()["sensor"], "reading_delay_steps", 1))
    assert [sensor.measure(np.full(6, float(k)), 1e-3 * k)[0] for k in (15, 16)] == [15.0, 15.0]


@pytest.mark.parametrize("bad", [-1, 1.5, MAX_READING_DELAY_STEPS + 1, "2", float("nan"), True])
def test_a_bad_reading_delay_is_refused_and_changes_nothing(bad):
    sensor = _quiet(2)
    with pytest.raises(ParamError, match="reading_delay_steps"):
        sensor.set_params("sensor", replaced(sensor.params()["sensor"], "reading_delay_steps", bad))
    assert sensor.reading_delay_steps == 2 and sensor.params()["sensor"].reading_delay_steps == 2


def test_a_session_sets_the_reading_delay_and_refuses_a_bad_one_in_one_line():
    from app.core.session import Session

    session = Session("polish")
    assert session.params()["sensor"].reading_delay_steps == DEFAULT_READING_DELAY_STEPS
    session.set_param("sensor", "reading_delay_steps", 3)
    with pytest.raises(ParamError) as err:
        session.set_param("sensor", "reading_delay_steps", -2)
    assert "sensor.reading_delay_steps" in str(err.value) and "\n" not in str(err.value)
    session.reset()  # the sensor is rebuilt: the value set is re-applied
    assert session.sensor.reading_delay_steps == 3  # type: ignore[attr-defined]


# ---- the polish experiment's latency table ------------------------------------------------------------
def _run(row: str, ds: int, da: float, band: float | None, lost: int = 0, threshold: float = 0.5) -> dict:
    """A polish run record with only what the latency table reads: its worst stroke band RMS, the
    threshold it was held against and the verdict they give (`app.scenarios.verdict`)."""
    from app.scenarios import verdict as V

    metrics = {"band_rms_max_n": band, "oscillation_threshold_n": threshold, "contact_lost_ms": lost}
    return {
        "row": row,
        "objective": "j",
        "mu": 1.0,
        "seed": 0,
        "reading_delay_steps": ds,
        "torque_delay_ms": da,
        "band_rms_max_n": band,
        "oscillation_threshold_n": threshold,
        "band_floor_n": threshold / 2.0,
        "verdict": V.verdict_of_metrics(metrics) if band is not None else V.STABLE,
        "contact_lost_ms": lost,
        "diverged": False,
        "force_error": {"ptp": 10.0},
        "converged_swivel_deg": 0.0,
        "Pd_fhat": {"stretch": 0.8 if row == "coupled" else 0.03},
    }


def test_the_latency_table_gives_the_smallest_delay_that_the_one_verdict_calls_not_stable():
    """A run is not stable in the latency table exactly when the one verdict says so: a stroke band RMS
    at the threshold oscillates, 1 % under it does not, a lost contact counts whatever the band RMS."""
    from app.headless.experiments.polish_latency import latency_table

    runs = [
        _run("coupled", 0, 0.0, 0.3),
        _run("coupled", 1, 0.0, 0.5 * 0.99),
        _run("coupled", 2, 0.0, 0.5),
        _run("coupled", 0, 1.0, 0.3, lost=3),
        _run("decoupled", 0, 0.0, 0.3),
        _run("decoupled", 1, 0.0, 0.3),
        _run("decoupled", 0, 1.0, 0.5 * 0.99),
    ]
    table = latency_table(runs)
    by = {e["row"]: e for e in table["rows"]}
    assert by["coupled"]["smallest_sensing_delay_steps"] == 2 and by["coupled"]["smallest_torque_delay_ms"] == 1.0
    assert by["decoupled"]["smallest_sensing_delay_steps"] is None
    assert by["decoupled"]["smallest_torque_delay_ms"] is None
    cells = by["coupled"]["cells"]
    assert [c["band_ratio"] for c in cells[:3]] == pytest.approx([0.6, 0.99, 1.0])
    assert [c["verdict"] for c in cells] == ["stable", "stable", "oscillating", "lost contact"]
    assert table["criterion"]["threshold_n"] == 0.5 and table["criterion"]["floor_n"] == 0.25


def test_latency_runs_vary_each_stage_alone_and_then_both_at_mu_1():
    """Each stage alone (the other at 0), then both at once: the F/T reading one period old with 1 ms at
    the drive (1 + 1 periods), in the table, its text and the report beside the single stages."""
    from app.headless.experiments.polish_latency import (
        LATENCY_COMBINED,
        LATENCY_ROWS,
        LATENCY_SENSING_STEPS,
        LATENCY_TORQUE_MS,
        format_latency,
        latency_specs,
        latency_table,
    )
    from app.headless.experiments.polish_report import latency_html

    specs = latency_specs()
    assert {s["mu"] for s in specs} == {1.0} and {s["seed"] for s in specs} == {0}
    both = [s for s in specs if s["reading_delay_steps"] > 0 and s["torque_delay_ms"] > 0.0]
    assert LATENCY_COMBINED == ((1, 1.0),)
    assert {(s["reading_delay_steps"], s["torque_delay_ms"]) for s in both} == set(LATENCY_COMBINED)
    per_row = len(LATENCY_SENSING_STEPS) + len(LATENCY_TORQUE_MS) - 1 + len(LATENCY_COMBINED)  # (0, 0) once
    assert len(specs) == len(LATENCY_ROWS) * per_row
    assert len({(s["row"], s["reading_delay_steps"], s["torque_delay_ms"]) for s in specs}) == len(specs)
    quick = latency_specs(quick=True)
    assert any(s["reading_delay_steps"] == 1 and s["torque_delay_ms"] == 1.0 for s in quick)
    runs = [_run("row", 0, 0.0, 0.3), _run("row", 1, 0.0, 0.3), _run("row", 0, 1.0, 0.3), _run("row", 1, 1.0, 2.0)]
    table = latency_table(runs)
    (row,) = table["rows"]
    assert row["smallest_sensing_delay_steps"] is None and row["smallest_torque_delay_ms"] is None
    assert row["combined"] == [
        {"reading_delay_steps": 1, "torque_delay_ms": 1.0, "oscillates": True, "verdict": "oscillating"}
    ]
    assert "| 1+1: 4.0!" in format_latency(table)
    page = latency_html({"latency": {**table, "runs": runs}})
    assert "<th>F/T 1 + τ 1 ms</th>" in page and "<td><b>4.0×</b></td></tr>" in page


def test_the_latency_report_states_the_criterion_of_the_run_and_ranks_no_posture_by_its_start_coupling():
    from app.headless.experiments.polish_latency import latency_table
    from app.headless.experiments.polish_report import latency_html

    calm, loud = 0.3, 2.0
    runs = [
        _run("coupled", 0, 0.0, calm),
        _run("coupled", 1, 0.0, loud),
        _run("decoupled", 0, 0.0, calm),
        _run("decoupled", 1, 0.0, calm),
    ]
    doc = {"latency": {**latency_table(runs), "runs": runs}}
    doc["latency"]["criterion"]["threshold_n"] = 0.62  # as a run with another sensor would record
    text = latency_html(doc)
    assert "at least 0.62 N" in text and "0.50 N" not in text and "the sensor&#x27;s floor" in text
    # P_d·f̂ at the trajectory start does not order the latency tolerance (the README says why): no ranking
    assert "P_d·f̂" not in text and "decoupled posture" not in text


def test_the_polish_report_reads_the_loop_and_sensor_from_its_runs():
    from app.headless.experiments.polish_report import _loop_text

    sensor = dict(
        noise=True,
        force_noise_var=8.0,
        torque_noise_var=0.05,
        sine_amplitude_n=3.0,
        sine_hz=2.0,
        cutoff_hz=40.0,
        reading_delay_steps=2,
    )
    contact = {"stiffness_n_per_m": 12000.0, "v_eps_m_per_s": 0.004, "mu": 1.0, "implicit_friction": False}
    run = {"timestep_s": 5e-4, "sensor": sensor, "contact": contact, "torque_delay_ms": 3.0}
    text = _loop_text({"runs": [run, dict(run)]})
    for part in ("2000 Hz", "12,000 N/m", "4 mm/s", "explicitly", "8 N² + 3 N at 2 Hz", "40 Hz low-pass"):
        assert part in text, (part, text)
    assert "2 control period(s) old" in text and "3 ms after" in text
    assert "5 N²" not in text and "25 Hz" not in text
    assert "12,000 N/m" in _loop_text({"runs": [run, dict(run, contact=dict(contact, mu=0.25))]})  # μ is a column
    other = dict(run, sensor=dict(sensor, cutoff_hz=25.0))
    assert "F/T settings differ between runs" in _loop_text({"runs": [run, other]})


def test_the_w_d_flip_explanation_is_printed_only_when_w_d_did_not_flip():
    from app.headless.experiments.polish_report import _w_d_flip

    scan = {
        "W_d": {
            "at_start": 13.3,
            "local_minima_swivel_deg": [-83.7, 77.3],
            "feasible_min_swivel_deg": 77.3,
            "feasible_min": 11.47,
            "feasible_max": 16.45,
            "ridge_swivel_deg": -23.4,
        },
        "inverted": {"swivel_deg": 180.0, "feasible": False, "infeasible_within_deg": 5.0, "W_d": 16.0},
    }

    def doc(swivel: float) -> dict:
        row = {"objective": "d", "mu": 1.0, "converged_swivel_deg": {"mean": swivel}}
        return {"summary": [row], "swivel_scan": scan, "armature": {"basins": []}}

    (text,) = _w_d_flip(doc(78.0))
    assert "+78°" in text and "outside the joint limits" in text and "not a minimum" in text
    assert _w_d_flip(doc(-170.0)) == []


def test_a_still_hold_that_oscillates_or_loses_contact_has_its_verdict_and_a_calm_or_flowing_one_has_none():
    """The latency runs stop while held once the verdict is known (`HoldWatch`): the posture still
    (swivel within still_deg over the window, the settle phase's own test), then the one verdict of that
    window (lost contact, or the reading's band RMS at least the threshold), looked at every `every`
    steps. A posture still flowing gets no verdict yet."""
    from app.headless.experiments.polish_latency import HOLD_STILL_DEG, HoldWatch, latency_table
    from app.scenarios.polish_stroke import SETTLE_SPEED_RAD_S, SETTLE_WINDOW_S

    assert HOLD_STILL_DEG == pytest.approx(np.rad2deg(SETTLE_SPEED_RAD_S * SETTLE_WINDOW_S))
    rng = np.random.default_rng(0)
    t = 1e-3 * np.arange(3000)
    still = np.full(t.size, 75.0) + rng.normal(0.0, 0.005, t.size)  # jitter ≪ 0.057°
    flowing = 10.0 + 0.2 * t  # 0.2°/s: the slowest settle flow

    def watch() -> HoldWatch:
        return HoldWatch(threshold_n=0.5, window=1000, dt=1e-3, every=100, still_deg=HOLD_STILL_DEG)

    calm = watch()
    noise = 20.0 + rng.normal(0.0, 1.5, t.size) + 2.0 * np.sin(2 * np.pi * t)  # broadband + 1 Hz: 0.2 N in band
    contact = np.full(t.size, 20.0)
    assert all(calm.add(tk, e, c, sw) is None for tk, e, c, sw in zip(t, noise, contact, still, strict=True))
    assert calm.verdict is None and calm.window_band_rms_n is not None and calm.window_band_rms_n < 0.5
    record = calm.result(stopped=False)
    assert record["verdict"] is None and record["window_s"] == 1.0 and record["still_deg"] == HOLD_STILL_DEG
    assert record["threshold_n"] == 0.5 and record["contact_lost_ms"] == 0 and record["stopped"] is False
    wave = 20.0 + 2.0 * np.sin(2 * np.pi * 13.0 * t)  # band RMS 1.41 N ≥ 0.5 N
    loud = watch()
    verdicts = [loud.add(tk, e, c, sw) for tk, e, c, sw in zip(t, wave, contact, still, strict=True)]
    first = next(k for k, v in enumerate(verdicts) if v)
    assert first == 999 and loud.verdict == "oscillating" and abs(loud.window_band_rms_n - np.sqrt(2.0)) < 0.1
    assert loud.at_swivel_deg is not None and abs(loud.at_swivel_deg - 75.0) < 0.1
    moving = watch()
    assert all(moving.add(tk, e, c, sw) is None for tk, e, c, sw in zip(t, wave, contact, flowing, strict=True))
    lost = watch()
    force = np.where(np.arange(t.size) == 500, 0.0, 20.0)  # contact lost at one step (0.5 s)
    verdicts = [lost.add(tk, 20.0, c, sw) for tk, c, sw in zip(t, force, still, strict=True)]
    assert next(k for k, v in enumerate(verdicts) if v) == 999 and lost.verdict == "lost contact"
    assert lost.contact_lost_ms == 1
    # a run stopped while held is not stable in the latency table, whatever its (absent) strokes say
    ref = _run("row", 0, 0.0, 0.3)
    held = dict(_run("row", 3, 0.0, None), held=loud.result(stopped=True))
    table = latency_table([ref, held])
    assert table["rows"][0]["smallest_sensing_delay_steps"] == 3
    assert table["criterion"]["held_window_s"] == 1.0
    assert [c["held"] for c in table["rows"][0]["cells"]] == [None, "oscillating"]


def test_only_the_latency_runs_stop_at_a_verdict_while_held():
    from app.headless.experiments.polish_latency import latency_specs
    from app.headless.experiments.polish_rows import table_specs

    assert all(s["stop_on_verdict"] for s in latency_specs())
    assert not any(s.get("stop_on_verdict") for s in table_specs([1.0], 1, quick=False))
