"""mass-drop: a 1.25 kg mass falls on a rope from the Gen3's (or the chosen arm's) wrist and jerks it ([C] §IV-D,
Fig. 5).

Position (joint PID) vs Torque + Residual vs Torque + Fusion. Each repetition draws the rig as it
varies on a bench (seeded): drop height, rope stiffness and the true mass (`draw_rig`); the three
modes see the same draw (paired). Peak deflection, stabilisation time and residual error of the TCP
over 4 s from the release: mean ± sd per mode, and per pair of modes the ratio of means with a
paired bootstrap 95 % interval (scipy.stats.bootstrap). A second case, "held-release" (the arm lets
go of a mass it held rigidly), is run with fewer repetitions and labelled as such.
Writes mass_drop.json, fig5.png and report.html.
"""

from __future__ import annotations

import argparse
import dataclasses
import html
import itertools
import json
import time
from collections.abc import Iterable
from pathlib import Path

import numpy as np
from scipy.stats import bootstrap

from app.core.provenance import code_record
from app.headless.experiments.c_common import (
    command_line,
    html_table,
    qp_session,
    run_parallel,
    write_json,
    write_report,
)
from app.headless.experiments.run_config import parse_settings, run_configuration
from app.scenarios import mass_drop as scenario_module
from app.scenarios.mass_drop import (
    CASES,
    MODES,
    RELEASE_TIME_S,
    WINDOW_S,
    MassDropParams,
    MassDropScenario,
    drop_metrics,
)
from app.scenarios.metrics import RESIDUAL_WINDOW_S, STABLE_BAND_M

METRICS = ("peak_deflection_mm", "stabilization_time_s", "residual_error_mm")
CONTEXT = ("peak_rope_tension_n", "saturated_steps", "relaxed_steps")
LABELS = {"position": "Position", "torque-residual": "Torque + Residual", "torque-fusion": "Torque + Fusion"}
DROP_SPREAD_M = 0.01  # a hand lifts the mass to the attachment point within ±1 cm
STIFFNESS_SPREAD = 0.2  # cord and knot: ±20 % of the nominal stiffness
MASS_SPREAD = 0.1  # the true mass within ±10 % of the nominal 1.25 kg
SIMILAR = (0.8, 1.25)  # a ratio of means inside this band counts as "similar" (±25 % either way)
BOOTSTRAP_RESAMPLES = 2000
CONFIDENCE = 0.95  # the bootstrap intervals' level


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of this experiment."""
    parser.add_argument("--repetitions", type=int, default=30, help="rope drops per mode, one rig draw each (30)")
    parser.add_argument(
        "--held-repetitions", type=int, default=6, help="repetitions of the second case, held-release (6; 0: skip)"
    )


def draw_rig(seed: int, nominal: MassDropParams | None = None) -> MassDropParams:
    """The rig of repetition `seed`: drop height L ± 1 cm, stiffness ± 20 %, true mass ± 10 % (uniform)."""
    base = nominal or MassDropParams()
    rng = np.random.default_rng([seed, 1325])  # a stream apart from the noise seed's
    return MassDropParams(
        rope_length_m=base.rope_length_m,
        rope_stiffness_n_per_m=base.rope_stiffness_n_per_m * (1.0 + rng.uniform(-STIFFNESS_SPREAD, STIFFNESS_SPREAD)),
        rope_damping_n_s_per_m=base.rope_damping_n_s_per_m,
        drop_height_m=base.drop_height + rng.uniform(-DROP_SPREAD_M, DROP_SPREAD_M),
        payload_mass_error=base.payload_mass_error + rng.uniform(-MASS_SPREAD, MASS_SPREAD),
    )


def run_mass_drop(
    mode: str,
    seed: int,
    case: str = "rope-drop",
    params: MassDropParams | None = None,
    window_s: float = WINDOW_S,
    observer_gain: float | None = None,
    session_params: Iterable[tuple[str, str, object]] = (),
) -> dict:
    """One release (noise seed `seed`, rig `params`, default: `draw_rig(seed)`); the metrics, the rig
    and a down-sampled deviation trace (mm). Ends early, with `stop` saying why, if the run diverges.
    observer_gain: the momentum observer's K_I [C25] (default: the scenario's, `OBSERVER_GAIN`).

    Every setting reaches the run through `Session.set_param`, as the GUI's do: the rig's fields
    (group "scenario"), K_I after the mode's own estimator settings, then `session_params` (group,
    field, value) in order; a refused one raises ParamError."""
    rig = params if params is not None else draw_rig(seed)
    scenario = MassDropScenario(mode, case)
    session = qp_session(scenario, seed=seed)
    changes = [("scenario", f.name, getattr(rig, f.name)) for f in dataclasses.fields(rig)]
    if observer_gain is not None:
        changes.append(("estimator", "observer_gain", float(observer_gain)))
    for group, name, value in [*changes, *session_params]:
        session.set_param(group, name, value)
    session.reset()
    config = run_configuration(session)
    in_force = session.params()["scenario"]  # the rig as it runs
    assert isinstance(in_force, MassDropParams)
    target = session.target_fn(0.0).position
    tau_max = session.robot.tau_max - 1e-9
    t: list[float] = []
    dev: list[float] = []
    tension: list[float] = []
    counts = {"saturated_steps": 0, "relaxed_steps": 0}

    def record(rec) -> None:
        t.append(rec.t)
        dev.append(float(np.linalg.norm(session.dyn.tcp_position_world - target)))
        tension.append(rec.signals.get("rope_tension_n", 0.0))
        counts["saturated_steps"] += int(rec.t >= RELEASE_TIME_S and np.any(np.abs(rec.tau) >= tau_max))
        counts["relaxed_steps"] += int(rec.signals.get("qp_relaxed", 0.0) > 0)

    result = session.run(RELEASE_TIME_S + window_s, record=record)
    ta, da = np.array(t), np.array(dev)
    out = drop_metrics(ta, da)
    out.update(counts)
    out.update(
        {
            "robot": session.robot.name,
            "posture": session.robot.guessed.get("mass_drop", "the sidecar's nominal posture"),
            "mode": mode,
            "case": case,
            "seed": seed,
            "stop": result.stop,
            "peak_rope_tension_n": float(max(tension)),
            "drop_height_m": in_force.drop_height,
            "rope_stiffness_n_per_m": in_force.rope_stiffness_n_per_m,
            "mass_kg": in_force.mass_kg,
            "rope_length_m": in_force.rope_length_m,
            "config": config,
        }
    )
    k0 = int(np.searchsorted(ta, RELEASE_TIME_S - 0.1))
    out["trace_t"] = (ta[k0::2] - RELEASE_TIME_S).tolist()
    out["trace_mm"] = (1e3 * da[k0::2]).tolist()
    return out


def ratio_of_means(a: np.ndarray, b: np.ndarray, seed: int = 0) -> dict:
    """mean(a) / mean(b) with a paired percentile-bootstrap 95 % interval (None where undefined)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if b.size == 0 or np.mean(b) == 0.0:
        return {"ratio": None, "low": None, "high": None}
    ratio = float(np.mean(a) / np.mean(b))
    if a.size < 3 or (np.ptp(a) == 0.0 and np.ptp(b) == 0.0):
        return {"ratio": ratio, "low": ratio, "high": ratio}
    res = bootstrap(
        (a, b),
        lambda x, y, axis=-1: np.mean(x, axis=axis) / np.maximum(np.mean(y, axis=axis), 1e-300),
        paired=True,
        vectorized=True,
        n_resamples=BOOTSTRAP_RESAMPLES,
        confidence_level=CONFIDENCE,
        method="percentile",
        rng=np.random.default_rng(seed),
    )
    return {"ratio": ratio, "low": float(res.confidence_interval.low), "high": float(res.confidence_interval.high)}


def summarize(runs: list[dict]) -> dict:
    """mean ± sd per mode and metric (context columns too), and per pair of modes the ratio of means
    with its paired bootstrap interval (runs paired by seed)."""
    stats: dict = {"modes": {}, "ratios": {}}
    by_mode = {m: sorted((r for r in runs if r["mode"] == m), key=lambda r: r["seed"]) for m in MODES}
    for mode, sel in by_mode.items():
        if not sel:
            continue
        entry: dict = {"n": len(sel)}
        for m in METRICS + tuple(k for k in CONTEXT if k in sel[0]):
            x = np.array([r[m] for r in sel], dtype=float)
            entry[m] = {"mean": float(np.mean(x)), "std": float(np.std(x, ddof=1)) if x.size > 1 else 0.0}
        stats["modes"][mode] = entry
    for a, b in itertools.combinations(MODES, 2):
        xa, xb = by_mode[a], by_mode[b]
        seeds = sorted({r["seed"] for r in xa} & {r["seed"] for r in xb})
        if not seeds:
            continue
        pick = {m: [next(r for r in by_mode[m] if r["seed"] == s) for s in seeds] for m in (a, b)}
        stats["ratios"][f"{b} / {a}"] = {
            m: ratio_of_means(np.array([r[m] for r in pick[b]]), np.array([r[m] for r in pick[a]])) for m in METRICS
        }
    return stats


def _fmt_ratio(r: dict) -> str:
    if r["ratio"] is None:
        return "undefined (denominator 0)"
    return f"{r['ratio']:.3g} ({CONFIDENCE:.0%} CI {r['low']:.3g}–{r['high']:.3g})"


def _smaller(r: dict) -> bool:
    return r["ratio"] is not None and r["high"] is not None and r["high"] < 1.0


def _similar(r: dict) -> bool:
    return r["ratio"] is not None and SIMILAR[0] <= r["low"] and r["high"] <= SIMILAR[1]


def findings(stats: dict) -> list[dict]:
    """[C]'s Fig. 5 statements (§IV-D text), each with our ratio of means and whether it reproduces.

    "smaller" reproduces when the whole 95 % interval of the ratio is below 1; "similar" when the
    interval lies inside `SIMILAR`. Every sentence is built from this run's numbers."""
    s, q = stats["modes"], stats["ratios"]
    if not all(m in s for m in MODES):
        return []

    def ms(mode: str, m: str) -> str:
        return f"{s[mode][m]['mean']:.3g} ± {s[mode][m]['std']:.2g}"

    fp = q["torque-fusion / position"]
    fr = q["torque-fusion / torque-residual"]
    out = [
        {
            "paper": "Fusion's peak deflection is similar to position control's",
            "ok": _similar(fp["peak_deflection_mm"]),
            "ours": f"fusion {ms('torque-fusion', 'peak_deflection_mm')} mm vs position "
            f"{ms('position', 'peak_deflection_mm')} mm; ratio {_fmt_ratio(fp['peak_deflection_mm'])}",
        },
        {
            "paper": "Fusion stabilises faster than position control",
            "ok": _smaller(fp["stabilization_time_s"]),
            "ours": f"fusion {ms('torque-fusion', 'stabilization_time_s')} s vs position "
            f"{ms('position', 'stabilization_time_s')} s; ratio {_fmt_ratio(fp['stabilization_time_s'])}",
        },
        {
            "paper": "Fusion leaves a smaller residual error than position control",
            "ok": _smaller(fp["residual_error_mm"]),
            "ours": f"fusion {ms('torque-fusion', 'residual_error_mm')} mm vs position "
            f"{ms('position', 'residual_error_mm')} mm; ratio {_fmt_ratio(fp['residual_error_mm'])}",
        },
        {
            "paper": "Fusion (precise measurements) does better than the residual alone (Fig. 5 bars)",
            "ok": all(_smaller(fr[m]) for m in METRICS),
            "ours": "; ".join(f"{m}: ratio {_fmt_ratio(fr[m])}" for m in METRICS),
        },
    ]
    return out


def held_vs_rope(held: dict, rope: dict) -> str:
    """What the held-release case adds, in numbers: the same ratios without the rope's jerk."""
    parts = []
    for pair in ("torque-residual / position", "torque-fusion / position"):
        for m in ("peak_deflection_mm", "stabilization_time_s"):
            a, b = held["ratios"][pair][m], rope["ratios"][pair][m]
            parts.append(f"{pair} {m}: {_fmt_ratio(a)} held vs {_fmt_ratio(b)} on the rope")
    return (
        "The same ratios without the rope: " + "; ".join(parts) + ". Where the two differ, the difference is what "
        "the rope's catch and the bouncing mass add to a plain load step."
    )


def _finding_html(f: dict) -> str:
    cls, word = ("ok", "reproduces") if f["ok"] else ("no", "does not reproduce")
    return f"<li><span class='{cls}'><b>{word}</b></span> — [C]: {f['paper']}. Ours: {f['ours']}.</li>"


def _figure(stats: dict, runs: list[dict], out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colors = {"position": "tab:blue", "torque-residual": "tab:orange", "torque-fusion": "tab:green"}
    titles = {
        "peak_deflection_mm": "peak deflection (mm)",
        "stabilization_time_s": "stabilization time (s)",
        "residual_error_mm": "residual error (mm)",
    }
    modes = [m for m in MODES if m in stats["modes"]]
    fig, axes = plt.subplots(1, 4, figsize=(14, 3.8), gridspec_kw={"width_ratios": [1, 1, 1, 1.6]})
    for ax, metric in zip(axes[:3], METRICS, strict=True):
        means = [stats["modes"][m][metric]["mean"] for m in modes]
        stds = [stats["modes"][m][metric]["std"] for m in modes]
        x = np.arange(len(modes))
        ax.bar(x, means, yerr=stds, color=[colors[m] for m in modes], capsize=4)
        for i, m in enumerate(modes):
            vals = [r[metric] for r in runs if r["mode"] == m]
            ax.plot(np.full(len(vals), i) + np.linspace(-0.2, 0.2, len(vals)), vals, ".", color="k", ms=2)
        ax.set_xticks(x, [LABELS[m].replace(" + ", "\n+ ") for m in modes], fontsize=8)
        ax.set_title(titles[metric], fontsize=10)
    ax = axes[3]
    for m in modes:
        r = next(r for r in runs if r["mode"] == m)
        ax.plot(r["trace_t"], r["trace_mm"], color=colors[m], lw=1, label=LABELS[m])
    ax.axhline(1e3 * STABLE_BAND_M, ls="--", color="0.5", lw=0.8, label="1 mm band")
    ax.set_xlim(-0.1, WINDOW_S)
    ax.set_yscale("symlog", linthresh=1.0)
    ax.set_xlabel("time from release (s)")
    ax.set_ylabel("TCP deviation (mm)")
    ax.set_title("first repetition of each mode", fontsize=10)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "fig5.png", dpi=120)
    plt.close(fig)


def _mean_sd_rows(stats: dict, keys: tuple[str, ...]) -> list[list]:
    return [
        [LABELS[m], stats["modes"][m]["n"]]
        + [f"{stats['modes'][m][k]['mean']:.4g} ± {stats['modes'][m][k]['std']:.2g}" for k in keys]
        for m in MODES
        if m in stats["modes"]
    ]


def _ratio_rows(stats: dict) -> list[list]:
    return [[pair] + [_fmt_ratio(stats["ratios"][pair][k]) for k in METRICS] for pair in stats["ratios"]]


def _torque_tracking(doc: dict) -> str:
    """How the runs' torques reached the joints (their recorded torque delays)."""
    delays = sorted({float(c["params"]["world"]["torque_delay_ms"]) for c in doc["configs"].values()})
    if delays == [0.0]:
        return "each torque reaches the joints exactly, in the step it is computed"
    return "each torque reaches the joints " + "/".join(f"{d:g}" for d in delays) + " ms after it is computed"


def scenario_record() -> dict:
    """The scenario's fixed figures a report names, recorded with the run (`app.scenarios.mass_drop`)."""
    m = scenario_module
    return {
        "posture": "mass_drop_nominal",
        "nominal_mass_kg": m.PAYLOAD_KG,
        "release_time_s": m.RELEASE_TIME_S,
        "window_s": m.WINDOW_S,
        "stable_band_m": STABLE_BAND_M,
        "residual_window_s": RESIDUAL_WINDOW_S,
        "pid_pole_rad_s": m.PID_OMEGA,
        "actuator_ripple_std_n_m": m.ACTUATOR_RIPPLE_STD,
    }


def setup_html(doc: dict, rigs: list[dict]) -> str:
    """The setup paragraphs from mass_drop.json: robot, posture, rope, release, metrics, each mode's
    controller as its run had it (`configs`) and the spread of the rigs drawn."""
    sc, cfg = doc["scenario"], doc["configs"]
    torque = cfg.get("torque-fusion") or next(iter(cfg.values()))
    p = torque["params"]
    pose, gamma0 = p.get("pose_task", {}), p.get("posture_task", {}).get("compliance")
    sensor = p.get("sensor")
    noise = (
        (f"σ = {sensor['force_noise_var'] ** 0.5:.3g} N" if sensor and sensor.get("noise") else "no noise")
        if sensor
        else "noise not recorded"
    )
    gains = ", ".join(
        f"{LABELS[m]} K_I = {c['params']['estimator']['observer_gain']:g} s⁻¹ ({c['params']['estimator']['source']})"
        for m, c in cfg.items()
        if m != "position" and "estimator" in c["params"]
    )
    spread = {
        k: (min(r[k] for r in rigs), max(r[k] for r in rigs))
        for k in ("drop_height_m", "rope_stiffness_n_per_m", "mass_kg", "rope_length_m")
    }
    return (
        f"<p>{html.escape(torque['robot'])} at <code>{sc['posture']}</code> ({html.escape(rigs[0]['posture'])}). A "
        "mass hangs from the TCP (distal to the F/T sensor) on a rope of "
        + "–".join(f"{100 * x:g}" for x in sorted(set(spread["rope_length_m"])))
        + " cm; a hand holds it at the "
        f"attachment point and lets go at t = {sc['release_time_s']:g} s; it falls, the rope goes taut and jerks the "
        f"arm. Metrics over the {sc['window_s']:g} s after the release. Deviation = distance of the TCP from its "
        "target. Peak deflection: its maximum; stabilization time: the last exit from a "
        f"{1e3 * sc['stable_band_m']:g} mm band (0 if it never leaves it); residual error: its mean over the last "
        f"{sc['residual_window_s']:g} s. Position: joint PID, triple pole at {sc['pid_pole_rad_s']:g} rad/s, no "
        f"external-torque estimate. Torque modes: TCP pose task (K_p = {pose.get('stiffness', float('nan')):g}, "
        f"K_d = {pose.get('damping', float('nan')):g}, Γ = {pose.get('compliance')}), posture task Γ₀ = {gamma0}, "
        f"momentum observer alone or fused with the F/T sensor ({gains}); F/T {noise}; control period "
        f"{torque['timestep_s'] * 1e3:g} ms.</p>"
        f"<p>What varies, per repetition (seeded, the same draw for the three modes): drop height "
        f"{spread['drop_height_m'][0] * 100:.2f}–{spread['drop_height_m'][1] * 100:.2f} cm, rope stiffness "
        f"{spread['rope_stiffness_n_per_m'][0]:.0f}–{spread['rope_stiffness_n_per_m'][1]:.0f} N/m, true mass "
        f"{spread['mass_kg'][0]:.3f}–{spread['mass_kg'][1]:.3f} kg (nominal {sc['nominal_mass_kg']:g} kg, which no "
        f"controller is told), plus the sensor noise and a {sc['actuator_ripple_std_n_m']:g} N m actuator torque "
        f"ripple. {doc['repetitions']} repetitions per mode; {doc['halted']} runs ended early (divergence or error); "
        f"wall time {doc['wall_s']:.1f} s.</p>"
    )


def run(args: argparse.Namespace) -> int:
    """Run the repetitions of both cases, write mass_drop.json, fig5.png and report.html."""
    if args.repetitions < 2:
        print("mass-drop: --repetitions must be at least 2 (a spread and an interval need two)")
        return 2
    if args.held_repetitions < 0:
        print("mass-drop: --held-repetitions must be 0 or more")
        return 2
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    settings = tuple(parse_settings(getattr(args, "set", [])))
    rope_args = [
        (mode, seed, "rope-drop", None, WINDOW_S, None, settings) for mode in MODES for seed in range(args.repetitions)
    ]
    held_args = [
        (mode, seed, "held-release", None, WINDOW_S, None, settings)
        for mode in MODES
        for seed in range(args.held_repetitions)
    ]
    t0 = time.perf_counter()
    runs = run_parallel(run_mass_drop, rope_args + held_args, args.jobs, "mass-drop")
    elapsed = time.perf_counter() - t0
    by_case = {case: [r for r in runs if r["case"] == case] for case in CASES}
    stats = {case: summarize(rs) for case, rs in by_case.items() if len(rs) >= 2 * len(MODES)}
    halted = [r for r in runs if r["stop"] != "done"]
    main = stats["rope-drop"]
    items = findings(main)
    configs = {m: next(r["config"] for r in runs if r["mode"] == m) for m in MODES}
    per_run = [{k: v for k, v in r.items() if not k.startswith("trace") and k != "config"} for r in runs]
    doc = {
        "cases": stats,
        "findings": items,
        "runs": per_run,
        "repetitions": args.repetitions,
        "held_repetitions": args.held_repetitions,
        "configs": configs,  # each mode's first run's configuration (the modes differ in their executor)
        "scenario": scenario_record(),
        "statistics": {"confidence": CONFIDENCE, "resamples": BOOTSTRAP_RESAMPLES, "similar_band": list(SIMILAR)},
        "halted": len(halted),
        "wall_s": elapsed,
        "command": command_line(args),
        "code": code_record(),
    }
    write_json(out / "mass_drop.json", doc)
    _figure(main, by_case["rope-drop"], out)
    header = ["mode", "n", "peak deflection (mm)", "stabilization time (s)", "residual error (mm)"]
    print(f"{'rope drop':20s} {'peak (mm)':>18s} {'settle (s)':>18s} {'residual (mm)':>18s}")
    for r in _mean_sd_rows(main, METRICS):
        print(f"{r[0]:20s} {r[2]:>18s} {r[3]:>18s} {r[4]:>18s}")
    for pair, row in main["ratios"].items():
        print(f"  ratio {pair}: " + ", ".join(f"{k.split('_')[0]} {_fmt_ratio(row[k])}" for k in METRICS))
    for f in items:
        print(("  reproduces: " if f["ok"] else "  does not reproduce: ") + f["paper"])
    setup = setup_html(doc, [r for r in by_case["rope-drop"] if r["mode"] == MODES[0]])
    notes = (
        "<p>Effect sizes are ratios of means (row mode / column mode as named) with paired percentile-bootstrap "
        f"{doc['statistics']['confidence']:.0%} intervals ({doc['statistics']['resamples']} resamples). 'Similar' "
        f"means the interval lies within {SIMILAR[0]}–{SIMILAR[1]}; 'smaller' means it lies below 1. "
        "No p-values: the spread here comes from "
        "a modelled rig, not from a robot, so a test of significance would only measure how many repetitions "
        "were run. [C] gives Fig. 5 as bars only, with no numbers in its text: its side of each statement is "
        f"the direction it reports. In this simulation {_torque_tracking(doc)} and the links are rigid (the cord "
        "stands in for the flexibility), so compare the ordering and the ratios, not the magnitudes.</p>"
    )
    sections = [
        ("Setup", setup),
        ("What the paper found and what we get", "<ul>" + "".join(_finding_html(f) for f in items) + "</ul>" + notes),
        ("Rope drop: mean ± sd per mode", html_table(header, _mean_sd_rows(main, METRICS))),
        (
            "Rope drop: context (peak rope tension, steps with a joint at its torque limit, QP relaxations)",
            html_table(["mode", "n", *CONTEXT], _mean_sd_rows(main, CONTEXT)),
        ),
        (
            f"Rope drop: ratio of means, paired bootstrap {doc['statistics']['confidence']:.0%} interval",
            html_table(["ratio", *METRICS], _ratio_rows(main)),
        ),
        ("Figure (Fig. 5 style)", "<img src='fig5.png'>"),
    ]
    if "held-release" in stats:
        held = stats["held-release"]
        sections.append(
            (
                "Second case, held-release (not the paper's protocol): the arm holds the mass rigidly (the same "
                "seeded mass draws) and lets it go — an unloading step with no impact",
                html_table(header, _mean_sd_rows(held, METRICS))
                + html_table(["ratio", *METRICS], _ratio_rows(held))
                + "<p>"
                + held_vs_rope(held, main)
                + "</p>",
            )
        )
    write_report(out, "Mass drop [C] §IV-D", sections, args)
    if args.json:
        print(json.dumps({"cases": stats, "findings": items}, indent=2))
    print(f"wrote {out / 'mass_drop.json'} and {out / 'report.html'} ({elapsed:.1f} s)")
    return 0
