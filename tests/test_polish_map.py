"""The stability map's cells (`app.headless.experiments.polish_map`): a cell forked from a settled posture
gives the verdict of a fresh run of the same held swivel, μ and latency; its tolerated-latency table."""

from __future__ import annotations

import pytest

from app.headless.experiments.polish import simulate
from app.headless.experiments.polish_map import parse_latency, run_cell
from app.headless.sweep.grid import SweepError
from app.headless.sweep.stability_map import agreement, tolerance
from app.scenarios import verdict as V


def _fresh(swivel: float, mu: float, latency: str) -> dict:
    reading, drive = parse_latency(latency)
    params = [("contact", "mu", mu), ("sensor", "reading_delay_steps", reading), ("world", "torque_delay_ms", drive)]
    return simulate({"seed": 0, "objective": "a", "hold_swivel_deg": swivel, "session_params": params})["result"]


def test_a_cell_at_the_settled_defaults_is_the_fresh_run_bit_for_bit():
    """μ 0.25 and the reading one period old are the settle's own: nothing changes at the strokes."""
    cell = run_cell(0.0, 0.25, "1+0", seed=0, stop_on_loss=False)
    fresh = _fresh(0.0, 0.25, "1+0")
    assert cell["verdict"] == fresh["verdict"] == V.STABLE
    assert cell["band_rms_max_n"] == pytest.approx(fresh["band_rms_max_n"], rel=1e-12, abs=0)
    assert cell["contact_lost_ms"] == fresh["contact_lost_ms"] == 0
    # the margin at the calm pass's postures against the run's own: the held posture fixes them
    assert cell["headroom_min_np"] == pytest.approx(fresh["stroke"]["headroom_min_np"], abs=0.05)


@pytest.mark.parametrize(
    ("swivel", "mu", "latency"),
    [(0.0, 1.0, "1+0"), (0.0, 1.0, "0+0"), (0.0, 0.25, "2+2"), (-90.0, 1.5, "2+2")],
)
def test_a_reused_settled_state_gives_the_fresh_runs_verdict(swivel, mu, latency):
    """Cells with another μ and latency than the settle's, each forked from the kept settled posture
    (lost contact, oscillating, stable at 4 periods, lost at 4 periods), against a fresh run."""
    run_cell(swivel, 0.25, "1+0", seed=0)  # the settled posture is kept from here on
    cell = run_cell(swivel, mu, latency, seed=0)
    fresh = _fresh(swivel, mu, latency)
    assert cell["settled_reused"]
    assert cell["verdict"] == fresh["verdict"]
    if cell["verdict"] == V.LOST:
        assert cell["stopped_at_loss"] and cell["contact_lost_ms"] == 1 <= fresh["contact_lost_ms"]
    else:  # the strokes' band RMS within 10 % (only the held second before them differs)
        assert cell["band_rms_max_n"] == pytest.approx(fresh["band_rms_max_n"], rel=0.1)
    assert (cell["headroom_min_np"] < 0) == (fresh["stroke"]["headroom_min_np"] < 0)


def test_latency_text_is_reading_plus_drive():
    assert parse_latency("2+1") == (2, 1)
    assert parse_latency(" 0 + 3 ") == (0, 3)
    for bad in ("2", "1+x", "-1+0", "1.5+0"):
        with pytest.raises(ValueError, match="READING\\+DRIVE"):
            parse_latency(bad)


def test_the_sweep_refuses_a_latency_beyond_the_stages_limits():
    from app.headless.sweep import experiments
    from app.headless.sweep.knobs import build_axes

    exp = experiments.get("polish-map")
    axes = build_axes(exp.knobs, [("hold_swivel", ["0"]), ("latency", ["1+1", "0+2"])], exp.groups)
    assert axes[1].values == ("1+1", "0+2")
    with pytest.raises(SweepError, match="latency=1\\+x"):
        build_axes(exp.knobs, [("latency", ["1+x"])], exp.groups)


def test_the_map_refuses_a_dask_cluster_before_running_anything(tmp_path, capsys):
    from app.cli import main

    out = tmp_path / "m"
    assert main(["sweep", "polish-map", "--grid", "hold_swivel=0", "--cluster", "local", "--out", str(out)]) == 2
    assert "local pool" in capsys.readouterr().err
    assert not out.exists()


def test_a_swivels_cells_are_sent_together_its_groups_spread_over_the_loop():
    from app.headless.sweep.runner import grouped, spread_order

    cells = [(s, m, lat) for s in range(8) for m in (0.25, 1.0) for lat in ("0+0", "1+1")]
    points = [{"hold_swivel": s, "mu": m, "latency": lat} for s, m, lat in cells]
    order = sorted(range(len(points)), key=lambda i: grouped(points, "hold_swivel")[i])
    swivels = [points[i]["hold_swivel"] for i in order]
    runs = [s for k, s in enumerate(swivels) if k == 0 or s != swivels[k - 1]]
    assert runs == spread_order(8)  # each swivel once, in one run of 4 cells, coarse to fine over the loop
    assert all(swivels.count(s) == 4 for s in runs)


def _rec(swivel, mu, latency, verdict, h):
    return {
        "status": "ok",
        "params": {"hold_swivel": swivel, "mu": mu, "latency": latency},
        "stable": verdict == V.STABLE,
        "metrics": {"verdict": verdict, "headroom_min_np": h, "margin_predicts_loss": h < 0},
    }


def test_the_tolerated_latency_is_the_largest_total_whose_cells_are_all_stable():
    records = [
        _rec(0.0, 1.0, "0+0", V.STABLE, 2.0),
        _rec(0.0, 1.0, "1+0", V.STABLE, 1.0),
        _rec(0.0, 1.0, "0+1", V.OSCILLATING, 0.5),  # one split of total 1 fails: tolerates 0
        _rec(0.0, 1.0, "1+1", V.STABLE, -1.0),
        _rec(10.0, 1.0, "0+0", V.STABLE, 2.0),
        _rec(10.0, 1.0, "1+0", V.STABLE, 2.0),
        _rec(10.0, 1.0, "0+1", V.STABLE, 2.0),
        _rec(10.0, 1.0, "1+1", V.LOST, -2.0),
        _rec(20.0, 1.0, "0+0", V.LOST, -3.0),
    ]
    assert tolerance(records) == {1.0: {0.0: 0, 10.0: 1, 20.0: -1}}
    a = agreement(records)
    assert (a["cells"], a["agree_unstable"], a["missed"], a["false_alarms"]) == (9, 7, 1, 1)
