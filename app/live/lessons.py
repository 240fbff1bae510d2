"""Guided lessons: short sequences of steps that set up a preset, say what to do and watch, and after
the step say what the student saw — with this run's numbers, measured from the step log.

A `Lesson` is a title, one line of purpose and its `Step`s. A step has the commands that set it up
(`setup(lab_defaults)`: preset, parameters, reset and play, as a person would with the panels), one
or two sentences of what to do and what to watch in the plot and in the 3D view, the charts it names
(`plots`: the Plots panel shows them first while the step's run is on), a condition on the loop's
status that says the step has run far enough (`ready`), and a `claim`: a sentence built from
`measure(lab)`'s numbers of this run and of the lesson's earlier steps. Nothing in a claim is a fixed
number; where a step has too little data to say something, the claim says that.

`measure(lab)` runs on the loop thread (`SimLoop.call`): it reads every logged 1 ms step since the
last reset (`StepLog`), so its numbers are those of the run the student just watched.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from app.core.commands import Command
from app.core.params import field_spec
from app.live.frames import LoopStatus, deflection_readouts
from app.live.lab import Lab
from app.scenarios import verdict as V
from app.scenarios.metrics import PUSH_AFTER_S, REVERSAL_HYSTERESIS_RAD_S, velocity_reversals
from app.scenarios.stroke_outcomes import StrokeOutcome, band_words, headroom_statement, stroke_figures

Obs = dict[str, float]  # one step's measured numbers
Memo = dict[str, Obs]  # the lesson's earlier steps' numbers, by step key

DROP_WATCH_S = 3.0  # a limit drop is over after this much simulated time (joint 4 at rest or chattering)
THRASH_SPEED_RAD_S = 0.5  # a joint other than the falling one moving faster than this counts as thrashing
CHATTER_WINDOW_S = 2.0  # reversals of q̇₄ are counted over the last seconds of the run


@dataclass(frozen=True)
class Step:
    """One step of a lesson (see the module docstring)."""

    key: str
    title: str
    todo: str  # what to do and what to watch in the plot and in the 3D view
    setup: Callable[[Lab | None], list[Command]]  # the commands that set the step up
    ready: Callable[[LoopStatus], bool]  # the step has run far enough to be measured
    claim: Callable[[Obs, Memo], str]  # what the student saw, from this run's numbers
    plots: tuple[str, ...] = ()  # the charts the step names (`app.live.ui.plots.CHARTS`), on top in this order
    compared: str | None = ""  # the step whose run is drawn faint: "" the one before, None none


@dataclass(frozen=True)
class Lesson:
    """A guided lesson: a title, its purpose in one line and its steps."""

    key: str
    title: str
    purpose: str
    steps: tuple[Step, ...] = field(default_factory=tuple)


# ---- measurements (loop thread) -------------------------------------------------------------------
def measure(lab: Lab) -> Obs:
    """The numbers of the run since the last reset that the lessons' claims use (every 1 ms step)."""
    s = lab.session
    out: Obs = {"t": float(s.world.time), "fallback_steps": float(lab.fallback_steps)}
    c = lab.log.window(lab.log.capacity * lab.dt, lab.dt)
    t = c.get("t", np.zeros(0))
    if not len(t):
        return out
    segments = s.scenario.segments  # a preset with strokes: the force error and headroom per stroke
    if segments:
        out["segments"] = float(segments)
        for k, v in lab.log.segment_force_error_std().items():
            out[f"std_S{k}"] = v
        out.update(least_headroom(c, segments))
        out.update(stroke_verdicts(c, s.params().get("sensor"), lab.dt, segments))
        if lab.twin is not None:  # the twin arm's strokes, over its own segments
            for k, v in lab.twin.log.segment_force_error_std().items():
                out[f"twin_std_S{k}"] = v
        found = delay_field()
        if found is not None and found[0] in s.params():
            out["reading_delay"] = float(getattr(s.params()[found[0]], found[1]))
        world = s.params().get("world")
        if world is not None:
            out["torque_delay_ms"] = float(getattr(world, "torque_delay_ms", math.nan))
    n = s.robot.nq
    for j in range(n):
        q = c[f"q_{j + 1}"]
        out[f"swing_{j + 1}"] = float(np.nanmax(q) - np.nanmin(q))
        out[f"peak_tau_{j + 1}"] = float(np.nanmax(np.abs(c[f"tau_{j + 1}"])))
        out[f"tau_max_{j + 1}"] = float(s.robot.tau_max[j])
    drop = s.scenario.fall(s.robot)  # a preset that drops a joint: the joint and the limit it falls toward
    if drop is not None:
        j = drop.joint
        dq = c[f"dq_{j + 1}"]
        out["reversals_first_3s"] = float(velocity_reversals(dq[t <= t[0] + DROP_WATCH_S]))
        late = t >= t[-1] - CHATTER_WINDOW_S
        out["reversals_late"] = float(velocity_reversals(dq[late]))
        out["late_peak_tau"] = float(np.nanmax(np.abs(c[f"tau_{j + 1}"][late])))
        hi, lo = float(s.robot.q_upper[j]), float(s.robot.q_lower[j])
        damper = s.params().get("damper")
        d_s = float(getattr(damper, "safety_fraction", 0.01)) * (hi - lo)
        sign, limit = drop.direction, drop.limit
        past = float(np.nanmax(sign * (c[f"q_{j + 1}"] - limit)))  # > 0 beyond the limit
        out["beyond_ds_mrad"] = 1e3 * max(0.0, past + d_s)
        out["lambda"] = float(getattr(damper, "lambda_", math.nan))  # the run's own, for the claim's label
        world = s.params().get("world")
        out["torque_delay_ms"] = float(getattr(world, "torque_delay_ms", math.nan))
        # the arm thrashing: any joint but the falling one faster than THRASH_SPEED_RAD_S
        others = np.vstack([np.abs(c[f"dq_{i + 1}"]) for i in range(n) if i != j])
        fast = np.flatnonzero(np.nanmax(others, axis=0) > THRASH_SPEED_RAD_S)
        out["thrash_end_s"] = float(t[fast[-1]] - t[0]) if fast.size else 0.0
        out["tcp_height_m"] = float(s.dyn.tcp_position_world[2])
        biggest = max((i for i in range(n) if i != j), key=lambda i: out[f"swing_{i + 1}"])
        out["widest_joint"] = float(biggest + 1)
    d = deflection_readouts(lab.log, s.scenario)
    if d:
        out.update(d)
    return out


def least_headroom(c: dict[str, np.ndarray], segments: int) -> Obs:
    """The least live stroke headroom (Np: the polish margin along each stroke, `stroke_figures`) per
    logged stroke 1…`segments`, "headroom_S{k}"; none for a stroke without a finite value."""
    found = stroke_figures(c, segments)
    return {f"headroom_S{k}": h for k, (h, _) in found.items() if math.isfinite(h)}


def stroke_verdicts(c: dict[str, np.ndarray], sensor: object, dt: float, segments: int) -> Obs:
    """The one verdict (`app.scenarios.verdict`) of each logged stroke: "verdict_S{k}" (its index in
    `verdict.SEVERITY`), "band_S{k}" (the F/T reading's band RMS, N) and the threshold it was held to."""
    out: Obs = {}
    seg, fz, contact = c.get("segment"), c.get("F_z"), c.get("contact_force_n")
    if seg is None or fz is None or contact is None or sensor is None:
        return out
    for s in V.strokes(seg, fz, contact, sensor, dt, range(1, segments + 1)):
        out[f"verdict_S{s.segment}"] = float(V.SEVERITY.index(s.verdict))
        out[f"band_S{s.segment}"] = s.band_rms_n
        out["oscillation_threshold_n"] = s.threshold_n
    return out


# ---- what a claim says -----------------------------------------------------------------------------
def _stroke_numbers(o: Obs) -> range:
    """The strokes 1…segments of the measured preset (`Scenario.segments`, "segments" in `measure`);
    empty for one without strokes (a claim on strokes then says it has no numbers)."""
    n = int(o.get("segments", 0))
    return range(1, n + 1) if n else range(1, 0)


def _strokes(o: Obs) -> tuple[list[float], list[float]] | None:
    """The stretching (even: S2, S4, S6) and the retracting (odd) strokes' force-error STDs, or None
    while a stroke is missing (or the preset has fewer than four)."""
    strokes = _stroke_numbers(o)
    if len(strokes) < 4 or not all(f"std_S{k}" in o for k in strokes):
        return None
    return [o[f"std_S{k}"] for k in strokes if k % 2 == 0], [o[f"std_S{k}"] for k in strokes if k % 2 == 1]


def _fmt(values: list[float]) -> str:
    return "/".join(f"{v:.1f}" for v in values)


def strokes_claim(label: str) -> Callable[[Obs, Memo], str]:
    """The polish claim: the stretching strokes' STD against the others', with this run's numbers."""

    def claim(o: Obs, memo: Memo) -> str:
        s = _strokes(o)
        if s is None:
            return "The zig-zag has not run through S6 since the last reset: no per-stroke numbers yet."
        forward, back = s
        ratio = o["std_S4"] / o["std_S3"] if o["std_S3"] > 0 else math.inf
        delay = (
            f" (F/T reading {o['reading_delay']:g} period(s) late{_torque_delay_words(o)})"
            if "reading_delay" in o
            else " (this build has no F/T reading delay to set)"
        )
        return (
            f"{label}{delay}: the stretching strokes S2/S4/S6 had a force-error STD of {_fmt(forward)} N against "
            f"{_fmt(back)} N on S1/S3/S5 — S4's {o['std_S4']:.1f} N is {ratio:.1f}× S3's {o['std_S3']:.1f} N."
            + verdict_claim(o)
            + headroom_claim(o)
        )

    return claim


def _torque_delay_words(o: Obs) -> str:
    """ ", torque 1 ms late" when the run had a torque delay ("" without one)."""
    delay = o.get("torque_delay_ms", 0.0)
    return f", torque {delay:g} ms late" if delay > 0 else ""


def _verdict_of(o: Obs, k: int) -> str | None:
    v = o.get(f"verdict_S{k}")
    return None if v is None else V.SEVERITY[int(v)]


def verdict_claim(o: Obs) -> str:
    """Each stroke's verdict in words ("" without them)."""
    strokes = _stroke_numbers(o)
    if not strokes or not all(f"verdict_S{k}" in o for k in strokes):
        return ""
    words = ", ".join(f"S{k} {_verdict_of(o, k)} ({o[f'band_S{k}']:.2f} N)" for k in strokes)
    return (
        f" By the one verdict (F/T band RMS around the 13 Hz contact mode, oscillating from "
        f"{o['oscillation_threshold_n']:.2f} N; lost contact: the contact force reached 0): {words}."
    )


def _named(keys: list[int]) -> str:
    return ", ".join(f"S{k}" for k in keys)


def _grouped(items: list[tuple[int, str]]) -> str:
    """ "S1, S3, S5: words; S2, S4, S6: other words" from (stroke, words), strokes with the same words together."""
    groups: dict[str, list[int]] = {}
    for k, words in items:
        groups.setdefault(words, []).append(k)
    return "; ".join(f"{_named(ks)}: {words}" for words, ks in groups.items())


def headroom_claim(o: Obs) -> str:
    """What the margin predicted for each stroke, in words (the sign of its least headroom with its band,
    `stroke_outcomes`; no magnitude), and after the strokes whether that came true and whether contact was
    kept, by the stroke's one verdict ("" without the headroom)."""
    strokes = _stroke_numbers(o)
    if not strokes or not all(f"headroom_S{k}" in o for k in strokes):
        return ""
    outcomes = [StrokeOutcome(k, headroom_statement(o[f"headroom_S{k}"]), _verdict_of(o, k)) for k in strokes]
    text = f" The force-loop margin ({band_words()}): " + _grouped([(x.segment, x.statement.words) for x in outcomes])
    if any(x.verdict is None for x in outcomes):
        return text + ". No verdict of the strokes: whether that came true is not known."
    after = _grouped([(x.segment, x.checked) for x in outcomes])
    return text + f". After the strokes: {after}."


def compare_strokes(label: str, other_key: str, other_label: str) -> Callable[[Obs, Memo], str]:
    """The polish claim of a second run, compared stroke by stroke with an earlier step's."""
    own = strokes_claim(label)

    def claim(o: Obs, memo: Memo) -> str:
        text = own(o, memo)
        other = memo.get(other_key)
        if _strokes(o) is None or other is None or _strokes(other) is None:
            return text + (f" (Run the step “{other_label}” to compare.)" if other is None else "")
        mean_here = float(np.mean(_strokes(o)[0]))  # type: ignore[index]
        mean_there = float(np.mean(_strokes(other)[0]))  # type: ignore[index]
        return text + (
            f" Over the stretching strokes that is a mean STD of {mean_here:.1f} N against {mean_there:.1f} N "
            f"with {other_label} ({mean_here / mean_there:.2f}×)."
        )

    return claim


def twin_strokes(o: Obs) -> Obs:
    """The twin arm's stroke STDs ("twin_std_S{k}") as an `Obs` of its own ("std_S{k}", "segments")."""
    out: Obs = {k.removeprefix("twin_"): v for k, v in o.items() if k.startswith("twin_std_S")}
    if "segments" in o:
        out["segments"] = o["segments"]
    return out


def side_by_side_claim(label: str, twin_label: str) -> Callable[[Obs, Memo], str]:
    """The claim of one run of two arms: this arm's stretching and retracting strokes against the twin's."""

    def claim(o: Obs, memo: Memo) -> str:
        own, twin = _strokes(o), _strokes(twin_strokes(o))
        if own is None or twin is None:
            return "The zig-zags of both arms have not run through S6 since the last reset: no per-stroke numbers yet."
        mean_own, mean_twin = float(np.mean(own[0])), float(np.mean(twin[0]))
        return (
            f"In one run, {label} on this arm and {twin_label} on the twin arm: the stretching strokes S2/S4/S6 had "
            f"a force-error STD of {_fmt(own[0])} N with {label} against {_fmt(twin[0])} N with {twin_label} (means "
            f"{mean_own:.1f} N and {mean_twin:.1f} N, {mean_own / mean_twin:.1f}×); the retracting strokes S1/S3/S5 "
            f"{_fmt(own[1])} N against {_fmt(twin[1])} N."
        )

    return claim


def drop_label(o: Obs) -> str:
    """The limit drop's damper and delay as this run had them: "λ = 100", "λ = 500, 5 ms delay"."""
    delay = o.get("torque_delay_ms", 0.0)
    return f"λ = {o.get('lambda', math.nan):g}" + (f", {delay:g} ms delay" if delay > 0 else "")


def delay_verdict(o: Obs, memo: Memo, delayed_stiff: str) -> str:
    """Whether this run's damper tolerated its torque delay, from its own numbers: it did when no joint but
    4 thrashed (moved faster than THRASH_SPEED_RAD_S, the failure of the stiffer damper under the delay) and
    joint 4's peak torque stayed below its limit; beside it, how the stiffer damper's run `delayed_stiff` did
    with the same delay."""
    thrashed, reversed_, peak, limit = o["thrash_end_s"], o["reversals_first_3s"], o["peak_tau_4"], o["tau_max_4"]
    stops = "without reversing" if reversed_ == 0 else f"after {reversed_:.0f} reversal(s)"
    if thrashed <= 0 and peak < limit:
        text = (
            f" **So {drop_label(o)} tolerates the delay in this run:** no joint but 4 moved faster than "
            f"{THRASH_SPEED_RAD_S:g} rad/s and joint 4 stopped {stops} at {100 * peak / limit:.0f} % of its "
            "torque limit."
        )
    else:
        why = [f"the arm thrashed for {thrashed:.1f} s"] if thrashed > 0 else []
        why += ["|τ₄| reached its limit"] if peak >= limit else []
        text = f" **So {drop_label(o)} does not tolerate the delay in this run:** {'; '.join(why)}."
    stiff = memo.get(delayed_stiff)
    if stiff is not None and "thrash_end_s" in stiff:
        text += (
            f" With the same delay, {drop_label(stiff)} thrashed for {stiff['thrash_end_s']:.1f} s."
            if stiff["thrash_end_s"] > 0
            else f" With the same delay, {drop_label(stiff)} did not thrash either."
        )
    return text


def drop_claim(baseline: str | None = None, delayed_stiff: str | None = None) -> Callable[[Obs, Memo], str]:
    """The limit-drop claim: joint 4's peak torque, how far it went beyond d_s and its reversals, labelled
    with the run's own λ and delay; with `delayed_stiff` (the step of the stiffer damper under the same
    delay), whether this run tolerated its delay (`delay_verdict`)."""

    def claim(o: Obs, memo: Memo) -> str:
        if "peak_tau_4" not in o:
            return "Nothing logged since the last reset: press Play."
        label = drop_label(o)
        text = (
            f"{label}: joint 4 peaked at |τ₄| = {o['peak_tau_4']:.1f} N m (limit {o['tau_max_4']:.0f} N m), "
            f"went {o['beyond_ds_mrad']:.1f} mrad beyond d_s and reversed its velocity "
            f"{o['reversals_first_3s']:.0f} times in the first 3 s (by more than ±{REVERSAL_HYSTERESIS_RAD_S:g} rad/s)."
        )
        before = memo.get(baseline) if baseline else None
        if before is not None and "peak_tau_4" in before:
            text += f" That is {o['peak_tau_4'] / before['peak_tau_4']:.1f}× the peak torque of {drop_label(before)}."
        if delayed_stiff is not None and "thrash_end_s" in o:
            text += delay_verdict(o, memo, delayed_stiff)
        return text

    return claim


def thrash_claim(o: Obs, memo: Memo) -> str:
    """The delayed λ = 500 drop as it happens: the whole arm first, then τ₄'s chatter."""
    if "peak_tau_4" not in o:
        return "Nothing logged since the last reset: press Play."
    n = sum(1 for k in o if k.startswith("swing_"))
    swings = ", ".join(f"joint {i} {o[f'swing_{i}']:.2f} rad" for i in range(1, n + 1) if i != 4)
    widest = int(o["widest_joint"])
    fallback = (
        f"the QP fell back to its safe solution in {o['fallback_steps']:.0f} steps"
        if o["fallback_steps"] > 0
        else "the QP never fell back"
    )
    thrash = (
        f"For {o['thrash_end_s']:.1f} s the whole arm thrashed (a joint other than 4 faster than "
        f"{THRASH_SPEED_RAD_S:g} rad/s): joint {widest} swung {o[f'swing_{widest}']:.2f} rad; all swings: {swings}; "
        if o["thrash_end_s"] > 0
        else f"No joint other than 4 moved faster than {THRASH_SPEED_RAD_S:g} rad/s; swings: {swings}; "
    )
    return (
        thrash + f"{fallback}; the tool ended {o['tcp_height_m']:.2f} m above the floor. "
        f"In the last {CHATTER_WINDOW_S:g} s τ₄ reached {o['late_peak_tau']:.1f} N m "
        f"(limit {o['tau_max_4']:.0f} N m) and q̇₄ reversed {o['reversals_late']:.0f} times (by more than "
        f"±{REVERSAL_HYSTERESIS_RAD_S:g} rad/s)."
    )


def push_claim(label: str) -> Callable[[Obs, Memo], str]:
    """The compliance claim: how far TCP and elbow moved under each push, and against the other modes."""

    def claim(o: Obs, memo: Memo) -> str:
        if "tcp_push_tcp_mm" not in o or "elbow_push_tcp_mm" not in o:
            return "The two pushes (TCP at 0.5 s, elbow at 2 s) have not both happened since the last reset."
        text = (
            f"{label} (peaks over each push and the {PUSH_AFTER_S:g} s after it): under the push at the TCP the TCP "
            f"moved {o['tcp_push_tcp_mm']:.1f} mm and the elbow "
            f"{o['tcp_push_elbow_mm']:.1f} mm; under the push at the elbow the TCP moved "
            f"{o['elbow_push_tcp_mm']:.1f} mm and the elbow {o['elbow_push_elbow_mm']:.1f} mm."
        )
        others = [
            (k, v) for k, v in memo.items() if k.startswith("gamma-") and "elbow_push_elbow_mm" in v and v is not o
        ]
        if others:
            text += " Elbow under the elbow push in the other modes: " + ", ".join(
                f"{k.removeprefix('gamma-')} {v['elbow_push_elbow_mm']:.1f} mm" for k, v in others
            )
            text += "."
        return text

    return claim


# ---- set-ups ------------------------------------------------------------------------------------
READING_DELAY = ("sensor", "reading_delay_steps")  # the F/T reading's age in control periods


def delay_field(lab: Lab | None = None) -> tuple[str, str] | None:
    """(group, field) of the F/T reading's delay in control periods, if this build models it."""
    try:
        field_spec(*READING_DELAY)
    except (KeyError, ValueError):
        return None
    return READING_DELAY
