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
    # what the run had (its result) over what it was asked: an armature set by --set, a swivel measured
    result = {"row": "W_j", "seed": 0, "wall_s": 7.0, "armature_scale": 1.5, "start_swivel_deg": -1.5e-05}
    (runs / "abc.json").write_text(json.dumps({"spec": {**spec, "armature_scale": 1.0}, "result": result}))
    (runs / "old.json").write_text(json.dumps({"spec": spec, "result": {**result, "wall_s": 3.0}}))
    doc = {"runs": [result]}
    text = run_files_html(tmp_path, doc)
    assert "start_swivel_deg 0°, armature_scale 1.5" in text and "Per-run files (1)" in text
    assert "old.json" not in text  # an earlier invocation's run in the same directory is not this report's


def test_table_iii_has_the_papers_rows_and_columns_with_ours_and_theirs_in_each_cell():
    from app.headless.experiments.polish_report import table_iii_html

    def entry(row: str, mu: float, ma: float, paper: tuple | None) -> dict:
        stat = {"mean": ma, "sd": 0.1}
        return {"row": row, "mu": mu, "ma": stat, "ptp": stat, "std": stat, "paper": paper}

    summary = [entry("W_j", 0.25, 2.0, (2.3, 18.2, 2.8)), entry("W_j", 1.0, 6.0, (5.9, 72.4, 9.3))]
    summary.append(entry("W_a from -30°", 1.0, 1.5, None))
    text = table_iii_html(summary)
    assert text.count("<th colspan='3'>") == 2 and "μ = 0.25" in text and "μ = 1</th>" in text
    assert text.count("<th>MA</th><th>PTP</th><th>STD</th>") == 2
    assert "<tr><th>W_j</th><td>2.0 ± 0.1<br><small>paper 2.3</small></td>" in text
    assert "paper 72.4" in text and "<th>W_a from -30°</th><td>-</td><td>-</td><td>-</td><td>1.5 ± 0.1</td>" in text
