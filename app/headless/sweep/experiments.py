"""What each experiment offers a sweep: its knobs, one cell (one single run), its headline metrics.

A cell calls the experiment's own single-run function (`run_drop`, `run_mass_drop`,
`polish.simulate`) with the cell's values over the experiment's defaults, and returns its
scalar metrics and whether the run was stable (the meaning is stated per experiment). A cell's
session values reach the run only through the parameter path (`session_params`: (group, field,
value) for `Session.set_param`, as the GUI sets them); only run knobs are the function's arguments.
Cell functions live at module level so that any `concurrent.futures.Executor` can ship them.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

from app.headless.experiments.polish_calibration import calibration_metrics
from app.headless.sweep.grid import SweepError
from app.headless.sweep.knobs import RUN, Knob, positive
from app.headless.sweep.overlays import polish_model_facts, polish_notes, polish_overlay
from app.scenarios import verdict as V


@dataclass(frozen=True)
class SweepExperiment:
    """An experiment as a sweep sees it."""

    name: str
    knobs: tuple[Knob, ...]
    cell: Callable[[dict, int], dict]
    map_metrics: tuple[str, ...]  # metrics drawn as maps / lines in the report
    # what "stable" means for this experiment (shown in the report): fixed words, or words from the cells
    stable_means: str | Callable[[list[dict]], str]
    seeded: bool = True  # False: the run does not depend on the seed (seeds repeat it)
    groups: Callable[[], dict] | None = None  # the default session's parameter groups by name
    overlay: Callable | None = None  # (ax, axes, records) → extra layers on its maps
    report_notes: Callable | None = None  # (axes, records, model facts) → HTML paragraph for the report
    model_facts: Callable | None = None  # () → the model's figures its maps and notes draw (kept in sweep.json)
    any_param: bool = False  # "GROUP.FIELD" sweeps any session parameter (the cell sets it by set_param)
    group_axis: str | None = None  # cells sharing this axis's value are sent together (their process reuses work)
    # (out dir, records, model facts, invocations) → HTML: files of its own written beside the report
    report_files: Callable | None = None
    local_only: bool = False  # its cells fork their worker process: the local pool only, no Dask cluster

    def check_combination(self, names: list[str]) -> None:
        """SweepError for knobs that cannot be swept together."""
        if self.name == "polish" and "hold_swivel" in names:
            clash = [n for n in ("swivel", "objective") if n in names]
            if clash:
                raise SweepError(f"hold_swivel sets the start swivel and the objective; drop {', '.join(clash)}")


def _scalars(d: dict, prefix: str = "") -> dict:
    """Flat {name: number|bool|str|None} of the scalar entries of a (nested) result dict."""
    out: dict = {}
    for key, value in d.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            out.update(_scalars(value, f"{name}_"))
        elif isinstance(value, bool | int | str) or value is None:
            out[name] = value
        elif isinstance(value, float):
            out[name] = value if math.isfinite(value) else None
    return out


def session_params(knobs: tuple[Knob, ...], values: dict) -> list[tuple[str, str, object]]:
    """The cell's session values as (group, field, value) for `Session.set_param`: its parameter knobs
    (not the RUN ones) in knob order, then any "GROUP.FIELD" names in the cell's order."""
    named = [(k.group, k.field, values[k.name]) for k in knobs if k.group != RUN and k.name in values]
    return named + [(*name.split("."), value) for name, value in values.items() if "." in name]  # type: ignore[misc]


# ---- limit-drop [C] §IV-B–C -------------------------------------------------------------------
LIMIT_DROP_KNOBS = (
    Knob("lambda", "damper", "lambda_", "damper gain λ (1/s) [C24]", ("lam", "λ", "lambda_")),
    Knob("M", "damper", "M", "damper overdamping M [C24]"),
    Knob("form", "damper", "form", "damper form: proposed [C24] or classic δt [C17–19]"),
    Knob("feedback", "compliance_qp", "feedback", "τ̂_e kept in the inverse dynamics [C8]"),
    Knob("torque_delay_ms", "world", "torque_delay_ms", "actuator latency, ms", ("delay", "torque_delay")),
    Knob("K_I", "estimator", "observer_gain", "momentum-observer gain K_I (1/s) [C25]", ("observer_gain",)),
    Knob("limit", RUN, "limit", "which limit joint 4 falls into", kind=("position", "velocity")),
    Knob(
        "duration",
        RUN,
        "duration",
        "simulated seconds per drop (a cap: it ends once joint 4 has stopped)",
        ("duration_s",),
        check=positive,
    ),
)


def limit_drop_groups() -> dict:
    """The limit-drop session's parameter groups (the QP executor's, the world's...)."""
    from app.headless.experiments.c_common import qp_session
    from app.scenarios.limit_drop import LimitDropScenario

    return qp_session(LimitDropScenario()).params()


def limit_drop_cell(values: dict, seed: int) -> dict:
    """One drop of limit-drop (`run_drop`); stable = joint 4 stays inside its limit. λ, M, the form,
    the feedback, K_I and the torque delay go the parameter path (`session_params`)."""
    from app.headless.experiments.limit_drop import run_drop
    from app.scenarios.limit_drop import DURATION_S

    r = run_drop(
        limit=str(values.get("limit", "position")),
        duration=float(values.get("duration", DURATION_S)),
        session_params=session_params(LIMIT_DROP_KNOBS, values),
    )
    metrics = _scalars({k: v for k, v in r.items() if not k.startswith("trace")})
    return {"metrics": metrics, "stable": bool(r["max_violation"] <= 0.0)}


# ---- mass-drop [C] §IV-D ----------------------------------------------------------------------
MASS_DROP_KNOBS = (
    Knob(
        "controller",
        RUN,
        "mode",
        "Position PID, Torque + Residual or Torque + Fusion",
        ("mode",),
        kind=("position", "torque-residual", "torque-fusion"),
    ),
    Knob("case", RUN, "case", "the mass falls on a rope, or is let go", kind=("rope-drop", "held-release")),
    Knob(
        "payload_mass_error",
        "scenario",
        "payload_mass_error",
        "true mass = 1.25 kg × (1 + error), unknown to every controller (nominal of the seeded rig draw)",
        ("mass_error",),
    ),
    Knob("rope_stiffness", "scenario", "rope_stiffness_n_per_m", "rope stiffness, N/m (nominal)"),
    Knob("drop_height", "scenario", "drop_height_m", "free fall before the rope is taut, m (nominal)"),
    Knob("K_I", "estimator", "observer_gain", "momentum-observer gain K_I (1/s) [C25]", ("observer_gain",)),
    Knob("window", RUN, "window_s", "seconds analysed after the release", ("window_s",), check=positive),
)


SETTLED_FOR_S = 0.1  # "settled": inside the band for at least the last 0.1 s of the window


def mass_drop_groups() -> dict:
    """The mass-drop session's parameter groups."""
    from app.headless.experiments.c_common import qp_session
    from app.scenarios.mass_drop import MassDropScenario

    return qp_session(MassDropScenario()).params()


def mass_drop_cell(values: dict, seed: int) -> dict:
    """One release of mass-drop (`run_mass_drop`) on the rig drawn for this seed around the nominal the
    cell sets; stable = the run completes and the TCP is inside the 1 mm band for the window's last 0.1 s
    or longer. The drawn rig and K_I go the parameter path (`session_params`)."""
    import dataclasses

    from app.headless.experiments.mass_drop import draw_rig, run_mass_drop
    from app.scenarios.mass_drop import WINDOW_S, MassDropParams

    nominal = {k.field: float(values[k.name]) for k in MASS_DROP_KNOBS if k.group == "scenario" and k.name in values}
    rig = draw_rig(seed, MassDropParams(**nominal))  # type: ignore[arg-type]
    drawn = [("scenario", f.name, getattr(rig, f.name)) for f in dataclasses.fields(rig)]
    others = [p for p in session_params(MASS_DROP_KNOBS, values) if p[0] != "scenario"]
    window = float(values.get("window", WINDOW_S))
    r = run_mass_drop(
        str(values.get("controller", "torque-fusion")),
        seed,
        case=str(values.get("case", "rope-drop")),
        window_s=window,
        session_params=drawn + others,
    )
    metrics = _scalars({k: v for k, v in r.items() if not k.startswith("trace")})
    stable = r.get("stop", "done") == "done" and r["stabilization_time_s"] < window - SETTLED_FOR_S
    return {"metrics": metrics, "stable": bool(stable)}


# ---- polish [T] §IV-B ---------------------------------------------------------------------------
POLISH_KNOBS = (
    Knob("mu", "contact", "mu", "Coulomb friction coefficient μ", ("μ",)),
    Knob("swivel", "scenario", "start_swivel_deg", "start swivel, degrees", ("start_swivel",)),
    Knob(
        "hold_swivel",
        RUN,
        "hold_swivel_deg",
        "start at this swivel and hold it (W_j on the start posture: no flow), degrees",
        check=lambda v: _held_swivel(v),
    ),
    Knob(
        "objective",
        RUN,
        "objective",
        "nullspace objective W_j/W_f/W_a/W_d [T15], or track the planned path (signed directional or W_a cost)",
        kind=("j", "f", "a", "d", "planned", "planned_a"),
    ),
    Knob("armature_scale", "scenario", "armature_scale", "armature × this, robot and model alike"),
    Knob("shaping", "motion_force", "shaping", "inertia shaping Λ̂x [T9] on/off"),
    Knob("sensor_cutoff", "sensor", "cutoff_hz", "F/T low-pass cutoff, Hz (0 = none)", ("cutoff_hz",)),
    Knob(
        "reading_delay",
        "sensor",
        "reading_delay_steps",
        "sensing delay: the F/T reading's age, control periods",
        ("reading_delay_steps", "sensing_delay"),
    ),
    Knob("torque_delay_ms", "world", "torque_delay_ms", "actuation delay, ms", ("torque_delay",)),
    Knob(
        "converge_timeout",
        RUN,
        "converge_timeout_s",
        "posture settle cap, s",
        check=lambda v: _polish(converge_timeout_s=v),
    ),
    Knob("sander", "sander", "enabled", "7000 RPM sander disturbance"),
    Knob(
        "strokes",
        RUN,
        "strokes",
        "run the first this many of the six strokes (1-6), e.g. S1 and S2 for a quicker stability map",
        kind="int",
        check=lambda v: _strokes(v),
    ),
    *(
        Knob(
            f"k0_{o}",
            "nullspace",
            f"k0_{o}",
            f"nullspace gain k0 of W_{o} [T15]" + (" (held/planned posture)" if o == "j" else ""),
        )
        for o in ("j", "f", "a", "d")
    ),
)


def _polish(**values):
    """The polish scenario validates its own arguments."""
    from app.scenarios.polish import PolishScenario

    return PolishScenario(**values)


def _strokes(value: int) -> None:
    from app.scenarios.polish_stroke import N_SEGMENTS

    if not 1 <= int(value) <= N_SEGMENTS:
        raise ValueError(f"strokes must be 1 to {N_SEGMENTS}, got {value}")


def _held_swivel(value: float) -> None:
    """A held swivel becomes the start swivel: the scenario group's `start_swivel_deg` range applies."""
    from app.scenarios.polish import PolishParams
    from control.params import replaced

    replaced(PolishParams(), "start_swivel_deg", value)
    _polish(hold_swivel_deg=value)


def polish_groups() -> dict:
    """The polish session's parameter groups (projection executor, contact, sensor, scenario...)."""
    from app.core.session import Session
    from app.scenarios.polish import PolishScenario

    return Session(PolishScenario()).params()


def polish_cell(values: dict, seed: int) -> dict:
    """One polish run (`polish.simulate`); stable = the one verdict (`app.scenarios.verdict`) over its
    strokes is "stable": no divergence, no lost contact, no stroke oscillating. The cell's
    session parameters (μ, start swivel, k0…) reach the run only through the parameter path
    (`session_params`, set by `Session.set_param` as the GUI's are); the run's own arguments (objective,
    a held swivel, the settle cap) are the spec's."""
    from app.headless.experiments.polish import simulate

    spec: dict = {"seed": int(seed), "objective": str(values.get("objective", "a")), "group": "sweep"}
    if "hold_swivel" in values:  # the nullspace holds the start posture (W_j on it): no flow
        spec["hold_swivel_deg"] = float(values["hold_swivel"])
    if "converge_timeout" in values:
        spec["converge_timeout_s"] = float(values["converge_timeout"])
    spec["session_params"] = session_params(POLISH_KNOBS, values)
    if "strokes" in values:
        spec["strokes"] = int(values["strokes"])
    r = simulate(spec)["result"]
    drop = ("per_segment", "q_start", "q_converged", "posture_change_deg", "plan", "stroke_margin", "config")
    keep = {k: v for k, v in r.items() if k not in drop}
    return {"metrics": {**_scalars(keep), **calibration_metrics(r)}, "stable": r["verdict"] == V.STABLE}


def polish_stable_means(records: list[dict]) -> str:
    """The one verdict's definition with the thresholds and the band the cells recorded."""
    metrics = [r.get("metrics", {}) for r in records if r.get("status") == "ok"]
    thresholds = sorted({round(m["oscillation_threshold_n"], 2) for m in metrics if m.get("oscillation_threshold_n")})
    if not thresholds:
        return "the one verdict (app.scenarios.verdict) is stable on every stroke (no finished cell recorded it)"
    spread = "" if len(thresholds) == 1 else f" (each cell's own sensor: {thresholds[0]:.2f}–{thresholds[-1]:.2f} N)"
    return (
        "the one verdict (app.scenarios.verdict) is stable on every stroke, no divergence"
        + spread
        + ". "
        + V.definition_text(thresholds[0], metrics[0]).rstrip(".")
    )


# ---- the stability map: held swivel × μ × latency (app.headless.experiments.polish_map) ---------------
LATENCY_MAX = 8  # periods per stage a latency value may name (the sensor's and the world's limits check them)
POLISH_MAP_KNOBS = (
    Knob(
        "hold_swivel",
        RUN,
        "hold_swivel_deg",
        "the held swivel, degrees (W_j on the start posture there, as polish's hold_swivel)",
        check=lambda v: _held_swivel(v),
    ),
    Knob("mu", "contact", "mu", "Coulomb friction coefficient μ", ("μ",)),
    Knob(
        "latency",
        RUN,
        "latency",
        "READING+DRIVE: the F/T reading's age and the drive's delay in control periods, e.g. 1+0, 1+1",
        kind=tuple(f"{r}+{d}" for r in range(LATENCY_MAX + 1) for d in range(LATENCY_MAX + 1)),
        check=lambda v: _latency(v),
    ),
)


def _latency(text: str) -> None:
    """Both stages inside their parameter's range (the sensor's reading age, the world's torque delay)."""
    from app.headless.experiments.polish_map import parse_latency
    from app.sim.sensor import SensorParams
    from app.sim.world import WorldParams
    from control.params import replaced

    reading, drive = parse_latency(text)
    replaced(SensorParams(), "reading_delay_steps", reading)
    replaced(WorldParams(), "torque_delay_ms", float(drive))


def polish_map_cell(values: dict, seed: int) -> dict:
    """One cell of the stability map (`polish_map.run_cell`): the held posture's strokes at this μ and
    latency from the process's settled posture; stable = the one verdict over the strokes is "stable"."""
    from app.headless.experiments.polish_map import run_cell

    m = run_cell(float(values["hold_swivel"]), float(values.get("mu", 0.25)), str(values.get("latency", "1+0")), seed)
    metrics = _scalars(m)
    metrics["stroke_verdicts"] = ",".join(m["stroke_verdicts"])
    return {"metrics": metrics, "stable": bool(m["stable"])}


def polish_map_report(out, records: list[dict], facts: dict | None, invocations: list[dict]) -> str:
    """The map's figure, its JSON and the margin's agreement (`sweep.stability_map`)."""
    from app.headless.sweep.stability_map import section

    return section(out, records, facts, invocations)


def polish_map_facts() -> dict:
    """The postures the map marks (`stability_map.marked_postures`), kept in sweep.json."""
    from app.headless.sweep.stability_map import marked_postures

    return marked_postures()


EXPERIMENTS: dict[str, SweepExperiment] = {
    "limit-drop": SweepExperiment(
        "limit-drop",
        LIMIT_DROP_KNOBS,
        limit_drop_cell,
        ("max_violation", "oscillations", "overshoot_beyond_ds", "peak_torque"),
        "joint 4 stays inside its limit (max violation ≤ 0)",
        seeded=False,
        groups=limit_drop_groups,
    ),
    "mass-drop": SweepExperiment(
        "mass-drop",
        MASS_DROP_KNOBS,
        mass_drop_cell,
        ("peak_deflection_mm", "stabilization_time_s", "residual_error_mm"),
        "the TCP settles inside the 1 mm band and stays there for at least the last 0.1 s of the window",
        groups=mass_drop_groups,
    ),
    "polish": SweepExperiment(
        "polish",
        POLISH_KNOBS,
        polish_cell,
        ("stable", "force_error_ptp", "force_error_ma", "contact_lost_ms", "converged_swivel_deg"),
        polish_stable_means,
        groups=polish_groups,
        any_param=True,
        overlay=polish_overlay,
        report_notes=polish_notes,
        model_facts=polish_model_facts,
    ),
    "polish-map": SweepExperiment(
        "polish-map",
        POLISH_MAP_KNOBS,
        polish_map_cell,
        ("stable",),
        polish_stable_means,
        groups=polish_groups,
        group_axis="hold_swivel",
        report_files=polish_map_report,
        local_only=True,
        model_facts=polish_map_facts,
    ),
}


def get(name: str) -> SweepExperiment:
    """The sweepable experiment `name`; SweepError naming the choices otherwise."""
    if name not in EXPERIMENTS:
        raise SweepError(f"unknown experiment {name!r}; sweepable: {', '.join(EXPERIMENTS)}")
    return EXPERIMENTS[name]
