"""The margin along the polish strokes (app.scenarios.polish_margin) and its calibration report
(app.headless.experiments.polish_calibration)."""

from __future__ import annotations

import numpy as np
import pytest

from app.headless.experiments import polish_calibration as C
from app.scenarios import polish as P
from app.scenarios import polish_environment as PE
from app.scenarios import polish_margin as PM
from app.scenarios import polish_stroke as PS


def _samples(rates, pds):
    return [PM.MarginSample(r, 10.0 * r, p) for r, p in zip(rates, pds, strict=True)]


def test_per_stroke_keeps_each_strokes_worst_rate_its_coupling_and_the_growth_it_accumulates():
    """Two strokes sampled every 25 ms: S1 decays everywhere (G = 0), S2 grows at 2/s for 1 s in the
    middle and decays at 1/s after it: G = 2 Np, so with a budget of 1.5 Np S2's least headroom is
    −0.5 Np and S1's the whole budget; worst σ, P_d·f̂ mean/max and the share negative are each
    stroke's own."""
    T, dt = PS.SEGMENT_DURATION_S, PM.MARGIN_SAMPLE_S
    taus = np.arange(0.0, 2 * T - 1e-9, dt)
    rates = np.where(taus < T, 3.0, np.where((taus >= T + 0.5) & (taus < T + 1.5), -2.0, 1.0))
    pds = np.where(taus < T, -1.0, np.linspace(0.5, 1.0, taus.size))
    strokes = PM.per_stroke(taus, _samples(rates, pds), budget_np=1.5)
    s1, s2 = strokes
    assert (s1["segment"], s2["segment"]) == (1, 2) and s2["direction"].startswith("stretch")
    assert s1["rate_min_per_s"] == 3.0 and s1["growth_np"] == 0.0 and s1["negative_share"] == 0.0
    assert s2["rate_min_per_s"] == -2.0 and s2["growth_np"] == pytest.approx(2.0, abs=1e-9)
    assert s1["headroom_min_np"] == 1.5 and s2["headroom_min_np"] == pytest.approx(-0.5, abs=1e-9)
    assert s2["negative_share"] == pytest.approx(1.0 / T, abs=dt / T)
    assert s2["kd_margin_min"] == -20.0 and s2["pd_fhat_max"] == pytest.approx(1.0)
    assert s2["pd_fhat_mean"] == pytest.approx(np.mean(pds[taus >= T]))
    total = PM.summary(strokes)
    assert total["rate_min_per_s"] == -2.0 and total["growth_max_np"] == pytest.approx(2.0)
    assert total["headroom_min_np"] == pytest.approx(-0.5)
    assert total["stretch_pd_fhat"] == {"mean": pytest.approx(s2["pd_fhat_mean"]), "max": pytest.approx(1.0)}


def test_the_stroke_headroom_starts_each_stroke_at_the_budget_and_spends_it_where_sigma_is_negative():
    """σ = −3/s for 0.5 s then +1/s: h falls 1.5 Np below the budget, climbs back at 1 Np/s (G ≥ 0 caps
    it at the budget); a new segment starts again from the budget; outside the strokes h is NaN."""
    h = PM.StrokeHeadroom(budget_np=2.0, first_dt=0.1)
    t = 0.0
    for _ in range(5):
        t += 0.1
        h.add(t, 2, -3.0)
    assert h.headroom_np == pytest.approx(0.5, abs=1e-9) and h.growth_np == pytest.approx(1.5, abs=1e-9)
    for _ in range(3):
        t += 0.1
        h.add(t, 2, 1.0)
    assert h.headroom_np == pytest.approx(0.8, abs=1e-9) and h.headroom_min_np == pytest.approx(0.5, abs=1e-9)
    assert h.add(t + 0.1, 3, 1.0) == 2.0 and h.headroom_min_np == 2.0
    assert np.isnan(h.add(t + 0.2, PS.N_SEGMENTS + 1, -5.0)) and np.isnan(h.add(t + 0.3, 0, -5.0))
    assert PM.headroom_budget_np(20.0, 0.0) == np.inf  # no noise: nothing at the floor to grow


def test_the_operating_point_is_the_commanded_speed_against_the_segments_friction_direction():
    """At a corner the commanded speed is 0, mid-stroke it is the minimum-jerk peak; f̂ opposes the motion."""
    speed0, f0 = PM.operating_point(0.0)
    mid, f_mid = PM.operating_point(1.5 * PS.SEGMENT_DURATION_S)
    assert speed0 == pytest.approx(0.0, abs=1e-12) and mid == pytest.approx(PS.PEAK_SPEED_M_S, rel=1e-9)
    assert f0[0] > 0.9 and f_mid[0] < -0.9  # S1 retracts along −X (friction +X), S2 stretches along +X


def _run(band, lost=0, rate=-1.0, growth=0.0, sensor=None):
    return {
        "row": "W_j",
        "mu": 1.0,
        "seed": 0,
        "diverged": False,
        "contact_lost_ms": lost,
        "band_rms_max_n": band,
        "stroke": {"rate_min_per_s": rate, "growth_max_np": growth},
        **({"sensor": sensor} if sensor is not None else {}),
    }


def test_outcome_is_the_one_verdict_against_the_runs_own_sensor_at_any_threshold_scale():
    """The margin's floor is the default sensor's noise in the contact mode's band (not its 1 Hz
    sinusoid); the outcome is the verdict with the threshold of the run's sensor, × 0.5 / 1 / 2."""
    from app.scenarios import verdict as V

    floor = V.band_floor_n(5.0, 25.0, 1e-3)
    assert C.run_floor_n({}) == pytest.approx(floor, rel=1e-12)
    assert C.run_floor_n({"sensor": {"sine_amplitude_n": 5.0}}) == pytest.approx(floor, rel=1e-12)
    limit = C.run_threshold_n({})
    assert limit == pytest.approx(V.reading_floor_n(5.0, 2.0, 25.0, 1e-3), rel=1e-12)
    assert C.outcome(_run(limit * 0.99))["why"] == "stable"
    assert C.outcome(_run(limit * 1.01))["why"] == "oscillating"
    assert [C.outcome(_run(limit * 0.6), s)["unstable"] for s in (0.5, 1.0, 2.0)] == [True, False, False]
    assert C.outcome(_run(0.1, lost=3))["why"] == "lost contact"
    noisier = {"force_noise_var": 50.0}  # a higher floor: √(50 α/(2 − α) + 2) = 2.52 N
    assert not C.outcome(_run(limit * 1.5, sensor=noisier))["unstable"]
    assert C.outcome({"contact_lost_ms": 0, "diverged": False})["why"] == "stable"  # a record before the verdict


def test_the_verdict_is_the_sign_of_the_least_headroom_and_sigma_is_kept_beside_it():
    """h_min = ln(F̂ / floor) − G: a run whose σ dips below 0 but whose growth stays under the budget is
    predicted stable; a growth beyond it, unstable; the budget follows the run's sensor."""
    budget = C.headroom_budget({})
    assert budget == pytest.approx(np.log(20.0 / C.run_floor_n({})), rel=1e-12)
    slow = _run(0.1, rate=-0.9, growth=0.5 * budget)
    fast = _run(0.1, rate=-9.0, growth=1.5 * budget)
    assert C.headroom_min(slow) == pytest.approx(0.5 * budget) and not C.predicted_unstable(slow)
    assert C.predicted_unstable(fast) and C.predicted_unstable_by_rate(slow) and C.predicted_unstable_by_rate(fast)
    noisier = _run(0.1, growth=0.9 * budget, sensor={"force_noise_var": 50.0})  # a higher floor, less budget
    assert C.headroom_budget(noisier) < budget and C.predicted_unstable(noisier)
    assert C.predicted_unstable({"stroke": {}}) is None


def _record(swivel, seed, predicted, band, lost=0):
    budget = C.headroom_budget({})
    return {
        "status": "ok",
        "params": {"hold_swivel": swivel, "mu": 1.0},
        "seed": seed,
        "metrics": {
            "stroke_growth_max_np": (1.5 if predicted else 0.5) * budget,
            "stroke_rate_min_per_s": -1.0,  # σ says unstable everywhere
            "band_rms_max_n": band,
            "oscillation_threshold_n": 0.5,
            "contact_lost_ms": lost,
            "diverged": False,
        },
    }


def test_confusion_counts_and_the_report_names_the_disagreeing_runs():
    """Both verdicts from each record's metrics (flattened as a sweep writes them): the headroom's
    table, then σ's, each with its disagreeing runs."""
    pairs = [(True, True), (True, False), (False, False), (False, False), (False, True)]
    c = C.confusion(pairs)
    assert (c["tp"], c["fp"], c["tn"], c["fn"], c["n"]) == (1, 1, 2, 1, 5) and c["agreement"] == pytest.approx(0.6)
    records = [_record(sw, 0, p, 5.0 if s else 0.1) for sw, (p, s) in zip((-80, -40, 0, 20, 40), pairs, strict=True)]
    page = C.sweep_section(["hold_swivel", "mu"], records)
    first, second = page.split("The same runs by the sign of the worst σ")
    assert "Agreement 3 of 5 (60 %)" in first and "Disagreeing runs by the sign of the headroom (2)" in first
    assert "<td>-40</td>" in first and "<td>40</td>" in first and "<td>20</td>" not in first
    assert "Agreement 2 of 5 (40 %)" in second and "Disagreeing runs by the sign of σ (3)" in second
    assert f"starts with {C.headroom_budget({}):.2f} Np" in page


def test_the_threshold_sensitivity_judges_each_cells_seeds_together_and_names_those_that_disagree():
    """Three seeds per cell: a cell whose seeds straddle the threshold is "seeds disagree" and counted
    for neither side at that scale, decided at the scales where they do not; boundary cells (a band RMS
    within a factor 2 of the threshold) with fewer than 3 seeds are named."""
    records = (
        [_record(-80, k, False, 0.1) for k in range(3)]  # calm, predicted calm: agrees at every scale
        + [_record(-40, k, True, b) for k, b in enumerate((0.45, 0.55, 0.6))]  # straddles × 1
        + [_record(0, k, True, 3.0, lost=5) for k in range(3)]  # lost, predicted: agrees
        + [_record(20, 0, False, 0.7)]  # one seed, at 1.4× the threshold: short of seeds, disagrees at × 1
    )
    sens = C.threshold_sensitivity(["hold_swivel", "mu"], records)
    by = {e["scale"]: e for e in sens["scales"]}
    assert by[1.0]["seeds_disagree"] == [(-40, 1.0)] and (by[1.0]["agree"], by[1.0]["decided"]) == (2, 3)
    assert by[0.5]["seeds_disagree"] == [] and (by[0.5]["agree"], by[0.5]["decided"]) == (3, 4)
    assert by[2.0]["seeds_disagree"] == [] and (by[2.0]["agree"], by[2.0]["decided"]) == (3, 4)
    assert [b["cell"] for b in sens["boundary"]] == [(-40, 1.0), (20, 1.0)] and sens["boundary_short"] == [(20, 1.0)]
    page = C.sweep_section(["hold_swivel", "mu"], records)
    assert "hold_swivel -40, mu 1.0" in page and "1 with fewer than 3 seeds" in page


def test_the_live_rate_is_recomputed_every_100_steps_from_the_logged_posture_and_shown(rizon):
    """The page's σ: updated every 0.1 s of simulated time (ten values in one second), each the offline
    margin (`polish_margin.sample`) of the posture of the step that logged it, with the session's
    sensing delay; the Nullspace panel prints it."""
    from app.core.session import Session
    from app.live.ui.panels.nullspace import _polish_lines
    from control.gains import MotionForceGains
    from control.model import RobotModel

    session = Session(P.PolishScenario(mu=1.0), seed=0)
    session.set_param("nullspace", "objective", "j")
    session.run(1.0)
    env = session.environment
    rates, qs = [], []
    session.run(1.0, record=lambda r: (rates.append(r.signals["margin_rate"]), qs.append(r.q.copy())))
    rates_a = np.array(rates)
    changes = np.flatnonzero(np.diff(rates_a) != 0.0) + 1
    assert 9 <= changes.size <= 10 and np.all(np.diff(changes) == 100)
    model = RobotModel(rizon.model)
    groups = session.params()
    loop = PM.contact_loop(env.contact, groups["sensor"], session.world)  # type: ignore[attr-defined]
    assert loop.sensing_delay_steps == groups["sensor"].reading_delay_steps  # type: ignore[attr-defined]
    gains = groups["motion_force"]
    assert isinstance(gains, MotionForceGains)
    for i in changes[:3]:
        offline = PM.sample(model.compute(qs[i], np.zeros(7)).Lambda, gains, loop, 0.0, find_kd=False).rate_per_s
        assert rates_a[i] == pytest.approx(offline, rel=0.02, abs=0.05)
    assert f"{rates_a[-1]:+.1f} 1/s now" in _polish_lines({"margin_rate": rates_a[-1]})


@pytest.mark.slow
def test_the_margins_verdicts_agree_with_the_simulation_on_a_small_grid():
    """Held swivel × μ × sensing delay, S1 and S2 of the sweep's polish cell: the coupled elbow-up
    posture at μ = 1 with one period of delay loses contact on S2 and both verdicts say so; the mirror
    W_a minimum (−82°) and μ = 0.25 stay calm and both say so; at −40°, μ = 0.5 with two periods σ dips
    below 0 for too short a time to matter: the headroom agrees with the outcome in every cell, the
    sign of σ in at least three of the four."""
    from app.headless.sweep.experiments import get

    cell = get("polish").cell
    grid = [(0.0, 1.0, 1), (-82.0, 1.0, 1), (0.0, 0.25, 1), (-40.0, 0.5, 2)]
    sign = headroom = 0
    outcomes = []
    for swivel, mu, delay in grid:
        m = cell({"hold_swivel": swivel, "mu": mu, "reading_delay": delay, "strokes": 2}, 0)["metrics"]
        outcomes.append(m["simulated_unstable"])
        headroom += m["predicted_unstable"] == m["simulated_unstable"]
        sign += m["predicted_unstable_rate"] == m["simulated_unstable"]
        assert m["predicted_unstable"] == (m["headroom_min_np"] < 0.0)
    assert outcomes == [True, False, False, False]
    assert headroom == len(grid) and sign >= len(grid) - 1


def test_stretch_floor_is_the_loops_least_positive_coupling_on_the_stretching_samples():
    """From a signed-cost map: per stretching sample the square root of the smallest cost over the
    swivel grid, and the plan's own stage costs there; retracting samples are left out."""
    from control.planner import Plan

    times = np.arange(0.0, 5.0 + 1e-9, 0.5)  # S1 at 0…2.0 s, S2 at 2.5…4.5 s, 5.0 s starts S3
    costs = np.full((times.size, 3), np.inf)
    costs[:, 0] = 0.04  # 0.2²
    costs[:, 1] = np.linspace(0.0, 0.01, times.size)  # ≤ 0.1²
    stage = costs[:, 0]
    plan = Plan(times, np.zeros(times.size), np.zeros((times.size, 7)), stage, 0.0, 0.3, 0.0, np.zeros(3), costs)
    f = PM.stretch_floor(plan)
    stretch = (times >= 2.5) & (times < 5.0)
    assert f is not None
    assert f["loop_best_mean"] == pytest.approx(np.mean(np.sqrt(costs[stretch, 1])))
    assert f["loop_best_max"] == pytest.approx(np.sqrt(costs[stretch, 1]).max())
    assert f["plan_mean"] == pytest.approx(0.2) and f["plan_max"] == pytest.approx(0.2)


def test_recomputed_run_margins_use_each_runs_own_sensing_delay(rizon):
    """`--combine` recomputes the start margin of earlier runs: with the reading delay each run
    recorded (none recorded: the same-step reading of the runs made before it existed)."""
    from app.headless.experiments.polish import _recompute_margins

    q = P.PolishScenario().initial_q(rizon)
    base = {"armature_scale": 1.0, "q_converged": [float(x) for x in q], "mu": 1.0, "shaping": True}
    runs = [dict(base), {**base, "reading_delay_steps": 0}, {**base, "reading_delay_steps": 1}]
    _recompute_margins(runs)
    old, zero, one = (r["margin"] for r in runs)
    assert old == zero and one < zero - 10.0


def test_the_observed_mode_finds_a_growing_oscillations_frequency_and_growth():
    """A 13.5 Hz oscillation growing at 1.5 /s over a 2.5 s stroke in noise: the peak within the
    spectrum's resolution (1/2.5 s), the band's envelope rising by ≈ 1.5 /s over the bins' span
    (2.25 s); the same oscillation at constant amplitude shows no growth beyond the noise."""
    dt, T = 1e-3, PS.SEGMENT_DURATION_S
    rng = np.random.default_rng(3)
    t = np.arange(0.0, T + 1.0, dt)  # 0.5 s either side of the stroke
    start, stop = round(0.5 / dt), round((0.5 + T) / dt)
    tau = np.clip(t - 0.5, 0.0, T)
    growing = 0.5 * np.exp(1.5 * tau) * np.sin(2 * np.pi * 13.5 * t) + rng.normal(0.0, 0.05, t.size)
    seen = C.observed_mode(growing, start, stop, dt)
    assert seen is not None and abs(seen["peak_hz"] - 13.5) <= 1.0 / T
    assert seen["growth_np"] == pytest.approx(1.5 * (T - C.OBSERVED_BIN_S), rel=0.1)
    steady = np.sin(2 * np.pi * 13.5 * t) + rng.normal(0.0, 0.05, t.size)
    calm = C.observed_mode(steady, start, stop, dt)
    assert calm is not None and calm["growth_np"] < 0.1 and calm["band_rms_n"] == pytest.approx(np.sqrt(0.5), rel=0.05)
    assert C.observed_mode(steady, start, start + 10, dt) is None  # shorter than two bins


def test_the_dominant_mode_is_the_eigenvalue_of_largest_modulus_with_its_frequency():
    from control.margin import dominant_mode

    dt, r, f = 1e-3, 0.999, 13.5
    th = 2 * np.pi * f * dt
    phi = np.zeros((3, 3))
    phi[:2, :2] = r * np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    phi[2, 2] = 0.5
    rho, hz = dominant_mode(phi, dt)
    assert rho == pytest.approx(r, rel=1e-12) and hz == pytest.approx(f, rel=1e-9)


def test_the_calibration_names_the_largest_growth_stroke_with_both_modes():
    run = {
        "stroke_margin": [
            {"segment": 4, "growth_np": 0.4, "mode_hz_at_worst": 13.2},
            {"segment": 6, "growth_np": 4.0, "mode_hz_at_worst": 13.0},
        ],
        "per_segment": [
            {"segment": 4, "observed": {"peak_hz": 13.2, "growth_np": 2.1}},
            {"segment": 6, "observed": {"peak_hz": 13.6, "growth_np": 1.4}},
        ],
    }
    assert C.growth_stroke(run) == {
        "growth_segment": 6,
        "growth_segment_np": 4.0,
        "growth_segment_mode_hz": 13.0,
        "growth_segment_peak_hz": 13.6,
        "growth_segment_observed_np": 1.4,
    }
    assert C.growth_stroke({"stroke_margin": []}) == {}


def test_the_live_margin_in_the_worker_process_is_the_inline_one_and_leaves_the_loop_thread_alone(monkeypatch):
    """The app's loop hands the live figures to a worker process (`app.live.offload`): stepping W_j at μ = 1
    for 0.5 s, each σ (every 100 steps) and the K_f^d margin, taken from the worker when the environment
    looks for answers (every LIVE_POLL_EVERY_S), are those the same session computes inline, to 1e-9;
    the stepping thread never computes one itself."""
    from app.core.session import Session
    from app.live.offload import LiveOffload

    poll = round(PE.LIVE_POLL_EVERY_S / 1e-3)

    def stepped(offload: LiveOffload | None) -> list[tuple[float, float]]:
        session = Session(P.PolishScenario(mu=1.0), seed=0)
        session.set_param("nullspace", "objective", "j")
        session.set_offload(offload)
        env = session.environment
        out = []
        for k in range(500):
            if offload is not None and k % 100 == poll:  # the tick's figures are in when they are looked for
                for sample in list(env._pending):  # type: ignore[attr-defined]
                    sample.future.result(timeout=30.0)
            sig = session.step().signals
            if k % 100 == poll:
                out.append((sig["margin_rate"], sig["margin_kd"]))
        return out

    inline = stepped(None)
    offload = LiveOffload()
    try:
        assert offload.ready(60.0)
        monkeypatch.setattr(PE.PolishEnvironment, "live_rate", lambda self, t: pytest.fail("σ on the loop thread"))
        monkeypatch.setattr(
            PE.PolishEnvironment, "live_margin", lambda self, t: pytest.fail("K_f^d on the loop thread")
        )
        away = stepped(offload)
    finally:
        offload.stop()
    assert len(away) == len(inline) == 5 and all(np.isfinite(inline[k][0]) for k in range(5))
    for (rate, kd), (rate_in, kd_in) in zip(away, inline, strict=True):
        assert rate == pytest.approx(rate_in, rel=1e-9, abs=1e-9) and kd == pytest.approx(kd_in, rel=1e-9, abs=1e-9)


def test_the_headroom_is_stated_as_a_sign_outside_its_band_and_checked_against_the_verdict():
    """h ± the calibration's growth error: below 0 all through the band predicts lost contact, above it
    keeps contact, a band across 0 is too close to call; after the stroke the prediction is checked
    against the one verdict's lost contact only (the margin's event)."""
    band = PM.HEADROOM_BAND_NP
    shake = PM.headroom_statement(-band - 0.1)
    calm = PM.headroom_statement(band + 0.1)
    close = PM.headroom_statement(0.5 * band)
    assert (shake.sign, calm.sign, close.sign) == (-1, 1, 0)
    assert shake.high_np == pytest.approx(-0.1) and calm.low_np == pytest.approx(0.1)
    assert "shake off the table (lose contact) within this stroke" in shake.words and "keep contact" in calm.words
    assert "too close to call" in close.words and PM.headroom_statement(float("nan")).sign == 0
    assert PM.headroom_came_true(shake, "lost contact").startswith("came true")
    assert PM.headroom_came_true(shake, "oscillating").startswith("did not come true")
    assert PM.headroom_came_true(calm, "oscillating").startswith("came true")
    assert PM.headroom_came_true(close, "stable").startswith("no prediction")


class _SlowOffload:
    """An offload that is still starting while `starting()` holds (submit answers None), then answers each
    job `lag_steps` ticks after it took it, and none at all once `stalled()` holds (a worker that stopped
    answering). `tick()` is one step of the loop."""

    def __init__(self, lag_steps: int, starting=lambda: False, stalled=lambda: False):
        from concurrent.futures import Future

        self._future = Future
        self.lag_steps, self.starting, self.stalled = lag_steps, starting, stalled
        self.gave_up: str | None = None
        self.jobs: list[tuple[int, object, object, tuple]] = []
        self.now = 0
        self.answered = 0

    def submit(self, fn, /, *args):
        if self.starting():
            return None
        future = self._future()
        self.jobs.append((self.now, future, fn, args))
        return future

    def tick(self) -> None:
        self.now += 1
        if self.stalled():
            return
        while self.jobs and self.now - self.jobs[0][0] >= self.lag_steps:
            _, future, fn, args = self.jobs.pop(0)
            future.set_result(fn(*args))  # type: ignore[operator,attr-defined]
            self.answered += 1


def _polish_run(offload: _SlowOffload | None, env_box: list) -> dict[str, np.ndarray]:
    """W_j at μ = 1 through its six strokes and 1.5 s after, with the live figures on `offload` (inline
    without one): the margin's logged columns (`stroke_outcomes.MARGIN_COLUMNS`) and "margin_waiting"."""
    from app.core.session import Session
    from app.scenarios.stroke_outcomes import MARGIN_COLUMNS

    session = Session(P.PolishScenario(mu=1.0), seed=0)
    session.set_param("nullspace", "objective", "j")
    session.set_offload(offload)
    env = session.environment
    env_box.append(env)
    names = (*MARGIN_COLUMNS, "margin_waiting")
    rows: list[list[float]] = []
    end = None
    while end is None or session.world.time < end:
        if offload is not None:
            offload.tick()
        sig = session.step().signals
        rows.append([sig.get(n, np.nan) for n in names])
        if end is None and sig["segment"] > PS.N_SEGMENTS:
            end = session.world.time + 1.5
        assert session.world.time < 120.0, "the zig-zag did not end"
    data = np.array(rows)
    return {n: data[:, i] for i, n in enumerate(names)}


def test_a_slow_or_stalled_offload_gives_each_stroke_the_headroom_the_run_computes_inline():
    """The lessons judge a stroke by its least headroom: it must not depend on how fast the offload
    answers. W_j at μ = 1 with an offload that is still starting until S2 (S1's samples wait), then
    answers 0.6 s of steps late (a stroke's last figures come while the next one runs): each stroke's
    least headroom and worst σ are those of the inline run to 1e-9, and so is each statement; no sample
    is dropped and none waits once the strokes are over. With one that stops answering during S5, the
    waiting samples are computed inline 1 s after the strokes: the same figures again."""
    from app.scenarios.stroke_outcomes import stroke_figures

    envs: list = []
    inline = stroke_figures(_polish_run(None, envs), PS.N_SEGMENTS)
    assert sorted(inline) == list(range(1, 7)) and all(np.isfinite(h) for h, _ in inline.values())
    assert any(h < 0 for h, _ in inline.values()) and any(h > 0 for h, _ in inline.values())

    def segment() -> int:
        return envs[-1].clock.segment(envs[-1]._world.time)[0] if envs[-1]._world is not None else 0

    slow = _SlowOffload(600, starting=lambda: segment() < 2)
    c = _polish_run(slow, envs)
    lagged = (c["margin_headroom_segment"] == c["segment"] - 1) & (c["segment"] >= 2) & (c["segment"] <= 6)
    assert np.count_nonzero(lagged) >= 5 * 400, "the figures of a stroke did not come while the next one ran"
    assert envs[-1].dropped_stroke_samples == 0 and c["margin_waiting"][-1] == 0
    late = stroke_figures(c, PS.N_SEGMENTS)
    stalled = _SlowOffload(600, stalled=lambda: segment() >= 5)
    c2 = _polish_run(stalled, envs)
    assert c2["margin_waiting"][-1] == 0 and np.max(c2["margin_waiting"]) >= 10
    for figures in (late, stroke_figures(c2, PS.N_SEGMENTS)):
        assert sorted(figures) == sorted(inline)
        for k, (h, rate) in inline.items():
            assert figures[k][0] == pytest.approx(h, abs=1e-9) and figures[k][1] == pytest.approx(rate, abs=1e-9), k
            assert PM.headroom_statement(figures[k][0]).sign == PM.headroom_statement(h).sign
