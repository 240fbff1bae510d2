"""The polish report's presentation: no "−0", plain log ticks, figure titles in words, links to the
per-run files (the numbers themselves: tests/test_polish.py and tests/test_latency.py)."""

from __future__ import annotations

import json

import numpy as np

from app.headless.experiments.polish_report import (
    FIGURE_TITLES,
    _deg,
    _figure_html,
    _fmt,
    _pm,
    readable_log_ticks,
    run_files_html,
)


def test_angles_and_numbers_that_round_to_zero_print_without_a_sign():
    assert [_deg(x) for x in (-0.3, 0.4, -2.6, 12.2)] == ["0", "0", "-3", "+12"]
    assert _fmt(-0.001, 2) == "0.00" and _fmt(-0.5, 0) == "0" and _fmt(-1.26, 1) == "-1.3"
    assert _pm({"mean": -0.2, "sd": 0.1}, 0) == "0 ± 0"


def test_log_ticks_read_as_plain_numbers():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (wide, narrow) = plt.subplots(2, 1)
    wide.plot([0, 1], [0.01, 50.0])
    wide.set_yscale("log")
    readable_log_ticks(wide)
    narrow.plot([0, 1], [0.55, 0.8])  # less than a decade: only minor ticks fall inside
    narrow.set_yscale("log")
    readable_log_ticks(narrow)
    fig.canvas.draw()
    for ax in (wide, narrow):
        lo, hi = ax.get_ylim()
        labels = [t.get_text() for t in ax.get_yticklabels(minor=False) + ax.get_yticklabels(minor=True)]
        ticks = list(ax.get_yticks()) + list(ax.get_yticks(minor=True))
        shown = [t for t, y in zip(labels, ticks, strict=True) if lo <= y <= hi and t]
        assert shown and not any("×" in t or "10^" in t or "$" in t for t in shown), shown
        assert all(np.isfinite(float(t)) for t in shown)
    plt.close(fig)


def test_figures_carry_titles_in_words_and_links_to_their_files():
    text = _figure_html("fig9_force_error")
    assert f"<h3>{FIGURE_TITLES['fig9_force_error']}</h3>" in text and 'href="fig9_force_error.png"' in text


def test_the_per_run_files_are_linked_with_what_each_run_was(tmp_path):
    assert run_files_html(tmp_path) == ""
    runs = tmp_path / "runs"
    runs.mkdir()
    spec = {"group": "table", "row": "W_j", "mu": 1.0, "seed": 0, "start_swivel_deg": 0.0}
    (runs / "abc.json").write_text(json.dumps({"spec": spec, "code": "x", "result": {}}))
    (runs / "abc.npz").write_bytes(b"")
    text = run_files_html(tmp_path)
    assert 'href="runs/abc.json"' in text and 'href="runs/abc.npz"' in text and "row W_j, mu 1" in text
