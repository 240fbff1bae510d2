"""One definition per metric: the page's readouts, the plots and the reports compute the same figure, and
a readout "since the reset" covers the whole run, not only the log's last 60 s."""

from __future__ import annotations

from collections import deque

import numpy as np
import pytest

from app.headless.experiments.compliance import run_mode
from app.live.frames import deflection_readouts, plot_data
from app.live.lab import Lab
from app.live.ui.plot_history import phase_markers
from app.scenarios.compliance import PUSHES, ComplianceScenario
from app.scenarios.mass_drop import RELEASE_TIME_S, drop_metrics
from app.scenarios.metrics import PUSH_AFTER_S, DropFold, run_fold


def test_the_mass_drop_readout_long_after_the_drop_is_its_value_at_the_drop():
    """Mass drop, torque + fusion: the readout at t = 81 s (beyond the 60 s the step log holds) equals
    the one 2.5 s after the release, to the digit; the same figures from the log's rows alone (what the
    readout read before) would have lost the drop."""
    lab = Lab("mass-drop")
    lab.advance(4000)
    at_drop = deflection_readouts(lab.log, lab.session.scenario)
    assert at_drop is not None and at_drop["peak_deflection_mm"] > 0.1
    while lab.session.world.time < 81.0:
        lab.advance(5000)  # the page asks every 0.1 s of wall time; every 5 s of simulated time is enough
        deflection_readouts(lab.log, lab.session.scenario)
    late = deflection_readouts(lab.log, lab.session.scenario)
    assert late is not None and lab.log.count > lab.log.capacity
    assert late["peak_deflection_mm"] == at_drop["peak_deflection_mm"]
    assert late["stabilization_time_s"] == pytest.approx(at_drop["stabilization_time_s"], abs=1e-9)
    c = lab.log.signal(("tcp_dev_mm",))
    assert c is not None and c["t"][0] > RELEASE_TIME_S + 20.0  # the log no longer holds the drop …
    from_log = drop_metrics(c["t"], 1e-3 * c["tcp_dev_mm"])
    assert from_log["peak_deflection_mm"] < 0.5 * at_drop["peak_deflection_mm"]  # … and would have lost it


def test_the_running_drop_figures_in_blocks_equal_those_of_the_whole_run_at_once():
    """`DropFold` fed 1 ms samples in uneven blocks gives the figures of one pass over the whole run."""
    rng = np.random.default_rng(3)
    t = np.arange(0.0, 6.0, 1e-3)
    s = np.clip(t - RELEASE_TIME_S, 0.0, None)
    dev = 4.0 * np.exp(-s / 0.3) * np.abs(np.sin(20 * s)) + 0.05 * rng.random(t.size)  # mm
    whole = run_fold(DropFold(RELEASE_TIME_S, "d"), {"t": t, "d": dev})
    fold = DropFold(RELEASE_TIME_S, "d")
    edges = np.sort(rng.choice(np.arange(1, t.size), 40, replace=False))
    for a, b in zip([0, *edges], [*edges, t.size], strict=True):
        fold.add({"t": t[a:b], "d": dev[a:b]})
    for key, value in whole.items():
        assert fold.value()[key] == pytest.approx(value, abs=1e-12), key
    assert 0.2 < whole["stabilization_time_s"] < 3.0 and whole["peak_deflection_mm"] > 3.0


def test_the_compliance_readout_its_plot_and_its_report_agree_on_the_elbow_push():
    """Compliance, Γ₀ = I: the elbow's deflection under the elbow push as the page's readout gives it, as
    the plot draws it (its samples in the push's window) and as the experiment's report measures it agree
    to 0.1 mm; the plot marks both pushes where they start."""
    lab = Lab("compliance")
    plot = None
    while lab.session.world.time < 4.0:
        lab.advance(100)
        plot = plot_data(lab, deque())  # as the loop builds it, 10 times a second
    assert plot is not None and plot.deflection is not None
    readout = plot.deflection["elbow_push_elbow_mm"]
    c = plot.columns
    (_, t0, t1) = next(p for p in PUSHES if p[0] == "elbow")
    inside = (c["t"] >= t0) & (c["t"] < t1 + PUSH_AFTER_S)
    drawn = float(np.max(c["elbow_dev_mm"][inside]))
    report = run_mode("nullspace")["phases"]["elbow"]
    print(
        f"elbow under the elbow push: readout {readout:.3f} mm, plot {drawn:.3f} mm, report "
        f"{report['peak_elbow_deflection_mm']:.3f} mm"
    )
    assert readout > 5.0  # Γ₀ = I: the elbow yields (mm)
    assert drawn == pytest.approx(readout, abs=0.1)
    assert report["peak_elbow_deflection_mm"] == pytest.approx(readout, abs=0.1)
    assert report["peak_tcp_deflection_mm"] == pytest.approx(plot.deflection["elbow_push_tcp_mm"], abs=0.1)
    markers = {m.label: m.t for m in phase_markers(c, 6, ComplianceScenario.phase_marks)}
    for where, start, _ in PUSHES:
        assert markers[f"{'TCP' if where == 'tcp' else 'elbow'} push"] == pytest.approx(start, abs=0.025)
