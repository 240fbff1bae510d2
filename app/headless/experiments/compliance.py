"""compliance: the three compliance modes of [C] §IV-E (Fig. 6) under the same scripted pushes.

Stiff (Γ = 0), nullspace-compliant (Γ₀ = I) and fully compliant (Γ = I): TCP linear and angular
velocity norms, joint velocity norm, the TCP's and the elbow's deflection (mm, `metrics.DeflectionProbe`,
as the page shows them) and the posture deviation per mode and push, each the peak over the push and the
`metrics.PUSH_AFTER_S` after it (`metrics.WindowPeaks`, the page's readout and the lesson's claim too).
Writes compliance.json, fig6.png and report.html.
"""

from __future__ import annotations

import argparse
import html
import json
import time
from pathlib import Path

import numpy as np

from app.core.provenance import code_record
from app.headless.experiments.c_common import (
    command_line,
    html_table,
    qp_session,
    run_parallel,
    verdict,
    write_json,
    write_report,
)
from app.headless.experiments.run_config import apply_settings, parse_settings, run_configuration
from app.scenarios.compliance import DURATION_S, MODES, PUSH_N, PUSHES, ComplianceScenario
from app.scenarios.metrics import PUSH_AFTER_S, WindowPeaks, push_windows
from control.compliance_qp import ComplianceQPExecutor

LABELS = {"stiff": "Γ = 0 (stiff)", "nullspace": "Γ₀ = I (nullspace compliant)", "full": "Γ = I (full compliance)"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of this experiment (none besides the common ones)."""


def run_mode(mode: str, settings: tuple = ()) -> dict:
    """One run of the scripted pushes; per-push peaks, down-sampled traces and the run's configuration
    (`run_configuration`). `settings`: (group, field, value) set after the mode's own (`--set`)."""
    scenario = ComplianceScenario(mode)
    session = qp_session(scenario)
    executor = session.executor
    assert isinstance(executor, ComplianceQPExecutor)
    apply_settings(session, settings)
    session.reset()
    q0 = session.world.q
    cols = ("t", "v", "w", "dq", "tcp_dev_mm", "elbow_dev_mm", "posture", "force", "est")
    rec: dict[str, list[float]] = {c: [] for c in cols}

    def record(r) -> None:
        dyn = session.dyn
        twist = dyn.J @ dyn.dq
        rec["t"].append(r.t)
        rec["v"].append(float(np.linalg.norm(twist[:3])))
        rec["w"].append(float(np.linalg.norm(twist[3:])))
        rec["dq"].append(float(np.linalg.norm(r.dq)))
        rec["tcp_dev_mm"].append(r.signals["tcp_dev_mm"])  # the TCP and the elbow from where they stood at the reset
        rec["elbow_dev_mm"].append(r.signals["elbow_dev_mm"])
        rec["posture"].append(float(np.linalg.norm(r.q - q0)))
        rec["force"].append(PUSH_N * (r.signals.get("push_tcp", 0.0) + r.signals.get("push_elbow", 0.0)))
        rec["est"].append(r.signals.get("tau_ext_estimate_norm", 0.0))

    result = session.run(DURATION_S, record=record)  # a halted run keeps what it ran (stop says why)
    arr = {c: np.array(v) for c, v in rec.items()}
    windows = push_windows(PUSHES)  # each push and the PUSH_AFTER_S after it
    peaks = WindowPeaks(windows, ("tcp_dev_mm", "elbow_dev_mm", "v", "w", "dq", "posture"))
    peaks.add(arr)
    found = peaks.value()
    phases = {}
    for where, _, _ in PUSHES:
        window = f"{where}_push"
        if WindowPeaks.key(window, "tcp_dev_mm") not in found:
            continue
        phases[where] = {
            "peak_tcp_speed_m_s": found[WindowPeaks.key(window, "v")],
            "peak_tcp_angular_speed_rad_s": found[WindowPeaks.key(window, "w")],
            "peak_joint_speed_rad_s": found[WindowPeaks.key(window, "dq")],
            "peak_tcp_deflection_mm": found[WindowPeaks.key(window, "tcp_dev_mm")],
            "peak_elbow_deflection_mm": found[WindowPeaks.key(window, "elbow_dev_mm")],
            "peak_posture_deviation_rad": found[WindowPeaks.key(window, "posture")],
        }
    traces = {c: arr[c][::4].tolist() for c in cols}
    return {
        "mode": mode,
        "phases": phases,
        "traces": traces,
        "stop": result.stop,
        "reason": result.reason,
        "config": run_configuration(session),
    }


def _figure(runs: list[dict], out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(runs), 1, figsize=(8, 2.4 * len(runs)), sharex=True)
    for ax, r in zip(np.atleast_1d(axes), runs, strict=True):
        tr = r["traces"]
        ax.plot(tr["t"], tr["v"], color="tab:blue", lw=1, label="‖v_TCP‖ (m/s)")
        ax.plot(tr["t"], tr["w"], color="tab:blue", lw=1, ls="--", label="‖ω_TCP‖ (rad/s)")
        ax.plot(tr["t"], tr["dq"], color="tab:purple", lw=1, label="‖q̇‖ (rad/s)")
        ax.set_ylabel("velocity")
        ax.set_title(LABELS[r["mode"]], fontsize=10)
        ax2 = ax.twinx()
        ax2.plot(tr["t"], tr["force"], color="tab:orange", lw=1, label="push (N)")
        ax2.set_ylabel("push (N)", color="tab:orange")
        ax2.set_ylim(0, 2.5 * PUSH_N)
        if r is runs[0]:
            ax.legend(fontsize=7, loc="upper right")
    np.atleast_1d(axes)[-1].set_xlabel("time (s)")
    fig.tight_layout()
    fig.savefig(out / "fig6.png", dpi=120)
    plt.close(fig)


def findings(runs: list[dict]) -> list[dict]:
    """[C] §IV-E's three statements checked against our numbers: per statement whether it reproduces,
    the sentence, and every number the sentence prints (kept in compliance.json beside it)."""
    by = {r["mode"]: r["phases"] for r in runs}
    if not all(by.get(m) for m in MODES):
        return []

    def worst(mode: str, key: str) -> float:
        return max(p[key] for p in by[mode].values())

    disp = {m: worst(m, "peak_tcp_deflection_mm") for m in MODES}
    post = {m: worst(m, "peak_posture_deviation_rad") for m in MODES}
    yield_ratio = post["nullspace"] / max(post["stiff"], 1e-9)
    follow_ratio = disp["full"] / max(disp["nullspace"], 1e-9)
    return [
        {
            "ok": disp["stiff"] < 1.0 and post["stiff"] < 0.05,
            "text": f"Γ = 0 suppresses motion: TCP moves at most {disp['stiff']:.2f} mm, posture "
            f"{post['stiff']:.3f} rad.",
            "numbers": {"tcp_mm": disp["stiff"], "posture_rad": post["stiff"]},
        },
        {
            "ok": disp["nullspace"] < 1.0 and post["nullspace"] > 5 * post["stiff"],
            "text": f"Γ₀ = I keeps the TCP ({disp['nullspace']:.2f} mm) while the joints yield "
            f"({post['nullspace']:.3f} rad, {yield_ratio:.0f}× the stiff mode).",
            "numbers": {"tcp_mm": disp["nullspace"], "posture_rad": post["nullspace"], "ratio": yield_ratio},
        },
        {
            "ok": disp["full"] > 10 * max(disp["nullspace"], 0.1),
            "text": f"Γ = I lets the TCP follow the push: {disp['full']:.1f} mm ({follow_ratio:.0f}× the nullspace "
            "mode).",
            "numbers": {"tcp_mm": disp["full"], "ratio": follow_ratio},
        },
    ]


def setup_html(doc: dict) -> str:
    """The setup paragraph from compliance.json: robot, posture, the tasks' gains, the estimate, the
    pushes and the window, as the runs had them (their recorded configuration)."""
    config = doc["config"]
    p = config["params"]
    pose, posture, est = p["pose_task"], p["posture_task"], p["estimator"]
    sensor = p.get("sensor")
    noise = (
        f", F/T noise σ = {sensor['force_noise_var'] ** 0.5:.3g} N"
        if sensor and sensor.get("noise")
        else ", no F/T noise"
        if sensor
        else ""
    )
    pushes = "; ".join(
        f"at the {'TCP' if where == 'tcp' else where} {start:g}–{end:g} s"
        + (
            " (seen by the F/T sensor)"
            if where == "tcp"
            else " (seen by the observer only)"
            if where == "elbow"
            else ""
        )
        for where, start, end in doc["pushes"]
    )
    return (
        f"<p>{html.escape(config['robot'])} at {html.escape(doc['posture'])}, "
        f"TCP pose task (K_p = {pose['stiffness']:g}, "
        f"K_d = {pose['damping']:g}, weight {pose['weight']:g}) and posture task (K_p = {posture['stiffness']:g}, "
        f"K_d = {posture['damping']:g}, weight {posture['weight']:g}), {html.escape(est['source'])} estimate "
        f"(K_I = {est['observer_gain']:g} s⁻¹){noise}, feedback {'on' if p['compliance_qp']['feedback'] else 'off'}, "
        f"control period {config['timestep_s'] * 1e3:g} ms. Pushes of {doc['push_n']:g} N along +y: {pushes}. "
        f"Peaks over each push and the {doc['after_push_s']:g} s after it; TCP and elbow moved: their distance from "
        f"where they stood at t = 0 (the page's deflection readout and plot). Wall time {doc['wall_s']:.1f} s.</p>"
    )


def run(args: argparse.Namespace) -> int:
    """Run the three modes, write compliance.json, fig6.png and report.html."""
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    settings = tuple(parse_settings(getattr(args, "set", [])))
    runs = run_parallel(run_mode, [(m, settings) for m in MODES], args.jobs, "compliance")
    elapsed = time.perf_counter() - t0
    summary = {r["mode"]: r["phases"] for r in runs}
    items = findings(runs)
    doc = {
        "modes": summary,
        "push_n": PUSH_N,
        "pushes": [list(p) for p in PUSHES],
        "after_push_s": PUSH_AFTER_S,
        "posture": "home",  # the scenario's initial posture (`Scenario.initial_q`)
        "config": runs[0]["config"],  # the stiff run's; each mode's own under "configs"
        "configs": {r["mode"]: r["config"] for r in runs},
        "findings": items,
        "wall_s": elapsed,
        "command": command_line(args),
        "code": code_record(),
    }
    write_json(out / "compliance.json", doc)
    _figure(runs, out)
    header = [
        "mode",
        "push at",
        "‖v‖ max (m/s)",
        "‖ω‖ max (rad/s)",
        "‖q̇‖ max (rad/s)",
        "TCP moved (mm)",
        "elbow moved (mm)",
        "posture (rad)",
    ]
    rows = [
        [LABELS[m], where, *summary[m][where].values()]
        for m in MODES
        for where, _, _ in PUSHES
        if where in summary.get(m, {})
    ]
    for r in runs:
        if r["stop"] != "done":
            print(f"compliance: the {r['mode']} run ended early: {r['reason']}")
    for r in rows:
        print(f"{r[0]:32s} {r[1]:6s} " + " ".join(f"{x:9.4f}" for x in r[2:]))
    write_report(
        out,
        "Compliance modes [C] §IV-E",
        [
            ("Setup", setup_html(doc)),
            (
                "What the paper found and what we get",
                "<ul>" + "".join(verdict(f["ok"], f["text"]) for f in items) + "</ul>",
            ),
            ("Peaks per mode and push", html_table(header, rows)),
            ("Figure (Fig. 6 style)", "<img src='fig6.png'>"),
        ],
        args,
    )
    if args.json:
        print(json.dumps(summary, indent=2))
    print(f"wrote {out / 'compliance.json'} and {out / 'report.html'} ({elapsed:.1f} s)")
    return 0
