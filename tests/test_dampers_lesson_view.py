"""The dampers lesson as its page shows it, without a browser: in every step the phase plot of joint 4
draws the limit, d_s and d_i, zoomed on the limit the joint falls to so that all three lie inside the
plot and d_s stands clear of the limit; step 4 says from its own numbers whether λ = 100 tolerates the delay."""

from __future__ import annotations

import time

import numpy as np
import pytest

from app.live.ui.panels.lessons import LessonsPanel

STEPS = ("l100", "l500", "l500d", "l100d")


def phase_lines(phase) -> dict[str, list[float]]:
    """The q of each vertical line series (limit, d_s, d_i) in the phase chart's data."""
    xs = np.asarray(phase.data[0], dtype=float)
    out = {}
    for series, name in ((4, "limit"), (5, "d_s"), (6, "d_i")):
        ys = np.asarray(phase.data[series], dtype=float)
        out[name] = sorted(set(np.round(xs[np.isfinite(ys)], 9).tolist()))
    return out


@pytest.fixture(scope="module")
def app():
    from app.live.server import start_app

    a = start_app(port=0, scenario="free", running=False)
    yield a
    a.stop()


def test_every_dampers_step_draws_limit_ds_and_di_in_view_and_step_4_concludes(app):
    panel = next(p for p in app.panels if isinstance(p, LessonsPanel))
    plots = app.publisher.plots
    for k, key in enumerate(STEPS):
        panel.select("dampers", k)
        panel.start_step()
        deadline = time.monotonic() + 300
        while ("dampers", key) not in panel.claims and time.monotonic() < deadline:
            time.sleep(0.5)
        assert ("dampers", key) in panel.claims, key
        time.sleep(0.5)  # a redraw after the step's end
        lines = phase_lines(plots.handles["phase"])
        lo, hi = plots.handles["phase"].scales["x"]["range"]
        for name in ("limit", "d_s", "d_i"):
            inside = [x for x in lines[name] if lo <= x <= hi]
            assert len(inside) == 1, (key, name, lines[name], (lo, hi))  # the line on the side it falls to
        limit = next(x for x in lines["limit"] if lo <= x <= hi)
        d_s = next(x for x in lines["d_s"] if lo <= x <= hi)
        assert abs(limit - d_s) / (hi - lo) > 0.05, key  # d_s clear of the limit: > 5 % of the plot's width
        assert "zoomed on the" in str(plots.handles["phase"].title), key
    obs = panel.results["dampers"]["l100d"]
    claim = panel.claims[("dampers", "l100d")]
    tolerated = obs["thrash_end_s"] <= 0 and obs["peak_tau_4"] < obs["tau_max_4"]
    verdict = "tolerates the delay in this run" if tolerated else "does not tolerate the delay in this run"
    assert f"So λ = 100, 5 ms delay {verdict}" in claim, claim
    stiff = panel.results["dampers"]["l500d"]
    assert f"thrashed for {stiff['thrash_end_s']:.1f} s" in claim or stiff["thrash_end_s"] <= 0
    assert tolerated and stiff["thrash_end_s"] > 1.0  # the lesson's point: λ = 100 tolerates what λ = 500 does not
