"""Lessons and the lab's case switch, without a browser: each claim carries this run's numbers, and
a case switch keeps the person's values of every field the case does not own."""

from __future__ import annotations

import re
import time

import numpy as np
import pytest

from app.core.commands import RestoreDefaults, SetParam, SwitchSession
from app.core.switching import owned_fields
from app.live.curriculum import LESSONS
from app.live.frames import deflection_readouts, make_status
from app.live.lab import Lab
from app.live.lesson_run import bind, cancel_line, finish, identity_of
from app.live.run_flags import RunFlags


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
            RunFlags(lab).apply(cmd)  # Play is a command of the loop's run flags
        bound = bind(lab, key, step.key)
        for _ in range(200):
            if step.ready(make_status(lab)) or lab.halted:
                break
            lab.advance(500)
            fold_strokes(lab)
        assert not lab.halted, lab.halted
        obs, claims[step.key] = finish(lab, bound, step, memo)
        assert obs is not None, claims[step.key]
        _RUNS[run] = obs
    return claims, memo


def fold_strokes(lab: Lab) -> None:
    """Fold the rows logged since the last call into the per-stroke force-error STDs of the arm and its twin,
    as the app's frames do every plot period (`app.live.frames`): a run longer than the log (a twin's W_a
    settles for almost a minute) keeps its first strokes' numbers."""
    lab.log.segment_force_error_std()
    if lab.twin is not None:
        lab.twin.log.segment_force_error_std()


def take_set_up(lesson_key: str, step_key: str, lab: Lab | None = None):
    """A Lab with a lesson step set up as the panel does it: (lab, step, its binding to the run)."""
    lab = lab or Lab("free")
    step = next(s for s in next(x for x in LESSONS if x.key == lesson_key).steps if s.key == step_key)
    run = RunFlags(lab)  # a set-up ends with Play, a command of the loop's run flags
    for cmd in step.setup(lab):
        run.apply(cmd)
    return lab, step, bind(lab, lesson_key, step.key)


def run_until_ready(lab: Lab, step) -> None:
    """Advance the lab (playing or not) until the step says it has run far enough."""
    for _ in range(200):
        if step.ready(make_status(lab)) or lab.halted:
            return
        lab.advance(500)


def test_the_dampers_step_changed_after_set_up_is_cancelled_and_never_labelled_with_the_set_up():
    """Issue 33's repro: Dampers step 1 set up (λ = 100), the preset switched to compliance and back to
    limit-drop, λ = 1000, Play. The page sees the switch at once (the frame's run differs: one line naming
    the preset); at the step's end the claim is the cancellation naming λ 100 → 1000, no "λ = 100" claim and
    no torque of that run. The same run without the change is claimed, naming λ = 100 and the peak it had."""
    lab, step, bound = take_set_up("dampers", "l100")
    lab.apply(SwitchSession(scenario="compliance"))
    line = cancel_line(bound, identity_of(lab))
    assert line is not None and line.startswith("Cancelled:") and "the preset limit-drop → compliance" in line
    lab.apply(SwitchSession(scenario="limit-drop"))
    lab.apply(SetParam("damper", "lambda_", 1000.0))
    run_until_ready(lab, step)
    assert lab.session.world.time >= 3.0 and not lab.halted
    obs, text = finish(lab, bound, step, {})
    assert obs is None and text.startswith("Cancelled:") and "λ (damper.lambda_) 100 → 1000 1/s" in text, text
    assert "N m" not in text and "λ = 100" not in text
    # the run it would have labelled: λ = 1000 really ran (its peak torque differs from λ = 100's by > 1 N m)
    peak_1000 = float(lab.log.extremes()[0][3])
    lab, step, bound = take_set_up("dampers", "l100", lab)
    run_until_ready(lab, step)
    obs, text = finish(lab, bound, step, {})
    assert obs is not None and abs(obs["peak_tau_4"] - peak_1000) > 1.0, (obs, peak_1000)
    assert text.startswith(f"λ = 100: joint 4 peaked at |τ₄| = {obs['peak_tau_4']:.1f} N m"), text
    assert "*Measured on* limit-drop (case position) on gen3" in text and "λ (damper.lambda_) = 100 1/s" in text


DAMPERS_CHANGES = [
    (SetParam("damper", "lambda_", 300.0), "λ (damper.lambda_) 100 → 300 1/s"),
    (SetParam("world", "torque_delay_ms", 5.0), "(world.torque_delay_ms) 0 → 5 ms"),
    (SetParam("damper", "M", 3.0), "(damper.M) 2 → 3"),
    (SetParam("damper", "form", "classic"), "(damper.form) proposed → classic"),
    (SetParam("payload", "mass_kg", 2.0), "(payload.mass_kg) 1.25 → 2"),
    (SwitchSession(variant="velocity"), "the case position → velocity"),
    (SwitchSession(robot="panda"), "the robot gen3 → panda"),
]
COMPLIANCE_CHANGES = [
    (SetParam("posture_task", "compliance", 0.0), "(posture_task.compliance) 1 → 0"),
    (SetParam("pose_task", "compliance", 1.0), "(pose_task.compliance) 0 → 1"),
    (SetParam("estimator", "source", "residual"), "(estimator.source) fusion → residual"),
    (SetParam("posture_task", "stiffness", 5.0), "(posture_task.stiffness) 1 → 5"),
    (SwitchSession(variant="full"), "the case nullspace → full"),
    (SwitchSession(robot="panda"), "the robot gen3 → panda"),
]


@pytest.mark.parametrize(
    "lesson,step_key,change,named",
    [("dampers", "l100", c, n) for c, n in DAMPERS_CHANGES]
    + [("compliance", "gamma-nullspace", c, n) for c, n in COMPLIANCE_CHANGES],
    ids=lambda v: getattr(v, "field", None) or getattr(v, "variant", None) or getattr(v, "robot", None) or None,
)
def test_a_change_after_set_up_cancels_the_step_with_one_line_naming_it(lesson, step_key, change, named):
    lab, _step, bound = take_set_up(lesson, step_key)
    assert cancel_line(bound, identity_of(lab), lab.edits) is None  # the set-up itself is the step's run
    lab.apply(change)
    assert not [n for n in lab.notice_log if n.level == "error"], list(lab.notice_log)
    line = cancel_line(bound, identity_of(lab), lab.edits, lab.last_edit)
    assert line is not None and named in line and "\n" not in line, line


def test_a_change_set_back_before_the_measurement_still_cancels_the_step():
    lab, step, bound = take_set_up("dampers", "l100")
    lab.apply(SetParam("damper", "lambda_", 1000.0))
    lab.advance(200)
    lab.apply(SetParam("damper", "lambda_", 100.0))
    assert identity_of(lab) == bound.identity  # the same run on paper …
    obs, text = finish(lab, bound, step, {})
    assert obs is None and "changed during the run (damper.lambda_ = 100.0) and set back" in text, text


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
    strokes and of W_a's; each claim quotes its strokes' STDs and the comparison; run side by side (W_a on
    the twin arm) both arms repeat their own steps' strokes."""
    claims, memo = run_lesson("posture")
    wj, wa = memo["wj"], memo["wa"]
    for key, o in memo.items():
        assert "/".join(f"{o[f'std_S{k}']:.1f}" for k in (2, 4, 6)) in claims[key]
    assert stretching_mean(wj) > 2.0 * float(np.mean([wj["std_S1"], wj["std_S3"], wj["std_S5"]]))
    assert stretching_mean(wj) > 2.0 * stretching_mean(wa)
    assert f"{stretching_mean(wa) / stretching_mean(wj):.2f}×" in claims["wa"]
    # the live margin, the stroke headroom from σ every 0.1 s of simulated time (measured −5.1/−6.2/−5.5 Np
    # on W_j's S2/S4/S6, +4.2 Np on its S1/S3/S5, W_a's least +3.4 Np): 1 Np below 0 on W_j's stretching
    # strokes and above 0 on its others, 0.5 Np above 0 on every stroke of W_a
    assert max(wj[f"headroom_S{k}"] for k in (2, 4, 6)) < -1.0
    assert min(wj[f"headroom_S{k}"] for k in (1, 3, 5)) > 0.5
    assert min(wa[f"headroom_S{k}"] for k in range(1, 7)) > 0.5
    # the one verdict per stroke (app.scenarios.verdict), in the claim with its band RMS: W_j's stretching
    # strokes are not stable
    assert all(verdict_of(wj, k) != "stable" for k in (2, 4, 6))
    for key in ("wj", "wa"):  # the side-by-side claim states the two arms' STDs only
        for k in range(1, 7):
            assert f"S{k} {verdict_of(memo[key], k)} ({memo[key][f'band_S{k}']:.2f} N)" in claims[key]
    # what the claim says of it: only the sign of the least headroom with its band, in words, no Np figure;
    # after the strokes whether that came true, stroke by stroke, by the one verdict
    assert "S2, S4, S6: predicted to shake off the table (lose contact)" in claims["wj"]
    assert "S1, S2, S3, S4, S5, S6: predicted to keep contact" in claims["wa"]
    assert not re.search(r"(?<![±\d.])\d+(\.\d+)? Np", claims["wj"] + claims["wa"])  # only the band, ±HEADROOM_BAND_NP
    for key in ("wj", "wa"):
        check_outcomes(claims[key], memo[key])
    # side by side: W_j on the arm and W_a on the twin in one run are the two steps' runs, stroke for stroke
    # (the twin is the same scenario with its own objective, in lockstep; it settles at its own pace)
    side = memo["side"]
    for k in range(1, 7):
        assert side[f"std_S{k}"] == pytest.approx(wj[f"std_S{k}"], rel=1e-9, abs=1e-9)
        assert side[f"twin_std_S{k}"] == pytest.approx(wa[f"std_S{k}"], rel=1e-9, abs=1e-9)
    assert stretching_mean(side) > 2.0 * float(np.mean([side[f"twin_std_S{k}"] for k in (2, 4, 6)]))
    assert "/".join(f"{side[f'twin_std_S{k}']:.1f}" for k in (2, 4, 6)) + " N with W_a" in claims["side"]


def test_the_posture_lesson_shows_the_decoupled_posture_within_one_period_and_not_two():
    """The posture lesson's third step: W_a at μ = 1 with 1 ms of torque delay on the F/T reading's one
    period (two periods in all). Its stretching strokes swing at more than twice the STD of W_a's at one
    period and at least one is not stable by the one verdict, while every stroke of W_a at one period is;
    the claim names both delays and quotes this run's STDs, verdicts and the ratio to W_a's."""
    claims, memo = run_lesson("posture")
    wa, wa2 = memo["wa"], memo["wa2"]
    assert wa["reading_delay"] == 1 and wa["torque_delay_ms"] == 0.0
    assert wa2["reading_delay"] == 1 and wa2["torque_delay_ms"] == 1.0
    assert "(F/T reading 1 period(s) late, torque 1 ms late)" in claims["wa2"]
    assert "torque" not in claims["wa"].split(":", 1)[0]  # one period: no torque delay named
    assert "/".join(f"{wa2[f'std_S{k}']:.1f}" for k in (2, 4, 6)) in claims["wa2"]
    assert stretching_mean(wa2) > 2.0 * stretching_mean(wa)
    assert f"{stretching_mean(wa2) / stretching_mean(wa):.2f}×" in claims["wa2"]
    assert all(verdict_of(wa, k) == "stable" for k in range(1, 7))
    assert any(verdict_of(wa2, k) != "stable" for k in (2, 4, 6))
    for k in range(1, 7):
        assert f"S{k} {verdict_of(wa2, k)} ({wa2[f'band_S{k}']:.2f} N)" in claims["wa2"]
    check_outcomes(claims["wa2"], wa2)


def after_the_strokes(claim: str) -> dict[int, str]:
    """What a polish claim says happened on each stroke against the margin's prediction ("After the
    strokes: S1, S5: came true: …; S2: …"), by stroke."""
    assert "After the strokes: " in claim, claim
    after = claim.split("After the strokes: ", 1)[1].split(". ", 1)[0]
    out: dict[int, str] = {}
    for names, words in re.findall(r"((?:S\d, )*S\d): (.*?)(?=; S\d|\.?$)", after):
        for k in re.findall(r"S(\d)", names):
            out[int(k)] = words
    return out


def check_outcomes(claim: str, o: dict) -> None:
    """Each stroke's outcome in the claim is its verdict's, says whether contact was kept, and whether the
    margin's prediction came true: "no prediction" inside the band, else the sign against lost contact."""
    from app.scenarios import polish_margin as PM
    from app.scenarios import verdict as V

    after = after_the_strokes(claim)
    assert sorted(after) == [1, 2, 3, 4, 5, 6], (after, claim)
    for k, words in after.items():
        verdict = V.SEVERITY[int(o[f"verdict_S{k}"])]
        h = o[f"headroom_S{k}"]
        assert f"the stroke was {verdict}" in words, (k, words)
        assert ("contact kept" in words) == (verdict not in (V.LOST, V.DIVERGED)), (k, words)
        if abs(h) <= PM.HEADROOM_BAND_NP:
            assert words.startswith("no prediction to check"), (k, h, words)
        else:
            came = (h < 0) == (verdict in (V.LOST, V.DIVERGED))
            assert words.startswith("came true" if came else "did not come true"), (k, h, words)


def test_the_latency_lesson_shows_that_the_sensing_delay_makes_the_posture_shake():
    """W_j at μ = 1: from the F/T reading 0 periods late to its default delay (≥ 1 period) the stretching
    strokes' mean force-error STD more than doubles; each claim names the delay in force."""
    claims, memo = run_lesson("latency")
    ideal, default = memo["delay0"], memo["delay1"]
    assert ideal["reading_delay"] == 0 and default["reading_delay"] >= 1
    assert "0 period(s) late" in claims["delay0"]
    assert stretching_mean(default) > 2.0 * stretching_mean(ideal)
    assert f"{stretching_mean(default) / stretching_mean(ideal):.2f}×" in claims["delay1"]
    # the no-delay step claims no prediction without saying, stroke by stroke, whether it came true and
    # whether contact was kept
    for key in ("delay0", "delay1"):
        check_outcomes(claims[key], memo[key])


def verdict_of(o: dict, k: int) -> str:
    """A stroke's verdict as `measure` recorded it (its index in `verdict.SEVERITY`)."""
    from app.scenarios.verdict import SEVERITY

    return SEVERITY[int(o[f"verdict_S{k}"])]


def test_the_lessons_panel_cancels_the_repro_as_soon_as_the_preset_changes_and_claims_an_untouched_run():
    """The Lessons tab on a running loop (no browser): Dampers step 1 set up, the preset switched to
    compliance: the next frame's run differs and the panel shows one line naming the switch instead of a
    claim, keeping no numbers for the step; set up again and left alone, the step's claim names its run."""
    import viser

    from app.live.loop import SimLoop
    from app.live.ui.panels.lessons import LessonsPanel
    from tests.conftest import free_port

    server = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    loop = SimLoop("free", capture=lambda s: None)
    loop.start(running=False)
    try:
        panel = LessonsPanel(server, loop)
        panel.select("dampers")

        def watch(until_s: float = 120.0) -> str:
            seq, deadline = 0, time.monotonic() + until_s
            while ("dampers", "l100") not in panel.claims and time.monotonic() < deadline:
                frame = loop.wait_frame(seq, 1.0)
                if frame is not None:
                    seq = frame.seq
                    panel.live(frame)
            return panel.claims.get(("dampers", "l100"), "")

        panel.start_step()
        loop.submit(SwitchSession(scenario="compliance"))
        text = watch()
        assert text.startswith("Cancelled:") and "the preset limit-drop → compliance" in text, text
        assert panel.result_md.content.startswith("**Step cancelled.**") and "l100" not in panel.results["dampers"]
        panel.start_step()
        text = watch()
        low = panel.results["dampers"]["l100"]
        assert text.startswith(f"λ = 100: joint 4 peaked at |τ₄| = {low['peak_tau_4']:.1f} N m"), text
        assert "*Measured on* limit-drop (case position) on gen3" in text and panel.armed is None
    finally:
        loop.stop()
        server.stop()


def test_the_nullspace_panel_states_the_margins_prediction_in_words_and_then_whether_it_came_true():
    """W_j at μ = 1 (the posture lesson's first step) into its third stroke: on the stroke the Nullspace
    panel states the margin's prediction in words with its band and no headroom figure; for the last
    stroke over (S2) it states whether that came true by S2's verdict, and whether contact was kept; the
    frame's strokes are the lesson's own judgement of the same run."""
    from app.live.frames import FrameBuilder
    from app.live.ui.panels.nullspace import _polish_lines
    from app.scenarios.stroke_outcomes import HEADROOM_BAND_NP, MARGIN_COLUMNS, stroke_outcomes

    lab, _step, _ = take_set_up("posture", "wj")
    builder = FrameBuilder(publish_period=1 / 30, plot_period=0.1)

    def on_the_third_stroke() -> bool:
        sig = make_status(lab).signals
        h = sig.get("margin_headroom_np", float("nan"))
        return sig.get("segment", 0.0) >= 3.0 and h == h  # the headroom comes with the stroke's first σ

    for _ in range(400):
        if on_the_third_stroke() or lab.halted:
            break
        lab.advance(250)
    frame = builder.build(lab, now=0.0)
    assert frame.plot is not None and [x.segment for x in frame.plot.strokes] == [1, 2]
    text = _polish_lines(frame.status.signals, frame.plot.strokes)
    assert "**Force-loop margin on S3:** predicted to keep contact through this stroke" in text
    assert f"±{HEADROOM_BAND_NP:g} Np" in text and not re.search(r"(?<![±\d.])\d+(\.\d+)? Np", text)
    c = lab.log.signal((*MARGIN_COLUMNS, "F_z", "contact_force_n"))
    own = {
        x.segment: x for x in stroke_outcomes(c, lab.session.params()["sensor"], lab.dt, lab.session.scenario.segments)
    }
    s2 = frame.plot.strokes[-1]
    assert s2.verdict == own[2].verdict and s2.statement == own[2].statement
    assert f"**Last stroke:** S2: {s2.statement.words} — " in text and f"the stroke was {s2.verdict}" in text
    assert s2.statement.sign == -1 and s2.came_true == (s2.verdict == "lost contact")
