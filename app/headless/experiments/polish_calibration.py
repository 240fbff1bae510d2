"""Is the force-loop margin a prediction? Its sign along the strokes against what the run did.

Predicted unstable: the stroke headroom h = ln(F̂ / noise floor) − G (`app.scenarios.polish_margin`,
with the run's μ, sensor and latency) falls below 0 on some stroke: a disturbance at the sensor's
noise floor grows to the desired force before the stroke ends. The sign of the worst decay rate σ
over the strokes is kept beside it as the instantaneous verdict.
Simulated unstable: the run diverged, lost contact during the strokes (true contact force ≤ 0 for
at least one 1 ms step), or oscillated: some stroke's force-error STD is at least
`OSCILLATION_FACTOR` times the noise floor, the STD that the run's sensor noise and sinusoid alone
give after its low-pass (`polish_margin.noise_floor_std_n`).
"""

from __future__ import annotations

import dataclasses
import html
from collections.abc import Mapping

import numpy as np

from app.scenarios import polish_stroke as PS
from app.scenarios.polish_margin import headroom_budget_np, sensor_floor_n
from app.sim.sensor import SensorParams

OSCILLATION_FACTOR = 3.0  # calm strokes sit at 1.2-1.5x the floor, the S2/S4/S6 limit cycles at 6-8x (issue 24)
DEFAULT_DT_S = 1e-3  # the step of runs that did not record theirs


def run_sensor(result: Mapping) -> dict:
    """The run's sensor fields (`SensorParams`): as the run recorded them, the defaults for a run that
    recorded none, or from a sweep record's flattened "sensor_FIELD" metrics."""
    defaults = dataclasses.asdict(SensorParams())
    own = result.get("sensor")
    if isinstance(own, Mapping):
        return {**defaults, **own}
    return {k: result.get(f"sensor_{k}", v) for k, v in defaults.items()}


def run_floor_n(result: Mapping) -> float:
    """The run's noise floor (N): its sensor's noise and sinusoid after its low-pass."""
    return sensor_floor_n(run_sensor(result), float(result.get("timestep_s") or DEFAULT_DT_S))


def oscillation_threshold_n(sensor: Mapping | None = None, dt: float = DEFAULT_DT_S) -> float:
    """The stroke force-error STD (N) from which a stroke counts as oscillating: `OSCILLATION_FACTOR`
    noise floors of this sensor (its fields; None: the defaults)."""
    return OSCILLATION_FACTOR * run_floor_n({"sensor": dict(sensor or {}), "timestep_s": dt})


def outcome(result: dict) -> dict:
    """What the run did: unstable (bool) and why ("diverged", "contact lost", "oscillation", "" when
    stable), the largest stroke STD and the threshold it was held against."""
    stds = [s["force_error"]["std"] for s in result.get("per_segment", []) if s["force_error"]["std"] is not None]
    worst = max(stds) if stds else None
    limit = OSCILLATION_FACTOR * run_floor_n(result)
    why = (
        "diverged"
        if result.get("diverged")
        else "contact lost"
        if result.get("contact_lost_ms", 0) > 0
        else "oscillation"
        if worst is not None and worst >= limit
        else ""
    )
    return {"unstable": bool(why), "why": why, "stroke_std_max_n": worst, "threshold_n": limit}


OBSERVED_BAND_HZ = (5.0, 40.0)  # where the force loop's modes lie (the linearised loop's: 13-14 Hz)
OBSERVED_HALF_BAND_HZ = 3.5  # the band around the stroke's spectral peak whose envelope is followed
OBSERVED_BIN_S = 0.25  # the envelope's averaging bins
OBSERVED_PAD_S = 0.5  # the series either side of the stroke that the band filter runs over


def observed_mode(error_n: np.ndarray, start: int, stop: int, dt: float) -> dict | None:
    """What the simulation did on one stroke (samples start:stop of a force-error series at step dt),
    for comparison with the linearised loop: the spectral peak (Hz) of the stroke's force error in
    `OBSERVED_BAND_HZ` (Hann window), the RMS (N) of the error in ±`OBSERVED_HALF_BAND_HZ` around it,
    and its observed growth (Np): the largest rise ln(b_j / b_i), j > i, of the band's envelope
    (|Hilbert transform|) averaged over `OBSERVED_BIN_S` bins, the counterpart of the margin's growth
    G. None for a stroke shorter than two bins."""
    from scipy.signal import butter, hilbert, sosfiltfilt

    x = np.asarray(error_n[start:stop], dtype=float)
    per_bin = max(1, round(OBSERVED_BIN_S / dt))
    if x.size < 2 * per_bin:
        return None
    x = x - np.mean(x)
    spectrum = np.abs(np.fft.rfft(x * np.hanning(x.size))) ** 2
    f = np.fft.rfftfreq(x.size, dt)
    inside = (f >= OBSERVED_BAND_HZ[0]) & (f <= OBSERVED_BAND_HZ[1])
    if not np.any(inside):
        return None
    peak = float(f[inside][np.argmax(spectrum[inside])])
    lo, hi = max(peak - OBSERVED_HALF_BAND_HZ, 0.5), min(peak + OBSERVED_HALF_BAND_HZ, 0.45 / dt)
    pad = round(OBSERVED_PAD_S / dt)
    a, b = max(0, start - pad), min(len(error_n), stop + pad)
    wide = np.asarray(error_n[a:b], dtype=float)
    band = sosfiltfilt(butter(4, [lo, hi], btype="band", fs=1.0 / dt, output="sos"), wide - np.mean(wide))
    env = np.abs(hilbert(band))[start - a : stop - a]
    bins = env[: env.size // per_bin * per_bin].reshape(-1, per_bin).mean(axis=1)
    logs = np.log(np.maximum(bins, 1e-12))
    growth = max(0.0, float(np.max(logs - np.minimum.accumulate(logs))))
    return {"peak_hz": peak, "band_rms_n": float(np.std(band[start - a : stop - a])), "growth_np": growth}


def desired_force_n(result: Mapping) -> float:
    """F̂ (N) of the run: as its margin recorded it (a sweep record: flattened), else the scenario's."""
    loop = result.get("stroke_loop")
    own = loop.get("desired_force_n") if isinstance(loop, Mapping) else result.get("stroke_loop_desired_force_n")
    return float(own) if own is not None else PS.DESIRED_FORCE_N


def headroom_budget(result: Mapping) -> float:
    """ln(F̂ / noise floor) (Np) of the run: the headroom each stroke starts with."""
    return headroom_budget_np(desired_force_n(result), run_floor_n(result))


def headroom_min(result: Mapping) -> float | None:
    """The least stroke headroom h = ln(F̂ / floor) − G (Np) over the run's strokes, from its largest
    growth G (a run dict, or a sweep record's flattened metrics); None without stroke samples."""
    stroke = result.get("stroke")
    g = stroke.get("growth_max_np") if isinstance(stroke, Mapping) else result.get("stroke_growth_max_np")
    return None if g is None else headroom_budget(result) - float(g)


def predicted_unstable(result: Mapping) -> bool | None:
    """The margin's verdict: the headroom falls below 0 on some stroke (None without stroke samples)."""
    h = headroom_min(result)
    return None if h is None else bool(h < 0.0)


def predicted_unstable_by_rate(result: Mapping) -> bool | None:
    """The instantaneous verdict beside it: the worst σ over the strokes is negative."""
    stroke = result.get("stroke")
    rate = stroke.get("rate_min_per_s") if isinstance(stroke, Mapping) else result.get("stroke_rate_min_per_s")
    return None if rate is None else bool(rate < 0.0)


def confusion(pairs: list[tuple[bool, bool]]) -> dict:
    """Counts of (predicted unstable, simulated unstable) and the agreement share."""
    c = {"tp": 0, "fp": 0, "fn": 0, "tn": 0}
    for pred, sim in pairs:
        c[("t" if pred == sim else "f") + ("p" if pred else "n")] += 1
    n = sum(c.values())
    return {**c, "n": n, "agreement": (c["tp"] + c["tn"]) / n if n else None}


def confusion_table_html(c: dict, unstable: str = "σ_min &lt; 0", stable: str = "σ_min ≥ 0") -> str:
    """The 2 × 2 table (rows: predicted, columns: simulated) with the agreement."""
    agree = "-" if c["agreement"] is None else f"{100 * c['agreement']:.0f} %"
    return (
        "<table><tr><th></th><th>simulated unstable</th><th>simulated stable</th></tr>"
        f"<tr><th>predicted unstable ({unstable})</th><td>{c['tp']}</td><td>{c['fp']}</td></tr>"
        f"<tr><th>predicted stable ({stable})</th><td>{c['fn']}</td><td>{c['tn']}</td></tr></table>"
        f"<p>Agreement {c['tp'] + c['tn']} of {c['n']} ({agree}).</p>"
    )


def _f(x, digits: int = 1) -> str:
    return "-" if x is None else f"{x:+.{digits}f}"


def runs_by_row(runs: list[dict]) -> list[tuple[tuple[str, float], list[dict]]]:
    """The runs grouped by (row, μ), groups and runs in the order the runs come."""
    groups: dict[tuple[str, float], list[dict]] = {}
    for r in runs:
        groups.setdefault((r["row"], r["mu"]), []).append(r)
    return list(groups.items())


def per_row(runs: list[dict]) -> list[dict]:
    """Per (row, μ), mean over its seeds: P_d·f̂ mean and max over the stretching strokes, P_d·f̂ at
    the start (stretching direction), the worst σ over the strokes; in the runs' order."""
    out = []
    for (row, mu), rs in runs_by_row(runs):
        pds = [r["stroke"]["stretch_pd_fhat"] for r in rs if r["stroke"].get("stretch_pd_fhat")]
        rates = [r["stroke"]["rate_min_per_s"] for r in rs if r["stroke"].get("rate_min_per_s") is not None]
        start = [r["Pd_fhat"]["stretch"] for r in rs if r.get("Pd_fhat")]
        floor = next((r["plan_stretch_floor"] for r in rs if r.get("plan_stretch_floor")), None)
        out.append(
            {
                "row": row,
                "mu": mu,
                "n": len(rs),
                "pd_start": sum(start) / len(start) if start else None,
                "pd_stretch_mean": sum(p["mean"] for p in pds) / len(pds) if pds else None,
                "pd_stretch_max": sum(p["max"] for p in pds) / len(pds) if pds else None,
                "rate_min_per_s": sum(rates) / len(rates) if rates else None,
                "loop_best": floor,  # a signed-cost plan: the least max(P_d·f̂, 0) the loop allows on the stretches
            }
        )
    return out


def _floor(x: dict | None) -> str:
    if not x:
        return "-"
    return f"{x['loop_best_mean']:.3f} ({x['loop_best_max']:.3f}) / {x['plan_mean']:.3f} ({x['plan_max']:.3f})"


def _verdicts_text(force_n: float, floor_n: float, budget_np: float, threshold_n: float) -> str:
    """The two verdicts and the outcome in words, with the run's F̂, floor and threshold."""
    return (
        "Predicted unstable (the margin's verdict): the stroke headroom h = ln(F̂ / floor) − G falls below 0 "
        f"on some stroke, with F̂ = {force_n:g} N and the sensor's noise floor {floor_n:.2f} N (its noise and "
        f"sinusoid after its low-pass), so each stroke starts with {budget_np:.2f} Np and G is the growth "
        "G_k = max(0, G_{k−1} − σ_k Δt) the rates accumulate along it: a disturbance at the noise floor "
        "reaches the desired force before the stroke ends. Beside it, the instantaneous verdict: the worst "
        "σ over the strokes is negative. Simulated unstable: the run diverged, lost contact, or a stroke's "
        f"force-error STD reached {threshold_n:.1f} N ({OSCILLATION_FACTOR:g}× the noise floor)."
    )


def _run_figures(runs: list[dict]) -> tuple[float, float, float, float]:
    """(F̂, floor, budget, oscillation threshold) of the first run, the runs' common sensor."""
    r = runs[0]
    return desired_force_n(r), run_floor_n(r), headroom_budget(r), OSCILLATION_FACTOR * run_floor_n(r)


def report_section(runs: list[dict]) -> str:
    """HTML: per run, the worst σ of each stroke, the stretching strokes' P_d·f̂, the least headroom,
    both verdicts; then the confusion tables over the runs (the headroom's, then σ's). Empty when no
    run carries stroke samples."""
    runs = [r for r in runs if r.get("stroke_margin")]
    if not runs:
        return ""
    rows, by_h, by_rate = [], [], []
    for r in runs:
        seg = {s["segment"]: s for s in r["stroke_margin"]}
        o = outcome(r)
        pred, pred_rate = predicted_unstable(r), predicted_unstable_by_rate(r)
        if pred is not None:
            by_h.append((pred, o["unstable"]))
        if pred_rate is not None:
            by_rate.append((pred_rate, o["unstable"]))
        pd = r["stroke"].get("stretch_pd_fhat") or {}
        cells = "".join(f"<td>{_f(seg[k]['rate_min_per_s']) if k in seg else '-'}</td>" for k in range(1, 7))
        verdict = "-" if pred is None else ("unstable" if pred else "stable")
        verdict_rate = "-" if pred_rate is None else ("unstable" if pred_rate else "stable")
        sim = o["why"] or "stable"
        mark = "" if pred is None or pred == o["unstable"] else " style='background:#fdd'"
        rows.append(
            f"<tr{mark}><td>{html.escape(str(r['row']))}</td><td>{r['mu']:g}</td><td>{r['seed']}</td>{cells}"
            f"<td>{_f(r['stroke'].get('kd_margin_min'), 0)}</td><td>{r['stroke']['growth_max_np']:.1f}</td>"
            f"<td>{_f(headroom_min(r), 2)}</td>"
            f"<td>{_f(pd.get('mean'), 3)}</td><td>{_f(pd.get('max'), 3)}</td><td>{verdict}</td><td>{verdict_rate}</td>"
            f"<td>{sim} ({_f(o['stroke_std_max_n'])} N)</td></tr>"
        )
    loops = {(r["stroke_loop"]["sensing_delay_steps"], r["stroke_loop"]["actuation_delay_steps"]) for r in runs}
    latency = "; ".join(f"d_s = {ds}, d_a = {da} periods" for ds, da in sorted(loops))
    force, floor, budget, limit = _run_figures(runs)
    row_table = "".join(
        f"<tr><td>{html.escape(str(e['row']))}</td><td>{e['mu']:g}</td><td>{e['n']}</td>"
        f"<td>{_f(e['pd_start'], 3)}</td><td>{_f(e['pd_stretch_mean'], 3)}</td>"
        f"<td>{_f(e['pd_stretch_max'], 3)}</td><td>{_f(e['rate_min_per_s'])}</td><td>{_floor(e['loop_best'])}</td></tr>"
        for e in per_row(runs)
    )
    return (
        "<h2>Force-loop margin along the strokes</h2>"
        "<p>Per row (mean over its seeds): the directional coupling P_d·f̂ [T10] at the trajectory start and "
        "its mean and max over the stretching strokes as executed, and the worst σ (1/s) over all strokes.</p>"
        "<table><tr><th>row</th><th>μ</th><th>runs</th><th>P_d·f̂ start</th><th>P_d·f̂ stretch mean</th>"
        f"<th>P_d·f̂ stretch max</th><th>worst σ</th><th>plan: loop's best / plan's own max(P_d·f̂, 0), "
        f"stretch mean (max)</th></tr>{row_table}</table>"
        "<p>σ = −ln ρ(Φ)/Δt (1/s) of the linearised force loop (contact stiffness, friction, the shaped "
        "inertia along z, K_f^p, K_f^d, K_f^i, the sensor's low-pass, the reading d_s periods late and the "
        f"torque d_a periods late; {html.escape(latency)}) at each posture the run passed through every "
        "25 ms, linearised about the commanded sliding speed and the segment's friction direction; each "
        "cell is a stroke's worst value (negative: a mode grows). K_f^d margin: the worst over all strokes "
        "(N s/m). G: the largest growth (nepers) the rates accumulate on a stroke; h_min: the least headroom "
        "(Np). P_d·f̂: mean and max over the stretching strokes S2, S4, S6. "
        f"{html.escape(_verdicts_text(force, floor, budget, limit))} Red rows disagree with the headroom.</p>"
        "<table><tr><th>row</th><th>μ</th><th>seed</th>"
        + "".join(f"<th>σ S{k}</th>" for k in range(1, 7))
        + "<th>K_f^d margin</th><th>G</th><th>h_min</th><th>P_d·f̂ mean</th><th>P_d·f̂ max</th>"
        "<th>predicted (h)</th><th>predicted (σ)</th><th>simulated (max stroke STD)</th></tr>"
        + "".join(rows)
        + "</table><p>By the sign of the headroom (the margin's verdict):</p>"
        + confusion_table_html(confusion(by_h), "h_min &lt; 0", "h_min ≥ 0")
        + "<p>By the sign of the worst σ (the instantaneous verdict):</p>"
        + confusion_table_html(confusion(by_rate))
    )


def calibration_metrics(result: dict) -> dict:
    """A sweep cell's scalars for the calibration: both verdicts, the least headroom and the run's
    outcome."""
    o = outcome(result)
    return {
        "predicted_unstable": predicted_unstable(result),
        "predicted_unstable_rate": predicted_unstable_by_rate(result),
        "headroom_min_np": headroom_min(result),
        "headroom_budget_np": headroom_budget(result),
        "simulated_unstable": o["unstable"],
        "outcome": o["why"] or "stable",
        "stroke_std_max_n": o["stroke_std_max_n"],
        **growth_stroke(result),
    }


def growth_stroke(result: dict) -> dict:
    """The stroke where the margin's growth G is largest, model beside simulation: its segment, G,
    the model's mode frequency at the stroke's worst σ, and the run's spectral peak and observed
    growth there (`observed_mode`); {} without stroke samples."""
    strokes = result.get("stroke_margin") or []
    if not strokes:
        return {}
    worst = max(strokes, key=lambda s: s["growth_np"])
    seg: dict = next((s for s in result.get("per_segment", []) if s["segment"] == worst["segment"]), {})
    seen = seg.get("observed") or {}
    return {
        "growth_segment": worst["segment"],
        "growth_segment_np": worst["growth_np"],
        "growth_segment_mode_hz": worst.get("mode_hz_at_worst"),
        "growth_segment_peak_hz": seen.get("peak_hz"),
        "growth_segment_observed_np": seen.get("growth_np"),
    }


def sweep_section(names: list[str], records: list[dict]) -> str:
    """HTML for a polish sweep: the confusion tables over its runs (one per cell and seed) of the
    headroom's verdict and of σ's, each followed by every run where it and the outcome disagree, by
    its swept values. Both verdicts come from each record's own metrics (its growth, worst σ, sensor
    and F̂), so a redrawn report of older records judges them alike. Empty without verdicts."""
    runs = [r for r in records if r.get("status") == "ok" and headroom_min(r.get("metrics") or {}) is not None]
    if not runs:
        return ""
    metrics = [r["metrics"] for r in runs]
    sim = [bool(m["simulated_unstable"]) for m in metrics]
    by_h = [bool(predicted_unstable(m)) for m in metrics]
    text = (
        "<h3>Calibration of the force-loop margin</h3>"
        f"<p>{html.escape(_sweep_verdicts_text(metrics))}</p>"
        "<p>By the sign of the headroom (the margin's verdict):</p>"
        + confusion_table_html(confusion(list(zip(by_h, sim, strict=True))), "h_min &lt; 0", "h_min ≥ 0")
        + _disagreeing(names, runs, by_h, sim, "the sign of the headroom")
    )
    rates = [predicted_unstable_by_rate(m) for m in metrics]
    if all(p is not None for p in rates):
        by_rate = [bool(p) for p in rates]
        text += (
            "<p>The same runs by the sign of the worst σ (the instantaneous verdict):</p>"
            + confusion_table_html(confusion(list(zip(by_rate, sim, strict=True))))
            + _disagreeing(names, runs, by_rate, sim, "the sign of σ")
        )
    return text


def _sweep_verdicts_text(metrics: list[dict]) -> str:
    """`_verdicts_text` with the records' F̂, floor and budget (their range when the sweep varies them)."""
    force = sorted({desired_force_n(m) for m in metrics})
    floors = sorted({round(run_floor_n(m), 6) for m in metrics})
    if len(force) == 1 and len(floors) == 1:
        return _verdicts_text(force[0], floors[0], headroom_budget(metrics[0]), OSCILLATION_FACTOR * floors[0])
    return (
        "Predicted unstable: the stroke headroom h = ln(F̂ / floor) − G falls below 0 on some stroke (F̂ "
        f"{force[0]:g}–{force[-1]:g} N, noise floor {floors[0]:.2f}–{floors[-1]:.2f} N, each run's own); "
        "beside it, the worst σ is negative. Simulated unstable: diverged, lost contact, or a stroke's "
        f"force-error STD of at least {OSCILLATION_FACTOR:g}× the run's noise floor."
    )


def _disagreeing(names: list[str], runs: list[dict], predicted: list[bool], sim: list[bool], verdict: str) -> str:
    """The table of the runs whose `predicted` differs from `sim`, or a sentence that none does."""
    bad = [(r, p) for r, p, s in zip(runs, predicted, sim, strict=True) if p != s]
    if not bad:
        return f"<p>No run disagrees with {verdict}.</p>"
    head = "".join(f"<th>{html.escape(n)}</th>" for n in names)
    rows = "".join(
        "<tr>"
        + "".join(f"<td>{html.escape(str(r['params'].get(n)))}</td>" for n in names)
        + f"<td>{r.get('seed', '-')}</td><td>{_f(m.get('stroke_rate_min_per_s'), 2)}</td>"
        f"<td>{_f(m.get('stroke_growth_max_np'), 1)}</td><td>{_f(headroom_min(m), 2)}</td>"
        f"<td>{'unstable' if p else 'stable'}</td><td>{html.escape(str(m['outcome']))}</td>"
        f"<td>{_f(m.get('stroke_std_max_n'), 1)}</td><td>{m.get('contact_lost_ms', '-')}</td>"
        f"<td>S{m.get('growth_segment', '-')}: {_f(m.get('growth_segment_mode_hz'), 1)} / "
        f"{_f(m.get('growth_segment_peak_hz'), 1)}</td><td>{_f(m.get('growth_segment_observed_np'), 1)}</td></tr>"
        for r, p in bad
        for m in [r["metrics"]]
    )
    return (
        f"<p>Disagreeing runs by {verdict} ({len(bad)}):</p>"
        f"<table><tr>{head}<th>seed</th><th>σ_min (1/s)</th><th>G (Np)</th><th>h_min (Np)</th>"
        "<th>predicted</th><th>simulated</th><th>max stroke STD (N)</th>"
        "<th>contact lost (ms)</th><th>stroke of the largest G: mode Hz, model / simulation</th>"
        f"<th>observed growth there (Np)</th></tr>{rows}</table>"
    )
