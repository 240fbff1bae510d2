"""Polish: reproduce the simulation study of [T] §IV-B (Table III, Figs. 6, 8, 9) headless.

Each run is one `Session` of the polish scenario (contact, posture convergence, six-segment
zig-zag) with one nullspace objective and one friction coefficient. Runs go to worker processes
(`--jobs`). Outputs in --out: polish.json (metrics per run), polish_series.npz (time series),
fig6_postures.png, fig8_coupling.png, fig9_force_error.png, swivel_scan.png, report.html.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path
from typing import Any

import numpy as np

from app.scenarios import polish as scenario_module
from app.scenarios.polish import N_SEGMENTS, PolishScenario

PAPER_TABLE_III = {  # [T] Table III: force error MA / PTP / STD (N)
    0.25: {"j": (2.3, 18.2, 2.8), "f": (2.5, 17.4, 3.1), "a": (1.5, 10.5, 1.8), "d": (1.6, 12.2, 2.0)},
    1.0: {"j": (5.9, 72.4, 9.3), "f": (7.4, 74.0, 12.0), "a": (1.6, 10.8, 2.0), "d": (1.8, 14.1, 2.1)},
}
OBJECTIVE_NAMES = {"j": "W_j", "f": "W_f", "a": "W_a", "d": "W_d"}
COLORS = {"j": "black", "f": "tab:green", "a": "tab:red", "d": "tab:blue"}
SENSITIVITY_SWIVELS_DEG = (-30.0, -15.0, 15.0, 30.0)  # start swivels on both sides of 0° (DESIGN §8)
LONG_CONVERGE_S = 60.0  # one more W_a run from 0° that may converge 4× longer than the protocol's timeout
RECORD_EVERY = 5  # time series kept at 200 Hz for the figures
MAX_SIM_S = 100.0  # safety cap on one run


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of `torquelab experiment polish`."""
    parser.add_argument("--objectives", default="j,f,a,d", help="nullspace objectives, comma separated (j,f,a,d)")
    parser.add_argument("--mu", default="0.25,1.0", help="Coulomb friction coefficients, comma separated")
    parser.add_argument("--sander", action="store_true", help="add the 7000 RPM electric-sander disturbance")
    parser.add_argument("--seed", type=int, default=0, help="seed of the sensor noise")
    parser.add_argument(
        "--no-diagnostics",
        action="store_true",
        help="skip the diagnostic runs (W_j at the largest μ without inertia shaping / without sensor low-pass)",
    )
    parser.add_argument(
        "--no-sensitivity",
        action="store_true",
        help="skip the start-posture sensitivity runs (W_a at the largest μ from other start swivels)",
    )


def _parse_list(text: str, kind: str) -> list:
    items = [s.strip() for s in str(text).split(",") if s.strip()]
    if not items:
        raise ValueError(f"--{kind} needs at least one value")
    if kind == "objectives":
        bad = [s for s in items if s not in OBJECTIVE_NAMES]
        if bad:
            raise ValueError(f"unknown objective(s) {', '.join(bad)}; choose from j, f, a, d")
        return items
    try:
        values = [float(s) for s in items]
    except ValueError:
        raise ValueError(f"--{kind} must be numbers, got {text!r}") from None
    if any(not np.isfinite(v) or v < 0 for v in values):
        raise ValueError(f"--{kind} values must be finite and non-negative")
    return values


# ---- one run ------------------------------------------------------------------------------------
def simulate(spec: dict) -> dict:
    """Run one polish session and return its metrics and (downsampled) time series."""
    from app.session import Session
    from control.coupling import swivel_angle

    t_wall = time.perf_counter()
    scenario = PolishScenario(
        mu=spec["mu"],
        sander=spec["sander"],
        start_swivel_deg=spec["start_swivel_deg"],
        converge_timeout_s=spec.get("converge_timeout_s", scenario_module.CONVERGE_TIMEOUT_S),
    )
    session = Session(scenario, seed=spec["seed"])
    session.executor.configure(objective=spec["objective"], shaping=bool(spec.get("shaping", True)))
    if spec.get("sensor_cutoff_hz") is not None:
        session.sensor.configure(cutoff_hz=spec["sensor_cutoff_hz"])
    clock = session.environment.clock  # type: ignore[attr-defined]
    ex = session.executor
    q_start = session.world.q.copy()
    cutoff = spec.get("sensor_cutoff_hz", scenario_module.SENSOR_CUTOFF_HZ)
    lag_s = 1.0 / (2.0 * np.pi * cutoff) if cutoff and spec.get("shaping", True) else 0.0
    lag_stiffness = scenario_module.CONTACT_STIFFNESS_N_PER_M * lag_s
    n_max = int(MAX_SIM_S * 1000)
    cols = ("t", "force_error", "force_error_true", "W_f", "W_a", "W_d", "segment", "x", "y", "coupled", "lag_damping")
    rec = {k: np.full(n_max, np.nan) for k in cols}
    q_converged = None
    diverged = False
    fallbacks = 0
    n = 0
    for i in range(n_max):
        r = session.step()
        sig = r.signals
        seg = sig["segment"]
        if q_converged is None and clock.trajectory_start is not None:
            q_converged = r.q.copy()
        fallbacks += int(r.fallback)
        terms = ex.last_terms  # type: ignore[attr-defined]
        # friction direction from the commanded TCP velocity (friction opposes the motion)
        v = r.target.velocity[:2]
        speed = float(np.hypot(v[0], v[1]))
        coupled = lag_damping = 0.0
        if terms is not None and speed > 1e-6:
            fdir = -v / speed
            coupled = float(terms.P_f[0, :2] @ fdir)  # m/s² per N of friction: <0 pushes into the table
            # lagged shaping term BᵀA⁻¹F_m^e of [T7]: with the reading τ late, it adds a force
            # μ (P_d·dir) k τ ż along z, i.e. negative damping (N s/m) when positive
            lag_damping = float(spec["mu"] * (terms.P_d[0, :2] @ fdir)) * lag_stiffness
        rec["t"][i] = r.t
        rec["force_error"][i] = scenario_module.DESIRED_FORCE_N - r.wrench_tcp[2]  # filtered F/T reading
        rec["force_error_true"][i] = scenario_module.DESIRED_FORCE_N - sig["contact_force_n"]
        rec["W_f"][i], rec["W_a"][i], rec["W_d"][i] = sig["W_f"], sig["W_a"], sig["W_d"]
        rec["segment"][i] = seg
        rec["x"][i], rec["y"][i] = session.dyn.tcp_position_world[:2]
        rec["coupled"][i] = coupled
        rec["lag_damping"][i] = lag_damping
        n = i + 1
        if session.diverged():
            diverged = True
            break
        if clock.finished(r.t):
            break
    for k in cols:
        rec[k] = rec[k][:n]
    if q_converged is None:
        q_converged = session.world.q.copy()
    model = session.model
    traj = (rec["segment"] >= 1) & (rec["segment"] <= N_SEGMENTS)
    hold = (rec["segment"] == 0) & (rec["t"] >= scenario_module.CONTACT_TIME_S)  # TCP held, posture converging
    result: dict[str, Any] = {
        "group": spec.get("group", "main"),
        "label": _label(spec, clock.timeout_s),
        "shaping": bool(spec.get("shaping", True)),
        "sensor_cutoff_hz": spec.get("sensor_cutoff_hz", scenario_module.SENSOR_CUTOFF_HZ),
        "objective": spec["objective"],
        "mu": spec["mu"],
        "sander": spec["sander"],
        "seed": spec["seed"],
        "start_swivel_deg": spec["start_swivel_deg"],
        "converge_timeout_s": clock.timeout_s,
        "force_error": _stats(rec["force_error"][traj]),
        "force_error_true_contact": _stats(rec["force_error_true"][traj]),
        "hold_force_error": _stats(rec["force_error"][hold]),
        "coupling": {w: _mean_max(rec[w][traj]) for w in ("W_f", "W_a", "W_d")},
        "posture_change_deg": [float(x) for x in np.rad2deg(q_converged - q_start)],
        "converged_swivel_deg": float(np.rad2deg(swivel_angle(model, q_converged))),
        "convergence_time_s": None if clock.trajectory_start is None else float(clock.trajectory_start),
        "converged_before_timeout": bool(
            clock.trajectory_start is not None
            and clock.trajectory_start < scenario_module.CONTACT_TIME_S + clock.timeout_s - 1e-9
        ),
        "contact_lost_ms": int(np.sum(rec["force_error_true"][traj] >= scenario_module.DESIRED_FORCE_N)),
        "qp_fallback_steps": fallbacks,
        "diverged": diverged,
        "per_segment": [],
        "wall_s": 0.0,
    }
    result["stable"] = bool(not diverged and result["contact_lost_ms"] == 0 and np.any(traj))
    for seg_k in range(1, N_SEGMENTS + 1):
        sel = rec["segment"] == seg_k
        segment: dict[str, Any] = {
            "segment": seg_k,
            "direction": "retract (-X)" if seg_k % 2 == 1 else "stretch (+X)",
            "force_error": _stats(rec["force_error"][sel]),
            "contact_lost_ms": int(np.sum(rec["force_error_true"][sel] >= scenario_module.DESIRED_FORCE_N)),
            "W_f_mean": _mean(rec["W_f"][sel]),
            "W_a_mean": _mean(rec["W_a"][sel]),
            "W_d_mean": _mean(rec["W_d"][sel]),
            "coupled_response_mps2_per_n": _mean(rec["coupled"][sel]),
            "lag_negative_damping_ns_per_m": _mean(rec["lag_damping"][sel]),
        }
        result["per_segment"].append(segment)
    result["q_start"] = [float(x) for x in q_start]
    result["q_converged"] = [float(x) for x in q_converged]
    result["wall_s"] = time.perf_counter() - t_wall
    series = {k: v[::RECORD_EVERY].astype(np.float32) for k, v in rec.items()}
    return {"result": result, "series": series}


def _label(spec: dict, timeout_s: float) -> str:
    """Short unique name of a run, e.g. "a_mu1_sw+30_to15" or "j_mu1_noshaping"."""
    label = f"{spec['objective']}_mu{spec['mu']:g}_sw{spec['start_swivel_deg']:+.0f}_to{timeout_s:.0f}"
    if not spec.get("shaping", True):
        label += "_noshaping"
    if spec.get("sensor_cutoff_hz") is not None:
        label += f"_lpf{spec['sensor_cutoff_hz']:g}"
    return label


def _stats(e: np.ndarray) -> dict:
    if e.size == 0:
        return {"ma": None, "ptp": None, "std": None}
    return {"ma": float(np.mean(np.abs(e))), "ptp": float(np.ptp(e)), "std": float(np.std(e))}


def _mean_max(x: np.ndarray) -> dict:
    if x.size == 0:
        return {"mean": None, "max": None}
    return {"mean": float(np.mean(x)), "max": float(np.max(x))}


def _mean(x: np.ndarray) -> float | None:
    return float(np.mean(x)) if x.size else None


# ---- the experiment -------------------------------------------------------------------------------
def run(args: argparse.Namespace) -> int:
    """Run all (objective, μ) combinations (+ sensitivity), write JSON, figures and the report."""
    objectives = _parse_list(args.objectives, "objectives")
    mus = _parse_list(args.mu, "mu")
    jobs = max(1, int(args.jobs))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    base = {"sander": bool(args.sander), "seed": int(args.seed), "start_swivel_deg": 0.0}
    specs = [{**base, "group": "main", "objective": o, "mu": m} for m in mus for o in objectives]
    mu_hi = max(mus)
    if not args.no_sensitivity and "a" in objectives:
        specs += [
            {**base, "group": "sensitivity", "objective": "a", "mu": mu_hi, "start_swivel_deg": sw}
            for sw in SENSITIVITY_SWIVELS_DEG
        ]
        specs.append(
            {**base, "group": "sensitivity", "objective": "a", "mu": mu_hi, "converge_timeout_s": LONG_CONVERGE_S}
        )
    if not args.no_diagnostics and "j" in objectives:
        # why W_j fails at high friction: the same run without inertia shaping, and without sensor lag
        specs.append({**base, "group": "diagnostic", "objective": "j", "mu": mu_hi, "shaping": False})
        specs.append({**base, "group": "diagnostic", "objective": "j", "mu": mu_hi, "sensor_cutoff_hz": 0.0})
    t0 = time.perf_counter()
    outputs: list[dict | None] = [None] * len(specs)
    print(f"polish: {len(specs)} runs on {jobs} process(es)", file=sys.stderr, flush=True)
    if jobs == 1:
        for i, spec in enumerate(specs):
            outputs[i] = simulate(spec)
            _progress(i, len(specs), outputs[i], t0)
    else:
        with ProcessPoolExecutor(max_workers=jobs) as pool:
            futures = {pool.submit(simulate, spec): i for i, spec in enumerate(specs)}
            done = 0
            for fut in as_completed(futures):
                i = futures[fut]
                outputs[i] = fut.result()
                _progress(done, len(specs), outputs[i], t0)
                done += 1
    results = [o["result"] for o in outputs if o is not None]
    series = [o["series"] for o in outputs if o is not None]
    main = [r for r in results if r["group"] == "main"]
    sensitivity = [r for r in results if r["group"] == "sensitivity"]
    if ("a", mu_hi) in {(r["objective"], r["mu"]) for r in main}:
        sensitivity += [r for r in main if r["objective"] == "a" and r["mu"] == mu_hi]
    sensitivity.sort(key=lambda r: (r["start_swivel_deg"], r["converge_timeout_s"]))
    diagnostics = [r for r in results if r["group"] == "diagnostic"]

    from app.experiments.polish_report import scan_at_start, write_figures, write_report

    scan = scan_at_start()
    doc = {
        "experiment": "polish",
        "settings": _settings(args, mus, objectives),
        "paper_table_iii": {
            str(mu): {OBJECTIVE_NAMES[k]: v for k, v in row.items()} for mu, row in PAPER_TABLE_III.items()
        },
        "runs": main,
        "sensitivity": sensitivity,
        "diagnostics": diagnostics,
        "swivel_scan": scan["summary"],
        "wall_s": time.perf_counter() - t0,
    }
    (out / "polish.json").write_text(json.dumps(doc, indent=2))
    np.savez_compressed(
        out / "polish_series.npz",
        **{f"{r['label']}__{k}": v for r, s in zip(results, series, strict=True) for k, v in s.items()},
    )
    write_figures(out, results, series, scan)
    write_report(out, doc)
    if args.json:
        print(json.dumps(doc, indent=2))
    else:
        print(format_table(main))
        print(f"wrote {out / 'polish.json'}, figures and {out / 'report.html'} in {doc['wall_s']:.0f} s")
    return 0


def _progress(i: int, total: int, output: dict | None, t0: float) -> None:
    if output is None:
        return
    r = output["result"]
    fe = r["force_error"]
    ma = "-" if fe["ma"] is None else f"{fe['ma']:.1f}/{fe['ptp']:.1f}/{fe['std']:.1f}"
    print(
        f"[{i + 1}/{total}] {r['label']}: "
        f"force error MA/PTP/STD {ma} N, {'stable' if r['stable'] else 'UNSTABLE'} "
        f"({r['wall_s']:.0f} s, total {time.perf_counter() - t0:.0f} s)",
        file=sys.stderr,
        flush=True,
    )


def _settings(args: argparse.Namespace, mus: list, objectives: list) -> dict:
    s = scenario_module
    return {
        "objectives": objectives,
        "mu": mus,
        "sander": bool(args.sander),
        "seed": int(args.seed),
        "table_height_m": s.TABLE_HEIGHT_M,
        "start_xy_m": list(s.START_XY_M),
        "start_swivel_deg": s.START_SWIVEL_DEG,
        "segment_dx_m": s.SEGMENT_DX_M,
        "segment_dy_m": s.SEGMENT_DY_M,
        "segment_duration_s": s.SEGMENT_DURATION_S,
        "converge_timeout_s": s.CONVERGE_TIMEOUT_S,
        "friction_v_eps_m_per_s": s.FRICTION_V_EPS_M_PER_S,
        "force_error": "20 N minus the filtered F/T reading along z, over the six segments",
    }


def format_table(runs: list[dict]) -> str:
    """Our Table III beside the paper's, as text."""
    lines = [f"{'case':6s} {'mu':>5s}   {'MA':>6s} {'PTP':>6s} {'STD':>6s}   paper MA/PTP/STD   stable"]
    for r in sorted(runs, key=lambda r: (r["mu"], "jfad".index(r["objective"]))):
        fe = r["force_error"]
        paper = PAPER_TABLE_III.get(r["mu"], {}).get(r["objective"])
        ptxt = "-" if paper is None else f"{paper[0]:.1f}/{paper[1]:.1f}/{paper[2]:.1f}"
        if fe["ma"] is None:
            lines.append(f"{OBJECTIVE_NAMES[r['objective']]:6s} {r['mu']:5.2f}   (no trajectory)")
            continue
        lines.append(
            f"{OBJECTIVE_NAMES[r['objective']]:6s} {r['mu']:5.2f}   {fe['ma']:6.1f} {fe['ptp']:6.1f} {fe['std']:6.1f}"
            f"   {ptxt:>16s}   {'yes' if r['stable'] else 'no'}"
        )
    return "\n".join(lines)
