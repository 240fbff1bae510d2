"""Figures and the HTML report of the polish experiment ([T] Figs. 6, 8, 9, Table III).

Every number and every "matches / does not match" sentence is computed from the run's JSON; a
sentence whose premise does not hold is not printed.
"""

from __future__ import annotations

import html
import json
from pathlib import Path

import numpy as np

from app.core.provenance import code_text
from app.headless.experiments.polish_rows import OBJECTIVE_NAMES as NAMES  # row names by objective key
from app.scenarios import polish_plan as plan_module
from app.scenarios import polish_stroke as stroke_module
from app.scenarios.polish import PolishScenario
from app.scenarios.polish_stroke import N_SEGMENTS
from app.scenarios.verdict import band_facts

COLORS = {
    "j": "black",
    "f": "tab:green",
    "a": "tab:red",
    "d": "tab:blue",
    "planned": "tab:purple",
    "planned_a": "tab:orange",
}
MATCH_REL = 0.25  # "matches the paper": within 25 % of its value or 2 sd of our seeds, whichever is larger
MATCH_SD = 2.0


def _v_eps_head(v_eps: list[dict]) -> str:
    """The friction-regularisation table's heading, with the hold's μ and length as the check ran them."""
    from app.headless.experiments.polish_v_eps import V_EPS_HOLD_S, V_EPS_MU

    mu = v_eps[0].get("mu", V_EPS_MU) if v_eps else V_EPS_MU
    hold = v_eps[0].get("hold_s", V_EPS_HOLD_S) if v_eps else V_EPS_HOLD_S
    return (
        f"<h2>Friction regularisation (W_j hold, μ = {mu:g}, {hold:g} s)</h2><table><tr><th>v_ε (mm/s)</th>"
        "<th>contact force STD (N)</th><th>contact lost (ms)</th></tr>"
    )


SCAN_STEP_DEG = 1.0  # the swivel scan's spacing along the self-motion loop
PAPER_STABLE_MU1 = {"j": False, "f": False, "a": True, "d": True}  # [T] Fig. 9: W_j/W_f oscillate at μ = 1


# ---- swivel scan at the start pose (DESIGN §8) -----------------------------------------------------
def scan_at_start(armature_scale: float = 1.0, armature: list[float] | None = None, unit_length_m: float = 0.0) -> dict:
    """W_f, W_a, W_d along the self-motion loop at the polish start pose (the run's arm: the Rizon 4s
    unless --robot/--urdf chose another), the basin each gradient flow from the Fig. 6a start
    reaches, the W_a ridge between the basins, and P_d·f̂ [T10] for the stretching friction
    direction along the loop and at each W_a basin (does a basin decouple that friction?).
    `armature`: the controller model's armature the runs had (kg m², their record), × armature_scale;
    None: the robot file's. `unit_length_m` > 0: W_f, W_a, W_d with that characteristic length
    (`control.coupling.task_scale`, m_c = 1 kg); 0: SI units."""
    import robots
    from control.coupling import POLISH_SUBSPACES, flow_minimum, swivel_scan, task_scale, terms_of
    from control.model import RobotModel

    robot = robots.load(robots.chosen("rizon4s"))
    scenario = PolishScenario(armature_scale=armature_scale)
    scenario.prepare_robot(robot)
    nominal = robot.armature if armature is None else np.asarray(armature, dtype=float)
    robot.set_armature(scenario.armature(nominal))
    model = RobotModel(robot.model)
    q0 = scenario.initial_q(robot)
    scan = swivel_scan(
        model, q0, POLISH_SUBSPACES, robot.q_lower, robot.q_upper, step_rad=np.deg2rad(SCAN_STEP_DEG),
        scale=task_scale(unit_length_m),
    )  # fmt: skip
    psi = (np.rad2deg(scan.swivel_rad) + 180.0) % 360.0 - 180.0
    order = np.argsort(psi)
    stretch = stroke_module.friction_direction(1.5 * stroke_module.SEGMENT_DURATION_S)  # S2: +X motion
    pd_stretch = np.array(
        [float(terms_of(model.compute(q, np.zeros(len(q))), POLISH_SUBSPACES).P_d[0, :2] @ stretch) for q in scan.q]
    )  # [T10] the normal force disturbance per unit stretching friction
    data = {
        "swivel_deg": psi[order],
        "W_f": scan.W_f[order],
        "W_a": scan.W_a[order],
        "W_d": scan.W_d[order],
        "Pd_fhat_stretch": pd_stretch[order],
        "feasible": scan.within_limits[order],
    }
    summary: dict = {
        "robot": robot.name,
        "closed_loop": bool(scan.closed),
        "points": len(psi),
        "armature_scale": armature_scale,
        "armature_model_kg_m2": [float(x) for x in robot.armature],
    }
    start = int(np.argmin(np.abs(data["swivel_deg"])))
    for w in ("W_f", "W_a", "W_d"):
        vals = np.where(data["feasible"], data[w], np.inf)
        i = int(np.argmin(vals))
        reached = flow_minimum(data[w], data["feasible"], start)
        summary[w] = {
            "at_start": float(data[w][start]),
            "feasible_min": float(vals[i]),
            "feasible_min_swivel_deg": float(data["swivel_deg"][i]),
            "feasible_max": float(np.max(np.where(data["feasible"], data[w], -np.inf))),
            "local_minima_swivel_deg": _local_minima(data["swivel_deg"], data[w], data["feasible"]),
            "flow_from_start_deg": float(data["swivel_deg"][reached]),
            "flow_from_start_value": float(data[w][reached]),
        }
    summary["W_a"]["ridge_swivel_deg"] = _ridge(data, start, "W_a")
    summary["W_a"]["basins"] = [
        {
            "swivel_deg": round(float(data["swivel_deg"][i]), 1),
            "W_a": float(data["W_a"][i]),
            "Pd_fhat_stretch": float(data["Pd_fhat_stretch"][i]),
        }
        for i in _local_minimum_indices(data["W_a"], data["feasible"])
    ]
    feasible_pd = np.where(data["feasible"], np.abs(data["Pd_fhat_stretch"]), np.inf)
    i = int(np.argmin(feasible_pd))
    summary["Pd_fhat_stretch"] = {
        "at_start": float(data["Pd_fhat_stretch"][start]),
        "feasible_min_abs": float(feasible_pd[i]),
        "feasible_min_abs_swivel_deg": float(data["swivel_deg"][i]),
        "feasible_max_abs": float(np.max(np.where(data["feasible"], np.abs(data["Pd_fhat_stretch"]), -np.inf))),
    }
    summary["W_d"]["ridge_swivel_deg"] = _ridge(data, start, "W_d")
    inverted = int(np.argmax(np.abs(data["swivel_deg"])))  # the elbow turned over: the swivel nearest ±180°
    summary["inverted"] = {
        "swivel_deg": float(data["swivel_deg"][inverted]),
        "feasible": bool(data["feasible"][inverted]),
        "infeasible_within_deg": _infeasible_span(data),
        **{w: float(data[w][inverted]) for w in ("W_f", "W_a", "W_d")},
    }
    return {"data": data, "summary": summary}


def _local_minimum_indices(w: np.ndarray, feas: np.ndarray) -> list[int]:
    return [i for i in range(len(w)) if feas[i] and w[i] < w[i - 1] and w[i] < w[(i + 1) % len(w)]]


def _infeasible_span(data: dict) -> float:
    """How far from ±180° (degrees) the run of swivels outside the joint limits around the inverted
    elbow reaches (0 when the inverted elbow itself is within the limits)."""
    psi, feas = data["swivel_deg"], data["feasible"]
    off = 180.0 - np.abs(psi)  # 0 at the inverted elbow
    order = np.argsort(off)
    span = 0.0
    for i in order:
        if feas[i]:
            break
        span = float(off[i])
    return span


def _ridge(data: dict, start: int, w: str) -> float | None:
    """The swivel nearest the start (on either side) from which the flow reaches another basin."""
    from control.coupling import flow_minimum

    home = flow_minimum(data[w], data["feasible"], start)
    k = len(data[w])
    for off in range(1, k // 2):
        for i in (start - off, start + off):
            j = i % k
            if data["feasible"][j] and abs(flow_minimum(data[w], data["feasible"], j) - home) > 2:
                prev = (j + (1 if i < start else -1)) % k
                return float(0.5 * (data["swivel_deg"][j] + data["swivel_deg"][prev]))
    return None


def _local_minima(psi: np.ndarray, w: np.ndarray, feas: np.ndarray) -> list[float]:
    return [
        round(float(psi[i]), 1) for i in range(len(w)) if feas[i] and w[i] < w[i - 1] and w[i] < w[(i + 1) % len(w)]
    ]


def armature_basins(scales: tuple[float, ...], armature: list[float] | None = None) -> list[dict]:
    """Per armature scale: the swivel each coupling objective's flow reaches from the Fig. 6a start
    (from the swivel scan of `armature` × scale) and the W_a ridge."""
    out = []
    for scale in scales:
        s = scan_at_start(scale, armature)["summary"]
        out.append(
            {
                "armature_scale": scale,
                **{f"{w}_flow_deg": s[w]["flow_from_start_deg"] for w in ("W_f", "W_a", "W_d")},
                "W_a_ridge_deg": s["W_a"]["ridge_swivel_deg"],
            }
        )
    return out


UNIT_LENGTHS_M = (0.05, 0.1, 0.2, 0.3, 0.5, 1.0, 2.0)  # characteristic lengths of the W_d table


def w_d_by_length(
    lengths_m: tuple[float, ...], armature_scale: float = 1.0, armature: list[float] | None = None
) -> list[dict]:
    """Per characteristic length L_c (`control.coupling.task_scale`): W_d's local minima along the
    self-motion loop at the start pose, the feasible minimum, where the flow from the Fig. 6a start
    settles, the W_d ridge, W_d at the turned-over elbow, and the share of W_d at the start that the
    rotational columns of P_d hold. L_c = 1 m (with m_c = 1 kg) is W_d in SI units."""
    out = []
    for length in lengths_m:
        sc = scan_at_start(armature_scale, armature, unit_length_m=length)
        w, inv = sc["summary"]["W_d"], sc["summary"]["inverted"]
        out.append(
            {
                "unit_length_m": length,
                "local_minima_swivel_deg": w["local_minima_swivel_deg"],
                "feasible_min_swivel_deg": w["feasible_min_swivel_deg"],
                "feasible_min": w["feasible_min"],
                "flow_from_start_deg": w["flow_from_start_deg"],
                "ridge_swivel_deg": w["ridge_swivel_deg"],
                "at_start": w["at_start"],
                "inverted_swivel_deg": inv["swivel_deg"],
                "inverted_feasible": inv["feasible"],
                "inverted": inv["W_d"],
                "feasible_max": w["feasible_max"],
            }
        )
    return out


def w_d_by_length_html(rows: list[dict]) -> str:
    """The W_d-by-characteristic-length table of the report."""
    if not rows:
        return ""
    body = "".join(
        f"<tr><td>{r['unit_length_m']:g}</td><td>{', '.join(f'{x:+.0f}°' for x in r['local_minima_swivel_deg'])}</td>"
        f"<td>{_deg(r['feasible_min_swivel_deg'])}° ({r['feasible_min']:.3g})</td>"
        f"<td>{_deg(r['flow_from_start_deg'])}°</td><td>{_fmt(r['ridge_swivel_deg'], 0)}°</td>"
        f"<td>{r['at_start']:.3g}</td><td>{r['inverted']:.3g} ({_deg(r['inverted_swivel_deg'])}°"
        f"{'' if r['inverted_feasible'] else ', outside the limits'})</td><td>{r['feasible_max']:.3g}</td></tr>"
        for r in rows
    )
    return (
        "<h2>W_d's minima against the characteristic length</h2><p>W_d in task coordinates √m_c [p; L_c r] "
        "(<code>--set nullspace.unit_length_m=L_c</code>): the rotational columns of P_d weigh L_c², the "
        "translational ones keep their weight, so the row with L_c = 1 m is W_d in SI units. Swivel scan at the "
        "start pose, as in the figure below; the turned-over elbow is the scan's swivel nearest ±180°.</p>"
        "<table><tr><th>L_c (m)</th><th>local minima (feasible)</th><th>feasible minimum (W_d)</th>"
        "<th>flow from the start</th><th>ridge</th><th>W_d at the start</th><th>W_d at the turned-over elbow</th>"
        f"<th>feasible maximum</th></tr>{body}</table>"
    )


# ---- figures ------------------------------------------------------------------------------------
def readable_log_ticks(ax) -> None:
    """Plain tick labels on a log y axis ("0.64", "20", "1e+04" only beyond 10⁴), not "6.4×10⁻¹"; the
    minor ticks are labelled only when the axis spans less than a decade (else they stay unlabelled)."""
    from matplotlib import ticker

    def plain(y: float, _pos: object = None) -> str:
        return f"{y:.2g}" if 1e-3 <= abs(y) < 1e4 else f"{y:.0e}"

    lo, hi = ax.get_ylim()
    narrow = lo > 0 and hi / lo < 10.0
    ax.yaxis.set_major_formatter(ticker.FuncFormatter(plain))
    ax.yaxis.set_minor_formatter(ticker.FuncFormatter(plain) if narrow else ticker.NullFormatter())


def write_figures(out: Path, results: list[dict], series: list[dict], scan: dict) -> None:
    """fig9_force_error.png, fig8_coupling.png, fig6_postures.png, swivel_scan.png, planned_path.png."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    main = [
        (r, s)
        for r, s in zip(results, series, strict=True)
        if r["group"] == "table" and r["seed"] == 0 and r["shaping"] and abs(r["start_swivel_deg"]) < 1e-6
    ]
    mus = sorted({r["mu"] for r, _ in main})
    if not mus:  # e.g. the armature runs alone: no table figures
        return

    fig, axes = plt.subplots(3, len(mus), figsize=(6 * len(mus), 7.5), squeeze=False, sharex=True)
    for col, mu in enumerate(mus):
        for r, s in main:
            if r["mu"] == mu:
                t, sel = _trajectory_time(s)
                for row, w in enumerate(("W_f", "W_a", "W_d")):
                    axes[row][col].plot(t, s[w][sel], color=COLORS[r["objective"]], lw=1.0, label=NAMES[r["objective"]])
        for row, w in enumerate(("W_f", "W_a", "W_d")):
            _shade_segments(axes[row][col])
            axes[row][col].set_ylabel(w)
            axes[row][col].set_yscale("log")
            readable_log_ticks(axes[row][col])
        axes[0][col].set_title(f"coupling objectives, μ = {mu:g} (seed 0)")
        axes[-1][col].set_xlabel("time since trajectory start (s)")
        axes[0][col].legend(fontsize=7, ncol=3)
    fig.tight_layout()
    fig.savefig(out / "fig8_coupling.png", dpi=110)
    plt.close(fig)

    fig, axes = plt.subplots(len(mus), 1, figsize=(10, 3.2 * len(mus)), squeeze=False, sharex=True)
    for row, mu in enumerate(mus):
        ax = axes[row][0]
        for r, s in main:
            if r["mu"] == mu:
                t, sel = _trajectory_time(s)
                ax.plot(t, s["force_error"][sel], color=COLORS[r["objective"]], lw=0.8, label=NAMES[r["objective"]])
        _shade_segments(ax, labels=True)
        ax.set_ylabel(f"{stroke_module.DESIRED_FORCE_N:g} N − filtered force (N)")
        ax.set_title(f"force error, μ = {mu:g}, seed 0 (grey: stretching segments S2, S4, S6)", pad=14)
        ax.legend(fontsize=7, ncol=3, loc="lower left")
    axes[-1][0].set_xlabel("time since trajectory start (s)")
    fig.tight_layout()
    fig.savefig(out / "fig9_force_error.png", dpi=110)
    plt.close(fig)

    _posture_figure(out, [r for r, _ in main if r["mu"] == mus[0]], plt)

    d = scan["data"]
    fig, axes = plt.subplots(3, 1, figsize=(9, 8), sharex=True)
    for ax, w in zip(axes, ("W_f", "W_a", "W_d"), strict=True):
        ax.plot(d["swivel_deg"], d[w], color="0.3", lw=1.2)
        ax.fill_between(d["swivel_deg"], 0, 1, where=~d["feasible"], transform=ax.get_xaxis_transform(), color="0.85")
        ax.axvline(0.0, color="k", ls="--", lw=0.8)
        for r in results:
            if r["group"] != "table" or r["objective"] not in ("f", "a", "d") or f"W_{r['objective']}" != w:
                continue
            psi = (r["converged_swivel_deg"] + 180.0) % 360.0 - 180.0
            marker = "o" if abs(r["start_swivel_deg"]) < 1e-6 else "^"
            ax.plot(psi, np.interp(psi, d["swivel_deg"], d[w]), marker, color=COLORS[r["objective"]], ms=6, mfc="none")
        ridge = scan["summary"]["W_a"].get("ridge_swivel_deg")
        if w == "W_a" and ridge is not None:
            ax.axvline(ridge, color="tab:red", ls=":", lw=1.0)
        ax.set_ylabel(w)
        ax.set_yscale("log")
        readable_log_ticks(ax)
    axes[0].set_title("coupling along the self-motion loop at the start pose (grey: outside joint limits)")
    axes[-1].set_xlabel("swivel (deg; 0 = Fig. 6a start; o: converged from 0°, ^: from −30°; dotted: W_a ridge)")
    fig.tight_layout()
    fig.savefig(out / "swivel_scan.png", dpi=110)
    plt.close(fig)

    planned = [  # the table's planned runs (a latency run may stop while held, before its trajectory starts)
        (r, s)
        for r, s in zip(results, series, strict=True)
        if "plan" in r and r["seed"] == 0 and r.get("group", "table") == "table"
    ]
    if planned:
        _plan_figure(out, planned, plt)


def _plan_figure(out: Path, planned: list[tuple[dict, dict]], plt) -> None:
    """Planned and executed swivel against time since the settle start, over the planning cost
    along the trajectory (drawn from the trajectory start the run actually had)."""
    from matplotlib.colors import LogNorm

    import robots
    from control.model import RobotModel

    robot = robots.load(robots.chosen("rizon4s"))
    model = RobotModel(robot.model)
    fig, axes = plt.subplots(len(planned), 1, figsize=(10, 3.6 * len(planned)), squeeze=False)
    for ax, (r, s) in zip(axes[:, 0], planned, strict=True):
        plan = plan_module.planned_path(robot, model, r["start_swivel_deg"], r["plan_cost_kind"])
        start = r["convergence_time_s"]  # trajectory start, s after the settle start
        k = plan.cost_map.shape[0]
        t_traj = start + np.arange(k) * plan_module.PLAN_SAMPLE_S
        C = np.where(np.isfinite(plan.cost_map) & (plan.cost_map > 0), plan.cost_map, np.nan)
        positive = C[np.isfinite(C)]
        norm = LogNorm(vmin=float(np.min(positive)), vmax=float(np.max(positive))) if positive.size else None
        mesh = ax.pcolormesh(t_traj, np.rad2deg(plan.grid_rad), C.T, shading="nearest", cmap="viridis", norm=norm)
        fig.colorbar(mesh, ax=ax, label=f"{r['plan_cost_kind']} cost (log)")
        psi = (np.rad2deg(np.unwrap(plan.swivel_rad)) + 180.0) % 360.0 - 180.0
        transfer = plan.t < 0
        t_plan = np.where(transfer, plan.t + plan.transfer_s, plan.t + start)
        ax.plot(t_plan[transfer], psi[transfer], "k-", lw=2, label="planned (transfer)")
        ax.plot(
            [plan.transfer_s, start], [psi[transfer][-1], psi[~transfer][0]], "k:", lw=1.5, label="hold until converged"
        )
        ax.plot(t_plan[~transfer], psi[~transfer], "w-", lw=2, label="planned (trajectory)")
        sel = s["t"] >= stroke_module.CONTACT_TIME_S
        ax.plot(s["t"][sel] - stroke_module.CONTACT_TIME_S, s["swivel"][sel], "r--", lw=1.2, label="executed")
        ax.set_xlim(0.0, t_traj[-1])
        ax.set_ylabel("swivel (deg)")
        ax.set_title(f"{NAMES[r['objective']]}, μ = {r['mu']:g}, seed {r['seed']}")
        ax.legend(fontsize=7, loc="upper right")
    axes[-1][0].set_xlabel("time since the settle phase began (s)")
    fig.tight_layout()
    fig.savefig(out / "planned_path.png", dpi=110)
    plt.close(fig)


def _trajectory_time(s: dict) -> tuple[np.ndarray, np.ndarray]:
    sel = s["segment"] >= 1
    if not np.any(sel):
        return np.zeros(0), sel
    t = s["t"][sel]
    return t - t[0], sel


def _shade_segments(ax, labels: bool = False) -> None:
    T = stroke_module.SEGMENT_DURATION_S
    for k in range(N_SEGMENTS):
        if k % 2 == 1:
            ax.axvspan(k * T, (k + 1) * T, color="0.9", lw=0)
        if labels:
            ax.text((k + 0.5) * T, 1.0, f"S{k + 1}", transform=ax.get_xaxis_transform(), ha="center", va="bottom")


def _posture_figure(out: Path, runs: list[dict], plt) -> None:
    import pinocchio as pin

    import robots

    robot = robots.load(robots.chosen("rizon4s"))
    model = robot.model
    data = model.createData()

    def chain(q: np.ndarray) -> np.ndarray:
        pin.forwardKinematics(model, data, np.asarray(q))
        pin.updateFramePlacements(model, data)
        pts = [np.zeros(3)] + [data.oMi[j].translation.copy() for j in range(1, model.njoints)]
        pts.append(data.oMf[model.getFrameId("tcp")].translation.copy())
        return np.array(pts)

    fig = plt.figure(figsize=(4.2 * max(len(runs), 1), 4.4))
    for i, r in enumerate(runs):
        ax = fig.add_subplot(1, max(len(runs), 1), i + 1, projection="3d")
        p0, p1 = chain(np.array(r["q_start"])), chain(np.array(r["q_converged"]))
        ax.plot(p0[:, 0], p0[:, 1], p0[:, 2], "-o", color="0.6", ms=3, lw=2, label="start (Fig. 6a)")
        ax.plot(p1[:, 0], p1[:, 1], p1[:, 2], "-o", color=COLORS[r["objective"]], ms=3, lw=2.5, label="converged")
        xx, yy = np.meshgrid([0.3, 0.8], [-0.35, 0.3])
        ax.plot_surface(xx, yy, np.full_like(xx, stroke_module.TABLE_HEIGHT_M), color="tan", alpha=0.3)
        ax.set_xlim(-0.1, 0.8)
        ax.set_ylim(-0.45, 0.45)
        ax.set_zlim(0.0, 0.9)
        ax.view_init(elev=20, azim=-60)
        ax.set_title(f"{NAMES[r['objective']]}: swivel {_deg(r['converged_swivel_deg'])}°", fontsize=10)
        ax.legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    fig.savefig(out / "fig6_postures.png", dpi=110)
    plt.close(fig)


# ---- report ---------------------------------------------------------------------------------------
def _pm(x: dict | None, digits: int = 1) -> str:
    if not x or x.get("mean") is None:
        return "-"
    if x.get("sd") is None:  # one seed: no spread to show
        return _num(x["mean"], digits)
    return f"{_num(x['mean'], digits)} ± {_num(x['sd'], digits)}"


def _code(settings: dict) -> str:
    """The code version the run recorded, in words (`code_text`)."""
    return code_text(settings["code"]) if settings.get("code") else "not recorded"


def _reused(settings: dict) -> str:
    n = settings.get("reused_runs")
    return f", {n} run(s) reused from an interrupted invocation" if n else ""


def _fmt(x, digits: int = 2) -> str:
    return "-" if x is None else _num(x, digits)


def _num(x: float, digits: int = 1, sign: bool = False) -> str:
    """x to `digits` decimals, never "−0" (a value that rounds to zero prints without a sign)."""
    text = f"{x:+.{digits}f}" if sign else f"{x:.{digits}f}"
    return text.lstrip("+-") if float(text) == 0.0 else text


def _deg(x: float) -> str:
    """An angle in whole degrees with its sign ("+12", "-3", "0"; never "-0")."""
    return _num(x, 0, sign=True)


def _common(runs: list[dict], key: str):
    """runs[i][key] when every run has the same value (None when they differ or none has it)."""
    values = [r.get(key) for r in runs]
    if not values or any(v is None or v != values[0] for v in values):
        return None
    return values[0]


def _loop_text(doc: dict) -> str:
    """The simulated loop, contact and F/T sensor as the table's runs had them (from their records)."""
    runs = doc["runs"]
    dt = _common(runs, "timestep_s")
    sensor = _common(runs, "sensor")
    # μ is a column of the table; the rest of the contact is the same for every row or it is said to differ
    contact = _common(
        [{"contact": {k: v for k, v in r.get("contact", {}).items() if k != "mu"} or None} for r in runs], "contact"
    )
    parts = [f"{1.0 / dt:g} Hz" if dt else "control period not recorded"]
    if contact:
        way = "implicitly (backward Euler)" if contact.get("implicit_friction") else "explicitly"
        parts.append(
            f"table contact {contact['stiffness_n_per_m']:,.0f} N/m with Coulomb friction regularised at "
            f"v_ε = {contact['v_eps_m_per_s'] * 1000:g} mm/s and integrated {way}"
        )
    else:
        parts.append("contact settings differ between runs or were not recorded")
    if sensor:
        noise = (
            f"F/T noise {sensor['force_noise_var']:g} N² + {sensor['sine_amplitude_n']:g} N at {sensor['sine_hz']:g} Hz"
            if sensor["noise"]
            else "no F/T noise"
        )
        lp = f"{sensor['cutoff_hz']:g} Hz low-pass" if sensor["cutoff_hz"] > 0 else "no low-pass"
        age = sensor["reading_delay_steps"]
        parts.append(f"{noise}, {lp}, the reading {age} control period(s) old when the controller uses it")
    else:
        parts.append("F/T settings differ between runs or were not recorded")
    delay = _common(runs, "torque_delay_ms")
    if delay is not None:
        parts.append(f"torque applied {delay:g} ms after it is computed")
    return ", ".join(parts)


def _robot_text(doc: dict) -> str:
    """The arm the table's runs were made on (their records; the settings' for runs that recorded none)."""
    names = sorted({str(r["robot"]) for r in doc["runs"] if r.get("robot")})
    return ", ".join(names) if names else str(doc["settings"].get("robot", "robot not recorded"))


def _gains_text(doc: dict) -> str:
    """The force-loop gains the table's runs had (their recorded configuration), or that they differ."""
    found = [((r.get("config") or {}).get("params") or {}).get("motion_force") for r in doc["runs"]]
    groups: list[dict] = [g for g in found if g is not None]
    if not groups or len(groups) < len(found):
        return "force gains not recorded"
    keys = ("force_kp", "force_kd", "force_ki")
    if any(tuple(g[k] for k in keys) != tuple(groups[0][k] for k in keys) for g in groups):
        return "force gains differ between runs"
    g = groups[0]
    return f"force gains K_f^p = {g['force_kp']:g}, K_f^d = {g['force_kd']:g} N s/m, K_f^i = {g['force_ki']:g}"


def armature_text(doc: dict) -> str:
    """The armature of the controller's model and of the simulated arm as the table's ×1 runs had it
    (their recorded configuration, kg m² per joint)."""
    base = [r for r in doc["runs"] if (r.get("config") or {}).get("armature_model_kg_m2")]
    if not base:
        return "The runs did not record their armature."
    cfg = base[0]["config"]
    model, sim = cfg["armature_model_kg_m2"], cfg["armature_simulated_kg_m2"]
    text = (
        f"The {cfg['robot']} armature as the runs' controller model had it: "
        + ", ".join(f"{a:g}" for a in model)
        + " kg m² (joints 1 to "
        + f"{len(model)}; scenario armature scale ×{base[0]['armature_scale']:g})"
    )
    if sim != model:
        text += "; the simulated arm's: " + ", ".join(f"{a:g}" for a in sim) + " kg m²"
    return text + "."


def start_margin_text(doc: dict) -> str:
    """What the table's "margin" column is, from the loop the runs recorded with it, what it leaves out,
    and how its sign and the runs' outcomes compare (named where they differ)."""
    loops = [(r.get("margin_detail") or {}).get("loop") for r in doc["runs"]]
    loop = loops[0] if loops and all(x == loops[0] for x in loops) and loops[0] else None
    parts = (
        f"contact stiffness {loop['stiffness_n_per_m']:g} N/m, K_f^p = {loop['force_kp']:g}, K_f^d, "
        f"K_f^i = {loop['force_ki']:g}, the sensor's {loop['sensor_cutoff_hz']:g} Hz low-pass, the reading "
        f"{loop['sensing_delay_steps']} and the torque {loop['actuation_delay_steps']} control period(s) late, "
        + ("the shaping term BᵀA⁻¹, " if loop["shaping"] else "no shaping term, ")
        + f"friction at up to {loop['speed_m_s']:.3g} m/s"
        if loop
        else "as each run recorded it (the runs' loops differ or were not recorded)"
    )
    text = (
        '"margin" is K_f^d minus the critical K_f^d of the force loop linearised at one posture, the trajectory '
        f"start ({parts}; worst over both friction directions and the speeds of a segment). It leaves out how "
        "the posture moves along the strokes, the sensor noise and sinusoid, and contact loss itself (the "
        "linearised contact never opens): negative says a small disturbance grows at the start posture, not that "
        'the run loses contact. "stable": the one verdict over the six segments: ' + _verdict_text(_runs_criterion(doc))
    )
    pairs = [(r, r["margin"] is not None and r["margin"] > 0) for r in doc["runs"]]
    differ = [r for r, positive in pairs if positive != bool(r["stable"])]
    if pairs:
        text += f" The margin's sign and the outcome agree in {len(pairs) - len(differ)} of {len(pairs)} runs" + (
            "; they differ for "
            + ", ".join(
                f"{r['row']} μ = {r['mu']:g} seed {r['seed']} (margin "
                + ("none" if r["margin"] is None else _num(r["margin"], 0, sign=True))
                + f", {r.get('verdict') or ('stable' if r['stable'] else 'not stable')})"
                for r in differ
            )
            + ", so the start-pose margin is no prediction of contact loss in this run."
            if differ
            else "."
        )
    return text


def latency_html(doc: dict) -> str:
    """The latency table: per row, the smallest F/T reading age and torque delay at which the run
    is not stable by the one verdict (`app.scenarios.verdict`), and each delay's worst stroke band RMS
    over the oscillation threshold (bold: not stable), with the contact it lost."""
    lat = doc.get("latency")
    if not lat or not lat["rows"]:
        return ""
    sensing = sorted({c["reading_delay_steps"] for e in lat["rows"] for c in e["cells"] if c["torque_delay_ms"] == 0})
    torque = sorted({c["torque_delay_ms"] for e in lat["rows"] for c in e["cells"] if c["reading_delay_steps"] == 0})
    both = sorted(
        {
            (c["reading_delay_steps"], c["torque_delay_ms"])
            for e in lat["rows"]
            for c in e["cells"]
            if c["reading_delay_steps"] > 0 and c["torque_delay_ms"] > 0
        }
    )

    def cell(e: dict, ds: int, da: float) -> str:
        c = next((x for x in e["cells"] if x["reading_delay_steps"] == ds and x["torque_delay_ms"] == da), None)
        if c is None:
            return "<td>-</td>"
        ratio = "-" if c.get("band_ratio") is None else f"{c['band_ratio']:.1f}×"
        lost = f", {c['contact_lost_ms']} ms lost" if c["contact_lost_ms"] else ""
        text = f"{ratio}{lost}{', diverged' if c['diverged'] else ''}"
        if c.get("held"):  # stopped while held (the settle phase): no strokes run
            std = "" if c.get("held_band_rms_n") is None else f", {c['held_band_rms_n']:.2f} N"
            at = "" if c.get("held_swivel_deg") is None else f" at {_deg(c['held_swivel_deg'])}°"
            text = f"held{at}: {c['held']}{std}"
        elif c.get("converged") is False:
            text += ", settle not converged"
        return f"<td><b>{text}</b></td>" if c["oscillates"] else f"<td>{text}</td>"

    def first(x, unit: str, tried: list) -> str:
        return f"{x:g} {unit}" if x is not None else (f"none up to {max(tried):g} {unit}" if tried else "-")

    head = "".join(f"<th>F/T {d} period(s)</th>" for d in sensing) + "".join(f"<th>τ {m:g} ms</th>" for m in torque)
    head += "".join(f"<th>F/T {d} + τ {m:g} ms</th>" for d, m in both)
    body = "".join(
        f"<tr><td>{html.escape(e['row'])}</td><td>{_fmt(e['swivel_deg'], 0)}°</td>"
        f"<td>{first(e['smallest_sensing_delay_steps'], 'period(s)', e['sensing_tried'])}</td>"
        f"<td>{first(e['smallest_torque_delay_ms'], 'ms', e['torque_tried'])}</td>"
        + "".join(cell(e, d, 0.0) for d in sensing)
        + "".join(cell(e, 0, m) for m in torque)
        + "".join(cell(e, d, m) for d, m in both)
        + "</tr>"
        for e in lat["rows"]
    )
    runs = lat.get("runs", [])
    seeds = sorted({r["seed"] for r in runs})
    return f"""<h2>Latency: how much delay each posture tolerates at μ = {lat["mu"]:g}</h2>
<p>Each stage of the loop's latency alone, the other at 0: the F/T reading's age in control periods (torque
delay 0) and the torque delay in ms (reading age 0); then both at once (the last columns);
seed(s) {", ".join(str(x) for x in seeds)}. A run
is <b>not stable</b> by the one verdict: {html.escape(_verdict_text(lat["criterion"]))}
{_held_html(lat["criterion"])}Cells: the worst stroke's band RMS over the oscillation threshold (bold: not stable).</p>
<table><tr><th>row</th><th>swivel (no latency)</th><th>smallest F/T age</th><th>smallest torque delay</th>
{head}</tr>{body}</table>
"""


def _verdict_text(criterion: dict) -> str:
    """The one verdict's definition with the table's threshold and floor."""
    from app.scenarios.verdict import definition_text

    threshold = criterion.get("threshold_n")
    if threshold is None:
        return "diverged or lost contact (runs made before the verdict recorded its band RMS)."
    return definition_text(threshold, criterion)


def _held_html(criterion: dict) -> str:
    """The latency runs' stop rule while the TCP is held, from the table's criterion ("" without it)."""
    if criterion.get("held_window_s") is None:
        return ""
    cap = criterion.get("settle_cap_s")
    return (
        "A run whose posture has stopped flowing while the TCP is still held before the strokes (the swivel "
        f"within {criterion.get('held_still_deg'):.3f}° over the last {criterion['held_window_s']:g} s) and whose "
        "verdict over that time, judged as a stroke, is not stable "
        "stops there with that verdict (cell <i>held</i>, with the swivel it stopped at)"
        + (f"; a settle that has not converged after {cap:g} s starts its strokes and says so. " if cap else ". ")
    )


def _runs_criterion(doc: dict) -> dict:
    """The verdict's threshold and floor as the table's runs recorded them."""
    runs = doc.get("runs", [])
    return {
        "threshold_n": next((r["oscillation_threshold_n"] for r in runs if r.get("oscillation_threshold_n")), None),
        "floor_n": next((r["band_floor_n"] for r in runs if r.get("band_floor_n")), None),
        **{k: next((r[k] for r in runs if r.get(k) is not None), None) for k in band_facts()},
    }


def _grouped_head(lead: str, groups: list[str], columns: tuple[str, ...]) -> str:
    """A two-row table head: the `lead` cells (spanning both rows), then each group's title over its `columns`."""
    titles = "".join(f"<th colspan='{len(columns)}'>{g}</th>" for g in groups)
    return f"<tr>{lead}{titles}</tr><tr>" + "".join(f"<th>{c}</th>" for c in columns) * len(groups) + "</tr>"


def table_iii_html(summary: list[dict]) -> str:
    """[T] Table III's layout: one row per case (W_j, W_f, W_a, W_d, then any other row), MA, PTP and
    STD under each μ; each cell ours (mean ± sd over seeds) with the paper's value under it."""
    mus = sorted({float(e["mu"]) for e in summary})
    cases = list(dict.fromkeys(e["row"] for e in summary))
    by = {(e["row"], float(e["mu"])): e for e in summary}
    head = _grouped_head("<th rowspan='2'>case</th>", [f"μ = {mu:g}" for mu in mus], ("MA", "PTP", "STD"))

    def cells(e: dict | None) -> str:
        if e is None:
            return "<td>-</td>" * 3
        paper = e.get("paper") or ()
        out = []
        for i, key in enumerate(("ma", "ptp", "std")):
            theirs = f"<br><small>paper {paper[i]:.1f}</small>" if len(paper) == 3 else ""
            out.append(f"<td>{_pm(e[key])}{theirs}</td>")
        return "".join(out)

    body = "".join(
        f"<tr><th>{html.escape(case)}</th>" + "".join(cells(by.get((case, mu))) for mu in mus) + "</tr>"
        for case in cases
    )
    return f"<table>{head}{body}</table>"


def _latency_name(e: dict) -> str:
    """A latency of Table III in words: "F/T 1 + τ 0 ms (1 period)"."""
    total = e["total_periods"]
    return (
        f"F/T {e['reading_delay_steps']} + τ {e['torque_delay_ms']:g} ms ({total:g} period{'' if total == 1 else 's'})"
    )


def table_iii_latency_html(doc: dict) -> str:
    """Table III's rows at each total latency the run made them at (`polish.table_at_latencies`): per case
    and μ, MA / PTP / STD (mean ± sd over the seeds) and how many seeds are stable by the one verdict, with
    the contact lost; then, per latency, the cases stable in every seed ("" without such runs)."""
    lat = doc.get("table_latency")
    if not lat or not lat.get("latencies"):
        return ""
    latencies = lat["latencies"]
    cases = list(dict.fromkeys((e["row"], float(e["mu"])) for x in latencies for e in x["summary"]))
    by = {(i, e["row"], float(e["mu"])): e for i, x in enumerate(latencies) for e in x["summary"]}
    head = _grouped_head(
        "<th rowspan='2'>case</th><th rowspan='2'>μ</th>",
        [html.escape(_latency_name(x)) for x in latencies],
        ("MA", "PTP", "STD", "stable"),
    )

    def cells(e: dict | None) -> str:
        if e is None:
            return "<td>-</td>" * 4
        lost = e["contact_lost_ms"]
        lost_text = f", {_pm(lost, 0)} ms lost" if lost.get("mean") else ""
        stable = f"{e['stable']}/{e['n']}{lost_text}"
        out = "".join(f"<td>{_pm(e[k])}</td>" for k in ("ma", "ptp", "std"))
        return out + (f"<td>{stable}</td>" if e["stable"] == e["n"] else f"<td><b>{stable}</b></td>")

    body = "".join(
        f"<tr><th>{html.escape(row)}</th><td>{mu:g}</td>"
        + "".join(cells(by.get((i, row, mu))) for i in range(len(latencies)))
        + "</tr>"
        for row, mu in cases
    )
    items = []
    for x in latencies:
        calm = [f"{e['row']} at μ = {e['mu']:g}" for e in x["summary"] if e["stable"] == e["n"]]
        items.append(
            f"<li>{html.escape(_latency_name(x))}: stable in every seed: "
            + (html.escape(", ".join(calm)) if calm else "none")
            + ".</li>"
        )
    seeds = sorted({r["seed"] for r in lat.get("runs", [])})
    return f"""<h2>Table III at total latencies of one and two control periods</h2>
<p>The paper's four cases again with the loop's latency changed: the F/T reading's age in control periods
plus the torque delay in ms, in all one or two of the runs' control periods; the table above is one of them;
seed(s) {", ".join(str(x) for x in seeds)}. Force error MA / PTP / STD in N (mean ± sd over the seeds);
"stable": the seeds stable by the one verdict (bold where some are not), with the contact lost over the six
segments. {html.escape(_verdict_text(_runs_criterion(doc)))}</p>
<table>{head}{body}</table>
<ul>{"".join(items)}</ul>
"""


def write_report(out: Path, doc: dict) -> None:
    """report.html: Table III (mean ± sd) beside the paper's, the computed findings, figures."""
    s = doc["settings"]
    rows = []
    for e in doc["summary"]:
        rows.append(
            "<tr>"
            f"<td>{html.escape(e['row'])}</td><td>{e['mu']:g}</td><td>{e['stable']}/{e['n']}</td>"
            f"<td>{_pm(e['contact_lost_ms'], 0)}</td>"
            f"<td>{e['converged']}/{e['n']}</td><td>{_pm(e['convergence_time_s'])}</td>"
            f"<td>{_pm(e['converged_swivel_deg'], 0)}°</td>"
            f"<td>{_pm(e['W_f'], 3)}</td><td>{_pm(e['W_a'], 3)}</td><td>{_pm(e['W_d'], 3)}</td>"
            f"<td>{_pm(e['Pf_fhat_stretch'], 3)}</td><td>{_pm(e['Pf_fhat_retract'], 3)}</td>"
            f"<td>{_pm(e['Pd_fhat_stretch'], 3)}</td><td>{_pm(e['Pd_fhat_retract'], 3)}</td>"
            f"<td>{_pm(e['margin'], 0)}</td><td>{_pm(e.get('plan_cost'), 3) if 'plan_cost' in e else '-'}</td></tr>"
        )
    findings = "".join(f"<li>{html.escape(t)}</li>" for t in findings_in_words(doc))
    arm_rows = "".join(
        f"<tr><td>×{b['armature_scale']:g}</td><td>{_fmt(b['W_f_flow_deg'], 0)}°</td>"
        f"<td>{_fmt(b['W_a_flow_deg'], 0)}°</td>"
        f"<td>{_fmt(b['W_d_flow_deg'], 0)}°</td><td>{_fmt(b['W_a_ridge_deg'], 0)}°</td>"
        + "".join(f"<td>{_arm_ptp(doc, b['armature_scale'], o)}</td>" for o in "jfad")
        + "</tr>"
        for b in doc["armature"]["basins"]
    )
    v_rows = "".join(
        f"<tr><td>{v['v_eps_m_per_s'] * 1e3:g}</td><td>{v['force_std_n']:.2f}</td><td>{v['lost_ms']}</td></tr>"
        for v in doc.get("v_eps", [])
    )
    figs = ["fig9_force_error", "fig8_coupling", "fig6_postures", "swivel_scan"]
    if (out / "planned_path.png").exists():
        figs.append("planned_path")
    page = f"""<!doctype html>
<html><head><meta charset="utf-8"><title>torquelab — polish experiment</title>
<style>body{{font-family:sans-serif;max-width:1300px;margin:2em auto;line-height:1.4}}
table{{border-collapse:collapse;margin:1em 0;font-size:90%}}
td,th{{border:1px solid #bbb;padding:3px 6px;text-align:right}}
th{{background:#eee}}img{{max-width:100%}}</style></head><body>
<h1>Polishing with nullspace coupling optimization — simulation study of [T] §IV-B</h1>
<p>Run: <code>{html.escape(s["command"])}</code> ({s["seeds"]} seed(s) per cell, {s["jobs"]} process(es), wall time
{doc["wall_s"]:.0f} s{_reused(s)}, code version {html.escape(_code(s))}).
{html.escape(_robot_text(doc))} model, {_loop_text(doc)}; {_gains_text(doc)};
start elbow up (swivel {s["start_swivel_deg"]:g}°);
six segments of {s["segment_dx_m"]:.2f} m in X and
{s["segment_dy_m"]:.2f} m in Y, {s["segment_duration_s"]:.1f} s each. The settle phase ends when the QP's goal
nullspace speed stayed below {s["settle"]["speed_tol_rad_s"]:g} rad/s and W changed by less than
{s["settle"]["w_rtol"]:g}·|W| + {s["settle"]["w_atol"]:g} over the last {s["settle"]["window_s"]:g} s (cap
{s["settle"]["cap_s"]:g} s). Force error = {html.escape(s["force_error"])}.</p>
<h2>Table III — statistical force error (N) of the simulation, as the paper prints it</h2>
{table_iii_html(doc["summary"])}
<h3>The same runs: stability, settling and the coupling terms</h3>
<table><tr><th>row</th><th>μ</th><th>stable</th>
<th>contact lost (ms)</th><th>converged</th><th>settle time (s)</th><th>swivel reached</th>
<th>W_f</th><th>W_a</th><th>W_d</th>
<th>P_f·f̂ stretch</th><th>P_f·f̂ retract</th><th>P_d·f̂ stretch</th><th>P_d·f̂ retract</th><th>margin (N s/m)</th>
<th>plan cost</th></tr>
{"".join(rows)}</table>
<p>W, P_f·f̂ (m/s² per N) and P_d·f̂ (N per N) at the trajectory start, f̂ the unit friction direction of a
stretching (S2) and a retracting (S1) segment. {html.escape(start_margin_text(doc))}</p>
{table_iii_latency_html(doc)}
{stroke_margin_html(doc)}
<h2>Findings (computed from this run)</h2>
<ul>{findings}</ul>
{latency_html(doc)}
<h2>Armature sensitivity</h2>
<p>{html.escape(armature_text(doc))} Basins below are where each gradient flow from the Fig. 6a start
ends along the swivel scan with the armature scaled (× the robot file's armature, model and simulation
alike); PTP is the simulated μ = {max(s["mu"]):g} force-error PTP (seed 0) where that run was made.</p>
<table><tr><th>armature</th><th>W_f flow</th><th>W_a flow</th><th>W_d flow</th><th>W_a ridge</th>
<th>W_j PTP</th><th>W_f PTP</th><th>W_a PTP</th><th>W_d PTP</th></tr>{arm_rows}</table>
{w_d_by_length_html(doc.get("w_d_by_length", []))}
{_v_eps_head(doc.get("v_eps", [])) + v_rows + "</table>" if v_rows else ""}
<h2>Figures</h2>
{"".join(_figure_html(f) for f in figs)}
{run_files_html(out, doc)}
</body></html>
"""
    (out / "report.html").write_text(page)


FIGURE_TITLES = {
    "fig9_force_error": "Force error along the zig-zag ([T] Fig. 9)",
    "fig8_coupling": "The coupling objectives along the zig-zag ([T] Fig. 8)",
    "fig6_postures": "The postures each objective settles in ([T] Fig. 6)",
    "swivel_scan": "Coupling along the self-motion loop at the start pose",
    "planned_path": "Planned and executed swivel paths over the planning cost",
}


def _figure_html(name: str) -> str:
    """A figure under its title in words, with a link to its file."""
    title = html.escape(FIGURE_TITLES.get(name, name.replace("_", " ")))
    return f'<h3>{title}</h3><p><a href="{name}.png">{name}.png</a></p><img src="{name}.png">'


RUN_KEYS = (  # a run file's line names these
    "group",
    "row",
    "mu",
    "seed",
    "start_swivel_deg",
    "armature_scale",
    "reading_delay_steps",
    "torque_delay_ms",
)


def _run_value(key: str, value) -> str:
    """A run file's value as its line prints it: a swivel in whole degrees, other numbers in short form."""
    if key == "start_swivel_deg" and isinstance(value, int | float):
        return _deg(float(value)) + "°"
    return f"{value:g}" if isinstance(value, float) else str(value)


def run_files_html(out: Path, doc: dict | None = None) -> str:
    """Links to the per-run files under out/runs (each run's record as JSON and its signals as .npz),
    one line per run named by its row, μ, seed and start, as the run had them; with `doc`, only the
    files of its runs (an earlier invocation's files in the same directory are left out); "" when
    there are none."""
    runs = out / "runs"
    lines = []
    mine = None
    if doc is not None:
        every = (
            doc["runs"]
            + doc.get("armature", {}).get("runs", [])
            + doc.get("latency", {}).get("runs", [])
            + doc.get("table_latency", {}).get("runs", [])
        )
        mine = {(r["row"], r["seed"], r.get("wall_s")) for r in every}
    for meta in sorted(runs.glob("*.json")) if runs.is_dir() else []:
        if meta.name.endswith(".tmp.json"):
            continue
        try:
            stored = json.loads(meta.read_text())
        except (OSError, ValueError):
            continue
        result = stored.get("result") or {}
        if mine is not None and (result.get("row"), result.get("seed"), result.get("wall_s")) not in mine:
            continue
        # what the run had (its result), over what it was asked (its spec) where it recorded no value
        spec = {**stored.get("spec", {}), **{k: v for k, v in (stored.get("result") or {}).items() if k in RUN_KEYS}}
        what = ", ".join(f"{k} {_run_value(k, spec[k])}" for k in RUN_KEYS if k in spec)
        arrays = meta.with_suffix(".npz")
        link = f' · <a href="runs/{arrays.name}">signals</a>' if arrays.exists() else ""
        lines.append(f'<li><a href="runs/{meta.name}">{html.escape(meta.stem)}</a> ({html.escape(what)}){link}</li>')
    if not lines:
        return ""
    return f"<h2>Per-run files ({len(lines)})</h2><ul>{''.join(lines)}</ul>"


def stroke_margin_html(doc: dict) -> str:
    """The section on the margin along the strokes (`polish_calibration.report_section`) over the table's runs."""
    from app.headless.experiments.polish_calibration import report_section

    return report_section(doc.get("runs", []))


def _arm_ptp(doc: dict, scale: float, objective: str) -> str:
    """PTP (swivel reached) of the armature run, flagged where it did not converge or lost contact."""
    for r in doc["armature"]["runs"]:
        if r["armature_scale"] == scale and r["objective"] == objective and r["force_error"]["ptp"] is not None:
            why = str(r.get("verdict") or "not stable")
            flags = [w for w, bad in (("not converged", not r["converged"]), (why, not r["stable"])) if bad]
            return (
                f"{r['force_error']['ptp']:.1f} ({_deg(r['converged_swivel_deg'])}°{''.join(', ' + f for f in flags)})"
            )
    return "-"


FLIPPED_WITHIN_DEG = 30.0  # a posture this close to ±180° swivel counts as the inverted elbow of [T] Fig. 6d


def _w_d_flip(doc: dict) -> list[str]:
    """Why W_d does not invert the elbow as [T] Fig. 6d does: the basin it reaches, whether the
    inverted elbow is a minimum and within the joint limits, and the armature scales' W_d basins;
    printed only when no W_d row of the table ended near ±180°."""
    rows = [e for e in doc["summary"] if e["objective"] == "d" and e["converged_swivel_deg"]["mean"] is not None]
    scan = doc.get("swivel_scan", {})
    wd, inv = scan.get("W_d"), scan.get("inverted")
    if not rows or not wd or not inv:
        return []
    if any(180.0 - abs(e["converged_swivel_deg"]["mean"]) <= FLIPPED_WITHIN_DEG for e in rows):
        return []
    reached = ", ".join(f"μ = {e['mu']:g}: {_deg(e['converged_swivel_deg']['mean'])}°" for e in rows)
    where = (
        f"outside the joint limits (every swivel within {inv['infeasible_within_deg']:.0f}° of ±180° is)"
        if not inv["feasible"]
        else "within the joint limits"
    )
    is_min = any(180.0 - abs(m) <= FLIPPED_WITHIN_DEG for m in wd["local_minima_swivel_deg"])
    text = (
        f"W_d does not invert the elbow as [T] Fig. 6d does (ours reaches {reached}). Along the self-motion loop "
        f"at the start pose W_d has its local minima at {wd['local_minima_swivel_deg']}° and its feasible minimum "
        f"at {_deg(wd['feasible_min_swivel_deg'])}° (W_d {wd['feasible_min']:.2f}); the flow from the start "
        f"({wd['at_start']:.2f} at 0°) ends there"
        + (
            f", the ridge to the other basin is at {_deg(wd['ridge_swivel_deg'])}°"
            if wd.get("ridge_swivel_deg") is not None
            else ""
        )
        + f". The inverted elbow ({_deg(inv['swivel_deg'])}°) is {where} and has W_d {inv['W_d']:.2f} "
        f"(feasible maximum {wd['feasible_max']:.2f})"
        + (": a minimum there, unreachable from this start." if is_min else ": not a minimum of this model's W_d.")
    )
    basins = doc.get("armature", {}).get("basins", [])
    if basins:
        flips = [
            b for b in basins if b["W_d_flow_deg"] is not None and 180.0 - abs(b["W_d_flow_deg"]) <= FLIPPED_WITHIN_DEG
        ]
        text += (
            " With the armature scaled the W_d flow from the start ends at "
            + ", ".join(f"×{b['armature_scale']:g}: {_fmt(b['W_d_flow_deg'], 0)}°" for b in basins)
            + ("; none of these inverts the elbow." if not flips else "; ")
            + (
                ""
                if not flips
                else "the inverted elbow is reached at ×" + ", ×".join(f"{b['armature_scale']:g}" for b in flips) + "."
            )
        )
    return [text]


def _close_to_boundary(doc: dict) -> list[str]:
    """The rows whose start-pose margin is below k·Δt, the negative damping a contact spring one step late
    would add, with k, Δt and how late this run's spring acts read from the runs' records ([] when the
    runs do not share them or no row is that close)."""
    runs, summary = doc["runs"], doc["summary"]
    contact = _common([{"c": {k: v for k, v in r.get("contact", {}).items() if k != "mu"} or None} for r in runs], "c")
    dt = _common(runs, "timestep_s")
    if not contact or not dt or "spring_lag_steps" not in contact:
        return []
    late_spring = contact["stiffness_n_per_m"] * dt  # k·Δt of a one-step-late contact spring
    close = [e for e in summary if e["margin"]["mean"] is not None and 0.0 <= e["margin"]["mean"] < late_spring]
    if not close:
        return []
    lag = contact["spring_lag_steps"]
    return [
        "Close to the boundary: "
        + ", ".join(f"{e['row']} μ = {e['mu']:g} ({e['margin']['mean']:+.0f} N s/m)" for e in close)
        + f" have a margin below k·Δt = {late_spring:.0f} N s/m, the negative damping a contact spring one step "
        "late would add: a simulation detail of that size decides whether these rows lose contact (this run's "
        + (
            "contact spring acts on the TCP position at the start of each step)."
            if lag == 0
            else f"contact spring acts on the TCP position {lag} step(s) old)."
        )
    ]


def findings_in_words(doc: dict) -> list[str]:
    """Sentences from this run's numbers only; each is printed only when its premise holds."""
    out: list[str] = []
    runs, summary = doc["runs"], doc["summary"]
    not_conv = [r for r in runs if not r["converged"]]
    times = [r["convergence_time_s"] for r in runs if r["converged"]]
    if runs and not not_conv:
        out.append(
            f"Every run converged before the {doc['settings']['settle']['cap_s']:g} s cap "
            f"(longest settle {max(times):.1f} s)."
        )
    elif not_conv:
        out.append(
            f"{len(not_conv)} of {len(runs)} runs reached the settle cap without converging: "
            + ", ".join(f"{r['row']} μ = {r['mu']:g} seed {r['seed']}" for r in not_conv)
            + "; their rows are not converged postures."
        )
    for e in summary:
        paper = e.get("paper")
        if not paper or e["ma"]["mean"] is None:
            continue
        verdict = []
        for name, key, p in (("MA", "ma", paper[0]), ("PTP", "ptp", paper[1]), ("STD", "std", paper[2])):
            ours, sd = e[key]["mean"], e[key]["sd"]
            ok = abs(ours - p) <= max(MATCH_REL * p, MATCH_SD * (sd or 0.0))
            verdict.append(f"{name} {ours:.1f} vs {p:.1f} {'matches' if ok else 'does not match'}")
        out.append(
            f"{e['row']}, μ = {e['mu']:g}: " + "; ".join(verdict) + f" (within {MATCH_REL:.0%} or {MATCH_SD:g} sd)."
        )
    hi = max((e["mu"] for e in summary), default=None)
    if hi is not None:
        for o, paper_stable in PAPER_STABLE_MU1.items():
            e = next((x for x in summary if x["row"] == NAMES[o] and x["mu"] == hi), None)
            if e is None or hi != 1.0:
                continue
            same = (e["stable"] == e["n"]) == paper_stable
            out.append(
                f"{NAMES[o]} at μ = 1: {e['stable']}/{e['n']} runs stable by the one verdict; the paper's Fig. 9 "
                f"has it {'stable' if paper_stable else 'oscillating'}: {'same' if same else 'different'} outcome."
            )
    out += _close_to_boundary(doc)
    scan = doc.get("swivel_scan", {})
    wa = scan.get("W_a", {})
    rows_a = [e for e in summary if e["objective"] == "a"]
    if wa and rows_a:
        txt = "; ".join(f"{e['row']} (μ = {e['mu']:g}) reaches {_pm(e['converged_swivel_deg'], 0)}°" for e in rows_a)
        out.append(
            f"W_a basins: along the scan at the start pose W_a has local minima at {wa['local_minima_swivel_deg']}°, "
            f"the flow from 0° ends at {_deg(wa['flow_from_start_deg'])}° (W_a {wa['flow_from_start_value']:.3f}), "
            f"the feasible minimum is at {_deg(wa['feasible_min_swivel_deg'])}° (W_a {wa['feasible_min']:.3f}) "
            + (
                f"and the ridge between the basins at {_deg(wa['ridge_swivel_deg'])}°"
                if wa.get("ridge_swivel_deg") is not None
                else "and no swivel of the scan flows to another basin (no ridge)"
            )
            + f". {txt}."
        )
    pd = scan.get("Pd_fhat_stretch")
    if wa.get("basins") and pd:
        basins = "; ".join(
            f"{_deg(b['swivel_deg'])}°: W_a {b['W_a']:.3f}, P_d·f̂ {b['Pd_fhat_stretch']:+.3f}" for b in wa["basins"]
        )
        out.append(
            f"Stretching friction along the loop ({scan.get('robot', '')}): P_d·f̂ is {pd['at_start']:+.3f} at the "
            "start, "
            f"|P_d·f̂| runs from {pd['feasible_min_abs']:.3f} (at {_deg(pd['feasible_min_abs_swivel_deg'])}°) to "
            f"{pd['feasible_max_abs']:.3f} over the feasible loop; at the W_a basins: {basins}."
        )
    out += _w_d_flip(doc)
    for e in summary:
        if e["mu"] != hi or e["Pd_fhat_stretch"]["mean"] is None:
            continue
        out.append(
            f"{e['row']} at μ = {hi:g}: P_d·f̂ stretch {_pm(e['Pd_fhat_stretch'], 3)}, W_a {_pm(e['W_a'], 3)}, margin "
            f"{_pm(e['margin'], 0)} N s/m, stable {e['stable']}/{e['n']}."
        )
    for e in summary:
        if "plan_cost" in e:
            out.append(
                f"{e['row']}, μ = {e['mu']:g}: plan cost {_pm(e['plan_cost'], 3)}, executed swivel within "
                f"{_pm(e['plan_tracking_max_deg'], 1)}° (max over the trajectory) of the plan, swivel at the start "
                f"{_pm(e['converged_swivel_deg'], 0)}°, MA/PTP {_pm(e['ma'])} / {_pm(e['ptp'])} N."
            )
    ve = doc.get("v_eps", [])
    if len(ve) >= 2 and all("implicit_friction" in v for v in ve) and len({v["mu"] for v in ve}) == 1:
        step = {True: "implicit step", False: "explicit step"}
        how = ", ".join(sorted({step[bool(v["implicit_friction"])] for v in ve}))
        out.append(
            f"Friction regularisation ({how}), {NAMES.get(ve[0].get('objective', 'j'), 'W_j')} hold at "
            f"μ = {ve[0]['mu']:g}: contact-force STD "
            + ", ".join(f"{v['force_std_n']:.2f} N at v_ε = {v['v_eps_m_per_s'] * 1e3:g} mm/s" for v in ve)
            + "."
        )
    return out
