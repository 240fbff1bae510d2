"""The one verdict (`app.scenarios.verdict`): its floor is the sensor's noise in the contact mode's band,
its strokes are stable, oscillating or lost contact by that floor and the contact force alone, and it is
the only place in the code that defines a threshold for stable / oscillating / lost."""

from __future__ import annotations

import ast
import math
import re
from pathlib import Path

import numpy as np
import pytest
from scipy.signal import lfilter

from app.scenarios import verdict as V

ROOT = Path(__file__).resolve().parents[1]
DT = 1e-3


def _sensor_noise(n: int, var: float, cutoff_hz: float, seed: int = 0) -> np.ndarray:
    """White force noise of variance `var` per 1 ms reading through the sensor's first-order low-pass."""
    x = np.random.default_rng(seed).standard_normal(n) * math.sqrt(var)
    a = 1.0 - math.exp(-2.0 * math.pi * cutoff_hz * DT)
    return lfilter([a], [1.0, -(1.0 - a)], x)


def test_the_band_floor_is_the_rms_the_sensor_noise_leaves_in_the_modes_band():
    """The analytic floor (noise density through the low-pass and the zero-phase band-pass) equals the
    band RMS of simulated sensor noise within 3 %, for the default sensor and a noisier, faster one;
    the 1 Hz sinusoid of 2 N adds less than 0.1 % to it (outside the band)."""
    for var, cutoff in ((5.0, 25.0), (20.0, 60.0)):
        noise = _sensor_noise(200_000, var, cutoff)
        measured = float(np.std(V.band_force_n(noise, DT)[2000:-2000]))
        assert measured == pytest.approx(V.band_floor_n(var, cutoff, DT), rel=0.03)
        t = DT * np.arange(noise.size)
        with_sine = float(np.std(V.band_force_n(noise + 2.0 * np.sin(2 * np.pi * t), DT)[2000:-2000]))
        assert with_sine == pytest.approx(measured, rel=1e-3)
    assert V.BAND_HZ[0] < 12.0 and V.BAND_HZ[1] > 14.0  # the contact mode's 12-14 Hz lies inside


def test_the_threshold_is_the_steady_readings_floor_of_the_runs_sensor():
    """The threshold is the STD a steady reading has: √(σ² α/(2 − α) + A²/2), 1.55 N for [T] §IV-A's
    sensor; a run's own sensor sets it, of its stated noise whether or not the noise is drawn."""
    a = 1.0 - math.exp(-2.0 * math.pi * 25.0 * DT)
    default = {"force_noise_var": 5.0, "sine_amplitude_n": 2.0, "cutoff_hz": 25.0, "noise": True}
    thr = V.oscillation_threshold_n(default, DT)
    assert thr == pytest.approx(math.sqrt(5.0 * a / (2.0 - a) + 2.0), rel=1e-12) and 1.5 < thr < 1.6
    steady = 20.0 + _sensor_noise(200_000, 5.0, 25.0) + 2.0 * np.sin(2 * np.pi * DT * np.arange(200_000))
    assert float(np.std(steady)) == pytest.approx(thr, rel=0.03)
    assert V.oscillation_threshold_n({**default, "noise": False}, DT) == pytest.approx(thr, rel=1e-12)
    assert V.oscillation_threshold_n({**default, "sine_amplitude_n": 0.0}, DT) == pytest.approx(
        math.sqrt(5.0 * a / (2.0 - a)), rel=1e-12
    )
    assert V.sensor_band_floor_n({**default, "noise": False}, DT, noise_switch=True) == 0.0
    assert V.oscillation_threshold_n(default, DT, scale=0.5) == pytest.approx(0.5 * thr, rel=1e-12)


def _log(extra: dict[int, np.ndarray], lost_at: dict[int, int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Segment, F/T reading and contact force of a synthetic run: 1 s of approach, six 2.5 s strokes of
    20 N with sensor noise, `extra` added to a stroke's reading, the contact force 0 at some steps."""
    n_seg = round(2.5 / DT)
    segment = np.concatenate([np.zeros(1000)] + [np.full(n_seg, k, dtype=float) for k in range(1, 7)])
    reading = 20.0 + _sensor_noise(segment.size, 5.0, 25.0, seed=3)
    contact = np.full(segment.size, 20.0)
    t = DT * np.arange(segment.size)
    for k, wave in extra.items():
        on = segment == k
        reading[on] += wave(t[on])  # type: ignore[operator]
    for k, steps in lost_at.items():
        first = int(np.flatnonzero(segment == k)[0]) + 500
        contact[first : first + steps] = 0.0
    return segment, reading, contact


def test_a_stroke_is_lost_oscillating_or_stable_by_the_contact_force_and_its_band_rms():
    """A 13 Hz ring of 3 thresholds RMS oscillates; a 1 Hz swing of 5 N does not (outside the band); a
    stroke whose contact force is 0 for 3 steps lost contact; the rest, sensor noise, is stable at its
    band floor; the run takes its worst stroke's verdict; a ring of 0.8 / 1.25 thresholds flips between
    the scales 1 and 0.5 / 2 as it should."""
    sensor = {"force_noise_var": 5.0, "sine_amplitude_n": 2.0, "cutoff_hz": 25.0, "noise": True}
    thr = V.oscillation_threshold_n(sensor, DT)
    ring = 3.0 * thr * math.sqrt(2.0)  # amplitude of an RMS of 3 thresholds

    extra = {2: lambda t: ring * np.sin(2 * np.pi * 13.0 * t), 6: lambda t: 5.0 * np.sin(2 * np.pi * 1.0 * t)}
    seg, reading, contact = _log(extra, {4: 3})
    got = V.strokes(seg, reading, contact, sensor, DT)
    assert [s.verdict for s in got] == [V.STABLE, V.OSCILLATING, V.STABLE, V.LOST, V.STABLE, V.STABLE]
    assert got[1].band_rms_n == pytest.approx(3.0 * thr, rel=0.05)
    assert got[3].contact_lost_ms == 3 and got[3].min_contact_force_n == 0.0
    for s in (got[0], got[2], got[4], got[5]):
        assert s.band_rms_n < 0.3 * thr  # the band floor (0.25 N) and the edges of the others' steps
    assert V.run_verdict(got) == V.LOST and V.run_verdict(got, diverged=True) == V.DIVERGED
    assert V.run_verdict([s for s in got if s.segment != 4]) == V.OSCILLATING
    for rms_in_thresholds, at_half, at_one, at_two in ((0.8, True, False, False), (1.25, True, True, False)):
        extra = {3: lambda t, a=rms_in_thresholds: a * thr * math.sqrt(2.0) * np.sin(2 * np.pi * 13.0 * t)}
        seg, reading, contact = _log(extra, {})
        s3 = V.strokes(seg, reading, contact, sensor, DT)[2]
        for scale, expected in ((0.5, at_half), (1.0, at_one), (2.0, at_two)):
            assert (V.judge(s3.band_rms_n, 0, thr, scale) == V.OSCILLATING) is expected, (rms_in_thresholds, scale)


def test_a_recorded_runs_verdict_is_judged_again_at_any_threshold_scale():
    metrics = {"band_rms_max_n": 0.75, "oscillation_threshold_n": 0.5, "contact_lost_ms": 0, "diverged": False}
    assert [V.verdict_of_metrics(metrics, s) for s in (0.5, 1.0, 2.0)] == [V.OSCILLATING, V.OSCILLATING, V.STABLE]
    assert V.verdict_of_metrics({**metrics, "contact_lost_ms": 2}, 2.0) == V.LOST
    assert V.verdict_of_metrics({**metrics, "diverged": True}) == V.DIVERGED
    assert V.verdict_of_metrics({"contact_lost_ms": 0}) is None  # made before the verdict


# ---- one place ---------------------------------------------------------------------------------------
# names that match but are no stable / oscillating / lost threshold: the sweep report's name of its
# stability column, the paper's own outcomes ([T] Fig. 9) and the mass drop's settling band ([C]'s
# stabilization time, a position tolerance)
NOT_A_CONTACT_VERDICT = ("STABLE", "PAPER_STABLE_MU1", "STABLE_BAND_M")
THRESHOLD_NAME = re.compile(r"OSCILLAT|STABLE|UNSTABLE|CONTACT_LOST|LOST_N|STD_FACTOR|FLOOR_FACTOR")


def _module_constants(path: Path) -> list[str]:
    """Module-level UPPER_CASE names a source file assigns."""
    tree = ast.parse(path.read_text())
    names = []
    for node in tree.body:
        targets = (
            node.targets if isinstance(node, ast.Assign) else [node.target] if isinstance(node, ast.AnnAssign) else []
        )
        names += [t.id for t in targets if isinstance(t, ast.Name) and t.id.isupper()]
    return names


def _imports(path: Path) -> set[str]:
    """The modules a source file imports (`from a.b import c` gives a.b and a.b.c)."""
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module:
            out.add(node.module)
            out |= {f"{node.module}.{a.name}" for a in node.names}
        elif isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
    return out


def test_the_verdict_module_is_the_only_place_a_stable_oscillating_or_lost_threshold_is_defined():
    """No module but app/scenarios/verdict.py defines a constant named for a stable / oscillating / lost
    threshold (the three rules it replaced were OSCILLATION_FACTOR, OSCILLATION_STD_FACTOR and the
    replay's CONTACT_LOST_N); the calibration, the latency table, the sweep's polish cell, the polish
    runs and the lessons import it (the replay takes its contact-lost events from the same
    `metrics.contact_lost` the verdict does)."""
    own = ROOT / "app" / "scenarios" / "verdict.py"
    offenders = {
        str(p.relative_to(ROOT)): hits
        for p in sorted((ROOT / "app").rglob("*.py"))
        if p != own
        for hits in [[n for n in _module_constants(p) if THRESHOLD_NAME.search(n) and n not in NOT_A_CONTACT_VERDICT]]
        if hits
    }
    assert offenders == {}
    assert {"MODE_HZ", "BAND_HZ", "DEFAULT_SENSOR"} <= set(_module_constants(own))
    users = (
        "app/headless/experiments/polish_calibration.py",
        "app/headless/experiments/polish_latency.py",
        "app/headless/experiments/polish.py",
        "app/headless/sweep/experiments.py",
        "app/live/lessons.py",
        "app/scenarios/polish_margin.py",
    )
    for rel in users:
        assert "app.scenarios.verdict" in _imports(ROOT / rel), rel
