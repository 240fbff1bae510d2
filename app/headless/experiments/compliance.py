"""compliance: the three compliance modes of [C] §IV-E (Fig. 6) under the same scripted pushes.

Stiff (Γ = 0), nullspace-compliant (Γ₀ = I) and fully compliant (Γ = I): TCP linear and angular
velocity norms, joint velocity norm, TCP displacement and posture deviation per mode and push.
Writes compliance.json, fig6.png and report.html.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from app.headless.experiments.c_common import html_table, qp_session, run_parallel, verdict, write_json, write_report
from app.scenarios.compliance import DURATION_S, MODES, PUSH_N, PUSHES, ComplianceScenario
from control.compliance_qp import ComplianceQPExecutor

LABELS = {"stiff": "Γ = 0 (stiff)", "nullspace": "Γ₀ = I (nullspace compliant)", "full": "Γ = I (full compliance)"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of this experiment (none besides the common ones)."""


def run_mode(mode: str) -> dict:
    """One run of the scripted pushes; per-push peaks and down-sampled traces."""
    scenario = ComplianceScenario(mode)
    session = qp_session(scenario)
    executor = session.executor
    assert isinstance(executor, ComplianceQPExecutor)
    scenario.configure_executor(executor, session.robot)
    session.reset()
    p0 = session.target_fn(0.0).position.copy()
    q0 = session.world.q
    cols = ("t", "v", "w", "dq", "disp", "posture", "force", "est")
    rec: dict[str, list[float]] = {c: [] for c in cols}

    def record(r) -> None:
        dyn = session.dyn
        twist = dyn.J @ dyn.dq
        rec["t"].append(r.t)
        rec["v"].append(float(np.linalg.norm(twist[:3])))
        rec["w"].append(float(np.linalg.norm(twist[3:])))
        rec["dq"].append(float(np.linalg.norm(r.dq)))
        rec["disp"].append(float(np.linalg.norm(dyn.tcp_position_world - p0)))
        rec["posture"].append(float(np.linalg.norm(r.q - q0)))
        rec["force"].append(PUSH_N * (r.signals.get("push_tcp", 0.0) + r.signals.get("push_elbow", 0.0)))
        rec["est"].append(r.signals.get("tau_ext_estimate_norm", 0.0))

    result = session.run(DURATION_S, record=record)  # a halted run keeps what it ran (stop says why)
    arr = {c: np.array(v) for c, v in rec.items()}
    phases = {}
    for where, start, end in PUSHES:
        sel = (arr["t"] >= start) & (arr["t"] < end + 0.5)  # the push and the half second after it
        if not sel.any():
            continue
        phases[where] = {
            "peak_tcp_speed_m_s": float(arr["v"][sel].max()),
            "peak_tcp_angular_speed_rad_s": float(arr["w"][sel].max()),
            "peak_joint_speed_rad_s": float(arr["dq"][sel].max()),
            "peak_tcp_displacement_mm": 1e3 * float(arr["disp"][sel].max()),
            "peak_posture_deviation_rad": float(arr["posture"][sel].max()),
        }
    traces = {c: arr[c][::4].tolist() for c in cols}
    return {"mode": mode, "phases": phases, "traces": traces, "stop": result.stop, "reason": result.reason}


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


def findings(runs: list[dict]) -> list[str]:
    """[C] §IV-E's three statements checked against our numbers."""
    by = {r["mode"]: r["phases"] for r in runs}
    if not all(by.get(m) for m in MODES):
        return []

    def worst(mode: str, key: str) -> float:
        return max(p[key] for p in by[mode].values())

    disp = {m: worst(m, "peak_tcp_displacement_mm") for m in MODES}
    post = {m: worst(m, "peak_posture_deviation_rad") for m in MODES}
    return [
        verdict(
            disp["stiff"] < 1.0 and post["stiff"] < 0.05,
            f"Γ = 0 suppresses motion: TCP moves at most {disp['stiff']:.2f} mm, posture {post['stiff']:.3f} rad.",
        ),
        verdict(
            disp["nullspace"] < 1.0 and post["nullspace"] > 5 * post["stiff"],
            f"Γ₀ = I keeps the TCP ({disp['nullspace']:.2f} mm) while the joints yield "
            f"({post['nullspace']:.3f} rad, {post['nullspace'] / max(post['stiff'], 1e-9):.0f}× the stiff mode).",
        ),
        verdict(
            disp["full"] > 10 * max(disp["nullspace"], 0.1),
            f"Γ = I lets the TCP follow the push: {disp['full']:.1f} mm "
            f"({disp['full'] / max(disp['nullspace'], 1e-9):.0f}× the nullspace mode).",
        ),
    ]


def run(args: argparse.Namespace) -> int:
    """Run the three modes, write compliance.json, fig6.png and report.html."""
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    runs = run_parallel(run_mode, [(m,) for m in MODES], args.jobs, "compliance")
    elapsed = time.perf_counter() - t0
    summary = {r["mode"]: r["phases"] for r in runs}
    write_json(out / "compliance.json", {"modes": summary, "push_n": PUSH_N, "estimate_source": "fusion"})
    _figure(runs, out)
    header = [
        "mode",
        "push at",
        "‖v‖ max (m/s)",
        "‖ω‖ max (rad/s)",
        "‖q̇‖ max (rad/s)",
        "TCP moved (mm)",
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
    setup = (
        f"<p>Gen3 at home, TCP pose task (K_p = 100, K_d = 20, weight 1e4) and posture task (K_p = 1, K_d = 2, "
        f"weight 1), fusion estimate (K_I = 50 s⁻¹), feedback on. Pushes of {PUSH_N:g} N along +y: at the TCP "
        "0.5–1.0 s (seen by the F/T sensor), at the elbow 2.0–2.5 s (seen by the observer only). Peaks over each "
        f"push and the 0.5 s after it. Wall time {elapsed:.1f} s.</p>"
    )
    write_report(
        out,
        "Compliance modes [C] §IV-E",
        [
            ("Setup", setup),
            ("What the paper found and what we get", "<ul>" + "".join(findings(runs)) + "</ul>"),
            ("Peaks per mode and push", html_table(header, rows)),
            ("Figure (Fig. 6 style)", "<img src='fig6.png'>"),
        ],
        args,
    )
    if args.json:
        print(json.dumps(summary, indent=2))
    print(f"wrote {out / 'compliance.json'} and {out / 'report.html'} ({elapsed:.1f} s)")
    return 0
