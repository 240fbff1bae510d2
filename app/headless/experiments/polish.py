"""Polish: reproduce the simulation study of [T] §IV-B (Table III, Figs. 6, 8, 9) headless.

Each run is one `Session` of the polish scenario (contact, settle until the posture has
converged, six-segment zig-zag) with one nullspace objective, one friction coefficient and one
noise seed; rows add the W_a start across the ridge, W_j without inertia shaping and the two
planned-path rows ([T] §IV-B future work, `control.planner`). Every run carries the force-loop
margin of its converged posture (`control.margin`). Runs go to worker processes (`--jobs`).
Outputs in --out: polish.json (every run and the mean ± sd per row), polish_series.npz,
figures and report.html; runs/ keeps each run as it finishes (`--resume` reuses them).
The rows and their specs are in `polish_rows`, the latency table in `polish_latency`, the per-run
storage in `polish_runs`, the v_ε check in `polish_v_eps`, the figures and report in `polish_report`.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from concurrent.futures import as_completed
from pathlib import Path
from typing import Any

import numpy as np

from app.core.provenance import code_record
from app.headless.experiments.polish_calibration import observed_mode, runs_by_row
from app.headless.experiments.polish_latency import HoldWatch, _latency_of, format_latency, latency_specs, latency_table
from app.headless.experiments.polish_report import _deg, _num
from app.headless.experiments.polish_rows import (
    ARMATURE_SCALES,
    OBJECTIVE_NAMES,
    PAPER_TABLE_III,
    ROW_KEYS,
    TABLE_LATENCIES,
    armature_specs,
    table_latency_specs,
    table_specs,
)
from app.headless.experiments.polish_runs import RUNS_DIR, _finished_runs, load_run, save_run
from app.headless.experiments.polish_v_eps import V_EPS_CHECK_M_PER_S, v_eps_check
from app.headless.experiments.run_config import parse_settings, run_configuration
from app.headless.sweep.engine import open_executor
from app.scenarios import polish_plan as plan_module
from app.scenarios import polish_stroke as stroke_module
from app.scenarios import verdict as V
from app.scenarios.metrics import force_error_std
from app.scenarios.polish import PolishScenario
from app.scenarios.polish_margin import MARGIN_SAMPLE_S
from app.scenarios.polish_stroke import N_SEGMENTS

PLAN_COST_OF = {"planned": "signed", "planned_a": "a"}
DEFAULT_SEEDS = 5
RECORD_EVERY = 5  # time series kept at 200 Hz for the figures
SAFETY_CAP_S = stroke_module.CONVERGE_TIMEOUT_S + stroke_module.CONTACT_TIME_S + 20.0  # settle cap + trajectory


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of `torquelab experiment polish`."""
    parser.add_argument("--mu", default="0.25,1.0", help="Coulomb friction coefficients, comma separated")
    parser.add_argument("--seeds", type=int, default=DEFAULT_SEEDS, help="noise seeds per cell (0, 1, ...)")
    parser.add_argument("--first-seed", type=int, default=0, help="first noise seed (to add seeds to an earlier run)")
    parser.add_argument("--sander", action="store_true", help="add the 7000 RPM electric-sander disturbance")
    parser.add_argument(
        "--quick", action="store_true", help="1 seed, the 8 paper cells only (W_j/W_f/W_a/W_d × μ): a few-minute look"
    )
    parser.add_argument("--no-armature", action="store_true", help="skip the armature sensitivity runs")
    parser.add_argument("--only-armature", action="store_true", help="run the armature sensitivity runs alone")
    parser.add_argument(
        "--combine",
        default=None,
        help="write one report from the runs of earlier output directories (comma separated), running nothing",
    )
    parser.add_argument(
        "--resume",
        action="store_true",
        help="reuse the runs an earlier (interrupted) invocation with the same --out already finished "
        "(runs/ in --out: each run is saved as it finishes) with the same code version",
    )
    parser.add_argument("--no-latency", action="store_true", help="skip the latency table's runs")
    parser.add_argument(
        "--no-table-latency",
        action="store_true",
        help="skip Table III at the other total latencies of one and two control periods (F/T age + torque delay "
        "1 + 0, 0 + 1, 1 + 1)",
    )
    parser.add_argument(
        "--rows", default=None, help=f"only these rows of the table, comma separated ({', '.join(ROW_KEYS)})"
    )


def _parse_mu(text: str) -> list[float]:
    items = [s.strip() for s in str(text).split(",") if s.strip()]
    if not items:
        raise ValueError("--mu needs at least one value")
    try:
        values = [float(s) for s in items]
    except ValueError:
        raise ValueError(f"--mu must be numbers, got {text!r}") from None
    if any(not np.isfinite(v) or v < 0 for v in values):
        raise ValueError("--mu values must be finite and non-negative")
    return values


# ---- one run ------------------------------------------------------------------------------------
def simulate(spec: dict) -> dict:
    """Run one polish session and return its metrics and (downsampled) time series.

    spec: objective ("j", "f", "a", "d", "planned", "planned_a"), mu, seed, start_swivel_deg,
    optional shaping, armature_scale, sander, sensor_cutoff_hz, converge_timeout_s (settle cap),
    hold_swivel_deg, row, group, reading_delay_steps (the F/T reading's age, control periods),
    torque_delay_ms, strokes (run only the first n segments), stop_on_verdict (end the run at a verdict
    while the TCP is held: `HoldWatch`; the latency table's runs), session_params ((group, field, value)
    set on the session after the others; a sweep's session parameters come this way). Every session
    parameter goes through the parameter path (`Session(changes=…)`); the result reports the values
    the session ran with."""
    from app.core.commands import SetParam
    from app.core.session import Session
    from control.coupling import swivel_angle

    t_wall = time.perf_counter()
    objective = str(spec["objective"])
    plan_cost = PLAN_COST_OF.get(objective)
    scenario = PolishScenario(
        converge_timeout_s=float(spec.get("converge_timeout_s", stroke_module.CONVERGE_TIMEOUT_S)),
        hold_swivel_deg=spec.get("hold_swivel_deg"),
        plan_cost=plan_cost,
    )
    optional = (
        ("mu", "contact", "mu"),
        ("sander", "sander", "enabled"),
        ("armature_scale", "scenario", "armature_scale"),
        ("shaping", "motion_force", "shaping"),
        ("sensor_cutoff_hz", "sensor", "cutoff_hz"),
        ("reading_delay_steps", "sensor", "reading_delay_steps"),
        ("torque_delay_ms", "world", "torque_delay_ms"),
    )
    changes = [SetParam(g, f, spec[key]) for key, g, f in optional if spec.get(key) is not None]
    if spec.get("hold_swivel_deg") is None and spec.get("start_swivel_deg") is not None:
        changes.append(SetParam("scenario", "start_swivel_deg", spec["start_swivel_deg"]))
    if plan_cost is None and spec.get("hold_swivel_deg") is None:
        changes.append(SetParam("nullspace", "objective", objective))
    changes += [SetParam(g, f, v) for g, f, v in spec.get("session_params", ())]  # e.g. ("nullspace", "k0_a", 0.5)
    session = Session(scenario, seed=int(spec["seed"]), changes=changes)
    ran = session.params()  # the groups the run is made with
    clock = session.environment.clock  # type: ignore[attr-defined]
    session.environment.live_margin_every_s = float("inf")  # type: ignore[attr-defined]  # a page signal only
    target = session.target_fn
    q_start = session.world.q.copy()
    cols = ("t", "force_error", "force_error_true", "W_f", "W_a", "W_d", "segment", "swivel", "swivel_plan")
    rec: dict[str, list[float]] = {k: [] for k in cols}
    q_converged: list[np.ndarray] = []
    stroke_q: list[tuple[float, np.ndarray]] = []  # (trajectory time, q) every MARGIN_SAMPLE_S on the strokes
    dt = float(session.world.model.opt.timestep)
    margin_every = max(1, round(MARGIN_SAMPLE_S / dt))
    hold = HoldWatch(
        V.oscillation_threshold_n(ran["sensor"], dt),
        round(stroke_module.SETTLE_WINDOW_S / dt),
        dt,
    )
    stop_on_verdict = bool(spec.get("stop_on_verdict", False))

    def record(r) -> None:
        sig = r.signals
        if clock.trajectory_start is None and r.t >= stroke_module.CONTACT_TIME_S:  # held, settling
            hold.add(r.t, r.wrench_tcp[2], sig["contact_force_n"], sig["swivel_deg"])
        if 1 <= sig["segment"] <= N_SEGMENTS and len(rec["t"]) % margin_every == 0:
            stroke_q.append((r.t - float(clock.trajectory_start), r.q.copy()))
        if not q_converged and clock.trajectory_start is not None:
            q_converged.append(r.q.copy())
        rec["t"].append(r.t)
        rec["force_error"].append(stroke_module.DESIRED_FORCE_N - r.wrench_tcp[2])  # filtered F/T reading
        rec["force_error_true"].append(stroke_module.DESIRED_FORCE_N - sig["contact_force_n"])
        rec["W_f"].append(sig["W_f"])
        rec["W_a"].append(sig["W_a"])
        rec["W_d"].append(sig["W_d"])
        rec["segment"].append(sig["segment"])
        rec["swivel"].append(sig["swivel_deg"])
        rec["swivel_plan"].append(target.planned_swivel_deg(r.t) if plan_cost else np.nan)  # type: ignore[attr-defined]

    strokes = int(spec.get("strokes", N_SEGMENTS))  # the first this many segments (a shorter stability map)
    result_run = session.run(
        SAFETY_CAP_S,
        until=lambda r: _run_over(clock, r.t, strokes) or (stop_on_verdict and hold.verdict is not None),
        record=record,
    )
    held = hold.result(stop_on_verdict and hold.verdict is not None)
    series = {k: np.asarray(v, dtype=float) for k, v in rec.items()}
    qc = q_converged[0] if q_converged else session.world.q.copy()
    model = session.model
    traj = (series["segment"] >= 1) & (series["segment"] <= N_SEGMENTS)
    contact_n = stroke_module.DESIRED_FORCE_N - series["force_error_true"]  # the true contact force
    mu, shaping = float(ran["contact"].mu), bool(ran["motion_force"].shaping)  # type: ignore[attr-defined]
    posture = posture_figures(session, qc, mu, shaping)
    stroke = stroke_margin_figures(session, stroke_q, shaping)
    result: dict[str, Any] = {
        "row": spec.get("row", OBJECTIVE_NAMES.get(objective, objective)),
        "group": spec.get("group", "table"),
        "objective": objective,
        "mu": mu,
        "seed": int(spec["seed"]),
        "start_swivel_deg": float(np.rad2deg(swivel_angle(model, q_start))),
        "shaping": shaping,
        "armature_scale": float(ran["scenario"].armature_scale),  # type: ignore[attr-defined]
        "sander": bool(ran["sander"].enabled),  # type: ignore[attr-defined]
        "sensor_cutoff_hz": float(ran["sensor"].cutoff_hz),  # type: ignore[attr-defined]
        "reading_delay_steps": int(ran["sensor"].reading_delay_steps),  # type: ignore[attr-defined]
        "torque_delay_ms": float(ran["world"].torque_delay_ms),  # type: ignore[attr-defined]
        "sensor": dataclasses.asdict(ran["sensor"]),  # type: ignore[call-overload]
        "contact": {
            **dataclasses.asdict(ran["contact"]),  # type: ignore[call-overload]
            "implicit_friction": bool(session.environment.contact.implicit),  # type: ignore[attr-defined]
            "spring_lag_steps": int(session.environment.contact.spring_lag_steps),  # type: ignore[attr-defined]
        },
        "robot": session.robot.name,
        "config": run_configuration(session),
        "timestep_s": float(session.world.model.opt.timestep),
        "converged": bool(clock.converged),
        "convergence_time_s": clock.convergence_time_s,
        "settle_cap_s": clock.timeout_s,
        "converged_swivel_deg": float(np.rad2deg(swivel_angle(model, qc))),
        "posture_change_deg": [float(x) for x in np.rad2deg(qc - q_start)],
        **posture,
        "force_error": _stats(series["force_error"][traj]),
        "force_error_true_contact": _stats(series["force_error_true"][traj]),
        "contact_lost_ms": int(np.sum(V.contact_lost(contact_n[traj]))),
        "run_stop": result_run.stop,
        "diverged": result_run.stop == "diverged",
        "held": held,
        "per_segment": [],
        **stroke,
        "q_start": [float(x) for x in q_start],
        "q_converged": [float(x) for x in qc],
    }
    # the one verdict (app.scenarios.verdict) per stroke, from the F/T reading and the true contact force
    judged = V.strokes(
        series["segment"],
        stroke_module.DESIRED_FORCE_N - series["force_error"],
        contact_n,
        ran["sensor"],
        dt,
    )
    verdict = V.run_verdict(judged, diverged=result["diverged"])
    if verdict != V.DIVERGED and held["stopped"]:  # stopped while held at a verdict (the latency runs)
        verdict = held["verdict"]
    result["verdict"] = verdict if np.any(traj) or verdict != V.STABLE else "no strokes"
    result["stable"] = result["verdict"] == V.STABLE
    result["band_floor_n"] = V.sensor_band_floor_n(ran["sensor"], dt)
    result["oscillation_threshold_n"] = V.oscillation_threshold_n(ran["sensor"], dt)
    result.update(V.band_facts())  # the band the strokes were judged in, for the reports' definition
    result["band_rms_max_n"] = max((s.band_rms_n for s in judged), default=None)
    by_segment = {s.segment: s for s in judged}
    if plan_cost is not None:
        plan = session.scenario.plan  # type: ignore[attr-defined]  # the session's copy of the scenario
        assert plan is not None
        result["plan_cost"] = plan.total_cost
        result["plan_cost_kind"] = plan_cost
        if plan_cost == "signed":  # the best max(P_d·f̂, 0) the self-motion loop allows on the stretching strokes
            from app.scenarios.polish_margin import stretch_floor

            result["plan_stretch_floor"] = stretch_floor(plan)
        sel = traj | ((series["segment"] == 0) & (series["t"] >= stroke_module.CONTACT_TIME_S + plan.transfer_s))
        err = np.abs((series["swivel"][sel] - series["swivel_plan"][sel] + 180.0) % 360.0 - 180.0)
        result["plan_tracking_deg"] = {"mean": _mean(err), "max": float(np.max(err)) if err.size else None}
        result["plan"] = {
            "t": [float(x) for x in plan.t],
            "swivel_deg": [float(x) for x in np.rad2deg(plan.swivel_rad)],
            "transfer_s": plan.transfer_s,
        }
    for seg_k in range(1, N_SEGMENTS + 1):
        sel = series["segment"] == seg_k
        idx = np.flatnonzero(sel)
        result["per_segment"].append(
            {
                "segment": seg_k,
                "direction": "retract (-X)" if seg_k % 2 == 1 else "stretch (+X)",
                "force_error": _stats(series["force_error"][sel]),
                "contact_lost_ms": int(np.sum(V.contact_lost(contact_n[sel]))),
                "verdict": by_segment[seg_k].verdict if seg_k in by_segment else None,
                "band_rms_n": by_segment[seg_k].band_rms_n if seg_k in by_segment else None,
                # the true contact force's mode on this stroke, beside the margin's (polish_calibration)
                "observed": observed_mode(series["force_error_true"], int(idx[0]), int(idx[-1]) + 1, dt)
                if idx.size
                else None,
            }
        )
    result["wall_s"] = time.perf_counter() - t_wall
    down = {k: v[::RECORD_EVERY].astype(np.float32) for k, v in series.items()}
    return {"result": result, "series": down}


def posture_figures(session, q: np.ndarray, mu: float, shaping: bool) -> dict:
    """W_f/W_a/W_d, P_f·f̂ and P_d·f̂ (stretching and retracting friction directions) and the
    force-loop margin at a posture (the trajectory start)."""
    from dataclasses import replace

    from control.coupling import POLISH_SUBSPACES, coupling_values, terms_of
    from control.margin import ContactLoop, posture_margin

    dyn = session.model.compute(q, np.zeros(len(q)))
    terms = terms_of(dyn, POLISH_SUBSPACES)
    W = coupling_values(terms)
    dirs = {"stretch": stroke_module.friction_direction(1.5 * stroke_module.SEGMENT_DURATION_S)}
    dirs["retract"] = stroke_module.friction_direction(0.5 * stroke_module.SEGMENT_DURATION_S)
    gains = replace(session.executor.gains, shaping=shaping)  # type: ignore[attr-defined]
    loop = ContactLoop(
        stiffness_n_per_m=session.environment.contact.stiffness_n_per_m,  # the run's own contact
        mu=mu,
        normal_force_n=stroke_module.DESIRED_FORCE_N,
        speed_m_s=peak_speed(),
        v_eps_m_per_s=session.environment.contact.v_eps_m_per_s,
        sensor_cutoff_hz=session.sensor.cutoff_hz,
        sensing_delay_steps=int(getattr(session.sensor, "reading_delay_steps", 0)),
        actuation_delay_steps=int(getattr(session.world, "torque_delay_steps", 0)),
    )
    pm = posture_margin(dyn.Lambda, POLISH_SUBSPACES, gains, loop, [dirs["stretch"], dirs["retract"]])
    return {
        "W": {"f": W["W_f"], "a": W["W_a"], "d": W["W_d"]},
        "Pf_fhat": {k: float(terms.P_f[0, :2] @ d) for k, d in dirs.items()},
        "Pd_fhat": {k: float(terms.P_d[0, :2] @ d) for k, d in dirs.items()},
        "margin": _finite_or_none(pm.kd_margin),  # None: no K_f^d up to 2000 N s/m stabilises the loop
        "margin_detail": {
            "kd_critical": _finite_or_none(pm.kd_critical),
            "kd_critical_stretch": _finite_or_none(pm.kd_critical_per_direction[0]),
            "kd_critical_retract": _finite_or_none(pm.kd_critical_per_direction[1]),
            "worst_direction": ("stretch", "retract")[pm.worst_direction],
            "worst_speed_m_s": pm.worst_speed_m_s,
            # the linearised loop the margin is computed on, as the run had it
            "loop": {
                "stiffness_n_per_m": loop.stiffness_n_per_m,
                "speed_m_s": loop.speed_m_s,
                "sensor_cutoff_hz": loop.sensor_cutoff_hz,
                "sensing_delay_steps": loop.sensing_delay_steps,
                "actuation_delay_steps": loop.actuation_delay_steps,
                "force_kp": float(gains.force_kp),
                "force_ki": float(gains.force_ki),
                "shaping": bool(gains.shaping),
            },
        },
    }


def _run_over(clock, t: float, strokes: int) -> bool:
    """The trajectory and its final hold are over, or the first `strokes` segments are."""
    start = clock.trajectory_start
    return clock.finished(t) or (
        strokes < N_SEGMENTS and start is not None and t >= start + strokes * stroke_module.SEGMENT_DURATION_S
    )


def stroke_margin_figures(session, stroke_q: list[tuple[float, np.ndarray]], shaping: bool) -> dict:
    """The force-loop margin along the executed strokes (`app.scenarios.polish_margin`) from the
    postures sampled on them, with the run's contact, sensor and latency: "stroke_margin" per
    segment (worst σ and K_f^d margin, growth, P_d·f̂ mean and max) and "stroke" over all strokes."""
    from dataclasses import replace

    from app.scenarios import polish_margin as PM

    gains = replace(session.executor.gains, shaping=shaping)  # type: ignore[attr-defined]
    loop = PM.contact_loop(session.environment.contact, session.sensor, session.world)  # type: ignore[attr-defined]
    n = len(session.world.q)
    taus = np.array([tau for tau, _ in stroke_q])
    samples = [PM.sample(session.model.compute(q, np.zeros(n)).Lambda, gains, loop, tau) for tau, q in stroke_q]
    floor = PM.sensor_floor_n(session.params()["sensor"], loop.dt)
    budget = PM.headroom_budget_np(stroke_module.DESIRED_FORCE_N, floor)
    strokes = PM.per_stroke(taus, samples, budget)
    return {
        "stroke_margin": strokes,
        "stroke": PM.summary(strokes),
        "stroke_loop": {
            "sensing_delay_steps": loop.sensing_delay_steps,
            "actuation_delay_steps": loop.actuation_delay_steps,
            "desired_force_n": stroke_module.DESIRED_FORCE_N,
            "noise_floor_n": floor,
            "headroom_budget_np": budget,
            "sample_s": MARGIN_SAMPLE_S,  # the postures' spacing along the strokes
        },
    }


def _finite_or_none(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


def peak_speed() -> float:
    """Peak TCP speed of a segment (minimum jerk: 1.875 × length / duration)."""
    return stroke_module.PEAK_SPEED_M_S


def _stats(e: np.ndarray) -> dict:
    if e.size == 0:
        return {"ma": None, "ptp": None, "std": None}
    return {"ma": float(np.mean(np.abs(e))), "ptp": float(np.ptp(e)), "std": force_error_std(e)}


def _mean(x: np.ndarray) -> float | None:
    return float(np.mean(x)) if x.size else None


# ---- summary ------------------------------------------------------------------------------------
def summarise(runs: list[dict]) -> list[dict]:
    """Mean ± sd per row and μ (the JSON's `summary`)."""
    out = []
    for (row, mu), rs in runs_by_row(runs):
        entry: dict[str, Any] = {
            "row": row,
            "objective": rs[0]["objective"],
            "mu": mu,
            "n": len(rs),
            "converged": sum(r["converged"] for r in rs),
            "stable": sum(r["stable"] for r in rs),
            "start_swivel_deg": rs[0]["start_swivel_deg"],
            "shaping": rs[0]["shaping"],
        }
        for k in ("ma", "ptp", "std"):
            entry[k] = _mean_sd([r["force_error"][k] for r in rs])
        entry["converged_swivel_deg"] = _mean_sd([r["converged_swivel_deg"] for r in rs])
        entry["convergence_time_s"] = _mean_sd([r["convergence_time_s"] for r in rs])
        entry["margin"] = _mean_sd([r["margin"] for r in rs])
        entry["contact_lost_ms"] = _mean_sd([r["contact_lost_ms"] for r in rs])
        for w in ("f", "a", "d"):
            entry[f"W_{w}"] = _mean_sd([r["W"][w] for r in rs])
        for key in ("Pf_fhat", "Pd_fhat"):
            for d in ("stretch", "retract"):
                entry[f"{key}_{d}"] = _mean_sd([r[key][d] for r in rs])
        if "plan_cost" in rs[0]:
            entry["plan_cost"] = _mean_sd([r["plan_cost"] for r in rs])
            entry["plan_tracking_max_deg"] = _mean_sd([r["plan_tracking_deg"]["max"] for r in rs])
        paper = (
            PAPER_TABLE_III.get(mu, {}).get(rs[0]["objective"])
            if row == OBJECTIVE_NAMES.get(rs[0]["objective"])
            else None
        )
        entry["paper"] = None if paper is None or not rs[0]["shaping"] else list(paper)
        out.append(entry)
    return out


def table_latency_of(settings: list) -> tuple[int, float] | None:
    """(F/T reading age in periods, torque delay in ms) the table's runs start with: the sensor's and the
    world's defaults; None when --set changes either (the table then runs at that latency alone)."""
    from app.sim.sensor import SensorParams
    from app.sim.world import WorldParams

    if any((g, f) in (("sensor", "reading_delay_steps"), ("world", "torque_delay_ms")) for g, f, _ in settings):
        return None
    return int(SensorParams().reading_delay_steps), float(WorldParams().torque_delay_ms)


def table_at_latencies(table: list[dict], runs: list[dict]) -> dict:
    """Table III at each total latency (`TABLE_LATENCIES`): per (F/T reading age, torque delay) its
    runs' `summarise`, with the total in control periods (the torque delay over the runs' period); the
    table's own runs of the same rows and start give the latency they ran at, the group "table_latency"
    the others. Returns {"latencies": [...], "runs": runs}."""
    rows = {r["row"] for r in runs}
    own = [r for r in table if r["row"] in rows and r["shaping"] and abs(r["start_swivel_deg"]) < 1e-6]
    order = {pair: i for i, pair in enumerate(TABLE_LATENCIES)}
    pairs = sorted(set(map(_latency_of, own + runs)), key=lambda p: (order.get(p, len(order)), str(p)))
    latencies = []
    for pair in pairs:
        at = [r for r in own + runs if _latency_of(r) == pair]
        period_ms = 1e3 * float(at[0]["timestep_s"])
        latencies.append(
            {
                "reading_delay_steps": pair[0],
                "torque_delay_ms": pair[1],
                "total_periods": pair[0] + pair[1] / period_ms,
                "summary": summarise(at),
            }
        )
    return {"latencies": latencies, "runs": runs}


def _mean_sd(values: list) -> dict:
    xs = np.array([v for v in values if v is not None], dtype=float)
    if xs.size == 0:
        return {"mean": None, "sd": None, "n": 0}
    return {"mean": float(np.mean(xs)), "sd": float(np.std(xs, ddof=1)) if xs.size > 1 else None, "n": int(xs.size)}


# ---- the experiment -------------------------------------------------------------------------------
def run(args: argparse.Namespace) -> int:
    """Run the table (+ armature sensitivity and the v_ε check), write JSON, figures and the report."""
    if getattr(args, "combine", None):
        return combine(args, [Path(d.strip()) for d in args.combine.split(",") if d.strip()])
    mus = _parse_mu(args.mu)
    if args.seeds < 1:
        raise ValueError("--seeds must be at least 1")
    jobs = max(1, int(args.jobs))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    quick = bool(args.quick)
    only = [k.strip() for k in args.rows.split(",") if k.strip()] if getattr(args, "rows", None) else None
    specs = (
        []
        if getattr(args, "only_armature", False)
        else table_specs(mus, args.seeds, quick, bool(args.sander), only, int(getattr(args, "first_seed", 0)))
    )
    if not quick and not args.no_armature:
        specs += armature_specs(max(mus))
    if not getattr(args, "no_latency", False) and not getattr(args, "only_armature", False):
        specs += latency_specs(quick, only)
    settings = [list(x) for x in parse_settings(getattr(args, "set", []))]  # --set: every run, after its own
    own = table_latency_of(settings)
    skip = quick or getattr(args, "no_table_latency", False) or getattr(args, "only_armature", False)
    if own is not None and not skip:
        specs += table_latency_specs(mus, args.seeds, own, only, int(getattr(args, "first_seed", 0)))
    for spec in specs:
        spec["session_params"] = [*spec.get("session_params", ()), *settings]
    t0 = time.perf_counter()
    print(f"polish: {len(specs)} runs on {jobs} process(es)", file=sys.stderr, flush=True)
    outputs, reused = _map(simulate, specs, jobs, t0, out / RUNS_DIR, bool(getattr(args, "resume", False)))
    results = [o["result"] for o in outputs]
    series = [o["series"] for o in outputs]
    v_eps = [] if quick else [v_eps_check(v, settings=settings) for v in V_EPS_CHECK_M_PER_S]

    from app.headless.experiments.polish_report import (
        UNIT_LENGTHS_M,
        armature_basins,
        scan_at_start,
        w_d_by_length,
    )

    table = [r for r in results if r["group"] == "table"]
    scan = scan_at_start(_table_scale(table), _model_armature(table))
    doc = {
        "experiment": "polish",
        "settings": {**_settings(args, mus, quick), "reused_runs": reused},
        "paper_table_iii": {
            str(mu): {OBJECTIVE_NAMES[k]: v for k, v in row.items()} for mu, row in PAPER_TABLE_III.items()
        },
        "runs": table,
        "summary": summarise(table),
        "armature": {
            "runs": [r for r in results if r["group"] == "armature"] + [r for r in table if _is_fig6a_start(r, mus)],
            "basins": armature_basins(ARMATURE_SCALES, _model_armature(table)),
        },
        "v_eps": v_eps,
        "swivel_scan": scan["summary"],
        "w_d_by_length": [] if quick else w_d_by_length(UNIT_LENGTHS_M, _table_scale(table), _model_armature(table)),
    }
    _add_latency_tables(doc, table, results)
    doc["wall_s"] = time.perf_counter() - t0
    _write_run(out, doc, results, series, scan)
    if args.json:
        print(json.dumps(doc, indent=2))
    else:
        _print_tables(doc)
        print(f"wrote {out / 'polish.json'}, figures and {out / 'report.html'} in {doc['wall_s']:.0f} s")
    return 0


def _add_latency_tables(doc: dict, table: list[dict], results: list[dict]) -> None:
    """The latency table and Table III at each total latency, into `doc`, from the runs that made them."""
    latency_runs = [r for r in results if r["group"] == "latency"]
    if latency_runs:
        doc["latency"] = {**latency_table(latency_runs), "runs": latency_runs}
    at_latencies = [r for r in results if r["group"] == "table_latency"]
    if at_latencies:
        doc["table_latency"] = table_at_latencies(table, at_latencies)


def _write_run(out: Path, doc: dict, results: list[dict], series: list[dict], scan: Any) -> None:
    """polish.json, the series (npz), the figures and the report of a run (or of combined runs) into `out`."""
    from app.headless.experiments.polish_report import write_figures, write_report

    (out / "polish.json").write_text(json.dumps(doc, indent=2))
    np.savez_compressed(
        out / "polish_series.npz",
        **{f"{_label(r)}__{k}": v for r, s in zip(results, series, strict=True) for k, v in s.items()},
    )
    write_figures(out, results, series, scan)
    write_report(out, doc)


def _print_tables(doc: dict) -> None:
    """The run's tables as text: Table III, then the tables at latencies and the latency table if made."""
    print(format_table(doc["summary"]))
    if "table_latency" in doc:
        print(format_table_latency(doc["table_latency"]))
    if "latency" in doc:
        print(format_latency(doc["latency"]))


def combine(args: argparse.Namespace, dirs: list[Path]) -> int:
    """One polish.json, figures and report from the runs of several earlier output directories
    (e.g. rows run separately); a run (row, μ, seed, armature, latency) present twice is kept from the
    first directory that has it. A directory without polish.json (an invocation that did not finish)
    gives the runs it finished (runs/, `save_run`); at least one directory needs its polish.json."""
    from app.headless.experiments.polish_report import (
        UNIT_LENGTHS_M,
        scan_at_start,
        w_d_by_length,
    )

    docs: list[dict] = []
    sources: list[tuple[list[dict], list[dict]]] = []  # per directory: its runs and their series
    unfinished: list[Path] = []
    for d in dirs:
        if (d / "polish.json").is_file():
            doc_d = json.loads((d / "polish.json").read_text())
            docs.append(doc_d)
            runs_d = (
                doc_d["runs"]
                + [x for x in doc_d["armature"]["runs"] if x["group"] == "armature"]
                + doc_d.get("latency", {}).get("runs", [])
                + doc_d.get("table_latency", {}).get("runs", [])
            )
            with np.load(d / "polish_series.npz") as npz:
                sources.append((runs_d, [_series_of(npz, r) for r in runs_d]))
        elif (d / RUNS_DIR).is_dir():
            unfinished.append(d)
            sources.append(_finished_runs(d / RUNS_DIR))
        else:
            raise ValueError(f"{d} has neither polish.json nor {RUNS_DIR}/ to combine")
    if not docs:
        raise ValueError("--combine needs at least one directory with its polish.json")
    seen: set[tuple] = set()
    results, series = [], []
    for runs_d, series_d in sources:
        for r, s in zip(runs_d, series_d, strict=True):
            if r.get("margin") is not None and not np.isfinite(r["margin"]):
                r["margin"] = None  # older outputs wrote ±inf for "no K_f^d stabilises"
            key = (r["row"], r["mu"], r["seed"], r["armature_scale"], r["group"], _latency_of(r))
            if key in seen:
                continue
            seen.add(key)
            results.append(r)
            series.append(s)
    if getattr(args, "recompute_margin", True):
        _recompute_margins(results)
    table = [r for r in results if r["group"] == "table"]
    mus = sorted({r["mu"] for r in table})
    settings = dict(docs[0]["settings"])
    settings["command"] = (
        "; ".join(d["settings"]["command"] for d in docs)
        + "".join(f"; the finished runs of {d} (not timed here)" for d in unfinished)
        + f" (combined: {args.combine})"
    )
    settings["mu"] = mus
    settings["seeds"] = max(d["settings"]["seeds"] for d in docs)
    scan = scan_at_start(_table_scale(table), _model_armature(table))
    basins: list = next((d["armature"]["basins"] for d in docs if d["armature"]["basins"]), [])
    doc = {
        "experiment": "polish",
        "settings": settings,
        "paper_table_iii": docs[0]["paper_table_iii"],
        "runs": table,
        "summary": summarise(table),
        "armature": {
            "runs": [r for r in results if r["group"] == "armature"] + [r for r in table if _is_fig6a_start(r, mus)],
            "basins": basins,
        },
        "v_eps": next((d["v_eps"] for d in docs if d.get("v_eps")), []),
        "swivel_scan": scan["summary"],
        "w_d_by_length": w_d_by_length(UNIT_LENGTHS_M, _table_scale(table), _model_armature(table)),
        "wall_s": float(sum(d["wall_s"] for d in docs)),
        "combined_from": [str(d) for d in dirs],
    }
    _add_latency_tables(doc, table, results)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    _write_run(out, doc, results, series, scan)
    _print_tables(doc)
    print(f"wrote {out / 'polish.json'}, figures and {out / 'report.html'} from {len(dirs)} directories")
    return 0


def _series_of(npz, r: dict) -> dict:
    prefix = f"{_label(r)}__"
    return {k[len(prefix) :]: npz[k] for k in npz.files if k.startswith(prefix)}


def _recompute_margins(results: list[dict]) -> None:
    """The posture figures (W, P·f̂, margin) of each run again from its converged posture with this
    version's `control.margin`, so runs made by different versions are compared alike."""
    from app.core.session import Session

    sessions: dict[float, Any] = {}
    for r in results:
        scale = float(r["armature_scale"])
        if scale not in sessions:
            sessions[scale] = Session(PolishScenario(armature_scale=scale), seed=0)
        session = sessions[scale]
        # the run's own latency (runs made before it was recorded had none)
        session.set_param("sensor", "reading_delay_steps", int(r.get("reading_delay_steps", 0)))
        session.set_param("world", "torque_delay_ms", float(r.get("torque_delay_ms", 0.0)))
        r.update(posture_figures(session, np.array(r["q_converged"]), float(r["mu"]), bool(r["shaping"])))


def _model_armature(runs: list[dict]) -> list[float] | None:
    """The controller model's armature (kg m²) the runs had before their scenario's armature scale (their
    recorded configuration over that scale), for the swivel scans; None when no run recorded it."""
    for r in runs:
        scale = float(r.get("armature_scale", 1.0))
        if scale > 0 and (r.get("config") or {}).get("armature_model_kg_m2"):
            return [a / scale for a in r["config"]["armature_model_kg_m2"]]
    return None


def _table_scale(runs: list[dict]) -> float:
    """The scenario's armature scale of the table's runs (1 when they differ or there are none)."""
    scales = {float(r.get("armature_scale", 1.0)) for r in runs}
    return scales.pop() if len(scales) == 1 else 1.0


def _is_fig6a_start(r: dict, mus: list[float]) -> bool:
    return (
        r["objective"] in ("j", "f", "a", "d")
        and r["mu"] == max(mus)
        and r["seed"] == 0
        and abs(r["start_swivel_deg"]) < 1e-6
        and r["shaping"]
    )


def _map(
    fn, specs: list[dict], jobs: int, t0: float, runs_dir: Path | None = None, resume: bool = False
) -> tuple[list[dict], int]:
    """fn over specs on `jobs` processes; each finished run is saved in runs_dir at once, and with
    `resume` a run saved there earlier is reused instead of run again. Returns (outputs, reused)."""
    outputs: list[dict | None] = [None] * len(specs)
    reused = 0
    if runs_dir is not None and resume:
        for i, spec in enumerate(specs):
            outputs[i] = load_run(runs_dir, spec)
        reused = sum(o is not None for o in outputs)
        print(f"polish: reusing {reused} finished run(s) from {runs_dir}", file=sys.stderr, flush=True)
    todo = [i for i, o in enumerate(outputs) if o is None]

    def finished(done: int, i: int, output: dict) -> None:
        outputs[i] = output
        if runs_dir is not None:
            save_run(runs_dir, specs[i], output)
        _progress(done, len(todo), output, t0)

    if jobs == 1:
        for done, i in enumerate(todo):
            finished(done, i, fn(specs[i]))
    else:
        with open_executor(None, jobs) as (pool, _):  # the sweeps' engine
            futures = {pool.submit(fn, specs[i]): i for i in todo}
            for done, fut in enumerate(as_completed(futures)):
                finished(done, futures[fut], fut.result())
    return [o for o in outputs if o is not None], reused


def _label(r: dict) -> str:
    """Unique name of a run, e.g. "a_mu1_sw+0_s0" or "j_mu1_sw+0_s0_noshaping_arm0.5"."""
    label = f"{r['objective']}_mu{r['mu']:g}_sw{r['start_swivel_deg']:+.0f}_s{r['seed']}"
    if not r["shaping"]:
        label += "_noshaping"
    if r["armature_scale"] != 1.0:
        label += f"_arm{r['armature_scale']:g}"
    if r.get("group") == "latency":
        label += f"_latency_ds{r['reading_delay_steps']}_da{r['torque_delay_ms']:g}"
    if r.get("group") == "table_latency":
        label += f"_table_ds{r['reading_delay_steps']}_da{r['torque_delay_ms']:g}"
    return label


def _progress(i: int, total: int, output: dict | None, t0: float) -> None:
    if output is None:
        return
    r = output["result"]
    fe = r["force_error"]
    ma = "-" if fe["ma"] is None else f"{fe['ma']:.1f}/{fe['ptp']:.1f}/{fe['std']:.1f}"
    held = r.get("held") or {}
    conv = (
        f"stopped while held at {held['at_s']:.1f} s ({held['verdict']})"
        if held.get("stopped")
        else f"converged in {r['convergence_time_s']:.1f} s"
        if r["converged"]
        else "NOT converged"
    )
    swivel = "-" if r.get("converged_swivel_deg") is None else f"{_deg(r['converged_swivel_deg'])}°"
    # margin None: no K_f^d stabilises the linearised loop
    margin = "none (no K_f^d stabilises)" if r.get("margin") is None else f"{_num(r['margin'], 0, sign=True)} N s/m"
    print(
        f"[{i + 1}/{total}] {_label(r)}: {conv} at {swivel}, "
        f"MA/PTP/STD {ma} N, margin {margin}, {'stable' if r['stable'] else 'UNSTABLE'} "
        f"({r['wall_s']:.0f} s, total {time.perf_counter() - t0:.0f} s)",
        file=sys.stderr,
        flush=True,
    )


def _settings(args: argparse.Namespace, mus: list, quick: bool) -> dict:
    import robots

    s = stroke_module
    robot = robots.chosen("")
    return {
        "robot": robot or PolishScenario.default_robot,
        "command": "torquelab experiment polish"
        + (f" --robot {robot}" if robot in robots.available() else f" --urdf {robot}" if robot else "")
        + (" --quick" if quick else f" --seeds {args.seeds}")
        + (f" --rows {args.rows}" if getattr(args, "rows", None) else "")
        + "".join(f" --set {x}" for x in getattr(args, "set", []) or [])
        + f" --mu {','.join(f'{m:g}' for m in mus)}",
        "code": code_record(),
        "quick": quick,
        "seeds": 1 if quick else int(args.seeds),
        "jobs": int(args.jobs),
        "mu": mus,
        "sander": bool(args.sander),
        "table_height_m": s.TABLE_HEIGHT_M,
        "start_xy_m": list(s.START_XY_M),
        "start_swivel_deg": s.START_SWIVEL_DEG,
        "segment_dx_m": s.SEGMENT_DX_M,
        "segment_dy_m": s.SEGMENT_DY_M,
        "segment_duration_s": s.SEGMENT_DURATION_S,
        "settle": {
            "speed_tol_rad_s": s.SETTLE_SPEED_RAD_S,
            "w_rtol": s.SETTLE_W_RTOL,
            "w_atol": s.SETTLE_W_ATOL,
            "window_s": s.SETTLE_WINDOW_S,
            "cap_s": s.CONVERGE_TIMEOUT_S,
        },
        "plan": {
            "sample_s": plan_module.PLAN_SAMPLE_S,
            "grid_deg": plan_module.PLAN_GRID_DEG,
            "rate_max_deg_s": plan_module.PLAN_RATE_MAX_DEG_S,
        },
        "friction_v_eps_m_per_s": s.FRICTION_V_EPS_M_PER_S,
        "force_error": f"{s.DESIRED_FORCE_N:g} N minus the filtered F/T reading along z, over the six segments",
        "desired_force_n": s.DESIRED_FORCE_N,
    }


def _pm(x: dict, digits: int = 1) -> str:
    if x["mean"] is None:
        return "-"
    if x["sd"] is None:  # one seed: no spread to show
        return f"{x['mean']:.{digits}f}"
    return f"{x['mean']:.{digits}f} ± {x['sd']:.{digits}f}"


def format_table(summary: list[dict]) -> str:
    """Our Table III (mean ± sd) beside the paper's, as text."""
    lines = [
        f"{'row':22s} {'mu':>5s} {'MA':>12s} {'PTP':>13s} {'STD':>12s}  {'paper':>15s} {'swivel':>8s} "
        f"{'margin':>8s} conv stable"
    ]
    for e in summary:
        paper = "-" if not e.get("paper") else "/".join(f"{x:.1f}" for x in e["paper"])
        sw = e["converged_swivel_deg"]["mean"]
        mg = e["margin"]["mean"]
        lines.append(
            f"{e['row']:22s} {e['mu']:5.2f} {_pm(e['ma']):>12s} {_pm(e['ptp']):>13s} {_pm(e['std']):>12s}  "
            f"{paper:>15s} {'-' if sw is None else _deg(sw) + '°':>8s} {'-' if mg is None else _num(mg, 0, True):>8s} "
            f"{e['converged']}/{e['n']} {e['stable']}/{e['n']}"
        )
    return "\n".join(lines)


def format_table_latency(at: dict) -> str:
    """Table III at each total latency (`table_at_latencies`) as text, one `format_table` per latency."""
    return "\n".join(
        f"Table III at F/T {x['reading_delay_steps']} + τ {x['torque_delay_ms']:g} ms ({x['total_periods']:g} "
        f"period(s)):\n" + format_table(x["summary"])
        for x in at["latencies"]
    )
