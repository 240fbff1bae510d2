"""limit-drop: joint 4 of the Gen3 (or the arm chosen) falls into its position / velocity limit ([C]
§IV-B–C, Figs. 2–4); the limit it falls toward is the one the payload's torque points to (upper on
the Gen3, lower on the Panda), and every margin is measured toward it.

Sweeps λ ∈ {70, 100, 300, 500} at M = 3, M ∈ {1.5, 2, 3, 5} at λ = 100 and the classic δt form,
each with and without external-force feedback, for (a) the position limit and (b) a lowered
velocity limit. Writes limit_drop.json, phase diagrams and report.html.
"""

from __future__ import annotations

import argparse
import html
import itertools
import time
from collections.abc import Iterable
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
from app.headless.experiments.run_config import parse_settings, run_configuration
from app.scenarios.limit_drop import (
    DURATION_S,
    FALLING_JOINT,
    PAYLOAD_KG,
    LimitDropScenario,
)
from app.scenarios.metrics import REVERSAL_HYSTERESIS_RAD_S, velocity_reversals
from control.compliance_qp import ComplianceQPExecutor

LAMBDAS_AT_M3 = (70.0, 100.0, 300.0, 500.0)
DELAY_STEPS = 5  # sensitivity check only: torque applied 5 ms late (a few ms of torque-loop/link latency)
MS_AT_L100 = (1.5, 2.0, 3.0, 5.0)
STOP_SPEED = 0.01  # rad/s: joint 4 counts as stopped below this speed ...
STOP_HOLD_S = 0.2  # ... held this long
FALLEN_RAD = 0.05  # rad: ... once it has fallen at least this far
OBSERVER_GAINS = (50.0, 200.0, 1000.0)  # 1/s: K_I of the velocity-overshoot study (50 is the default)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of this experiment."""
    parser.add_argument(
        "--duration", type=float, default=DURATION_S, help="cap in seconds per drop; each runs until joint 4 stops (6)"
    )
    parser.add_argument("--quick", action="store_true", help="only λ=100, M=2 and the classic form")


def variants(quick: bool = False) -> list[tuple[str, float, float]]:
    """(form, λ, M) of the sweep; the classic form takes ξ from λ = 100, M = 2 via [C23]."""
    if quick:
        return [("proposed", 100.0, 2.0), ("classic", 100.0, 2.0)]
    out = [("proposed", lam, 3.0) for lam in LAMBDAS_AT_M3]
    out += [("proposed", 100.0, M) for M in MS_AT_L100 if M != 3.0]
    out.append(("classic", 100.0, 2.0))
    return out


def run_drop(
    form: str | None = None,
    lam: float | None = None,
    M: float | None = None,
    feedback: bool | None = None,
    limit: str = "position",
    duration: float = DURATION_S,
    observer_gain: float | None = None,
    delay_steps: int = 0,
    source: str | None = None,
    until_stopped: bool = True,
    session_params: Iterable[tuple[str, str, object]] = (),
) -> dict:
    """One drop, until joint 4 has stopped (fallen ≥ FALLEN_RAD, then slower than STOP_SPEED for
    STOP_HOLD_S) or `duration` s (the cap); returns the
    metrics of limit_drop.json and the joint-4 trace. `source` overrides the τ̂_e source (fusion).

    Every setting reaches the run through `Session.set_param`, as the GUI's do: the damper form, λ,
    M, the feedback switch, K_I, τ̂_e's source and the torque delay (None / 0: the preset's own), then
    `session_params` (group, field, value) in order; a refused one raises ParamError."""
    scenario = LimitDropScenario(limit)
    session = qp_session(scenario)
    robot = session.robot
    executor = session.executor
    assert isinstance(executor, ComplianceQPExecutor)
    named = [
        ("damper", "form", form),
        ("damper", "lambda_", lam),
        ("damper", "M", M),
        ("compliance_qp", "feedback", feedback),
        ("estimator", "observer_gain", observer_gain),
        ("estimator", "source", source),
        # actuator latency in the simulation (the app's Safety → Torque delay)
        ("world", "torque_delay_ms", delay_steps * 1e3 * session.world.model.opt.timestep if delay_steps else None),
    ]
    for group, name, value in [*((g, f, v) for g, f, v in named if v is not None), *session_params]:
        session.set_param(group, name, value)
    session.reset()
    j = FALLING_JOINT
    dt = session.world.model.opt.timestep
    qs: list[float] = []
    dqs: list[float] = []
    taus: list[float] = []
    counts = {"relaxed": 0, "slow": 0}  # QP relaxations; consecutive steps slower than STOP_SPEED
    q_start = session.world.q
    others = np.arange(robot.nq) != j
    drift = np.zeros(robot.nq)  # per joint: the largest |q − q_start| (joint 4's own entry stays 0)

    def record(rec) -> None:
        qs.append(float(rec.q[j]))
        dqs.append(float(rec.dq[j]))
        taus.append(float(rec.tau[j]))
        counts["relaxed"] += int(rec.signals.get("qp_relaxed", 0.0) > 0)
        counts["slow"] = counts["slow"] + 1 if abs(rec.dq[j]) < STOP_SPEED else 0
        np.maximum(drift, np.where(others, np.abs(rec.q - q_start), 0.0), out=drift)

    hold = round(STOP_HOLD_S / dt)

    def stopped(rec) -> bool:  # fallen at least FALLEN_RAD, then slower than STOP_SPEED for STOP_HOLD_S
        return counts["slow"] >= hold and abs(qs[-1] - qs[0]) >= FALLEN_RAD

    until = stopped if until_stopped else None
    result = session.run(duration, record=record, until=until)
    q, dq, tau = np.array(qs), np.array(dqs), np.array(taus)
    steps = q.size
    relaxed = counts["relaxed"]
    drift_max = float(np.max(drift))
    fall = scenario.fall(robot)
    s = fall.direction  # +1: joint 4 falls toward its upper limit, −1: toward its lower one
    q_lim = fall.limit
    d_s = 0.01 * float(robot.q_upper[j] - robot.q_lower[j])
    dq_lim = float(scenario.velocity_limits(robot)[j])
    toward, speed = s * (q - q_lim), s * dq  # past the limit (> 0 beyond it), speed toward it
    k_peak = int(np.argmax(speed))
    slow = np.flatnonzero(speed[k_peak:] < 0.9 * speed[k_peak])
    k_brake = k_peak + int(slow[0]) if slow.size else steps - 1  # braking: below 90 % of the peak speed
    window = 5  # steps: deceleration from 5 ms velocity differences
    ddq = (speed[window:] - speed[:-window]) / (window * dt)
    if limit == "position":
        violation = float(np.max(toward))
    else:
        violation = float(np.max(speed) - dq_lim)
    damper = executor.damper.gains  # the values in force
    return {
        "robot": robot.name,
        "form": damper.form,
        "lambda": damper.lambda_,
        "M": damper.M,
        "feedback": bool(executor.settings.feedback),
        "limit": limit,
        "max_violation": violation,
        "overshoot_beyond_ds": float(np.max(toward) + d_s),
        "oscillations": velocity_reversals(dq),
        "peak_torque": float(np.max(np.abs(tau))),
        "peak_velocity": float(np.max(speed)),
        "brake_onset_margin": float(-toward[k_brake]),
        "peak_deceleration": float(-np.min(ddq)),
        "observer_gain": float(executor.estimator.gains.observer_gain),
        "source": str(executor.estimator.gains.source),
        "stop": result.stop,  # "until": joint 4 stopped; "done": still moving at the cap
        "duration_s": steps * dt,
        "torque_delay_ms": session.world.torque_delay_steps * 1e3 * dt,  # in force (whole steps)
        "final_margin": float(-toward[-1]),
        "relaxed_steps": relaxed,
        "other_joints_drift": drift_max,
        "other_joints_drift_per_joint": [float(x) for x in drift],  # joint k + 1 at index k
        "falling_joint": j + 1,  # numbered from 1, as the report names joints
        "config": run_configuration(session),
        "direction": s,
        "q_limit": q_lim,
        "d_s": d_s,
        "dq_limit": dq_lim,
        "trace_q": q[::5].tolist(),
        "trace_dq": dq[::5].tolist(),
    }


def _phase_figure(runs: list[dict], title: str, path: Path, key: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.4))
    r0 = runs[0]
    q_lim, d_s, dq_lim, s = r0["q_limit"], r0["d_s"], r0["dq_limit"], r0["direction"]
    qs = np.concatenate([np.asarray(r["trace_q"]) for r in runs])
    dqs = np.concatenate([np.asarray(r["trace_dq"]) for r in runs])
    x_lo, x_hi = min(float(qs.min()), q_lim) - 0.03, max(float(qs.max()), q_lim) + 0.03
    y_lo = min(float(dqs.min()), 0.0, s * dq_lim) - (0.1 if s < 0 else 0.05)
    y_hi = max(float(dqs.max()), 0.0, s * dq_lim) + (0.1 if s > 0 else 0.05)
    beyond = (q_lim, x_hi) if s > 0 else (x_lo, q_lim)  # the side joint 4 falls toward
    ax.axvspan(*beyond, color="0.75", label="beyond position limit")
    ax.axvspan(*sorted((q_lim - s * d_s, q_lim)), color="0.9", label="safety distance d_s")
    ax.axhspan(*((dq_lim, y_hi) if s > 0 else (y_lo, -dq_lim)), color="0.85")
    ax.axhline(s * dq_lim, ls="--", color="0.4", lw=0.8, label="velocity limit")
    for r in runs:
        if r["form"] == "classic":
            ax.plot(r["trace_q"], r["trace_dq"], color="0.5", lw=1.6, label="classic δt [C17–19]")
        else:
            ax.plot(r["trace_q"], r["trace_dq"], lw=1.2, label=f"{key} = {r[key]:g}")
    ax.set_xlim(x_lo, x_hi)
    ax.set_ylim(y_lo, y_hi)
    ax.set_xlabel("joint 4 position q (rad)")
    ax.set_ylabel("joint 4 velocity q̇ (rad/s)")
    ax.set_title(title, fontsize=10)
    ax.legend(fontsize=7, loc="lower left" if s > 0 else "upper right")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _select(runs, *, limit, feedback, sweep):
    out = []
    for r in runs:
        if r["limit"] != limit or r["feedback"] != feedback:
            continue
        if r["form"] == "classic":
            out.append(r)
        elif sweep == "lambda" and r["M"] == 3.0:
            out.append(r)
        elif sweep == "M" and r["lambda"] == 100.0:
            out.append(r)
    return out


def _label(r: dict) -> str:
    fb = "on" if r["feedback"] else "off"
    delay = f", torque {r['torque_delay_ms']:g} ms late" if r.get("torque_delay_ms", 0.0) > 0 else ""
    return f"{r['limit']} {r['form']} λ={r['lambda']:g} M={r['M']:g} feedback {fb}{delay}"


def velocity_overshoot_item(study: list[dict], table_gain: float) -> str:
    """The lowered velocity limit's excess with feedback per K_I and τ̂_e source (each run's
    `excess_share_of_limit`), as an HTML item; `table_gain` is the K_I of the table's runs."""

    def pct(r: dict) -> str:
        return f"{100 * r['excess_share_of_limit']:+.2f} %"

    by = {(r["source"], r["observer_gain"]): r for r in study}
    gains = sorted({r["observer_gain"] for r in study})
    rows = []
    for src in ("fusion", "residual"):
        cells = [f"K_I = {k:g} s⁻¹: {pct(by[(src, k)])}" for k in gains if (src, k) in by]
        rows.append(f"{src}: " + ", ".join(cells))
    res = [by[("residual", k)] for k in gains if ("residual", k) in by]
    shrinks = all(a["max_violation"] >= b["max_violation"] - 1e-6 for a, b in itertools.pairwise(res))
    lag = (
        "the excess shrinks as K_I grows (the observer's time constant 1/K_I: "
        + ", ".join(f"{1e3 * r['observer_time_constant_s']:g} ms" for r in res)
        + ")"
        if shrinks
        else "the excess does not shrink monotonically with K_I"
    )
    both = [k for k in gains if ("fusion", k) in by and ("residual", k) in by]
    fusion_less = [k for k in both if by[("fusion", k)]["max_violation"] < by[("residual", k)]["max_violation"]]
    fusion = (
        f"With fusion the excess is smaller than with the observer alone at {len(fusion_less)} of {len(both)} K_I."
        if both
        else ""
    )
    default = by.get(("fusion", table_gain))
    return (
        "<li>Velocity-limit overshoot with feedback (λ = "
        + ", ".join(f"{x:g}" for x in sorted({r["lambda"] for r in study}))
        + ", M = "
        + ", ".join(f"{x:g}" for x in sorted({r["M"] for r in study}))
        + f"), peak q̇ above the lowered limit as a share of it — {'; '.join(rows)}. With the observer alone {lag}. "
        + fusion
        + f" The table's runs use K_I = {table_gain:g} s⁻¹ (the paper gives none)"
        + (f": {pct(default)} with fusion." if default else ".")
        + "</li>"
    )


def _high_lambda_rings_more(delayed: list[dict]) -> bool:
    """True when, with the torque delayed, the highest λ has more velocity reversals than the lowest."""
    if len(delayed) < 2:
        return False
    by_lambda = sorted(delayed, key=lambda r: r["lambda"])
    return by_lambda[-1]["oscillations"] > by_lambda[0]["oscillations"]


def findings(runs: list[dict], derived: dict | None = None) -> list[str]:
    """The paper's claims checked against our runs, as HTML list items with numbers; the numbers they
    print that no run holds (shares, counts) go into `derived` (limit_drop.json keeps them)."""
    derived = {} if derived is None else derived
    joint = runs[0].get("falling_joint", 4) if runs else 4  # runs recorded before the joint was: joint 4
    items = []
    fb = [r for r in runs if r["feedback"] and r["form"] == "proposed"]
    nofb = [r for r in runs if not r["feedback"]]
    pos_fb = [r for r in fb if r["limit"] == "position"]
    vel_fb = [r for r in fb if r["limit"] == "velocity"]
    if pos_fb:
        worst = max(r["max_violation"] for r in pos_fb)
        worst_ds = max(r["overshoot_beyond_ds"] for r in pos_fb)
        items.append(
            verdict(
                worst <= 0.0,
                f"with feedback the proposed damper keeps joint {joint} inside its position limit: largest "
                f"excursion {worst * 1e3:+.2f} mrad relative to the limit, {worst_ds * 1e3:+.2f} mrad relative "
                f"to q⁺ − d_s (paper Figs. 2–3: inside).",
            )
        )
    if vel_fb:
        worst_v = max(r["max_violation"] for r in vel_fb)
        derived["velocity_excess_pct_of_limit"] = 100 * worst_v / vel_fb[0]["dq_limit"]
        derived["velocity_excess_accepted_pct"] = 2.0
        items.append(
            verdict(
                worst_v <= 0.02 * vel_fb[0]["dq_limit"],
                f"with feedback the lowered velocity limit holds: largest excess {worst_v * 1e3:+.1f} mrad/s "
                f"({100 * worst_v / vel_fb[0]['dq_limit']:+.1f} % of the limit; 2 % accepted).",
            )
        )
    lam_runs = {r["lambda"]: r for r in pos_fb if r["M"] == 3.0}
    if all(lam in lam_runs for lam in LAMBDAS_AT_M3):
        hi = max(lam_runs[300.0]["oscillations"], lam_runs[500.0]["oscillations"])
        lo = max(lam_runs[70.0]["oscillations"], lam_runs[100.0]["oscillations"])
        no_delay = all(lam_runs[lam].get("torque_delay_ms", 0.0) == 0.0 for lam in LAMBDAS_AT_M3)
        items.append(
            verdict(
                hi > lo,
                f"λ = {LAMBDAS_AT_M3[-2]:g}–{LAMBDAS_AT_M3[-1]:g} oscillates more than "
                f"λ = {LAMBDAS_AT_M3[0]:g}–{LAMBDAS_AT_M3[1]:g} (velocity reversals at M = 3: "
                + ", ".join(f"λ={lam:g}: {lam_runs[lam]['oscillations']}" for lam in LAMBDAS_AT_M3)
                + ")."
                + (
                    " Every one of these runs had its torque applied in the step it was computed (the latency check "
                    "below delays it)."
                    if no_delay
                    else ""
                ),
            )
        )
    m_runs = {r["M"]: r for r in pos_fb if r["lambda"] == 100.0}
    if all(M in m_runs for M in MS_AT_L100):
        late = min(m_runs.values(), key=lambda r: r["brake_onset_margin"])
        hard = max(m_runs.values(), key=lambda r: r["peak_deceleration"])
        strong = max(m_runs.values(), key=lambda r: r["peak_torque"])
        items.append(
            verdict(
                late["M"] == 1.5 and hard["M"] == 1.5 and strong["M"] == 1.5,
                "M near 1 brakes late and hard: braking (speed below 90 % of its peak) starts at "
                + ", ".join(f"M={M:g}: {m_runs[M]['brake_onset_margin']:.3f} rad" for M in MS_AT_L100)
                + " from the limit; peak deceleration "
                + ", ".join(f"M={M:g}: {m_runs[M]['peak_deceleration']:.1f} rad/s²" for M in MS_AT_L100)
                + f"; peak joint-{joint} torque "
                + ", ".join(f"M={M:g}: {m_runs[M]['peak_torque']:.1f} N m" for M in MS_AT_L100)
                + ".",
            )
        )
    if nofb:
        pairs = []
        for r in nofb:
            twin = next(
                (
                    f
                    for f in runs
                    if f["feedback"]
                    and f["form"] == r["form"]
                    and f["lambda"] == r["lambda"]
                    and f["M"] == r["M"]
                    and f["limit"] == r["limit"]
                ),
                None,
            )
            if twin is not None:
                pairs.append((r, twin))

        def crossed(r: dict) -> bool:  # the constraint: q⁺ − d_s (position) or q̇⁺ (velocity)
            return r["overshoot_beyond_ds"] > 0 if r["limit"] == "position" else r["max_violation"] > 0

        over = [r for r, _ in pairs if crossed(r)]
        beyond = [r for r, _ in pairs if r["limit"] == "position" and r["max_violation"] > 0]
        n_pos = sum(r["limit"] == "position" for r, _ in pairs)
        more = [r for r, f in pairs if r["overshoot_beyond_ds"] > f["overshoot_beyond_ds"]]
        derived["without_feedback"] = {
            "pairs": len(pairs),
            "crossed": len(over),
            "further_than_with_feedback": len(more),
            "position_runs": n_pos,
            "beyond_hard_limit": len(beyond),
        }
        items.append(
            verdict(
                len(over) == len(pairs),
                f"without feedback every setting overshoots its constraint: {len(over)}/{len(pairs)} runs cross it "
                f"(position: q > q⁺ − d_s; velocity: q̇ > q̇⁺), {len(more)}/{len(pairs)} go further than the same "
                f"setting with feedback; {len(beyond)}/{n_pos} position runs also cross the hard limit q⁺ "
                "(paper Fig. 4: all overshoot).",
            )
        )
    return items


def other_joints_item(runs: list[dict], derived: dict) -> str:
    """How far the other joints moved with and without feedback, naming the joint that moved most
    without it (from each run's per-joint record), and whether the runs without feedback had stopped."""
    on = [r for r in runs if r["feedback"]]
    off = [r for r in runs if not r["feedback"]]
    if not on or not off:
        return ""
    j = runs[0]["falling_joint"]
    per_joint = np.max([r["other_joints_drift_per_joint"] for r in off], axis=0)
    k = int(np.argmax(per_joint))
    derived["most_moved_joint_without_feedback"] = k + 1
    moving = sum(r["stop"] == "done" for r in off)
    return (
        f"<li>Posture of the other joints: with feedback they move at most "
        f"{max(r['other_joints_drift'] for r in on) * 1e3:.1f} mrad; without feedback up to "
        f"{max(r['other_joints_drift'] for r in off):.2f} rad, most at joint {k + 1} ({per_joint[k]:.2f} rad). "
        f"Velocity reversals of joint {j} without feedback: "
        + ", ".join(f"{_label(r)}: {r['oscillations']}" for r in off)
        + (
            f"; {moving} of these runs are still moving at the cap, so their reversals count a motion that had "
            "not ended."
            if moving
            else "; every one of these runs had stopped before the cap."
        )
        + "</li>"
    )


def setup_html(doc: dict, runs: list[dict]) -> str:
    """The setup paragraph from limit_drop.json: robot, posture, payload, the posture task, the
    estimate and the limits as the runs had them (their recorded configuration)."""
    cfg = doc["config"]
    p = cfg["params"]
    posture, est = p["posture_task"], p["estimator"]
    payload = p.get("payload", {}).get("mass_kg", doc["payload_kg"])
    j = doc["falling_joint"]
    pos = next((r for r in runs if r["limit"] == "position"), None)
    vel = next((r for r in runs if r["limit"] == "velocity"), None)
    classic = next((r for r in runs if r["form"] == "classic"), None)
    crit = doc["criteria"]
    return (
        f"<p>{html.escape(doc['robot'])} at <code>{doc['posture']}</code>, {payload:g} kg at the TCP in the "
        f"simulation only, posture task only (K_p = {posture['stiffness']:g}, K_d = {posture['damping']:g}), "
        f"Γ₀ = {posture['compliance']}, external torque from the momentum observer"
        + (" fused with the F/T sensor" if est["source"] == "fusion" else f" ({html.escape(est['source'])})")
        + f" (K_I = {est['observer_gain']:g} s⁻¹), each drop until joint {j} has stopped (at most "
        f"{crit['duration_cap_s']:g} s), control period {cfg['timestep_s'] * 1e3:g} ms. The F/T model reads the "
        "payload's weight and its inertial force m(g − a)."
        + (
            f" Case (a): joint {j} falls toward its {'upper' if pos['direction'] > 0 else 'lower'} position limit"
            f" q⁺ = {pos['q_limit']:.2f} rad (q⁺ names that limit below; d_s = {pos['d_s'] * 1e3:.1f} mrad)."
            if pos
            else ""
        )
        + (f" Case (b): joint-{j} velocity limit lowered to {vel['dq_limit']:g} rad/s." if vel else "")
        + (
            f" The classic δt form uses d_i = {p['damper']['influence_fraction']:.0%} of the range and ξ from [C23] "
            f"with λ = {classic['lambda']:g}, M = {classic['M']:g}."
            if classic
            else ""
        )
        + " Violation: positive = beyond the limit. "
        f"Oscillations: velocity reversals larger than {crit['velocity_hysteresis_rad_s']} rad/s. "
        f"Sweep wall time {doc['elapsed_s']:.1f} s.</p>"
    )


def run(args: argparse.Namespace) -> int:
    """Run the sweep, write limit_drop.json, figures and report.html."""
    if not args.duration > 0:
        print("limit-drop: --duration must be positive")
        return 2
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    settings = tuple(parse_settings(getattr(args, "set", [])))
    # (form, λ, M, feedback, limit, duration, K_I, delay steps, source, until stopped, --set parameters)
    jobs_args = [
        (form, lam, M, fb, limit, args.duration, None, 0, None, True, settings)
        for limit in ("position", "velocity")
        for fb in (True, False)
        for form, lam, M in variants(args.quick)
    ]
    t0 = time.perf_counter()
    # velocity-limit overshoot with feedback, per observer gain K_I, for fusion [C26] and the
    # observer alone [C25]: how much of the excess is the observer's lag
    extra_args = (
        []
        if args.quick
        else [
            ("proposed", 100.0, 2.0, True, "velocity", args.duration, k, 0, src, True, settings)
            for src in ("fusion", "residual")
            for k in OBSERVER_GAINS
        ]
    )
    # latency check: the λ sweep at M = 3 with the torque applied DELAY_STEPS periods late
    delay_args = (
        []
        if args.quick
        else [
            ("proposed", lam, 3.0, True, "position", args.duration, None, DELAY_STEPS, None, True, settings)
            for lam in LAMBDAS_AT_M3
        ]
    )
    all_runs = run_parallel(run_drop, jobs_args + extra_args + delay_args, args.jobs, "limit-drop")
    n0, n1 = len(jobs_args), len(jobs_args) + len(extra_args)
    runs, extra, delayed = all_runs[:n0], all_runs[n0:n1], all_runs[n1:]
    for r in extra:
        r["excess_share_of_limit"] = r["max_violation"] / r["dq_limit"]
        r["observer_time_constant_s"] = 1.0 / r["observer_gain"]
    elapsed = time.perf_counter() - t0
    keys = (
        "form",
        "lambda",
        "M",
        "feedback",
        "limit",
        "max_violation",
        "overshoot_beyond_ds",
        "oscillations",
        "stop",
        "duration_s",
    )
    extra_keys = (
        "peak_torque",
        "peak_velocity",
        "brake_onset_margin",
        "peak_deceleration",
        "other_joints_drift",
        "other_joints_drift_per_joint",
        "q_limit",
        "d_s",
        "dq_limit",
        "direction",
    )
    summary = [{k: r[k] for k in (*keys, *extra_keys)} for r in runs]
    delay_summary = [{k: r[k] for k in (*keys, *extra_keys, "torque_delay_ms")} for r in delayed]
    study_keys = (
        "source",
        "observer_gain",
        "observer_time_constant_s",
        "lambda",
        "M",
        "max_violation",
        "excess_share_of_limit",
        "peak_velocity",
        "dq_limit",
        "stop",
        "duration_s",
    )
    derived: dict = {}
    items = findings(runs, derived)
    doc = {
        "runs": summary,
        "latency_check": delay_summary,
        "velocity_overshoot_per_K_I": [{k: r[k] for k in study_keys} for r in extra],
        "elapsed_s": elapsed,
        "robot": runs[0]["robot"],
        "falling_joint": runs[0]["falling_joint"],
        "posture": "l_shape",  # the scenario's initial posture (`LimitDropScenario.initial_q`)
        "payload_kg": PAYLOAD_KG,
        "config": runs[0]["config"],  # the first drop's; the runs differ only in the damper, feedback, K_I, delay
        "criteria": {
            "duration_cap_s": args.duration,
            "velocity_hysteresis_rad_s": REVERSAL_HYSTERESIS_RAD_S,
            "stop_speed_rad_s": STOP_SPEED,
            "stop_hold_s": STOP_HOLD_S,
            "fallen_rad": FALLEN_RAD,
            "delay_steps": DELAY_STEPS,
        },
        "derived": derived,
        "command": command_line(args),
        "code": code_record(),
    }
    write_json(out / "limit_drop.json", doc)
    write_json(out / "limit_drop_traces.json", runs)
    figures = []
    for limit in ("position", "velocity"):
        for fb, sweep, key, fig in ((True, "lambda", "lambda", 2), (True, "M", "M", 3), (False, "M", "M", 4)):
            sel = _select(runs, limit=limit, feedback=fb, sweep=sweep)
            if not sel:
                continue
            name = f"fig{fig}_{limit}.png"
            fixed = "M = 3" if sweep == "lambda" else "λ = 100"
            title = f"Fig. {fig} style: {limit} limit, {fixed}, feedback {'on' if fb else 'off'}"
            _phase_figure(sel, title, out / name, key)
            figures.append((name, title))
    rows = [
        [
            r["limit"],
            r["form"],
            r["lambda"],
            r["M"],
            "on" if r["feedback"] else "off",
            r["max_violation"],
            r["overshoot_beyond_ds"],
            r["oscillations"],
            r["peak_torque"],
            r["brake_onset_margin"],
            {"until": "stopped", "done": "moving"}.get(r["stop"], "halted") + f" at {r['duration_s']:.2f} s",
        ]
        for r in runs
    ]
    j = runs[0]["falling_joint"]
    header = [
        "limit",
        "form",
        "λ",
        "M",
        "feedback",
        "max violation (rad | rad/s)",
        "beyond q⁺−d_s (rad)",
        "oscillations",
        f"peak τ{j} (N m)",
        "braking starts (rad from q⁺)",
        "end",
    ]
    print(f"{'limit':9s} {'form':9s} {'λ':>5s} {'M':>4s} {'fb':>3s} {'violation':>10s} {'beyond_ds':>10s} osc peakτ")
    for r in runs:
        print(
            f"{r['limit']:9s} {r['form']:9s} {r['lambda']:5.0f} {r['M']:4.1f} {'on' if r['feedback'] else 'off':>3s} "
            f"{r['max_violation']:+10.4f} {r['overshoot_beyond_ds']:+10.4f} {r['oscillations']:3d} "
            f"{r['peak_torque']:5.1f}"
        )
    drift_item = other_joints_item(runs, derived)
    if drift_item:
        items.append(drift_item)
    if delayed:
        items.append(
            "<li>Latency check (not in the paper's setup): with the torque applied "
            + ", ".join(f"{x:g}" for x in sorted({r["torque_delay_ms"] for r in delayed}))
            + " ms late, the same λ sweep (M = 3, feedback on) gives velocity reversals "
            + ", ".join(f"λ={r['lambda']:g}: {r['oscillations']}" for r in delayed)
            + "; largest position excursion "
            + ", ".join(f"λ={r['lambda']:g}: {r['max_violation'] * 1e3:+.1f} mrad" for r in delayed)
            + "."
            + (
                " With the delay the highest λ reverses more often than the lowest."
                if _high_lambda_rings_more(delayed)
                else ""
            )
            + "</li>"
        )
    if extra:
        items.append(velocity_overshoot_item(extra, runs[0]["observer_gain"]))
    moving = [r for r in runs + extra + delayed if r["stop"] != "until"]
    derived["still_moving_at_cap"] = len(moving)
    derived["runs_in_all"] = len(runs) + len(extra) + len(delayed)
    items.append(
        f"<li>Run length: each drop runs until joint {j} has stopped (|q̇{j}| &lt; {STOP_SPEED} rad/s for "
        f"{STOP_HOLD_S} s after falling ≥ {FALLEN_RAD} rad), at most {args.duration:g} s; the runs took "
        f"{min(r['duration_s'] for r in runs):.2f}–{max(r['duration_s'] for r in runs):.2f} s; "
        f"{len(moving)} of {len(runs) + len(extra) + len(delayed)} were still moving at the cap"
        + (": " + ", ".join(_label(r) for r in moving) if moving else "")
        + ".</li>"
    )
    write_json(out / "limit_drop.json", doc)  # with the counts the items above added to `derived`
    setup = setup_html(doc, runs)
    figs_html = "".join(f"<figure><img src='{n}'><figcaption>{t}</figcaption></figure>" for n, t in figures)
    write_report(
        out,
        "Joint-limit drop [C] §IV-B–C",
        [
            ("Setup", setup),
            ("What the paper found and what we get", "<ul>" + "".join(items) + "</ul>"),
            ("All runs", html_table(header, rows)),
            ("Phase diagrams (Figs. 2–4 style)", figs_html),
        ],
        args,
    )
    if args.json:
        import json

        print(json.dumps(summary, indent=2))
    print(f"wrote {out / 'limit_drop.json'} and {out / 'report.html'} ({elapsed:.1f} s)")
    return 0
