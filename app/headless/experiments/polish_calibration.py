"""Is the force-loop margin a prediction? Its sign along the strokes against what the run did.

Predicted unstable: the worst decay rate σ of the linearised force loop over the six strokes
(`app.scenarios.polish_margin`, with the run's μ, sensor and latency) is negative.
Simulated unstable: the run diverged, lost contact during the strokes (true contact force ≤ 0 for
at least one 1 ms step), or oscillated: some stroke's force-error STD is at least
`OSCILLATION_FACTOR` times the noise floor, the STD that the sensor's noise and sinusoid alone give
after its low-pass (√(σ_n² α/(2 − α) + A²/2)).
"""

from __future__ import annotations

import html
import math

import numpy as np

OSCILLATION_FACTOR = 3.0  # calm strokes sit at 1.2-1.5x the floor, the S2/S4/S6 limit cycles at 6-8x (issue 24)
NOISE_VAR_N2, SINE_AMPLITUDE_N, CUTOFF_HZ, DT_S = 5.0, 2.0, 25.0, 1e-3  # the polish sensor's defaults ([T] §IV-A)


def noise_floor_std_n(
    noise_var_n2: float = NOISE_VAR_N2, sine_n: float = SINE_AMPLITUDE_N, cutoff_hz: float = CUTOFF_HZ, dt: float = DT_S
) -> float:
    """STD (N) of the reading's noise and sinusoid after the first-order low-pass ([T] §IV-A): white
    noise of variance σ² leaves σ² α/(2 − α); a slow sinusoid of amplitude A passes with A²/2."""
    alpha = 1.0 - math.exp(-2.0 * math.pi * cutoff_hz * dt) if cutoff_hz > 0 else 1.0
    return math.sqrt(noise_var_n2 * alpha / (2.0 - alpha) + 0.5 * sine_n**2)


def oscillation_threshold_n(cutoff_hz: float | None = None) -> float:
    """The stroke force-error STD (N) from which a stroke counts as oscillating."""
    return OSCILLATION_FACTOR * noise_floor_std_n(cutoff_hz=CUTOFF_HZ if cutoff_hz is None else float(cutoff_hz))


def outcome(result: dict) -> dict:
    """What the run did: unstable (bool) and why ("diverged", "contact lost", "oscillation", "" when
    stable), the largest stroke STD and the threshold it was held against."""
    stds = [s["force_error"]["std"] for s in result.get("per_segment", []) if s["force_error"]["std"] is not None]
    worst = max(stds) if stds else None
    limit = oscillation_threshold_n(result.get("sensor_cutoff_hz"))
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


def growth_limit_np(force_n: float = 20.0) -> float:
    """ln(F̂ / noise floor) (nepers): the growth that takes a disturbance at the noise floor to the
    desired force itself, i.e. to contact loss ([T] Table II F̂ = 20 N)."""
    return math.log(force_n / noise_floor_std_n())


def predicted_unstable_by_growth(result: dict) -> bool | None:
    """The margin's second verdict: some stroke accumulates a growth G ≥ `growth_limit_np`."""
    g = (result.get("stroke") or {}).get("growth_max_np")
    return None if g is None else bool(g >= growth_limit_np())


def predicted_unstable(result: dict) -> bool | None:
    """The margin's verdict: the worst σ over the strokes is negative (None without stroke samples)."""
    rate = (result.get("stroke") or {}).get("rate_min_per_s")
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


def report_section(runs: list[dict]) -> str:
    """HTML: per run, the worst σ of each stroke, the stretching strokes' P_d·f̂, the verdicts; then
    the confusion table over the runs. Empty when no run carries stroke samples."""
    runs = [r for r in runs if r.get("stroke_margin")]
    if not runs:
        return ""
    rows, pairs = [], []
    for r in runs:
        seg = {s["segment"]: s for s in r["stroke_margin"]}
        o = outcome(r)
        pred = predicted_unstable(r)
        if pred is not None:
            pairs.append((pred, o["unstable"]))
        pd = r["stroke"].get("stretch_pd_fhat") or {}
        cells = "".join(f"<td>{_f(seg[k]['rate_min_per_s']) if k in seg else '-'}</td>" for k in range(1, 7))
        verdict = "-" if pred is None else ("unstable" if pred else "stable")
        sim = o["why"] or "stable"
        mark = "" if pred is None or pred == o["unstable"] else " style='background:#fdd'"
        rows.append(
            f"<tr{mark}><td>{html.escape(str(r['row']))}</td><td>{r['mu']:g}</td><td>{r['seed']}</td>{cells}"
            f"<td>{_f(r['stroke'].get('kd_margin_min'), 0)}</td><td>{r['stroke']['growth_max_np']:.1f}</td>"
            f"<td>{_f(pd.get('mean'), 3)}</td><td>{_f(pd.get('max'), 3)}</td><td>{verdict}</td>"
            f"<td>{sim} ({_f(o['stroke_std_max_n'])} N)</td></tr>"
        )
    loops = {(r["stroke_loop"]["sensing_delay_steps"], r["stroke_loop"]["actuation_delay_steps"]) for r in runs}
    latency = "; ".join(f"d_s = {ds}, d_a = {da} periods" for ds, da in sorted(loops))
    limit = oscillation_threshold_n(runs[0].get("sensor_cutoff_hz"))
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
        "(N s/m). G: the largest growth (nepers) the rates accumulate on a stroke. P_d·f̂: mean and max "
        "over the stretching strokes S2, S4, S6. Predicted unstable when the worst σ is negative; simulated "
        f"unstable when the run diverged, lost contact, or a stroke's force-error STD reached {limit:.1f} N "
        f"({OSCILLATION_FACTOR:g}× the sensor's noise floor). Red rows disagree.</p>"
        "<table><tr><th>row</th><th>μ</th><th>seed</th>"
        + "".join(f"<th>σ S{k}</th>" for k in range(1, 7))
        + "<th>K_f^d margin</th><th>G</th><th>P_d·f̂ mean</th><th>P_d·f̂ max</th><th>predicted</th>"
        "<th>simulated (max stroke STD)</th></tr>"
        + "".join(rows)
        + "</table>"
        + confusion_table_html(confusion(pairs))
        + f"<p>By the growth G ≥ ln(F̂ / noise floor) = {growth_limit_np():.2f} Np instead:</p>"
        + confusion_table_html(
            confusion([(bool(predicted_unstable_by_growth(r)), outcome(r)["unstable"]) for r in runs]),
            "G ≥ limit",
            "G &lt; limit",
        )
    )


def calibration_metrics(result: dict) -> dict:
    """A sweep cell's scalars for the calibration: the margin's verdict and the run's outcome."""
    o = outcome(result)
    return {
        "predicted_unstable": predicted_unstable(result),
        "predicted_unstable_growth": predicted_unstable_by_growth(result),
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
    """HTML for a polish sweep: the confusion tables over its runs (one per cell and seed) of both
    verdicts, and every run where a verdict and the outcome disagree, by its swept values. Empty
    without verdicts."""
    runs = [
        r for r in records if r.get("status") == "ok" and (r.get("metrics") or {}).get("predicted_unstable") is not None
    ]
    if not runs:
        return ""
    sim = [bool(r["metrics"]["simulated_unstable"]) for r in runs]
    by_sign = [bool(r["metrics"]["predicted_unstable"]) for r in runs]
    grown = [r["metrics"].get("stroke_growth_max_np") for r in runs]
    limit = oscillation_threshold_n()
    text = (
        "<h3>Calibration of the force-loop margin</h3>"
        "<p>Predicted unstable: the worst decay rate σ of the linearised force loop over the six strokes, "
        "evaluated along each run's executed postures with its μ and latency, is negative. Simulated "
        "unstable: the run diverged, lost contact, or a stroke's force-error STD reached "
        f"{limit:.1f} N ({OSCILLATION_FACTOR:g}× the noise floor of the default sensor).</p>"
        + confusion_table_html(confusion(list(zip(by_sign, sim, strict=True))))
        + _disagreeing(names, runs, by_sign, sim, "the sign of σ")
    )
    if all(g is not None for g in grown):
        by_growth = [bool(g >= growth_limit_np()) for g in grown]
        text += (
            "<p>The same runs judged by the growth G a stroke accumulates (G ≥ ln(F̂ / noise floor) = "
            f"{growth_limit_np():.2f} Np: a disturbance at the noise floor grows to the desired force):</p>"
            + confusion_table_html(confusion(list(zip(by_growth, sim, strict=True))), "G ≥ limit", "G &lt; limit")
            + _disagreeing(names, runs, by_growth, sim, "the growth G")
        )
    return text


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
        f"<td>{_f(m.get('stroke_growth_max_np'), 1)}</td>"
        f"<td>{'unstable' if p else 'stable'}</td><td>{html.escape(str(m['outcome']))}</td>"
        f"<td>{_f(m.get('stroke_std_max_n'), 1)}</td><td>{m.get('contact_lost_ms', '-')}</td>"
        f"<td>S{m.get('growth_segment', '-')}: {_f(m.get('growth_segment_mode_hz'), 1)} / "
        f"{_f(m.get('growth_segment_peak_hz'), 1)}</td><td>{_f(m.get('growth_segment_observed_np'), 1)}</td></tr>"
        for r, p in bad
        for m in [r["metrics"]]
    )
    return (
        f"<p>Disagreeing runs by {verdict} ({len(bad)}):</p>"
        f"<table><tr>{head}<th>seed</th><th>σ_min (1/s)</th><th>G (Np)</th>"
        "<th>predicted</th><th>simulated</th><th>max stroke STD (N)</th>"
        "<th>contact lost (ms)</th><th>stroke of the largest G: mode Hz, model / simulation</th>"
        f"<th>observed growth there (Np)</th></tr>{rows}</table>"
    )
