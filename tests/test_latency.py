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
