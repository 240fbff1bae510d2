"""Sweeps: grid parsing and validation, resume after a kill, failed cells, and the same limit-drop
metrics from the local process pool and from a real Dask LocalCluster's workers."""

from __future__ import annotations

import csv
import json
import os
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import pytest

from app.cli import main
from app.headless.sweep.grid import cells, parse_grid, parse_item
from app.headless.sweep.knobs import build_axes
from app.headless.sweep.report import _cell_summary
from app.headless.sweep.runner import coarse_to_fine, run_sweep, spread_order
from app.headless.sweep.store import CellStore

KILL_FLAG = "TORQUELAB_TEST_SWEEP_KILL"  # file: the cell x = 4 raises SystemExit while it exists
FAIL_FLAG = "TORQUELAB_TEST_SWEEP_FAIL"  # file: the cell x = 3 raises ValueError while it exists
RUN_LOG = "TORQUELAB_TEST_SWEEP_LOG"  # file: every cell that runs appends its x


def toy_cell(values: dict, seed: int) -> dict:
    """A cell that logs that it ran, and dies or fails on a flag."""
    x = values["x"]
    with open(os.environ[RUN_LOG], "a") as f:
        f.write(f"{x}\n")
    if x == 4 and os.path.exists(os.environ[KILL_FLAG]):
        raise SystemExit("killed")
    if x == 3 and os.path.exists(os.environ[FAIL_FLAG]):
        raise ValueError("cell three refuses")
    backend = os.environ.get("TORQUELAB_QP_BACKEND", "")
    return {"metrics": {"square": float(x * x), "seed": seed, "backend": backend}, "stable": x < 5}


def _one_line_error(capsys, argv: list[str]) -> str:
    rc = main(argv)
    err = capsys.readouterr().err.strip()
    assert rc == 2, err
    assert len(err.splitlines()) == 1, err
    return err


def test_grid_values_as_linspace_list_or_single():
    name, values = parse_item("swivel=-180:180:24")
    xs = [float(v) for v in values]
    assert name == "swivel" and len(xs) == 24
    assert xs[0] == pytest.approx(-180.0) and xs[-1] == pytest.approx(180.0)
    assert np.allclose(np.diff(xs), 360.0 / 23)
    assert parse_item("mu=0.25,0.5,1.0") == ("mu", ["0.25", "0.5", "1.0"])
    assert parse_item("form=classic") == ("form", ["classic"])
    grid = parse_grid(["lambda=100,300", "M=1.5:3:2"])
    from app.headless.sweep.experiments import get

    exp = get("limit-drop")
    axes = build_axes(exp.knobs, grid, exp.groups)
    assert [a.values for a in axes] == [(100.0, 300.0), (1.5, 3.0)]
    assert len(cells(axes, seeds=3)) == 2 * 2 * 3


@pytest.mark.parametrize(
    ("argv", "words"),
    [
        (["limit-drop", "--grid", "bogus=1"], "unknown parameter 'bogus'"),
        (["limit-drop", "--grid", "lambda=-5"], "lambda_ must be between 1 and 1000"),
        (["limit-drop", "--grid", "form=wobbly"], "choose from proposed, classic"),
        (["limit-drop", "--grid", "torque_delay_ms=50"], "between 0 and 20 ms"),
        (["limit-drop", "--grid", "M=1:2"], "a:b:n"),
        (["limit-drop", "--grid", "M=1:2:zero"], "whole number"),
        (["limit-drop", "--grid", "M=abc"], "must be a number"),
        (["limit-drop", "--grid", "M=nan"], "finite"),
        (["limit-drop", "--grid", "lambda"], "NAME=VALUES"),
        (["limit-drop", "--grid", "M=1", "M=2"], "given twice"),
        (["limit-drop", "--grid", "feedback=maybe"], "on/off"),
        (["polish", "--grid", "mu=-0.5"], "mu must be between 0 and 1.5"),
        (["polish", "--grid", "objective=z"], "choose from j, f, a, d, planned"),
        (["polish", "--grid", "armature_scale=-1"], "armature_scale must be between 0 and 4"),
        (["polish", "--grid", "hold_swivel=0,30", "swivel=10"], "drop swivel"),
        (["polish", "--grid", "swivel=200"], "start_swivel_deg must be between -180 and 180"),
        (["polish", "--grid", "hold_swivel=0,200"], "hold_swivel=200: start_swivel_deg must be between -180 and 180"),
        (["mass-drop", "--grid", "payload_mass_error=0.6"], "between -0.5 and 0.5"),
        (["mass-drop", "--grid", "controller=magic"], "choose from position"),
        (["mass-drop", "--grid", "K_I=0"], "observer_gain must be between 1 and 1000"),
        (["polish", "--grid", "k0_a=2"], "k0_a must be between 0 and 1"),
        (["polish", "--grid", "nullspace.k0_a=2"], "k0_a must be between 0 and 1"),
        (["polish", "--grid", "nullspace.no_such=1"], "has no parameter 'no_such'"),
        (["polish", "--grid", "nowhere.x=1"], "no parameter group 'nowhere'"),
        (["limit-drop", "--grid", "damper.lambda_=100"], "unknown parameter 'damper.lambda_'"),
        (["juggle", "--grid", "x=1"], "unknown experiment 'juggle'"),
        (["limit-drop", "--grid", "M=2", "--seeds", "0"], "--seeds"),
        (["limit-drop", "--grid", "M=2", "--jobs", "0"], "--jobs"),
        (["limit-drop", "--grid", "M=2", "--cluster", "not an address"], "scheduler address"),
    ],
)
def test_bad_grid_is_a_one_line_error_and_nothing_runs(capsys, tmp_path, argv, words):
    out = tmp_path / "out"
    err = _one_line_error(capsys, ["sweep", *argv, "--out", str(out)])
    assert words in err
    assert not out.exists()


@pytest.fixture
def toy_env(tmp_path, monkeypatch):
    flags = {k: tmp_path / k.lower() for k in (KILL_FLAG, FAIL_FLAG, RUN_LOG)}
    for k, p in flags.items():
        monkeypatch.setenv(k, str(p))
    return flags


def _ran(log: Path) -> list[int]:
    return [int(x) for x in log.read_text().split()] if log.exists() else []


def test_a_killed_sweep_resumes_with_only_the_missing_cells(tmp_path, toy_env):
    grid = [({"x": x}, 0) for x in range(6)]
    out = tmp_path / "sweep"
    toy_env[KILL_FLAG].touch()
    with ProcessPoolExecutor(max_workers=1) as pool, pytest.raises(SystemExit):
        run_sweep("toy", toy_cell, grid, out, pool, progress=False)
    kept = CellStore(out / "cells.jsonl").records
    done_first = sorted(r["params"]["x"] for r in kept.values())
    assert done_first == [0, 1, 3]  # one worker runs them in the spread order 0, 3, 1, 4, …; x = 4 "killed" it
    toy_env[KILL_FLAG].unlink()
    toy_env[RUN_LOG].unlink()
    with ProcessPoolExecutor(max_workers=1) as pool:
        result = run_sweep("toy", toy_cell, grid, out, pool, progress=False)
    assert sorted(_ran(toy_env[RUN_LOG])) == [2, 4, 5]
    assert (result.ran, result.skipped, result.failed) == (3, 3, 0)
    lines = (out / "cells.jsonl").read_text().splitlines()
    assert len(lines) == 6 and len({json.loads(line)["key"] for line in lines}) == 6
    assert [r["metrics"]["square"] for r in result.records] == [float(x * x) for x in range(6)]


def test_a_failing_cell_is_recorded_and_rerun_only_with_retry_failed(tmp_path, toy_env):
    grid = [({"x": x}, s) for x in (3, 4, 5) for s in (0, 1)]
    out = tmp_path / "sweep"
    toy_env[FAIL_FLAG].touch()
    with ProcessPoolExecutor(max_workers=2) as pool:
        first = run_sweep("toy", toy_cell, grid, out, pool, progress=False)
    assert (first.ran, first.failed) == (6, 2)
    errors = [r for r in first.records if r["status"] == "error"]
    assert {r["params"]["x"] for r in errors} == {3}
    assert all("ValueError: cell three refuses" in r["error"] for r in errors)
    toy_env[FAIL_FLAG].unlink()
    with ProcessPoolExecutor(max_workers=2) as pool:
        again = run_sweep("toy", toy_cell, grid, out, pool, progress=False)
        assert (again.ran, again.skipped) == (0, 6)
        retried = run_sweep("toy", toy_cell, grid, out, pool, retry_failed=True, progress=False)
    assert (retried.ran, retried.failed, retried.skipped) == (2, 0, 4)
    assert all(r["status"] == "ok" for r in retried.records)
    rows = list(csv.DictReader((out / "cells.csv").open()))
    assert len(rows) == 6 and {r["status"] for r in rows} == {"ok"}
    assert sorted(float(r["m_square"]) for r in rows) == [9.0, 9.0, 16.0, 16.0, 25.0, 25.0]


def test_cells_are_submitted_spread_over_the_grid():
    order = spread_order(24)
    assert sorted(order) == list(range(24))
    assert order[:4] == [0, 12, 6, 18]
    first_half = order[:12]
    assert min(first_half) == 0 and max(first_half) >= 18  # an early stop still covers the whole axis


def test_a_two_axis_grid_is_filled_coarse_to_fine_on_both_axes():
    points = [{"a": a, "b": b} for a in range(24) for b in range(3)]
    keys = coarse_to_fine(points)
    first = [points[i] for i in sorted(range(len(points)), key=keys.__getitem__)[:12]]
    assert {p["b"] for p in first} == {0, 1, 2}  # every value of the short axis early
    assert {p["a"] for p in first} == {0, 12, 6, 18}  # and the long axis at quarter steps


def test_workers_started_earlier_see_the_submitters_qp_backend(tmp_path, toy_env, monkeypatch):
    monkeypatch.delenv("TORQUELAB_QP_BACKEND", raising=False)
    with ProcessPoolExecutor(max_workers=1) as pool:
        assert pool.submit(os.getpid).result() != os.getpid()  # the worker exists before the setting
        monkeypatch.setenv("TORQUELAB_QP_BACKEND", "osqp")
        result = run_sweep("toy", toy_cell, [({"x": 1}, 0)], tmp_path / "sweep", pool, progress=False)
    assert result.records[0]["metrics"]["backend"] == "osqp"
    assert result.records[0]["env"] == {"TORQUELAB_QP_BACKEND": "osqp"}


def test_a_half_written_last_line_is_ignored(tmp_path):
    path = tmp_path / "cells.jsonl"
    path.write_text(json.dumps({"key": "a", "status": "ok"}) + "\n" + '{"key": "b", "sta')
    store = CellStore(path)
    assert set(store.records) == {"a"}
    assert store.finished("a", retry_failed=True) and not store.finished("b", retry_failed=False)


def test_cells_whose_seeds_disagree_on_stability_are_marked():
    ok = {"status": "ok", "metrics": {"m": 1.0}}
    mean, sd, disagree, failed = _cell_summary([{**ok, "stable": True}, {**ok, "stable": False}], "m")
    assert (mean, sd, disagree, failed) == (1.0, 0.0, True, False)
    assert _cell_summary([{**ok, "stable": True}] * 2, "stable")[:3] == (1.0, 0.0, False)
    assert _cell_summary([{**ok, "stable": True}, {"status": "error"}], "m")[3]


LIMIT_DROP_GRID = ["lambda=100,300", "M=1.5,3", "duration=1.2"]


def _records(out: Path) -> dict[str, dict]:
    return CellStore(out / "cells.jsonl").records


def test_limit_drop_on_a_dask_localcluster_matches_the_local_pool(tmp_path, capsys):
    distributed = pytest.importorskip("distributed")
    local_out, dask_out = tmp_path / "local", tmp_path / "dask"
    base = ["sweep", "limit-drop", "--grid", *LIMIT_DROP_GRID, "--no-progress"]
    assert main([*base, "--out", str(local_out), "--jobs", "2"]) == 0
    with (
        distributed.LocalCluster(
            n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None, host="127.0.0.1"
        ) as cluster,
        distributed.Client(cluster) as client,
    ):
        worker_pids = set(client.run(os.getpid).values())
        assert main([*base, "--out", str(dask_out), "--cluster", cluster.scheduler_address]) == 0
    local, dask = _records(local_out), _records(dask_out)
    assert len(local) == 4 and set(local) == set(dask)
    for key, rec in dask.items():
        assert rec["status"] == "ok" and local[key]["status"] == "ok"
        assert int(rec["worker"].rsplit(":", 1)[1]) in worker_pids  # ran on a Dask worker
        a, b = local[key]["metrics"], rec["metrics"]
        assert a.keys() == b.keys()
        for name, value in a.items():
            if isinstance(value, float):
                assert b[name] == pytest.approx(value, rel=1e-9, abs=1e-12), name
            else:
                assert b[name] == value, name
    assert int(next(iter(local.values()))["worker"].rsplit(":", 1)[1]) not in worker_pids
    assert os.getpid() not in worker_pids
    violations = {r["params"]["lambda"]: r["metrics"]["max_violation"] for r in local.values()}
    assert all(np.isfinite(v) for v in violations.values())
    report = (local_out / "report.html").read_text()
    assert "Map: max_violation" in report and "Map: oscillations" in report and "data:image/png;base64" in report
    rows = list(csv.DictReader((local_out / "cells.csv").open()))
    assert len(rows) == 4 and {"p_lambda", "p_M", "m_max_violation", "worker"} <= set(rows[0])
    capsys.readouterr()


def test_the_grid_itself_must_be_given(capsys, tmp_path):
    with pytest.raises(SystemExit):
        main(["sweep", "limit-drop", "--out", str(tmp_path)])
    assert "--grid" in capsys.readouterr().err


def test_mass_drop_k_i_reaches_the_run_a_faster_observer_catches_the_drop_with_less_deflection():
    from app.headless.sweep.experiments import get

    cell = get("mass-drop").cell
    slow = cell({"controller": "torque-residual", "K_I": 10.0}, 0)["metrics"]
    fast = cell({"controller": "torque-residual", "K_I": 400.0}, 0)["metrics"]
    # the residual observer's lag is 1/K_I: 100 ms vs 2.5 ms; measured 18.9 vs 1.1 mm
    assert fast["peak_deflection_mm"] < 0.25 * slow["peak_deflection_mm"]


def test_polish_k0_reaches_the_session_a_larger_k0_a_moves_the_posture_further_in_the_same_settle_time():
    from app.headless.sweep.experiments import get

    cell = get("polish").cell
    base = {"objective": "a", "mu": 0.25, "converge_timeout": 2.0}
    slow = cell({**base, "k0_a": 0.01}, 0)["metrics"]
    fast = cell({**base, "k0_a": 0.5}, 0)["metrics"]
    # W_a's flow from the Fig. 6a start is a slow crawl at the default k0_a = 0.05 (+75° after ~55 s);
    # in a 2 s settle cap k0_a = 0.5 must move the swivel at least 5× as far as k0_a = 0.01 (measured
    # +20.2° vs +2.6°)
    assert abs(fast["converged_swivel_deg"]) > 5.0 * abs(slow["converged_swivel_deg"]) + 1.0


def test_polish_map_marks_the_planned_paths_over_the_swivels_they_visit():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from app.headless.sweep.grid import Axis
    from app.headless.sweep.overlays import PLAN_STYLES, planned_swivels, polish_notes, polish_overlay

    swivels = tuple(float(x) for x in np.linspace(-180.0, 180.0, 13))
    axes = [Axis("swivel", swivels), Axis("mu", (0.25, 1.0))]
    fig, ax = plt.subplots()
    polish_overlay(ax, axes, [])
    plans = planned_swivels()
    labels = ax.get_legend_handles_labels()[1]
    for cost, p in plans.items():
        assert f"planned path, cost {PLAN_STYLES[cost][0]}" in labels
        # the band spans the plan's swivels, in map units (index along the swivel axis)
        band = next(h for h in ax.patches if h.get_label() == f"planned path, cost {PLAN_STYLES[cost][0]}")
        x0, x1 = band.get_x(), band.get_x() + band.get_width()  # axvspan: a Rectangle in data x
        lo = np.interp(p["lo"], swivels, np.arange(len(swivels)))
        hi = np.interp(p["hi"], swivels, np.arange(len(swivels)))
        assert x0 <= lo + 1e-9 and x1 >= hi - 1e-9 and x1 - x0 <= hi - lo + 0.2 + 1e-9
        assert np.all((p["swivel_deg"] >= p["lo"]) & (p["swivel_deg"] <= p["hi"]))
    assert "Planned nullspace paths" in polish_notes(axes, [])
    plt.close(fig)


def test_a_polish_cell_sets_its_session_parameters_only_through_the_parameter_path(monkeypatch):
    """Every session knob of a polish cell (μ, start swivel, k0…) reaches `simulate` as a
    (group, field, value) for `Session.set_param`; only the run's own arguments are spec fields."""
    from app.headless.experiments import polish as polish_experiment
    from app.headless.sweep import experiments as sweep_experiments

    seen: list[dict] = []

    def fake(spec: dict) -> dict:
        seen.append(spec)
        return {"result": {"stable": True, "verdict": "stable"}}

    monkeypatch.setattr(polish_experiment, "simulate", fake)
    values = {"mu": 1.0, "swivel": 30.0, "k0_a": 0.5, "sander": True, "objective": "d", "converge_timeout": 20.0}
    values["motion_force.force_kd"] = 150.0  # any session parameter by GROUP.FIELD
    sweep_experiments.polish_cell(values, seed=3)
    (spec,) = seen
    assert sorted(spec["session_params"]) == sorted(
        [
            ("contact", "mu", 1.0),
            ("scenario", "start_swivel_deg", 30.0),
            ("nullspace", "k0_a", 0.5),
            ("sander", "enabled", True),
            ("motion_force", "force_kd", 150.0),
        ]
    )
    assert not {"mu", "start_swivel_deg", "sander"} & set(spec)
    assert spec["objective"] == "d" and spec["converge_timeout_s"] == 20.0 and spec["seed"] == 3


def test_limit_drop_and_mass_drop_cells_set_their_session_values_only_through_the_parameter_path(monkeypatch):
    """λ, M, the form, the feedback, K_I and the delay of a limit-drop cell, and the rig drawn around a
    mass-drop cell's nominal with its K_I, reach the run as (group, field, value) for `Session.set_param`;
    only the run knobs (limit, duration; controller, case, window) are arguments."""
    from app.headless.experiments import limit_drop, mass_drop
    from app.headless.sweep import experiments as sweep_experiments
    from app.scenarios.mass_drop import MassDropParams

    seen: list[tuple[tuple, dict]] = []

    def fake(*args, **kwargs) -> dict:
        seen.append((args, kwargs))
        return {"max_violation": 0.0, "stop": "done", "stabilization_time_s": 0.0}

    monkeypatch.setattr(limit_drop, "run_drop", fake)
    monkeypatch.setattr(mass_drop, "run_mass_drop", fake)
    values = {"lambda": 300.0, "M": 3.0, "form": "classic", "feedback": False, "K_I": 200.0, "torque_delay_ms": 2.0}
    sweep_experiments.limit_drop_cell({**values, "limit": "velocity", "duration": 1.5}, seed=0)
    args, kwargs = seen.pop()
    assert args == () and kwargs.pop("limit") == "velocity" and kwargs.pop("duration") == 1.5
    assert kwargs == {
        "session_params": [
            ("damper", "lambda_", 300.0),
            ("damper", "M", 3.0),
            ("damper", "form", "classic"),
            ("compliance_qp", "feedback", False),
            ("world", "torque_delay_ms", 2.0),
            ("estimator", "observer_gain", 200.0),
        ]
    }
    sweep_experiments.mass_drop_cell({"rope_stiffness": 800.0, "K_I": 40.0, "controller": "position"}, seed=4)
    args, kwargs = seen.pop()
    assert args == ("position", 4) and kwargs.pop("case") == "rope-drop" and "window_s" in kwargs
    drawn = mass_drop.draw_rig(4, MassDropParams(rope_stiffness_n_per_m=800.0))
    assert kwargs["session_params"][-1] == ("estimator", "observer_gain", 40.0)
    rig = dict((f, v) for g, f, v in kwargs["session_params"][:-1] if g == "scenario")
    assert MassDropParams(**rig) == drawn and len(kwargs["session_params"]) == len(rig) + 1
    assert set(kwargs) == {"window_s", "session_params"}


def test_a_drops_settings_are_the_sessions_after_the_parameter_path():
    """What a drop reports as its damper, feedback, K_I and delay is what its session ran with."""
    from app.headless.experiments.limit_drop import run_drop

    r = run_drop(
        limit="position",
        duration=0.05,
        session_params=[("damper", "lambda_", 300.0), ("compliance_qp", "feedback", False)],
        delay_steps=2,
    )
    assert (r["lambda"], r["M"], r["feedback"], r["torque_delay_ms"]) == (300.0, 2.0, False, 2.0)


def test_session_changes_put_scenario_values_in_force_from_t0_and_the_rest_after_the_build():
    """`Session(changes=…)`: a start swivel is the start posture's, μ is the contact's, and both stay
    after a reset; a refused value raises ParamError naming the field."""
    from app.core.commands import SetParam
    from app.core.session import Session
    from app.scenarios.polish import PolishScenario
    from control.coupling import swivel_angle
    from control.params import ParamError

    changes = [SetParam("contact", "mu", 1.0), SetParam("scenario", "start_swivel_deg", 30.0)]
    s = Session(PolishScenario(), changes=changes)
    assert s.environment.contact.mu == 1.0  # type: ignore[attr-defined]
    assert abs(np.rad2deg(swivel_angle(s.model, s.world.q)) - 30.0) < 0.5
    s.reset()
    assert s.environment.contact.mu == 1.0 and s.overrides()["scenario"] == {"start_swivel_deg": 30.0}  # type: ignore[attr-defined]
    with pytest.raises(ParamError, match=r"contact\.mu"):
        Session(PolishScenario(), changes=[SetParam("contact", "mu", -1.0)])


def test_experiments_map_their_runs_on_the_sweeps_engine_and_keep_the_order(monkeypatch):
    """`run_parallel` (the [C] experiments) opens its processes through `open_executor`, as sweeps do."""
    from app.headless.experiments import c_common

    opened = []
    real = c_common.open_executor

    def spy(cluster, jobs):
        opened.append((cluster, jobs))
        return real(cluster, jobs)

    monkeypatch.setattr(c_common, "open_executor", spy)
    assert c_common.run_parallel(abs, [(-3,), (-1,), (-2,)], 2, "abs") == [3, 1, 2]
    assert opened == [(None, 2)]


def test_a_group_field_name_is_typed_by_its_fields_metadata():
    """`motion_force.shaping=off,on` is a bool axis and `nullspace.k0_j=0.5` a float one, as their
    fields declare; no knob table names them."""
    from app.headless.sweep.experiments import get

    polish = get("polish")
    axes = build_axes(
        polish.knobs,
        [("motion_force.shaping", ["off", "on"]), ("nullspace.k0_j", ["0.5"])],
        polish.groups,
        polish.any_param,
    )
    assert [(a.name, a.values) for a in axes] == [("motion_force.shaping", (False, True)), ("nullspace.k0_j", (0.5,))]
