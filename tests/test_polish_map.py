"""The stability map's cells (`app.headless.experiments.polish_map`): a cell forked from a settled posture
gives the verdict of a fresh run of the same held swivel, μ and latency; its tolerated-latency table."""

from __future__ import annotations

import numpy as np
import pytest

from app.headless.experiments import polish_map as PMAP
from app.headless.experiments.polish import simulate
from app.headless.experiments.polish_map import parse_latency, run_cell
from app.headless.sweep.grid import SweepError
from app.headless.sweep.stability_map import agreement, tolerance
from app.scenarios import polish_margin as PM
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


def _table_in_a_cell(entry):
    out = PMAP._cell_in_copy(entry, 1.0, 1, 1, False)
    return entry.session.target_fn.missed, out["stroke_steps"]


def _table_after_a_new_setpoint(entry):
    kept = entry.targets.current()
    entry.session.set_param("target", "force_setpoint_n", 25.0)
    return kept, entry.targets.current()


def test_the_cells_read_the_zigzag_from_a_table_of_every_step_of_the_strokes():
    """The settled posture's target table (`TargetTable`): a cell's world clock reads only times the
    table holds (none computed again, all six strokes and the hold), and at those times the table's
    targets are the scenario's, every array equal."""
    from app.headless.sweep.forked import call_forked

    entry, _ = PMAP.settled(0.0, 0)
    table = entry.targets
    assert table is not None and entry.session.target_fn is table
    missed, steps = call_forked(_table_in_a_cell, entry)
    assert missed == 0 and steps == len(table) == 15501
    times = sorted(table._at)
    for t in (times[0], times[1], times[len(times) // 3], times[-2], times[-1]):
        kept, built = table(t), table._fn(t)
        for name in ("position", "velocity", "acceleration", "rotation", "wrench", "q_posture"):
            assert np.array_equal(getattr(kept, name), getattr(built, name)), (t, name)
    # a target changed after the table was built (not a map cell's change): the table says so
    assert call_forked(_table_after_a_new_setpoint, entry) == (True, False)


def _margins_in_a_cell(entry, mu, latency):
    session = entry.session
    PMAP._set_cell(session, mu, *parse_latency(latency))
    gains, loop = PMAP._margin_inputs(session)
    shared = PMAP.margin_prediction(session, entry.taus, entry.lambdas, entry.parts)
    own = PMAP.margin_prediction(session, entry.taus, entry.lambdas)
    per_posture = [
        PM.sample(lam, gains, loop, float(tau), find_kd=False).rate_per_s
        for tau, lam in zip(entry.taus, entry.lambdas, strict=True)
    ]
    batched = PMAP.rates(PMAP.loop_parts(entry.taus, entry.lambdas, gains, loop), loop)
    return PMAP._without_latency(loop) in entry.parts, shared, own, batched, per_posture


@pytest.mark.parametrize(
    ("mu", "latency", "loss"), [(0.25, "0+0", False), (1.0, "1+1", False), (0.75, "3+1", None), (1.5, "2+2", True)]
)
def test_the_margin_from_parts_shared_across_latencies_is_the_per_posture_margin_exactly(mu, latency, loss):
    """σ from the latency-free parts built once per μ in the settled process (`share_parts`), with the
    maps and the eigenvalue problems of all postures in one call each, is `polish_margin.sample`'s σ at
    every posture, and the cell's headroom figures are those it gets building its own parts, bit for bit
    (no latency, 1 + 1, 3 + 1 and 2 + 2: maps of 16 to 34 states)."""
    from app.headless.sweep.forked import call_forked

    entry, _ = PMAP.settled(-90.0, 0)
    PMAP.share_parts(entry, mu)
    used, shared, own, batched, per_posture = call_forked(_margins_in_a_cell, entry, mu, latency)
    assert used, "the cell's loop is not the one the parts were shared for"
    assert batched == per_posture and len(per_posture) == len(entry.taus) >= 500
    assert shared == own
    if loss is not None:  # calm at 0.25 without latency and at 1 and 1 + 1, lost at 1.5 and 2 + 2
        assert (own["headroom_min_np"] < 0) == loss


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
