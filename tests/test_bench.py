"""`torquelab bench` entries carry a real-time factor; the placo peer's failure is a clear message."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from app.tools.bench import placo_step, run_bench, time_call


def test_every_bench_entry_reports_per_step_figures_of_its_own_timing(monkeypatch):
    """On a clock that moves 125 µs at each reading, every entry `run_bench` times reads 125 µs
    median and p95, 12.5 % of the 1 ms step, 8× real time."""
    import app.tools.bench

    clock = [0.0]

    def tick() -> float:
        clock[0] += 125e-6
        return clock[0]

    monkeypatch.setattr(app.tools.bench.time, "perf_counter", tick)
    report = run_bench(only=["mj_step", "dynamics_snapshot"], repeats=5)
    assert set(report["results"]) == {"mj_step", "dynamics_snapshot"}
    for entry in report["results"].values():
        assert entry["median_us"] == pytest.approx(125.0, rel=1e-6)
        assert entry["p95_us"] == pytest.approx(125.0, rel=1e-6)
        assert entry["share_of_1ms"] == pytest.approx(0.125, rel=1e-6)
        assert entry["real_time_factor"] == pytest.approx(8.0, rel=1e-6)


@pytest.mark.parametrize("kind", ["nullspace", "compliance"])
def test_qp_solve_entries_solve_fifty_distinct_problems_and_the_two_backends_agree(rizon, kind):
    """Each `qp_solve_*` entry cycles through 50 problems of a moving state (the compliance ones as its
    executor built them): every solve is "solved", the 50 solutions differ, and the dense and OSQP
    entries agree on each to 1e-5 relative (OSQP's tolerance is 1e-6; measured: 3e-8 and 4e-7)."""
    from app.tools.bench import BENCHES

    dense, osqp = BENCHES[f"qp_solve_{kind}_dense"](rizon), BENCHES[f"qp_solve_{kind}_osqp"](rizon)
    solutions = set()
    for _ in range(50):
        a, b = dense(), osqp()
        assert (a.status, b.status) == ("solved", "solved")
        assert np.max(np.abs(a.x - b.x)) <= 1e-5 * max(1.0, float(np.max(np.abs(a.x))))
        solutions.add(tuple(np.round(a.x, 9)))
    assert len(solutions) == 50


def test_the_app_step_entry_times_a_frames_burst_of_lab_steps_per_step():
    """`app_step_polish_W_a` runs `Lab.advance(33)` after a simulated second (33 healthy steps per
    call, 33 ms further each), and its figures are per step: 1/33 of the call's."""
    from app.tools.bench import BENCHES

    burst = BENCHES["app_step_polish_W_a"](None)
    results = [burst() for _ in range(3)]
    assert [(r.steps, r.stop) for r in results] == [(33, "done")] * 3
    assert [r.t for r in results] == pytest.approx([1.033, 1.066, 1.099], abs=1e-9)


def test_a_bench_entry_of_several_steps_per_call_reports_per_step(monkeypatch):
    """`time_call` divides by `fn.steps_per_call`: on a clock each call moves by 2 ms, 4 steps a
    call read 500 µs."""
    import app.tools.bench

    clock = [0.0]
    monkeypatch.setattr(app.tools.bench.time, "perf_counter", lambda: clock[0])

    def four_steps():
        clock[0] += 2e-3

    four_steps.steps_per_call = 4  # type: ignore[attr-defined]
    out = time_call(four_steps, repeats=5, warmup=0)
    assert out["median_us"] == pytest.approx(500.0, rel=1e-9)
    assert out["p95_us"] == pytest.approx(500.0, rel=1e-9)
    assert out["real_time_factor"] == pytest.approx(2.0, rel=1e-9)


def test_placo_peer_without_placo_says_why(rizon):
    """This venv has no placo (it pins another Pinocchio): the error names the failure."""
    try:
        import placo  # noqa: F401
    except ImportError:
        pass
    else:  # pragma: no cover - a venv with placo installed
        pytest.skip("placo is importable here")
    with pytest.raises(ValueError, match=r"placo run with .* failed: .*placo"):
        placo_step(sys.executable, rizon, steps=5)


def test_the_stall_probe_counts_late_wakeups_in_a_process_of_its_own():
    """`python -m app.tools.stall_probe` sleeps 1 ms at a time and reports its wake-up delays as JSON;
    a stall made on purpose (the probe process stopped for 0.15 s) is counted as one over a frame period."""
    import json
    import signal
    import subprocess
    import sys
    import time

    from app.tools.stall_probe import probe

    quiet = probe(0.2)
    assert 20 < quiet["wakeups"] <= 200
    assert quiet["stalls_over_frame_period"] <= quiet["stalls_over_10ms"] <= quiet["wakeups"]
    assert quiet["delay_p99_ms"] <= quiet["delay_max_ms"]
    proc = subprocess.Popen([sys.executable, "-m", "app.tools.stall_probe", "1.0"], stdout=subprocess.PIPE, text=True)
    time.sleep(0.4)
    proc.send_signal(signal.SIGSTOP)
    time.sleep(0.15)
    proc.send_signal(signal.SIGCONT)
    report = json.loads(proc.communicate(timeout=30)[0])
    assert report["stalls_over_frame_period"] >= 1
    assert report["delay_max_ms"] > 140.0
    assert report["stalled_s_over_frame_period"] > 0.14
