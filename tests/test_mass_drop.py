"""Mass-drop metrics [C] §IV-D and the scenario's modes."""

from __future__ import annotations

import numpy as np
import pytest

from app.experiments.mass_drop import drop_metrics, summarize
from app.scenarios.mass_drop import RELEASE_TIME_S, STABLE_BAND_M, MassDropScenario


def test_metrics_of_a_known_deviation_curve():
    t = np.arange(0.0, RELEASE_TIME_S + 4.0, 1e-3)
    s = np.clip(t - RELEASE_TIME_S, 0.0, None)
    dev = 5e-3 * s / 0.05 * np.exp(1 - s / 0.05) + 2e-4  # peak 5.2 mm at 50 ms, then decays
    m = drop_metrics(t, dev)
    assert m["peak_deflection_mm"] == pytest.approx(5.2, abs=1e-3)
    # last time above the 1 mm band: solve 5 (s/τ) e^{1−s/τ} + 0.2 = 1 (mm) on the decaying side
    late = s[(dev > STABLE_BAND_M) & (s > 0.05)].max()
    assert m["stabilization_time_s"] == pytest.approx(late, abs=2e-3)
    assert m["residual_error_mm"] == pytest.approx(0.2, abs=1e-3)


def test_never_leaving_the_band_means_zero_stabilization_time():
    t = np.arange(0.0, RELEASE_TIME_S + 4.0, 1e-3)
    m = drop_metrics(t, np.full(t.size, 0.5 * STABLE_BAND_M))
    assert m["stabilization_time_s"] == 0.0


def test_summary_gives_mean_std_and_mann_whitney_p_values():
    runs = [
        {"mode": mode, "peak_deflection_mm": base + 0.1 * i, "stabilization_time_s": base, "residual_error_mm": base}
        for mode, base in (("position", 7.0), ("torque-residual", 3.0), ("torque-fusion", 0.2))
        for i in range(6)
    ]
    stats = summarize(runs)
    assert stats["modes"]["position"]["peak_deflection_mm"]["mean"] == pytest.approx(7.25)
    assert stats["modes"]["position"]["peak_deflection_mm"]["std"] == pytest.approx(np.std(np.arange(6) * 0.1, ddof=1))
    p = stats["mann_whitney_p"]["position vs torque-fusion"]["peak_deflection_mm"]
    assert p < 0.01  # fully separated groups of 6: exact p = 2/924


def test_unknown_mode_is_rejected():
    with pytest.raises(ValueError, match="mode"):
        MassDropScenario("hydraulic")
