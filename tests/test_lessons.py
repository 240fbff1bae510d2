"""Lessons and the lab's case switch, without a browser: each claim carries this run's numbers, and
a case switch keeps the person's values of every field the case does not own."""

from __future__ import annotations

import re

import numpy as np
import pytest

from app.core.commands import RestoreDefaults, SetParam, SwitchSession
from app.live.frames import deflection_readouts, make_status
from app.live.lab import Lab, owned_fields
from app.live.lessons import LESSONS, measure


def numbers(text: str) -> list[float]:
    """The decimal numbers in a sentence, in order."""
    return [float(x) for x in re.findall(r"-?\d+\.\d+", text)]


# a step's numbers by what it runs (its commands, from the defaults, and when it is done): two lessons
# that take the same run (W_j at μ = 1 with the default delay: the posture lesson's first step, the
# latency lesson's second) measure it once
_RUNS: dict[tuple, dict] = {}


def run_lesson(key: str) -> tuple[dict, dict]:
    """Take every step of a lesson on a Lab as the panel does; (claims, numbers) by step key."""
    lab = Lab("free")
    lesson = next(x for x in LESSONS if x.key == key)
    memo: dict = {}
    claims: dict = {}
    for step in lesson.steps:
        commands = tuple(step.setup(lab))
        run = (commands, step.ready)
        if isinstance(commands[0], RestoreDefaults) and run in _RUNS:  # from the defaults: the same run
            memo[step.key] = obs = _RUNS[run]
            claims[step.key] = step.claim(obs, memo)
            continue
        for cmd in commands:
            lab.apply(cmd)
        for _ in range(200):
            if step.ready(make_status(lab)) or lab.halted:
                break
            lab.advance(500)
        assert not lab.halted, lab.halted
        obs = _RUNS[run] = measure(lab)
        memo[step.key] = obs
        claims[step.key] = step.claim(obs, memo)
    return claims, memo


def test_a_case_switch_keeps_the_persons_values_and_names_those_the_case_owns():
    lab = Lab("polish", robot="rizon4s")
    lab.apply(SetParam("contact", "mu", 1.0))
    lab.apply(SetParam("nullspace", "objective", "d"))
    lab.apply(SetParam("scenario", "start_swivel_deg", 10.0))
    lab.apply(SwitchSession(variant="mirror start"))
    p = lab.session.params()
    assert p["contact"].mu == pytest.approx(1.0) and p["nullspace"].objective == "d"
    assert p["scenario"].start_swivel_deg == pytest.approx(-30.0)  # the case owns the start swivel
    notices = [n for n in lab.notice_log if n.title.startswith("Case")]
    assert len(notices) == 1 and "scenario.start_swivel_deg" in notices[0].body and "contact.mu" not in notices[0].body
    lab.apply(SwitchSession(scenario="limit-drop"))  # a preset switch still starts from its defaults
    assert not [o for o in lab.overrides if o.group != "drag"]


def test_owned_fields_are_those_whose_defaults_differ_between_the_cases():
    a = Lab("compliance").defaults
    lab = Lab("compliance")
    lab.apply(SwitchSession(variant="full"))
    owned = owned_fields(a, lab.defaults)
    assert ("pose_task", "compliance") in owned and ("damper", "lambda_") not in owned


def test_the_dampers_lesson_states_this_runs_numbers_including_the_other_joints():
    claims, memo = run_lesson("dampers")
    low, high, thrash = memo["l100"], memo["l500"], memo["l500d"]
    # each claim quotes its run's peak torque (to 0.1 N m) and the comparison it makes
    assert f"{low['peak_tau_4']:.1f}" in claims["l100"] and f"{high['peak_tau_4']:.1f}" in claims["l500"]
    assert f"{high['peak_tau_4'] / low['peak_tau_4']:.1f}×" in claims["l500"]
    assert high["peak_tau_4"] > low["peak_tau_4"] + 5.0  # the stiffer damper brakes harder
    assert low["reversals_first_3s"] == 0 and high["reversals_first_3s"] == 0  # ideal motors: clean stops
    # with 5 ms of delay the whole arm moves: the claim names every other joint's swing and the fallbacks
    for j in (1, 2, 3, 5, 6, 7):
        assert f"joint {j} {thrash[f'swing_{j}']:.2f} rad" in claims["l500d"]
    assert f"{thrash['thrash_end_s']:.1f} s" in claims["l500d"] and thrash["thrash_end_s"] > 1.0
    assert max(thrash[f"swing_{j}"] for j in (1, 2, 3)) > 1.0  # rad: not only joint 4
    assert thrash["reversals_late"] >= 10  # then τ₄ chatters
    assert memo["l100d"]["reversals_first_3s"] <= 2  # λ = 100 with the same delay stops (nearly) cleanly


def test_the_compliance_lesson_measures_tcp_and_elbow_under_each_push():
    claims, memo = run_lesson("compliance")
    stiff, null, full = memo["gamma-stiff"], memo["gamma-nullspace"], memo["gamma-full"]
    for key, o in memo.items():
        assert f"{o['elbow_push_elbow_mm']:.1f} mm" in claims[key]
    assert null["elbow_push_elbow_mm"] > 3.0 * stiff["elbow_push_elbow_mm"]  # Γ₀ = I: the elbow yields
    assert null["tcp_push_tcp_mm"] < 1.0  # … while the TCP holds (mm)
    assert full["tcp_push_tcp_mm"] > 10.0 * null["tcp_push_tcp_mm"]  # Γ = I: the TCP moves with the hand


def test_mass_drop_readouts_are_the_experiments_metrics_of_the_logged_run():
    lab = Lab("mass-drop")
    lab.advance(3000)
    d = deflection_readouts(lab.log, lab.session.scenario)
    assert d is not None and d["peak_deflection_mm"] > 0.1
    c = lab.log.signal(("tcp_dev_mm",))
    assert c is not None and d["peak_deflection_mm"] == pytest.approx(float(np.max(c["tcp_dev_mm"][c["t"] >= 1.5])))


def stretching_mean(o: dict) -> float:
    """Mean force-error STD (N) of the stretching strokes S2, S4, S6."""
    return float(np.mean([o["std_S2"], o["std_S4"], o["std_S6"]]))


def test_the_posture_lesson_shows_the_coupled_posture_shaking_on_the_stretching_strokes():
    """W_j at μ = 1 (the default sensing delay) swings on S2/S4/S6 at more than twice the STD of the other
    strokes and of W_a's; each claim quotes its strokes' STDs and the comparison."""
    claims, memo = run_lesson("posture")
    wj, wa = memo["wj"], memo["wa"]
    for key, o in memo.items():
        assert "/".join(f"{o[f'std_S{k}']:.1f}" for k in (2, 4, 6)) in claims[key]
    assert stretching_mean(wj) > 2.0 * float(np.mean([wj["std_S1"], wj["std_S3"], wj["std_S5"]]))
    assert stretching_mean(wj) > 2.0 * stretching_mean(wa)
    assert f"{stretching_mean(wa) / stretching_mean(wj):.2f}×" in claims["wa"]
    # the live margin, the stroke headroom from σ every 0.1 s of simulated time (measured −6.9/−8.0/−7.3 Np
    # on W_j's S2/S4/S6, +2.4 Np on its S1/S3/S5, W_a's least +1.56 Np): 1 Np below 0 on W_j's stretching
    # strokes and above 0 on its others, 0.5 Np above 0 on every stroke of W_a
    assert max(wj[f"headroom_S{k}"] for k in (2, 4, 6)) < -1.0
    assert min(wj[f"headroom_S{k}"] for k in (1, 3, 5)) > 0.5
    assert min(wa[f"headroom_S{k}"] for k in range(1, 7)) > 0.5
    assert "below 0 on S2, S4, S6:" in claims["wj"] and "above 0 on every stroke" in claims["wa"]
    assert "/".join(f"{wj[f'headroom_S{k}']:+.1f}" for k in (2, 4, 6)) in claims["wj"]


def test_the_latency_lesson_shows_that_the_sensing_delay_makes_the_posture_shake():
    """W_j at μ = 1: from the F/T reading 0 periods late to its default delay (≥ 1 period) the stretching
    strokes' mean force-error STD more than doubles; each claim names the delay in force."""
    claims, memo = run_lesson("latency")
    ideal, default = memo["delay0"], memo["delay1"]
    assert ideal["reading_delay"] == 0 and default["reading_delay"] >= 1
    assert "0 period(s) late" in claims["delay0"]
    assert stretching_mean(default) > 2.0 * stretching_mean(ideal)
    assert f"{stretching_mean(default) / stretching_mean(ideal):.2f}×" in claims["delay1"]
