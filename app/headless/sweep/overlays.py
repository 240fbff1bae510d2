"""Layers drawn on an experiment's maps from its own model, not from the sweep's runs.

Polish, along a swivel axis: the W_a basins of the self-motion loop at the start pose
(`polish_report.scan_at_start`, DESIGN §8): a solid line at each feasible local minimum of W_a
(where the gradient flow of [T15] ends), a dashed line at each ridge between two minima (the
basin border) and grey where the loop leaves the joint limits. With a μ axis: the linearised
force-loop margin (`control.margin.posture_margin`, as each run reports it at its converged
posture): a circle where that start-pose margin is negative (K_f^d below the critical damping),
and for a held swivel its zero line over (swivel, μ) along the start-pose loop. The planned
nullspace paths (`control.planner`, [T] §IV-B) over the zig-zag from the Fig. 6a start (the
table's): a hatched band over the swivels each plan visits during the six segments.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from app.headless.experiments.polish_calibration import sweep_section
from app.headless.sweep.grid import Axis

SWIVEL_AXES = ("swivel", "hold_swivel")


@lru_cache(maxsize=1)
def wa_basins() -> dict:
    """W_a minima and ridges (deg) and infeasible swivel bands along the loop at the start pose."""
    from app.headless.experiments.polish_report import scan_at_start

    data = scan_at_start()["data"]
    psi, w, feas = data["swivel_deg"], data["W_a"], data["feasible"]
    n = len(psi)
    minima, ridges = [], []
    for i in range(n):
        a, b = w[i - 1], w[(i + 1) % n]
        if feas[i] and w[i] < a and w[i] < b:
            minima.append(float(psi[i]))
        if feas[i] and feas[i - 1] and feas[(i + 1) % n] and w[i] > a and w[i] > b:
            ridges.append(float(psi[i]))
    step = float(np.median(np.diff(psi))) if n > 1 else 0.0
    infeasible = [(float(p) - step / 2, float(p) + step / 2) for p, ok in zip(psi, feas, strict=True) if not ok]
    return {"minima": minima, "ridges": ridges, "infeasible": infeasible}


PLAN_STYLES = {"signed": ("max(P_d·f̂, 0)²", "tab:green", "////"), "a": ("W_a", "tab:orange", "\\\\")}


@lru_cache(maxsize=1)
def planned_swivels() -> dict[str, dict]:
    """Per plan cost: the swivel (deg, wrapped to (−180, 180]) planned from the Fig. 6a start over the six
    segments, and its span."""
    import robots
    from app.scenarios.polish import PolishScenario
    from app.scenarios.polish_plan import planned_path
    from control.model import RobotModel

    robot = robots.load(robots.chosen("rizon4s"))
    PolishScenario().prepare_robot(robot)
    model = RobotModel(robot.model)
    out: dict[str, dict] = {}
    for cost in PLAN_STYLES:
        plan = planned_path(robot, model, 0.0, cost)
        psi = (np.rad2deg(plan.swivel_rad[plan.t >= 0.0]) + 180.0) % 360.0 - 180.0
        out[cost] = {"swivel_deg": psi, "lo": float(psi.min()), "hi": float(psi.max()), "cost": plan.total_cost}
    return out


def _plan_layer(ax, to_x) -> None:
    for cost, p in planned_swivels().items():
        name, color, hatch = PLAN_STYLES[cost]
        a, b = to_x(p["lo"]), to_x(p["hi"])
        if a is None or b is None:
            continue
        if b - a < 0.2:  # a plan that barely moves: a visible band around it
            a, b = a - 0.1, b + 0.1
        ax.axvspan(a, b, facecolor="none", edgecolor=color, hatch=hatch, lw=1.0, label=f"planned path, cost {name}")


MARGIN_SWIVEL_STEP_DEG = 4.0  # posture spacing along the loop for the margin
MARGIN_FINE_MU = 5  # μ values for the zero line between the map's lowest and highest μ


@lru_cache(maxsize=1)
def _loop_postures() -> tuple[np.ndarray, np.ndarray]:
    """(swivel deg in (−180, 180], Λx per posture) of the feasible postures of the start-pose loop."""
    import robots
    from app.scenarios.polish import PolishScenario
    from control.coupling import POLISH_SUBSPACES, swivel_scan
    from control.model import RobotModel

    robot = robots.load(robots.chosen("rizon4s"))
    model = RobotModel(robot.model)
    q0 = PolishScenario().initial_q(robot)
    scan = swivel_scan(
        model, q0, POLISH_SUBSPACES, robot.q_lower, robot.q_upper, step_rad=np.deg2rad(MARGIN_SWIVEL_STEP_DEG)
    )
    psi = (np.rad2deg(scan.swivel_rad) + 180.0) % 360.0 - 180.0
    keep = np.flatnonzero(scan.within_limits)
    order = keep[np.argsort(psi[keep])]
    lambdas = np.array([model.compute(scan.q[i], np.zeros(len(scan.q[i]))).Lambda for i in order])
    return psi[order], lambdas


@lru_cache(maxsize=256)
def posture_margin_at(psi_index: int, mu: float) -> float:
    """K_f^d margin (N s/m, > 0 stable) of loop posture `psi_index` at friction μ [T12], as the polish
    experiment computes it (both friction directions, speeds from rest to the segments' peak)."""
    from app.scenarios import polish_stroke as stroke_module
    from control.coupling import POLISH_SUBSPACES
    from control.gains import MotionForceGains
    from control.margin import ContactLoop, posture_margin

    _, lambdas = _loop_postures()
    loop = ContactLoop(
        stiffness_n_per_m=stroke_module.CONTACT_STIFFNESS_N_PER_M,
        mu=float(mu),
        normal_force_n=stroke_module.DESIRED_FORCE_N,
        speed_m_s=stroke_module.PEAK_SPEED_M_S,
        v_eps_m_per_s=stroke_module.FRICTION_V_EPS_M_PER_S,
        sensor_cutoff_hz=stroke_module.SENSOR_CUTOFF_HZ,
    )
    dirs = [
        stroke_module.friction_direction(1.5 * stroke_module.SEGMENT_DURATION_S),
        stroke_module.friction_direction(0.5 * stroke_module.SEGMENT_DURATION_S),
    ]
    speeds = (0.0, 0.3 * stroke_module.PEAK_SPEED_M_S, stroke_module.PEAK_SPEED_M_S)
    return float(posture_margin(lambdas[psi_index], POLISH_SUBSPACES, MotionForceGains(), loop, dirs, speeds).kd_margin)


def _cell_margin(rec: dict) -> float | None:
    """The run's own margin (the polish experiment's, at its converged posture), else the margin of
    the loop posture nearest its converged swivel."""
    m = rec.get("metrics") or {}
    if m.get("margin") is not None:
        return float(m["margin"])
    if m.get("converged_swivel_deg") is None:
        return None
    psi, _ = _loop_postures()
    i = int(np.argmin(np.abs((psi - float(m["converged_swivel_deg"]) + 180.0) % 360.0 - 180.0)))
    mu = float(rec["params"].get("mu", m.get("mu", 0.25)))
    return posture_margin_at(i, round(mu, 9))


def _cell_predictions(axes: list[Axis], records: list[dict]) -> dict[tuple, tuple[bool, bool]]:
    """(x value, y value, rest…) → (margin predicts stable for every seed, every seed stable)."""
    groups: dict[tuple, list[tuple[float, bool]]] = {}
    for r in records:
        if r.get("status") != "ok":
            continue
        margin = _cell_margin(r)
        if margin is not None:
            groups.setdefault(tuple(r["params"][a.name] for a in axes), []).append((margin, bool(r["stable"])))
    return {k: (all(m >= 0.0 for m, _ in v), all(s for _, s in v)) for k, v in groups.items()}


def _margin_layer(ax, axes: list[Axis], records: list[dict]) -> None:
    x_axis, y_axis = axes[0], axes[1]
    if y_axis.name != "mu":
        return
    y_values = np.asarray(y_axis.values, dtype=float)
    unstable = [key for key, (pred, _) in _cell_predictions(axes, records).items() if not pred]
    for k, key in enumerate(unstable):
        x, y = x_axis.values.index(key[0]), y_axis.values.index(key[1])
        label = "start-pose margin negative" if k == 0 else None
        ax.plot(x, y, "o", mfc="none", mec="magenta", ms=11, mew=1.5, label=label)
    if x_axis.name != "hold_swivel" or len(y_axis) < 2:
        return
    psi, _ = _loop_postures()
    mus = np.linspace(y_values.min(), y_values.max(), MARGIN_FINE_MU)
    held = np.asarray(x_axis.values, dtype=float)
    nearest = [int(np.argmin(np.abs((psi - h + 180.0) % 360.0 - 180.0))) for h in held]
    grid = np.array([[posture_margin_at(i, round(float(m), 9)) for i in nearest] for m in mus])
    ys = np.interp(mus, y_values, np.arange(len(y_values), dtype=float))
    ax.contour(
        np.arange(len(held), dtype=float), ys, grid, levels=[0.0], colors="magenta", linewidths=1.6, linestyles=":"
    )


def polish_overlay(ax, axes: list[Axis], records: list[dict]) -> None:
    """W_a basins and the margin's prediction on a map whose x axis is a swivel angle (nothing otherwise)."""
    x_axis = axes[0]
    if x_axis.name not in SWIVEL_AXES or len(x_axis) < 2:
        return
    values = np.asarray(x_axis.values, dtype=float)
    index = np.arange(len(values), dtype=float)

    def to_x(deg: float) -> float | None:
        if not values[0] <= deg <= values[-1]:
            return None
        return float(np.interp(deg, values, index))

    basins = wa_basins()
    for lo, hi in basins["infeasible"]:
        a, b = to_x(max(lo, values[0])), to_x(min(hi, values[-1]))
        if a is not None and b is not None:
            ax.axvspan(a, b, color="0.5", alpha=0.25, lw=0)
    for k, deg in enumerate(basins["minima"]):
        x = to_x(deg)
        if x is not None:
            ax.axvline(x, color="magenta", lw=1.6, label="W_a minimum (basin)" if k == 0 else None)
    for k, deg in enumerate(basins["ridges"]):
        x = to_x(deg)
        if x is not None:
            ax.axvline(x, color="magenta", lw=1.2, ls="--", label="W_a ridge (basin border)" if k == 0 else None)
    _plan_layer(ax, to_x)
    _margin_layer(ax, axes, records)
    if basins["minima"] or basins["ridges"]:
        ax.legend(fontsize=6, loc="upper center", bbox_to_anchor=(0.5, -0.2), ncol=3, frameon=False)  # below the map


def polish_model_facts() -> dict:
    """The model's figures the polish maps and notes draw, for sweep.json beside the cells: the robot, the
    W_a minima and ridges along the start pose's self-motion loop and each planned path's swivel span and
    cost (computed from the model with the robot file's armature, not from the runs)."""
    import robots
    from app.headless.experiments.polish_report import SCAN_STEP_DEG

    basins = wa_basins()
    return {
        "scan_step_deg": SCAN_STEP_DEG,
        "robot": robots.load(robots.chosen("rizon4s")).name,
        "armature": "the robot file's armature (scenario armature scale ×1)",
        "W_a_minima_deg": basins["minima"],
        "W_a_ridges_deg": basins["ridges"],
        "plans": {c: {"lo_deg": p["lo"], "hi_deg": p["hi"], "cost": p["cost"]} for c, p in planned_swivels().items()},
    }


def polish_notes(axes: list[Axis], records: list[dict], facts: dict | None = None) -> str:
    """What the overlay shows, with its numbers (`facts`: `polish_model_facts` as sweep.json recorded
    them; None: computed now), and where the runs ended along the loop."""
    facts = facts or polish_model_facts()
    fmt = ", ".join
    text = (
        f"<p>Self-motion loop of the {facts['robot']} at the polish start pose (swivel scan, "
        f"{facts['scan_step_deg']:g}° steps, {facts['armature']}): W_a has feasible local minima "
        f"at {fmt(f'{d:+.0f}°' for d in facts['W_a_minima_deg']) or 'none'} (solid lines: the basins the W_a flow "
        f"ends in) and ridges at {fmt(f'{d:+.0f}°' for d in facts['W_a_ridges_deg']) or 'none'} (dashed: basin "
        "borders); grey: outside the joint limits.</p>"
    )
    text += (
        "<p>Planned nullspace paths over the zig-zag (dynamic programming over the swivel grid, "
        "`control.planner`) from the Fig. 6a start, as the polish table runs them (hatched bands: the "
        "swivels each plan visits during the six segments): "
        + fmt(
            f"cost {PLAN_STYLES[c][0]} {p['lo_deg']:+.0f}°…{p['hi_deg']:+.0f}° (plan cost {p['cost']:.3g})"
            for c, p in facts["plans"].items()
        )
        + ".</p>"
    )
    if len(axes) >= 2 and axes[1].name == "mu":
        pred = _cell_predictions(axes, records)
        agree = sum(p == s for p, s in pred.values())
        cutoffs = sorted(
            {
                float(r["metrics"]["sensor_cutoff_hz"])
                for r in records
                if (r.get("metrics") or {}).get("sensor_cutoff_hz")
            }
        )
        lag = (
            "the " + "/".join(f"{c:g}" for c in cutoffs) + " Hz sensor low-pass" if cutoffs else "the sensor's low-pass"
        )
        text += (
            f"<p>Linearised force-loop margin ([T12] loop with contact stiffness, K_f^p, K_f^d, K_f^i, {lag}, the "
            "reading's and the torque's delay and the shaping term; `control.margin.posture_margin`) at each run's "
            "converged posture, before the strokes (it leaves out how the posture moves along them, the noise, and "
            f"contact loss itself): its sign and the simulated outcome (all seeds stable or not) agree in "
            f"{agree} of {len(pred)} cells; circles mark the cells where it is negative"
            + ("; the dotted line is its zero over (held swivel, μ)." if axes[0].name == "hold_swivel" else ".")
            + "</p>"
        )
    text += sweep_section([a.name for a in axes], records)
    ended = [
        r["metrics"].get("converged_swivel_deg")
        for r in records
        if r.get("status") == "ok" and r.get("metrics") and r["metrics"].get("converged_swivel_deg") is not None
    ]
    if ended and facts["W_a_minima_deg"]:
        mins = np.asarray(facts["W_a_minima_deg"])
        nearest = [float(mins[np.argmin(np.abs((mins - e + 180.0) % 360.0 - 180.0))]) for e in ended]
        counts = {m: nearest.count(m) for m in facts["W_a_minima_deg"]}
        text += (
            "<p>Where the runs' postures were when the trajectory started (nearest W_a minimum): "
            + fmt(f"{m:+.0f}°: {c} run(s)" for m, c in counts.items())
            + ".</p>"
        )
    return text
