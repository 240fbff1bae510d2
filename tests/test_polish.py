"""The polish scenario and experiment: protocol pieces and a short closed-loop run."""

from __future__ import annotations

import numpy as np
import pytest

from app.core.session import Session
from app.headless.experiments.polish import _parse_mu, _stats, format_table, summarise
from app.scenarios import polish as P
from app.scenarios import polish_environment as PE
from app.scenarios import polish_plan as PP
from app.scenarios import polish_stroke as PS
from control.coupling import swivel_angle


def test_zigzag_alternates_retract_and_stretch_with_smooth_profiles():
    corners = PS.segment_waypoints()
    dx = np.diff(corners[:, 0])
    assert np.all(dx[0::2] < 0) and np.all(dx[1::2] > 0)  # S1, S3, S5 −X; S2, S4, S6 +X
    assert np.all(np.diff(corners[:, 1]) > 0)
    for s in (0.0, 1.0):  # minimum jerk: rest at both ends
        _, v, a = PS.min_jerk(s)
        assert v == 0.0 and abs(a) < 1e-12
    assert PS.min_jerk(0.5)[1] == pytest.approx(1.875)


def test_start_posture_is_elbow_up_with_the_tool_down_above_the_table(rizon):
    scenario = P.PolishScenario()
    q0 = scenario.initial_q(rizon)
    session = Session(scenario, seed=0)
    dyn = session.model.compute(q0, np.zeros(7))
    p, R = scenario.start_pose()
    np.testing.assert_allclose(dyn.tcp_position_world, p, atol=1e-9)
    np.testing.assert_allclose(dyn.tcp_rotation_world, R, atol=1e-9)
    assert dyn.tcp_position_world[2] - PS.TABLE_HEIGHT_M == pytest.approx(PS.START_GAP_M)
    assert swivel_angle(session.model, q0) == pytest.approx(0.0, abs=1e-5)
    assert np.all(q0 > rizon.q_lower) and np.all(q0 < rizon.q_upper)


def test_short_polish_run_holds_20_newtons(rizon):
    """Contact, then segment S1 (retract) at μ = 0.25 with the noisy, filtered sensor.

    Tolerances: the reading carries filtered noise (std √5·√(α/(2−α)) ≈ 0.6 N) and the 2 N,
    1 Hz sinusoid, which the force loop (K_f^p = 0.5) tracks: the error of the reading has RMS
    ≈ 1.5-2 N when all is well. We accept |mean| < 0.5 N, RMS < 2.5 N, |error| < 8 N, and
    the true contact force within 20 ± 5 N with the TCP on the table at all times.
    """
    session = Session(P.PolishScenario(mu=0.25), seed=3)
    session.set_param("nullspace", "objective", "j")
    clock = session.environment.clock  # type: ignore[attr-defined]
    session.run(0.8)  # press on the table
    clock.trajectory_start = session.world.time
    errors, contact, xs = [], [], []
    for _ in range(int(PS.SEGMENT_DURATION_S * 1000)):
        rec = session.step()
        errors.append(PS.DESIRED_FORCE_N - rec.wrench_tcp[2])
        contact.append(rec.signals["contact_force_n"])
        xs.append(session.dyn.tcp_position_world[0])
    e = np.array(errors)
    assert abs(e.mean()) < 0.5
    assert np.sqrt(np.mean(e**2)) < 2.5
    assert np.max(np.abs(e)) < 8.0
    assert np.min(contact) > 15.0 and np.max(contact) < 25.0
    assert xs[-1] == pytest.approx(PS.START_XY_M[0] - PS.SEGMENT_DX_M, abs=0.01)  # S1 reached its corner


def test_metrics_summary_and_table_helpers():
    st = _stats(np.array([1.0, -3.0, 2.0]))
    assert st["ma"] == pytest.approx(2.0) and st["ptp"] == pytest.approx(5.0)
    assert st["std"] == pytest.approx(np.std([1.0, -3.0, 2.0]))
    with pytest.raises(ValueError, match="non-negative"):
        _parse_mu("-1")
    with pytest.raises(ValueError, match="numbers"):
        _parse_mu("x")

    def run(seed: int, ma: float, stable: bool) -> dict:
        return {
            "row": "W_a",
            "objective": "a",
            "mu": 1.0,
            "seed": seed,
            "start_swivel_deg": 0.0,
            "shaping": True,
            "converged": True,
            "convergence_time_s": 50.0 + seed,
            "converged_swivel_deg": 75.0,
            "force_error": {"ma": ma, "ptp": 10 * ma, "std": ma / 2},
            "stable": stable,
            "margin": 20.0,
            "contact_lost_ms": 0,
            "W": {"f": 0.1, "a": 0.7, "d": 0.5},
            "Pf_fhat": {"stretch": -0.1, "retract": 0.1},
            "Pd_fhat": {"stretch": 0.8, "retract": -0.7},
        }

    summary = summarise([run(0, 1.0, True), run(1, 3.0, False)])
    assert len(summary) == 1 and summary[0]["n"] == 2 and summary[0]["stable"] == 1
    assert summary[0]["ma"]["mean"] == pytest.approx(2.0) and summary[0]["ma"]["sd"] == pytest.approx(np.sqrt(2.0))
    assert summary[0]["paper"] == [1.6, 10.8, 2.0]
    text = format_table(summary)
    assert "W_a" in text and "2.0 ± 1.4" in text and "20.0" in text and "1.6/10.8/2.0" in text


def test_table_iii_at_latencies_runs_the_other_latencies_and_groups_every_run_by_the_one_it_had():
    """The paper's four rows at the total latencies of one and two periods the table's own runs do not
    have (1 + 0 being the default's, 0 + 1 and 1 + 1 are run), none with a --set of either delay; each
    latency's Table III takes the runs that had it, the table's own included, with its total in periods."""
    from app.headless.experiments.polish import table_at_latencies, table_latency_of
    from app.headless.experiments.polish_rows import table_latency_specs

    own = table_latency_of([])
    assert own == (1, 0.0)
    assert table_latency_of([("world", "torque_delay_ms", 1.0)]) is None
    specs = table_latency_specs([0.25, 1.0], 2, own)
    assert {(s["reading_delay_steps"], s["torque_delay_ms"]) for s in specs} == {(0, 1.0), (1, 1.0)}
    assert len(specs) == 2 * 4 * 2 * 2 and {s["objective"] for s in specs} == {"j", "f", "a", "d"}
    assert all(s["group"] == "table_latency" for s in specs)
    assert {s["objective"] for s in table_latency_specs([1.0], 1, own, only=["a", "mirror"])} == {"a"}

    def run(row: str, ds: int, da: float, stable: bool, group: str = "table_latency", start: float = 0.0) -> dict:
        return {
            "row": row, "objective": row[-1], "group": group, "mu": 1.0, "seed": 0, "start_swivel_deg": start,
            "shaping": True, "converged": True, "convergence_time_s": 1.0, "converged_swivel_deg": 0.0,
            "force_error": {"ma": 1.0, "ptp": 10.0, "std": 2.0}, "stable": stable, "margin": 1.0,
            "contact_lost_ms": 0 if stable else 100, "W": {"f": 0.1, "a": 0.7, "d": 0.5},
            "Pf_fhat": {"stretch": -0.1, "retract": 0.1}, "Pd_fhat": {"stretch": 0.8, "retract": -0.7},
            "reading_delay_steps": ds, "torque_delay_ms": da, "timestep_s": 0.001,
        }  # fmt: skip

    table = [run("W_a", 1, 0.0, True, "table"), run("W_a from -30°", 1, 0.0, True, "table", start=-30.0)]
    at = table_at_latencies(table, [run("W_a", 1, 1.0, False), run("W_a", 0, 1.0, True)])
    pairs = [(x["reading_delay_steps"], x["torque_delay_ms"], x["total_periods"]) for x in at["latencies"]]
    assert pairs == [(1, 0.0, 1.0), (0, 1.0, 1.0), (1, 1.0, 2.0)]
    assert [[(e["row"], e["stable"], e["n"]) for e in x["summary"]] for x in at["latencies"]] == [
        [("W_a", 1, 1)],
        [("W_a", 1, 1)],
        [("W_a", 0, 1)],
    ]


def test_the_console_tables_print_a_swivel_or_margin_that_rounds_to_zero_as_0_not_minus_0():
    """A posture that settled at −0.3° and a margin of −0.2 N s/m print as "0°" and "0" (the HTML report's
    way), a real −3° keeps its sign."""
    cell = {"mean": 1.0, "sd": None}

    def entry(swivel: float, margin: float) -> dict:
        return {
            "row": "W_a",
            "mu": 1.0,
            "ma": cell,
            "ptp": cell,
            "std": cell,
            "paper": None,
            "converged_swivel_deg": {"mean": swivel},
            "margin": {"mean": margin},
            "converged": 1,
            "stable": 1,
            "n": 1,
        }

    near, far = format_table([entry(-0.3, -0.2), entry(-3.2, -12.4)]).splitlines()[1:]
    assert near.split()[6:8] == ["0°", "0"] and "-0" not in near
    assert far.split()[6:8] == ["-3°", "-12"]


def test_cli_registers_the_polish_experiment_with_its_options():
    import argparse

    from app.headless.experiments import EXPERIMENTS
    from app.headless.experiments.polish import add_arguments
    from app.headless.experiments.polish_rows import table_specs

    assert EXPERIMENTS["polish"] == "polish"
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    args = parser.parse_args(["--mu", "1.0", "--sander", "--seeds", "3", "--quick"])
    assert args.mu == "1.0" and args.sander and args.seeds == 3 and args.quick
    quick = table_specs([0.25, 1.0], 5, quick=True)
    assert len(quick) == 8 and {s["objective"] for s in quick} == {"j", "f", "a", "d"}
    full = table_specs([0.25, 1.0], 5, quick=False)
    assert len(full) == 8 * 2 * 5
    assert {s["objective"] for s in full} == {"j", "f", "a", "d", "planned", "planned_a"}
    assert any(s["start_swivel_deg"] == -30.0 for s in full) and any(not s["shaping"] for s in full)


def test_a_gradient_flow_on_a_plateau_is_not_declared_converged():
    """1-D gradient flow ψ̇ = −∂W/∂ψ at 1 kHz: a plateau of constant slope (flow speed 0.008 rad/s,
    the W_a plateau speed of the Fig. 6a start) from ψ = 0.6 to 1, then a quadratic well at 1.2.

    The old criterion (‖q̇‖ < 0.01 rad/s for 0.3 s) stops on the plateau; the settle criterion must
    not fire before the flow has reached the well's minimum within 0.025 rad (where the speed
    0.04·|ψ − 1.2| falls below 1e-3 rad/s), and must fire once it is there."""

    def grad(psi: float) -> float:
        return -0.008 if psi < 1.0 else 0.04 * (psi - 1.2)

    def value(psi: float) -> float:
        return 1.0 - 0.008 * psi if psi < 1.0 else 0.992 + 0.02 * ((psi - 1.2) ** 2 - 0.04)

    crit = PS.SettleCriterion()
    psi, dt = 0.6, 1e-3
    old_fired_at = fired_at = None
    quiet = 0
    for _ in range(150_000):
        speed = abs(grad(psi))
        quiet = quiet + 1 if speed < 0.01 else 0
        if old_fired_at is None and quiet >= 300:
            old_fired_at = psi
        if crit.update(speed, value(psi)):
            fired_at = psi
            break
        psi -= dt * grad(psi)
    assert old_fired_at is not None and old_fired_at < 1.0  # the old test stops on the plateau
    assert fired_at is not None and abs(fired_at - 1.2) <= 0.025 + 1e-3


def test_settle_criterion_needs_a_full_quiet_second_and_restarts_on_bad_numbers():
    crit = PS.SettleCriterion()
    for _ in range(1000):
        assert not crit.update(0.0, 1.0)  # the window is not full yet
    assert crit.update(0.0, 1.0)
    assert not crit.update(2e-3, 1.0)  # one fast step: a new quiet second is needed
    assert not any(crit.update(0.0, 1.0) for _ in range(999))
    assert crit.update(0.0, 1.0)
    assert not crit.update(float("nan"), 1.0)
    assert not crit.update(0.0, 1.0)


def test_settle_now_ends_the_settle_phase_on_the_criterion_and_the_panel_shows_it():
    """A W_j hold converges one window after contact (q̂̇n ≈ 0, W_j ≈ 0); settle_now runs until then."""
    from app.live.ui.panels.nullspace import _polish_lines

    session = Session(P.PolishScenario(mu=0.25, hold_swivel_deg=0.0), seed=0)
    assert session.executor.nullspace.objective == "j"  # holding a swivel runs W_j on the start posture
    clock = session.environment.clock  # type: ignore[attr-defined]
    res = P.settle_now(session)
    assert res.stop == "until" and clock.converged
    assert clock.convergence_time_s == pytest.approx(PS.CONVERGE_MIN_S, abs=0.01)
    sig = session.step().signals
    assert sig["settle_converged"] == 1.0 and abs(sig["swivel_deg"]) < 0.5
    assert P.settle_now(session).steps == 0  # nothing left to settle
    text = _polish_lines({**sig, "margin_kd": -12.0, "margin_rate": 3.0})
    assert "converged after 1.0 s" in text and "decays" in text
    assert "K_f^d" not in text and "N s/m" not in text  # the worst-case K_f^d margin does not contradict σ here
    assert _polish_lines({}) == ""


def test_polish_cases_pick_the_mirror_start_or_a_planned_path():
    from app.core.variants import make_variant, variant_of

    assert variant_of(P.SCENARIO).options == P.MODES
    assert make_variant("polish", "mirror start").start_swivel_deg == P.MIRROR_START_DEG
    assert make_variant("polish", "planned W_a").plan_cost == "a"
    assert make_variant("polish", "planned max(P_d·f̂, 0)²").plan_cost == "signed"
    with pytest.raises(ValueError, match="unknown polish case"):
        P.PolishScenario(mode="x")


def _toy_run(spec: dict) -> dict:
    """A stand-in for `simulate` with the result fields the progress line reads; margin None as a
    posture no K_f^d stabilises reports it."""
    result = {
        "objective": spec["objective"],
        "mu": spec["mu"],
        "seed": spec["seed"],
        "start_swivel_deg": 0.0,
        "shaping": True,
        "armature_scale": 1.0,
        "converged": False,
        "convergence_time_s": None,
        "converged_swivel_deg": None,
        "margin": None,
        "stable": False,
        "force_error": {"ma": None, "ptp": None, "std": None},
        "wall_s": 0.0,
    }
    return {"result": result, "series": {"t": np.arange(3.0) * spec["seed"]}}


def test_finished_runs_are_kept_as_they_finish_and_resume_reuses_only_matching_ones(tmp_path, capsys):
    from app.headless.experiments.polish import _map
    from app.headless.experiments.polish_runs import load_run

    specs = [{"objective": "j", "mu": 1.0, "seed": s, "session_params": [("nullspace", "k0_j", 2.0)]} for s in (1, 2)]
    runs = tmp_path / "runs"
    first, _ = _map(_toy_run, specs, 1, 0.0, runs)  # None swivel and margin print without an error
    assert "margin none" in capsys.readouterr().err
    assert [o["result"]["seed"] for o in first] == [1, 2]
    again = load_run(runs, specs[1])
    assert again is not None and np.array_equal(again["series"]["t"], [0.0, 2.0, 4.0])
    assert load_run(runs, {**specs[1], "mu": 0.25}) is None  # another spec is not a saved run

    ran: list[int] = []

    def counting(spec: dict) -> dict:
        ran.append(spec["seed"])
        return _toy_run(spec)

    more = [*specs, {**specs[0], "seed": 3}]
    out, reused = _map(counting, more, 1, 0.0, runs, resume=True)
    assert ran == [3] and reused == 2 and [o["result"]["seed"] for o in out] == [1, 2, 3]
    _map(counting, more, 1, 0.0, runs)  # without --resume every run runs again
    assert ran == [3, 1, 2, 3]


def test_an_unfinished_invocations_runs_can_be_combined_and_a_combine_needs_one_finished_one(tmp_path):
    """--combine takes a directory without polish.json by the runs it finished (runs/, `save_run`),
    half-written ones left out; with no directory that has its polish.json it refuses in one line."""
    import argparse

    from app.headless.experiments.polish import combine
    from app.headless.experiments.polish_runs import _finished_runs, save_run

    runs = tmp_path / "unfinished" / "runs"
    for seed in (1, 2):
        spec = {"objective": "j", "mu": 1.0, "seed": seed}
        save_run(runs, spec, _toy_run(spec))
    (runs / "half.tmp.json").write_text("{")  # a run being written when the invocation stopped
    results, series = _finished_runs(runs)
    assert sorted(r["seed"] for r in results) == [1, 2]
    assert sorted(float(s["t"][-1]) for s in series) == [2.0, 4.0]
    args = argparse.Namespace(combine=str(tmp_path / "unfinished"), out=str(tmp_path / "out"))
    with pytest.raises(ValueError, match=r"at least one directory with its polish\.json") as err:
        combine(args, [tmp_path / "unfinished"])
    assert "\n" not in str(err.value)
    with pytest.raises(ValueError, match=r"neither polish\.json nor runs/"):
        combine(args, [tmp_path / "nothing"])


def test_a_quick_one_row_experiment_writes_a_report_from_its_own_runs(tmp_path):
    import json

    from app.cli import main

    out = tmp_path / "polish"
    args = ["experiment", "polish", "--quick", "--rows", "j", "--mu", "1", "--no-latency", "--out", str(out)]
    assert main(args) == 0
    doc = json.loads((out / "polish.json").read_text())
    (run,) = doc["runs"]
    assert run["objective"] == "j" and run["mu"] == 1.0 and run["converged"]
    assert doc["settings"]["code"] and doc["settings"]["reused_runs"] == 0
    page = (out / "report.html").read_text()
    fe = run["force_error"]
    # the table row and the findings carry this run's numbers, and the run is kept in runs/
    # (Table III as the paper prints it: each cell holds ours over the paper's value)
    assert (
        f"<td>{fe['ma']:.1f}<br><small>paper 5.9</small></td><td>{fe['ptp']:.1f}<br><small>paper 72.4</small></td>"
        f"<td>{fe['std']:.1f}<br><small>paper 9.3</small></td>"
    ) in page
    assert f"MA {fe['ma']:.1f} vs 5.9" in page
    assert len(list((out / "runs").glob("*.json"))) == 1
    # the margin along the strokes: six strokes, and the report's row carries the run's own values
    assert [s["segment"] for s in run["stroke_margin"]] == [1, 2, 3, 4, 5, 6]
    pd = run["stroke"]["stretch_pd_fhat"]
    assert f"<td>{pd['mean']:+.3f}</td><td>{pd['max']:+.3f}</td>" in page and "Agreement " in page


def test_armature_table_flags_runs_that_did_not_converge_or_were_not_stable_with_their_verdict():
    from app.headless.experiments.polish_report import _arm_ptp

    def run(objective, converged, stable):
        return {
            "armature_scale": 0.0,
            "objective": objective,
            "force_error": {"ptp": 10.64},
            "converged_swivel_deg": -86.2,
            "converged": converged,
            "stable": stable,
            "verdict": "stable" if stable else "oscillating",
        }

    doc = {"armature": {"runs": [run("d", False, True), run("f", True, False), run("a", True, True)]}}
    assert _arm_ptp(doc, 0.0, "d") == "10.6 (-86°, not converged)"
    assert _arm_ptp(doc, 0.0, "f") == "10.6 (-86°, oscillating)"
    assert _arm_ptp(doc, 0.0, "a") == "10.6 (-86°)"
    assert _arm_ptp(doc, 1.0, "a") == "-"


def test_a_planned_case_names_its_work_and_a_deferred_session_raises_before_it_is_built(monkeypatch):
    """`pending_work` names the plan while it is not cached; `Session(defer_work=True)` raises
    WorkPending with it; once its result is stored the same session builds with that plan."""
    from app.core.session import Session, WorkPending
    from app.core.variants import make_variant

    monkeypatch.setattr(PP, "_PLAN_CACHE", {})
    spec = make_variant("polish", "planned W_a")
    with pytest.raises(WorkPending) as pending:
        Session(spec, defer_work=True)
    work = pending.value.work
    assert work.compute is PP.compute_plan and "swivel path" in work.what
    plan = type("Plan", (), {"transfer_s": 0.5, "t": np.array([0.0, 1.0]), "q": np.zeros((2, 7))})()
    work.store(plan)  # (a stand-in: the plan itself is tested in test_planner.py)
    monkeypatch.setattr(PP, "compute_plan", lambda *a, **k: pytest.fail("computed again"))
    session = Session(spec, defer_work=True)
    assert session.scenario.plan is plan and spec.pending_work(session.robot) is None


def test_a_run_without_the_live_margin_computes_none_not_even_at_the_start(monkeypatch):
    """`live_margin_every_s = inf` (headless runs) means no live margin: the first step computes
    none either (with a long torque delay one costs seconds), and the signal stays NaN."""
    session = Session(P.PolishScenario())
    session.environment.live_margin_every_s = float("inf")  # type: ignore[attr-defined]
    monkeypatch.setattr(PE.PolishEnvironment, "live_margin", lambda self, t: pytest.fail("computed"))
    session.run(steps=5)
    assert np.isnan(session.last.signals["margin_kd"])


def test_the_armature_scale_set_on_a_running_session_reaches_the_world_and_the_model_at_reset():
    """The polish armature scale goes the parameter path: after `set_param` and a reset the simulated arm's
    armature, the controller model's and the joint inertia M both carry it; a world armature scale
    multiplies the simulated one on top."""
    session = Session("polish", seed=0)
    nominal = session.robot.armature.copy()
    M0 = session.dyn.M.copy()
    session.set_param("scenario", "armature_scale", 2.0)
    session.reset()
    dof = session.world.dof_adr
    np.testing.assert_allclose(session.world.model.dof_armature[dof], 2.0 * nominal, rtol=1e-12)
    np.testing.assert_allclose(session.robot.model.armature, 2.0 * nominal, rtol=1e-12)
    np.testing.assert_allclose(np.diag(session.dyn.M) - np.diag(M0), nominal, rtol=1e-9, atol=1e-12)
    session.set_param("world", "armature_scale", 1.5)
    np.testing.assert_allclose(session.world.model.dof_armature[dof], 3.0 * nominal, rtol=1e-12)
    np.testing.assert_allclose(session.robot.model.armature, 2.0 * nominal, rtol=1e-12)  # the model: no
    session.restore_defaults()
    np.testing.assert_allclose(session.world.model.dof_armature[dof], nominal, rtol=1e-12)
    np.testing.assert_allclose(session.robot.model.armature, nominal, rtol=1e-12)
