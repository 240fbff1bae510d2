"""The page of an app started on a preset that lives only in the tests (tests/toy_preset.py, registered
before the app starts): its chart, its phase, its phase mark and its readout reach the page through the
`Scenario` contract alone; and the tick texts every chart draws are distinct numbers at its scale (the
deflection chart at rest, the self-motion loop's W with its top decade)."""

from __future__ import annotations

import re
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest

from app.tools.bench_serve import CHROMIUM_ARGS
from tests import toy_preset as toy
from tests.conftest import free_port
from tests.test_browser import charts, chromium_path, open_page, open_tab, wait_for

pytestmark = [pytest.mark.browser, pytest.mark.usefixtures("warm_kernels")]

# what the page drew on each visible chart's y axis: the tick texts (uPlot's `_values`) and positions
_TICKS_JS = """(scrollTo) => {
    const out = [];
    for (const v of Object.values((window.__viserTestpoints || {}).uplots || {})) {
        const c = v.chart;
        if (!c.root.isConnected || c.root.offsetParent === null) continue;
        const y = c.axes[1] || {};
        if (scrollTo && y.label === scrollTo) c.root.scrollIntoView({block: 'center'});
        out.push({title: c.root.querySelector('.u-title')?.textContent || '', label: y.label || '',
                  drawn: (y._values || []).map(String), splits: (y._splits || []).map(Number),
                  ymin: c.scales.y.min, ymax: c.scales.y.max});
    }
    return out;
}"""


@pytest.fixture(scope="module")
def toy_app() -> Iterator[Any]:
    from app.core.commands import Play
    from app.live.server import start_app

    with pytest.MonkeyPatch.context() as mp:
        toy.register(mp)
        running = start_app("127.0.0.1", free_port(), toy.NAME, "rizon4s", "projection")
        running.loop.submit(Play())
        try:
            yield running
        finally:
            running.stop()


@pytest.fixture(scope="module")
def toy_page(toy_app: Any) -> Iterator[Any]:
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=chromium_path(), headless=True, args=CHROMIUM_ARGS)
        try:
            pg, _ = open_page(toy_app, browser)
            yield pg
        finally:
            browser.close()


def drawn_ticks(pg: Any, scroll_to: str = "") -> list[dict[str, Any]]:
    """Each visible chart's title, y label and the tick texts the page drew (the chart whose y label is
    `scroll_to` scrolled into view first)."""
    return pg.evaluate(_TICKS_JS, scroll_to)


def test_the_toy_preset_appears_in_the_page_with_its_chart_phase_and_readout(toy_app, toy_page):
    """Its chart is on top of the Plots tab with its title, its label and the logged wave; the torque chart
    under it; the status line says its phase, the readout line its peak and its beat marker."""
    from app.core.commands import Play, Reset

    pg = toy_page
    wait_for(lambda: toy_app.loop.status.scenario == toy.NAME and toy_app.loop.status.t > 1.0, 120, "the toy to run")

    def toy_chart_on_top() -> list[dict[str, Any]] | None:
        shown = charts(pg)
        return shown if shown and shown[0]["title"] == toy.CHART.title and shown[0]["finite"] >= 10 else None

    shown = wait_for(toy_chart_on_top, 90, "the toy's chart on top with the wave", period=0.5)
    assert shown[0]["label"] == toy.CHART.y_label
    assert shown[0]["ymax"] >= toy.WAVE_N and shown[0]["ymin"] == -shown[0]["ymax"]  # widened to hold the wave
    assert [c["title"] for c in shown[:2]] == [toy.CHART.title, "Torques / limits (%)"] and len(shown) == 2
    # a new run: its beat (0.4 s) stays in the 60 s the plots hold while the words are looked for
    toy_app.loop.submit(Reset())
    toy_app.loop.submit(Play())
    wait_for(lambda: 1.0 < toy_app.loop.status.t < 30.0, 60, "the new run past its beat")
    wait_for(lambda: "toy_peak_wave_n" in toy_app.publisher.plots.readouts, 30, "the new run's readout")
    peak = toy_app.publisher.plots.readouts["toy_peak_wave_n"]
    assert peak == pytest.approx(toy.WAVE_N, abs=1e-4)
    for words in (f"Toy wave: peak {peak:.3f} N", "beat 0.4 s", "toy: after the beat"):
        wait_for(lambda w=words: pg.get_by_text(w, exact=False).count() > 0, 30, f"'{words}' in the page")


def _distinct_numbers(chart: dict[str, Any]) -> None:
    where = f"{chart['title'] or chart['label']}: {chart['drawn']}"
    texts = chart["drawn"]
    assert len(texts) >= 2 and len(set(texts)) == len(texts), where
    values = [float(t.replace(",", "")) for t in texts]
    np.testing.assert_allclose(values, chart["splits"], rtol=1e-6, atol=0, err_msg=where)  # the texts say the ticks
    assert re.search(r"\(.+\)|×", chart["label"]), where  # a unit in the label


def test_every_chart_draws_distinct_tick_texts_the_deflection_at_rest_and_the_w_loop_to_its_top(toy_app, toy_page):
    """Show all plots: every chart's drawn tick texts are distinct numbers equal to its ticks (the deflection
    chart of an arm at rest drew "0 0 0 0"); the self-motion loop's W axis draws a tick at the top of its
    range (its top decade) as well as at its bottom."""
    from app.core.commands import Pause, Play
    from app.live.ui.panels.nullspace import NullspacePanel

    pg = toy_page
    plots = toy_app.publisher.plots
    plots.show_all.value = True
    try:
        wait_for(lambda: len(drawn_ticks(pg)) >= 9, 60, "every chart shown")  # force, rate, W×3, torque, …

        def deflection_drawn() -> dict[str, Any] | None:
            found = [c for c in drawn_ticks(pg, "deflection (mm)") if c["label"] == "deflection (mm)" and c["drawn"]]
            if not found:  # a chart laid out after its axes came draws none until they come again
                plots.resend_axes()
            return found[0] if found else None

        wait_for(deflection_drawn, 120, "the deflection chart drawn", period=3.0)
        for chart in drawn_ticks(pg):
            if chart["drawn"]:
                _distinct_numbers(chart)
    finally:
        plots.show_all.value = False
    toy_app.loop.submit(Pause())  # a running simulation keeps a software-rendered page busy: clicks wait
    toy_app.loop.sync()
    open_tab(pg, "Tune", timeout_ms=90_000)
    box = pg.get_by_label("Self-motion preview", exact=True)
    box.wait_for(timeout=60_000)
    preview = next(p for p in toy_app.panels if isinstance(p, NullspacePanel)).preview
    box.check(timeout=90_000)
    try:
        wait_for(lambda: preview.scans > 0 and preview.latest is not None, 60, "a scan of the self-motion loop")

        def loop_drawn() -> dict[str, Any] | None:
            found = [c for c in drawn_ticks(pg) if "self-motion loop" in c["title"] and len(c["drawn"]) >= 2]
            return found[0] if found and found[0]["ymax"] == pytest.approx(preview._decades[0][1]) else None

        loop = wait_for(loop_drawn, 60, "the self-motion loop's W axis on the scanned range")
        _distinct_numbers(loop)
        assert loop["splits"][-1] == pytest.approx(loop["ymax"], rel=1e-9)  # the top tick
        assert loop["splits"][0] == pytest.approx(loop["ymin"], rel=1e-9)
    finally:
        box.uncheck(timeout=90_000)
        toy_app.loop.submit(Play())
