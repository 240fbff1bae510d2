"""`bench --classroom`'s arithmetic: a seat's 1 s real-time factor windows from its status samples."""

from __future__ import annotations

import pytest

from app.tools.bench_classroom import windows_rtf


def test_one_second_windows_divide_simulated_by_wall_time_and_leave_out_a_paused_window():
    # samples every 0.5 s of the seat's clock: 1.0 s simulated per wall second, then 0.5, then paused, then 0.9
    samples = [(0.0, 0.0, True), (0.5, 0.5, True), (1.0, 1.0, True), (1.5, 1.25, True), (2.0, 1.5, True)]
    samples += [(2.5, 1.5, False), (3.0, 1.5, False), (3.5, 1.95, True), (4.0, 2.4, True), (4.5, 2.85, True)]
    samples += [(5.0, 3.3, True)]
    windows = windows_rtf(samples)
    assert windows == pytest.approx([1.0, 0.5, 0.9], abs=1e-12)  # 2–3 s and 3–4 s hold a paused sample: left out
    assert windows_rtf(samples[:1]) == [] and windows_rtf([]) == []


def test_a_window_spans_at_least_a_second_of_uneven_samples():
    samples = [(0.0, 0.0, True), (0.3, 0.3, True), (0.7, 0.7, True), (1.2, 1.08, True), (1.9, 1.71, True)]
    assert windows_rtf(samples) == pytest.approx([1.08 / 1.2], abs=1e-12)  # 0–1.2 s; 1.2–1.9 s is too short


def test_counts_read_a_list_and_none_is_no_run():
    from app.tools.bench_classroom import _counts

    assert _counts("1,2, 4") == [1, 2, 4]
    assert _counts("none") == [] and _counts("") == []
    for bad in ("1,x", "-1"):
        with pytest.raises(ValueError, match="expected counts like 1,2,4"):
            _counts(bad)
