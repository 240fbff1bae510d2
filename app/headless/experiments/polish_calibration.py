"""Is the force-loop margin a prediction? Its sign along the strokes against what the run did.

Predicted unstable: the stroke headroom h = ln(F̂ / noise floor) − G (`app.scenarios.polish_margin`,
with the run's μ, sensor and latency) falls below 0 on some stroke: a disturbance at the sensor's
noise floor in the contact mode's band grows to the desired force before the stroke ends. The sign of
the worst decay rate σ over the strokes is kept beside it as the instantaneous verdict.
Simulated unstable: the one verdict (`app.scenarios.verdict`) is not "stable": the run diverged, lost
contact, or some stroke oscillated. The calibration shows the agreement at the verdict's threshold
× 0.5, × 1 and × 2 (`threshold_sensitivity`), each cell's seeds judged together: a cell whose seeds
disagree is named as such, not counted for either side.
"""

from __future__ import annotations

import base64
import dataclasses
import html
import io
from collections.abc import Mapping

import numpy as np

from app.scenarios import polish_stroke as PS
from app.scenarios import verdict as V
from app.scenarios.polish_margin import headroom_budget_np, sensor_floor_n
from app.sim.sensor import SensorParams

DEFAULT_DT_S = 1e-3  # the step of runs that did not record theirs
THRESHOLD_SCALES = (0.5, 1.0, 2.0)  # the verdict's oscillation threshold × these: its sensitivity
MIN_BOUNDARY_SEEDS = 3  # seeds a cell within a factor 2 of the threshold needs


def run_sensor(result: Mapping) -> dict:
    """The run's sensor fields (`SensorParams`): as the run recorded them, the defaults for a run that
    recorded none, or from a sweep record's flattened "sensor_FIELD" metrics."""
    defaults = dataclasses.asdict(SensorParams())
    own = result.get("sensor")
    if isinstance(own, Mapping):
        return {**defaults, **own}
    return {k: result.get(f"sensor_{k}", v) for k, v in defaults.items()}


def run_dt(result: Mapping) -> float:
    """The run's step (s)."""
    return float(result.get("timestep_s") or DEFAULT_DT_S)


def run_floor_n(result: Mapping) -> float:
    """The margin's noise floor of the run (N): its sensor's noise in the contact mode's band."""
    return sensor_floor_n(run_sensor(result), run_dt(result))


def run_threshold_n(result: Mapping) -> float:
    """The run's oscillation threshold (N): as recorded, else from its sensor (`verdict`)."""
    own = result.get("oscillation_threshold_n")
    return float(own) if own is not None else V.oscillation_threshold_n(run_sensor(result), run_dt(result))


def run_verdict(result: Mapping, scale: float = 1.0) -> str:
    """The run's one verdict with the threshold × scale: recomputed from its recorded band RMS, as
    recorded when it has none (a run stopped while held), else from its divergence and lost contact
    alone (a record made before the verdict)."""
    if result.get("diverged"):
        return V.DIVERGED
    rms = result.get("band_rms_max_n")
    if rms is not None:
        return V.judge(float(rms), int(result.get("contact_lost_ms") or 0), run_threshold_n(result), scale)
    if result.get("verdict"):
        return str(result["verdict"])
    return V.DIVERGED if result.get("diverged") else V.LOST if (result.get("contact_lost_ms") or 0) > 0 else V.STABLE


def outcome(result: Mapping, scale: float = 1.0) -> dict:
    """What the run did by the one verdict: unstable (bool), the verdict, the worst stroke's band RMS
    and the threshold it was held against."""
    verdict = run_verdict(result, scale)
    return {
        "unstable": V.unstable(verdict),
        "why": verdict,
        "band_rms_max_n": result.get("band_rms_max_n"),
        "threshold_n": scale * run_threshold_n(result),
    }


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


def _verdicts_text(force_n: float, floor_n: float, budget_np: float, threshold_n: float, run: dict) -> str:
    """The two verdicts and the outcome in words, with the run's F̂, floor and threshold (`run`: the
    record the verdict's band is read from)."""
    return (
        "Predicted unstable (the margin's verdict): the stroke headroom h = ln(F̂ / floor) − G falls below 0 "
        f"on some stroke, with F̂ = {force_n:g} N and the sensor's noise floor in the contact mode's band "
        f"{floor_n:.3f} N, so each stroke starts with {budget_np:.2f} Np and G is the growth "
        "G_k = max(0, G_{k−1} − σ_k Δt) the rates accumulate along it: a disturbance at the noise floor "
        "reaches the desired force before the stroke ends. Beside it, the instantaneous verdict: the worst "
        "σ over the strokes is negative. Simulated unstable: the one verdict is not stable. "
        + V.definition_text(threshold_n, run)
    )


def _sample_ms(runs: list[dict]) -> str:
    """The postures' spacing along the strokes as the runs recorded it ("25 ms")."""
    spacing = sorted({r.get("stroke_loop", {}).get("sample_s") for r in runs} - {None})
    return " / ".join(f"{1e3 * s:g} ms" for s in spacing) if spacing else "(spacing not recorded)"


def _run_figures(runs: list[dict]) -> tuple[float, float, float, float]:
    """(F̂, margin floor, budget, oscillation threshold) of the first run, the runs' common sensor."""
    r = runs[0]
    return desired_force_n(r), run_floor_n(r), headroom_budget(r), run_threshold_n(r)


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
        sim = o["why"]
        mark = "" if pred is None or pred == o["unstable"] else " style='background:#fdd'"
        rows.append(
            f"<tr{mark}><td>{html.escape(str(r['row']))}</td><td>{r['mu']:g}</td><td>{r['seed']}</td>{cells}"
            f"<td>{_f(r['stroke'].get('kd_margin_min'), 0)}</td><td>{r['stroke']['growth_max_np']:.1f}</td>"
            f"<td>{_f(headroom_min(r), 2)}</td>"
            f"<td>{_f(pd.get('mean'), 3)}</td><td>{_f(pd.get('max'), 3)}</td><td>{verdict}</td><td>{verdict_rate}</td>"
            f"<td>{sim} ({_f(o['band_rms_max_n'], 2)} N)</td></tr>"
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
        f"{_sample_ms(runs)}, linearised about the commanded sliding speed and the segment's friction direction; each "
        "cell is a stroke's worst value (negative: a mode grows). K_f^d margin: the worst over all strokes "
        "(N s/m). G: the largest growth (nepers) the rates accumulate on a stroke; h_min: the least headroom "
        "(Np). P_d·f̂: mean and max over the stretching strokes S2, S4, S6. "
        f"{html.escape(_verdicts_text(force, floor, budget, limit, runs[0]))} Red rows disagree with the headroom.</p>"
        "<table><tr><th>row</th><th>μ</th><th>seed</th>"
        + "".join(f"<th>σ S{k}</th>" for k in range(1, 7))
        + "<th>K_f^d margin</th><th>G</th><th>h_min</th><th>P_d·f̂ mean</th><th>P_d·f̂ max</th>"
        "<th>predicted (h)</th><th>predicted (σ)</th><th>simulated (worst stroke band RMS)</th></tr>"
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
        "outcome": o["why"],
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
    """HTML for a polish sweep: the margin's agreement with the one verdict at the threshold × 0.5,
    × 1, × 2 over the grid's cells (seeds judged together, `threshold_sensitivity`) with the cells
    whose seeds disagree and the boundary cells; then the confusion tables over its runs (one per cell
    and seed) of the headroom's verdict and of σ's, each followed by every run where it and the
    outcome disagree; then the margin's growth against the observed one (`growth_comparison`). Both
    verdicts come from each record's own metrics (its growth, worst σ, sensor, F̂, band RMS), so a
    redrawn report of older records judges them alike. Empty without verdicts."""
    runs = [r for r in records if r.get("status") == "ok" and headroom_min(r.get("metrics") or {}) is not None]
    if not runs:
        return ""
    metrics = [r["metrics"] for r in runs]
    sim = [outcome(m)["unstable"] for m in metrics]
    by_h = [bool(predicted_unstable(m)) for m in metrics]
    text = (
        "<h3>Calibration of the force-loop margin</h3>"
        f"<p>{html.escape(_sweep_verdicts_text(metrics))}</p>"
        + sensitivity_html(names, threshold_sensitivity(names, runs))
        + "<p>Per run, at the threshold × 1, by the sign of the headroom (the margin's verdict):</p>"
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
    return text + growth_html(growth_comparison(metrics))


def cell_key(names: list[str], record: Mapping) -> tuple:
    """The grid point of a sweep record (its swept values in the grid's order)."""
    return tuple(record["params"].get(n) for n in names)


def threshold_sensitivity(names: list[str], runs: list[dict], scales: tuple = THRESHOLD_SCALES) -> dict:
    """Per threshold scale: each cell's simulated verdict over its seeds (all seeds unstable, all
    stable, or "seeds disagree") and the margin's (likewise), the agreement over the cells where both
    are decided, and the cells left undecided; beside them the boundary cells (a seed's worst band RMS
    within a factor 2 of the threshold × 1) and those of them with fewer than `MIN_BOUNDARY_SEEDS` seeds."""
    cells: dict[tuple, list[dict]] = {}
    for r in runs:
        cells.setdefault(cell_key(names, r), []).append(r)
    per_scale = []
    for scale in scales:
        rows, agree, decided = [], 0, 0
        for key, rs in cells.items():
            sims = {outcome(r["metrics"], scale)["unstable"] for r in rs}
            preds = {bool(predicted_unstable(r["metrics"])) for r in rs}
            sim = None if len(sims) > 1 else sims.pop()
            pred = None if len(preds) > 1 else preds.pop()
            if sim is not None and pred is not None:
                decided += 1
                agree += int(sim == pred)
            rows.append({"cell": key, "seeds": len(rs), "simulated": sim, "predicted": pred})
        per_scale.append(
            {
                "scale": scale,
                "cells": rows,
                "decided": decided,
                "agree": agree,
                "agreement": agree / decided if decided else None,
                "seeds_disagree": [c["cell"] for c in rows if c["simulated"] is None],
                "margin_seeds_disagree": [c["cell"] for c in rows if c["predicted"] is None],
            }
        )
    boundary: list[dict] = []
    for key, rs in cells.items():
        ratios = [
            float(m["band_rms_max_n"]) / run_threshold_n(m)
            for m in (r["metrics"] for r in rs)
            if m.get("band_rms_max_n") is not None and not (m.get("contact_lost_ms") or m.get("diverged"))
        ]
        if any(0.5 <= x <= 2.0 for x in ratios):
            verdicts = sorted({outcome(r["metrics"])["why"] for r in rs})
            boundary.append({"cell": key, "seeds": len(rs), "ratios": ratios, "verdicts": verdicts})
    return {
        "scales": per_scale,
        "boundary": boundary,
        "boundary_short": [b["cell"] for b in boundary if int(b["seeds"]) < MIN_BOUNDARY_SEEDS],
        "cells": len(cells),
    }


def _cell_text(names: list[str], key: tuple) -> str:
    return ", ".join(f"{n} {v}" for n, v in zip(names, key, strict=True))


def sensitivity_html(names: list[str], sens: dict) -> str:
    """The agreement table at each threshold scale, the cells whose seeds disagree, the boundary cells."""

    def pct(x) -> str:
        return "-" if x is None else f"{100 * x:.0f} %"

    rows = "".join(
        f"<tr><td>× {e['scale']:g}</td><td>{e['agree']} of {e['decided']}</td><td>{pct(e['agreement'])}</td>"
        f"<td>{len(e['seeds_disagree'])}</td><td>{len(e['margin_seeds_disagree'])}</td>"
        f"<td>{sum(1 for c in e['cells'] if c['simulated'])}</td></tr>"
        for e in sens["scales"]
    )
    undecided = "".join(
        f"<li>× {e['scale']:g}: " + html.escape("; ".join(_cell_text(names, k) for k in e["seeds_disagree"])) + "</li>"
        for e in sens["scales"]
        if e["seeds_disagree"]
    )
    boundary = "".join(
        f"<tr><td>{html.escape(_cell_text(names, b['cell']))}</td><td>{b['seeds']}</td>"
        f"<td>{' / '.join(f'{x:.2f}' for x in b['ratios'])}</td><td>{html.escape(', '.join(b['verdicts']))}</td></tr>"
        for b in sens["boundary"]
    )
    short = sens["boundary_short"]
    return (
        f"<p>Threshold sensitivity over the {sens['cells']} cells: the margin's sign (h_min &lt; 0) against the "
        "one verdict with its oscillation threshold halved, as defined and doubled. A cell is decided when all "
        "its seeds give the same verdict (and the margin the same sign); a cell whose seeds disagree is "
        "reported as such and counted for neither side.</p>"
        "<table><tr><th>threshold</th><th>cells agreeing</th><th>agreement</th><th>seeds disagree</th>"
        f"<th>margin's seeds disagree</th><th>cells unstable (all seeds)</th></tr>{rows}</table>"
        + (
            f"<p>Cells whose seeds disagree:</p><ul>{undecided}</ul>"
            if undecided
            else "<p>No cell's seeds disagree.</p>"
        )
        + f"<p>Boundary cells (a seed's worst stroke band RMS within a factor 2 of the threshold, contact kept; "
        f"{len(sens['boundary'])} cells, {len(short)} with fewer than {MIN_BOUNDARY_SEEDS} seeds"
        + (": " + html.escape("; ".join(_cell_text(names, k) for k in short)) if short else "")
        + "):</p><table><tr><th>cell</th><th>seeds</th><th>band RMS / threshold per seed</th><th>verdicts</th></tr>"
        + boundary
        + "</table>"
    )


def growth_comparison(metrics: list[dict]) -> dict | None:
    """The margin's growth G on each run's stroke of largest G against the growth the run's band envelope
    showed there (`observed_mode`), over the runs that kept contact (a lost contact ends the
    linear growth): the pairs, the mean and RMS error (predicted − observed, Np) and the error
    over the runs with G > 0. None without pairs."""
    pairs = [
        (float(m["growth_segment_np"]), float(m["growth_segment_observed_np"]))
        for m in metrics
        if m.get("growth_segment_np") is not None
        and m.get("growth_segment_observed_np") is not None
        and not (m.get("contact_lost_ms") or m.get("diverged"))
    ]
    if not pairs:
        return None
    p = np.array(pairs)
    err = p[:, 0] - p[:, 1]
    grew = p[:, 0] > 0.0
    return {
        "pairs": pairs,
        "n": len(pairs),
        "mean_error_np": float(np.mean(err)),
        "rms_error_np": float(np.sqrt(np.mean(err**2))),
        "n_growing": int(np.sum(grew)),
        "rms_error_growing_np": float(np.sqrt(np.mean(err[grew] ** 2))) if np.any(grew) else None,
        "max_abs_error_np": float(np.max(np.abs(err))),
    }


def growth_html(g: dict | None) -> str:
    """The predicted-against-observed growth figure (inline PNG) with its errors ("" without pairs)."""
    if g is None:
        return ""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    p = np.array(g["pairs"])
    fig, ax = plt.subplots(figsize=(4.8, 4.2))
    ax.scatter(p[:, 1], p[:, 0], s=14)
    top = float(max(1.0, p.max()) * 1.05)
    ax.plot([0, top], [0, top], "k--", lw=0.8, label="predicted = observed")
    ax.set_xlabel("observed growth of the mode's band envelope (Np)")
    ax.set_ylabel("margin's growth G (Np)")
    ax.set_title("Stroke of the largest G, runs that kept contact", fontsize=9)
    ax.legend(fontsize=8)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    grow = "-" if g["rms_error_growing_np"] is None else f"{g['rms_error_growing_np']:.2f}"
    return (
        "<p>The margin's growth G against the observed growth (the largest rise of the band envelope of the "
        f"true contact force over 0.25 s bins) on each run's stroke of the largest G, over {g['n']} runs that "
        f"kept contact: mean error (G − observed) {g['mean_error_np']:+.2f} Np, RMS {g['rms_error_np']:.2f} Np, "
        f"largest {g['max_abs_error_np']:.2f} Np; over the {g['n_growing']} runs with G &gt; 0, RMS {grow} Np.</p>"
        f"<img alt='predicted against observed growth' src='data:image/png;base64,"
        f"{base64.b64encode(buf.getvalue()).decode()}'>"
    )


def _sweep_verdicts_text(metrics: list[dict]) -> str:
    """`_verdicts_text` with the records' F̂, floor and budget (their range when the sweep varies them)."""
    force = sorted({desired_force_n(m) for m in metrics})
    floors = sorted({round(run_floor_n(m), 6) for m in metrics})
    thresholds = sorted({round(run_threshold_n(m), 6) for m in metrics})
    if len(force) == 1 and len(floors) == 1 and len(thresholds) == 1:
        return _verdicts_text(force[0], floors[0], headroom_budget(metrics[0]), thresholds[0], metrics[0])
    return (
        "Predicted unstable: the stroke headroom h = ln(F̂ / floor) − G falls below 0 on some stroke (F̂ "
        f"{force[0]:g}–{force[-1]:g} N, noise floor in the mode's band {floors[0]:.3f}–{floors[-1]:.3f} N, each "
        "run's own); beside it, the worst σ is negative. Simulated unstable: the one verdict is not stable "
        f"(oscillation threshold {thresholds[0]:.2f}–{thresholds[-1]:.2f} N, each run's own). "
        + V.definition_text(thresholds[0], metrics[0])
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
        f"<td>{'unstable' if p else 'stable'}</td><td>{html.escape(outcome(m)['why'])}</td>"
        f"<td>{_f(m.get('band_rms_max_n'), 2)}</td><td>{m.get('contact_lost_ms', '-')}</td>"
        f"<td>S{m.get('growth_segment', '-')}: {_f(m.get('growth_segment_mode_hz'), 1)} / "
        f"{_f(m.get('growth_segment_peak_hz'), 1)}</td><td>{_f(m.get('growth_segment_observed_np'), 1)}</td></tr>"
        for r, p in bad
        for m in [r["metrics"]]
    )
    return (
        f"<p>Disagreeing runs by {verdict} ({len(bad)}):</p>"
        f"<table><tr>{head}<th>seed</th><th>σ_min (1/s)</th><th>G (Np)</th><th>h_min (Np)</th>"
        "<th>predicted</th><th>simulated</th><th>worst stroke band RMS (N)</th>"
        "<th>contact lost (ms)</th><th>stroke of the largest G: mode Hz, model / simulation</th>"
        f"<th>observed growth there (Np)</th></tr>{rows}</table>"
    )
