"""The force-loop margin along the polish stroke (`control.margin` with the run's own latency).

The margin of one posture is the decay rate σ = −ln ρ(Φ)/Δt (1/s) of the linearised force loop
(`control.margin`) at that posture's Λx, linearised about the stroke's nominal state at that
instant: sliding at the zig-zag's commanded speed ‖ṗ°_xy‖ (minimum jerk: 0 at the corners,
≈ 0.16 m/s mid-stroke) against the friction direction f̂ of the segment, with the contact's μ,
stiffness and v_ε, the sensor's cutoff and reading age d_s and the world's torque delay d_a.
Besides σ it gives the K_f^d margin (K_f^d minus the lowest stable K_f^d, N s/m) and the signed
directional coupling P_d·f̂ [T10] there. Evaluated on samples of the executed trajectory, each
stroke keeps its worst (smallest) σ and K_f^d margin, the mean and max of P_d·f̂, and the growth
G (nepers) that the frozen-posture rates accumulate over the stroke: G_k = max(0, G_{k−1} − σ_k Δt),
the log of how much a disturbance at the noise level can be amplified before the stroke ends.

The margin itself is the stroke's headroom h_k = ln(F̂ / floor) − G_k (nepers): the growth still
allowed before a disturbance at the sensor's noise floor in the contact mode's band (`sensor_floor_n`)
reaches the desired force F̂, i.e. lifts the tool off the table. h > 0 all along a stroke: the stroke ends first; h < 0:
it does not. σ and the K_f^d margin stay as the instantaneous diagnostics: a slowly growing mode
(σ slightly negative) on a 2.5 s stroke does not use up the headroom.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from app.scenarios import polish_stroke as P
from app.scenarios import verdict as V
from control.coupling import POLISH_SUBSPACES
from control.gains import MotionForceGains
from control.margin import ContactLoop, force_loop_margin, loop_rate, posture_margin
from control.planner import Plan

MARGIN_SAMPLE_S = 0.025  # 100 samples per 2.5 s stroke: finer than the ≈ 0.3 s the rates change over


def sensor_floor_n(sensor: object, dt: float) -> float:
    """The margin's noise floor (N) of a sensor group (`SensorParams`) or its fields as a mapping: the
    RMS of its force noise in the contact mode's band, after its low-pass (`verdict.sensor_band_floor_n`;
    0 with the noise off). The 1 Hz sinusoid is left out: it cannot seed the 12–14 Hz mode."""
    return V.sensor_band_floor_n(sensor, dt, noise_switch=True)


def headroom_budget_np(force_n: float, floor_n: float) -> float:
    """ln(F̂ / floor) (nepers): the growth that takes a disturbance at the noise floor to the desired
    force, the headroom a stroke starts with (inf for a sensor without noise)."""
    return math.log(force_n / floor_n) if floor_n > 0 else math.inf


# The margin's growth G against the growth the runs showed (the calibration's predicted-against-observed
# figure, `polish_calibration.growth_comparison`): its RMS error over the runs with G > 0 that kept contact,
# 1.35 Np over 48 such runs of the calibration grid (docs/margin.md).
# The headroom's sign is stated only outside ± this band; inside it the prediction is too close to call.
HEADROOM_BAND_NP = 1.35


@dataclass(frozen=True)
class HeadroomStatement:
    """The margin of a stroke as it may be shown: the sign of its least headroom h, the band h ± the
    growth error within which that sign is not decided, and the words."""

    sign: int  # −1: predicted to lose contact; +1: predicted to keep it; 0: too close to call
    low_np: float
    high_np: float
    words: str


def headroom_statement(headroom_np: float, band_np: float = HEADROOM_BAND_NP) -> HeadroomStatement:
    """What the least headroom h of a stroke predicts, with its band h ± band_np (module docstring)."""
    if not math.isfinite(headroom_np):
        return HeadroomStatement(0, math.nan, math.nan, "no prediction on this stroke")
    low, high = headroom_np - band_np, headroom_np + band_np
    if high < 0.0:
        return HeadroomStatement(-1, low, high, "predicted to shake off the table (lose contact) within this stroke")
    if low > 0.0:
        return HeadroomStatement(1, low, high, "predicted to keep contact through this stroke")
    return HeadroomStatement(0, low, high, "too close to call: the headroom is within the margin's error of 0")


def prediction_held(statement: HeadroomStatement, verdict: str) -> bool | None:
    """After the stroke, against its one verdict (`app.scenarios.verdict`): whether the prediction came
    true (the margin predicts lost contact: its event is the contact force reaching 0); None without one."""
    if statement.sign == 0:
        return None
    return (statement.sign < 0) == (verdict in (V.LOST, V.DIVERGED))


def headroom_came_true(statement: HeadroomStatement, verdict: str) -> str:
    """`prediction_held` in words, with the stroke's verdict."""
    held = prediction_held(statement, verdict)
    if held is None:
        return f"no prediction to check; the stroke was {verdict}"
    return f"{'came true' if held else 'did not come true'}: the stroke was {verdict}"


class StrokeHeadroom:
    """The headroom h = budget − G along the current stroke from σ samples (module docstring): G
    starts at 0 at each segment's start and G ← max(0, G − σ Δt) with Δt the time since the
    stroke's previous sample (`first_dt` for its first); NaN outside the strokes."""

    def __init__(self, budget_np: float, first_dt: float):
        self.budget_np = float(budget_np)
        self.first_dt = float(first_dt)
        self.segment = -1
        self.growth_np = 0.0
        self.headroom_np = math.nan
        self.headroom_min_np = math.nan  # the least h of this stroke so far
        self._t = math.nan

    def add(self, t: float, segment: int, rate_per_s: float) -> float:
        """Take σ (1/s) sampled at time t in `segment` (1..6 the strokes); returns h now."""
        if segment != self.segment:
            self.segment, self.growth_np, self._t = segment, 0.0, math.nan
            self.headroom_np = self.headroom_min_np = math.nan
        if not 1 <= segment <= P.N_SEGMENTS or not math.isfinite(rate_per_s):
            return self.headroom_np
        dt = self.first_dt if not math.isfinite(self._t) else t - self._t
        self._t = t
        self.growth_np = max(0.0, self.growth_np - rate_per_s * dt)
        self.headroom_np = self.budget_np - self.growth_np
        prev = self.headroom_min_np
        self.headroom_min_np = self.headroom_np if not math.isfinite(prev) else min(prev, self.headroom_np)
        return self.headroom_np


def contact_loop(contact: object, sensor: object, world: object, speed_m_s: float = 0.0) -> ContactLoop:
    """The `ContactLoop` of a polish run: its contact (μ, stiffness, v_ε), the sensor's low-pass and
    reading age (an ideal sensor: no filter, no delay), the world's torque delay and step."""
    model = getattr(world, "model", None)
    dt = float(model.opt.timestep) if model is not None else 1e-3
    return ContactLoop(
        stiffness_n_per_m=float(getattr(contact, "stiffness_n_per_m", P.CONTACT_STIFFNESS_N_PER_M)),
        mu=float(getattr(contact, "mu", 0.0)),
        normal_force_n=P.DESIRED_FORCE_N,
        speed_m_s=float(speed_m_s),
        v_eps_m_per_s=float(getattr(contact, "v_eps_m_per_s", P.FRICTION_V_EPS_M_PER_S)),
        sensor_cutoff_hz=float(getattr(sensor, "cutoff_hz", 0.0)),
        dt=dt,
        sensing_delay_steps=int(getattr(sensor, "reading_delay_steps", 0)),
        actuation_delay_steps=int(getattr(world, "torque_delay_steps", 0)),
    )


def operating_point(tau: float) -> tuple[float, np.ndarray]:
    """(commanded sliding speed m/s, unit friction direction f̂ in xy) at trajectory time tau."""
    _, v, _ = P.trajectory_state(tau)
    return float(np.hypot(*v)), P.friction_direction(tau)


@dataclass(frozen=True)
class MarginSample:
    """The margin at one instant of the stroke."""

    rate_per_s: float  # σ, > 0 decays
    kd_margin: float  # N s/m; −inf when no K_f^d up to 2000 N s/m is stable
    pd_fhat: float  # P_d·f̂ [T10] along the segment's friction direction
    frequency_hz: float = math.nan  # the slowest-decaying mode's frequency (NaN: rate alone)


def sample(
    Lambda: np.ndarray, gains: MotionForceGains, loop: ContactLoop, tau: float, find_kd: bool = True
) -> MarginSample:
    """The margin of the posture with this Λx at trajectory time tau (module docstring); without
    `find_kd` only σ (the K_f^d margin and P_d·f̂ NaN)."""
    speed, f_hat = operating_point(tau)
    if not find_kd:  # the rate alone: one map, one eigenvalue problem
        rate = loop_rate(Lambda, POLISH_SUBSPACES, gains, _at_speed(loop, speed), f_hat)
        return MarginSample(rate, math.nan, math.nan)
    m = force_loop_margin(Lambda, POLISH_SUBSPACES, gains, _at_speed(loop, speed), f_hat, find_kd=find_kd)
    kd = math.nan if not find_kd else (-math.inf if m.kd_critical is None else gains.force_kd - m.kd_critical)
    return MarginSample(m.rate_per_s, kd, m.directional_coupling, m.frequency_hz)


def _at_speed(loop: ContactLoop, speed: float) -> ContactLoop:
    from dataclasses import replace

    return replace(loop, speed_m_s=speed)


def per_stroke(taus: np.ndarray, samples: list[MarginSample], budget_np: float = math.inf) -> list[dict]:
    """Per segment 1..6: the worst σ (and when), the worst K_f^d margin, P_d·f̂ mean and max, the
    growth G and the least headroom budget_np − G (module docstring), the frequency of the
    slowest-decaying mode at the worst σ; segments without samples are left out."""
    taus = np.asarray(taus, dtype=float)
    out = []
    for k in range(1, P.N_SEGMENTS + 1):
        sel = np.flatnonzero((taus >= (k - 1) * P.SEGMENT_DURATION_S) & (taus < k * P.SEGMENT_DURATION_S))
        if sel.size == 0:
            continue
        rate = np.array([samples[i].rate_per_s for i in sel])
        kd = np.array([samples[i].kd_margin for i in sel])
        pd = np.array([samples[i].pd_fhat for i in sel])
        hz = np.array([samples[i].frequency_hz for i in sel])
        along = StrokeHeadroom(budget_np, MARGIN_SAMPLE_S if sel.size == 1 else float(taus[sel[1]] - taus[sel[0]]))
        growth = 0.0
        for i, r in zip(sel, rate, strict=True):
            along.add(float(taus[i]), k, float(r))
            growth = max(growth, along.growth_np)
        worst = int(np.argmin(rate))
        out.append(
            {
                "segment": k,
                "direction": "retract (-X)" if k % 2 == 1 else "stretch (+X)",
                "rate_min_per_s": float(rate[worst]),
                "rate_min_at_s": float(taus[sel[worst]] - (k - 1) * P.SEGMENT_DURATION_S),
                "kd_margin_min": float(np.min(kd)) if np.all(np.isfinite(kd)) else None,
                "negative_share": float(np.mean(rate < 0.0)),
                "growth_np": float(growth),
                "headroom_min_np": float(budget_np - growth),
                "pd_fhat_mean": float(np.mean(pd)),
                "pd_fhat_max": float(np.max(pd)),
                "mode_hz_at_worst": float(hz[worst]) if np.isfinite(hz[worst]) else None,
            }
        )
    return out


def summary(strokes: list[dict]) -> dict:
    """Over all strokes: worst σ and K_f^d margin, largest growth, least headroom, and P_d·f̂ over the
    stretching strokes (the mean of the stroke means, the max of the maxima)."""
    if not strokes:
        return {
            "rate_min_per_s": None,
            "kd_margin_min": None,
            "growth_max_np": None,
            "headroom_min_np": None,
            "stretch_pd_fhat": None,
        }
    kds = [s["kd_margin_min"] for s in strokes]
    stretch = [s for s in strokes if s["segment"] % 2 == 0]
    return {
        "rate_min_per_s": min(s["rate_min_per_s"] for s in strokes),
        "kd_margin_min": None if any(k is None for k in kds) else min(kds),
        "growth_max_np": max(s["growth_np"] for s in strokes),
        "headroom_min_np": min(s["headroom_min_np"] for s in strokes),
        "stretch_pd_fhat": None
        if not stretch
        else {
            "mean": float(np.mean([s["pd_fhat_mean"] for s in stretch])),
            "max": float(max(s["pd_fhat_max"] for s in stretch)),
        },
    }


def stretch_floor(plan: Plan) -> dict | None:
    """For a plan with the signed cost max(P_d·f̂, 0)² (`control.planner`): the smallest max(P_d·f̂, 0)
    that any feasible posture of the self-motion loop reaches at each stretching-stroke sample, its
    mean and max over those samples, and the plan's own values there — how far the plan is from the
    best the loop allows. None for a plan without trajectory samples."""
    t = np.asarray(plan.t)
    costs = np.asarray(plan.cost_map)
    stage = np.asarray(plan.cost)[t >= 0.0]
    times = t[t >= 0.0]
    if times.size == 0 or costs.shape[0] != times.size:
        return None
    segment = np.minimum((times // P.SEGMENT_DURATION_S).astype(int), P.N_SEGMENTS - 1) + 1
    stretch = segment % 2 == 0
    best = np.sqrt(np.min(costs[stretch], axis=1))
    own = np.sqrt(stage[stretch])
    return {
        "loop_best_mean": float(np.mean(best)),
        "loop_best_max": float(np.max(best)),
        "plan_mean": float(np.mean(own)),
        "plan_max": float(np.max(own)),
    }


def rate_at(Lambda: np.ndarray, gains: MotionForceGains, loop: ContactLoop, tau: float) -> float:
    """σ (1/s) of the force loop at a posture's Λx at trajectory time tau (`sample`), NaN
    where the model cannot be formed; a module-level function, so the app's loop can compute it in
    its worker process."""
    try:
        return sample(Lambda, gains, loop, tau, find_kd=False).rate_per_s
    except (ValueError, np.linalg.LinAlgError):
        return float("nan")


def kd_margin_at(Lambda: np.ndarray, gains: MotionForceGains, loop: ContactLoop) -> float:
    """Force-loop margin (N s/m, `control.margin`) of a posture's Λx: K_f^d minus the critical K_f^d
    over the stretching and retracting friction directions, at rest and at the segments' peak speed
    (`loop` at that speed), with the loop's latency (a coarse version of the report's, for once a
    second); NaN where the model cannot be formed."""
    dirs = [P.friction_direction(1.5 * P.SEGMENT_DURATION_S), P.friction_direction(0.5 * P.SEGMENT_DURATION_S)]
    try:
        pm = posture_margin(
            Lambda, POLISH_SUBSPACES, gains, loop, dirs, speeds=(0.0, 0.3 * P.PEAK_SPEED_M_S, P.PEAK_SPEED_M_S)
        )
    except (ValueError, np.linalg.LinAlgError):
        return float("nan")
    return pm.kd_margin
