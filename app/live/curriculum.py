"""The lessons' curriculum: which preset, case and parameters each step sets up, and when it has run
far enough. A lesson step is a script over named presets, as a person picks them from the menu; this
module is the one place of the live app that names presets (`tests/test_scenario_contract.py`), the
machinery it uses (steps, measurements, claims) is `app.live.lessons`.
"""

from __future__ import annotations

from collections.abc import Callable

from app.core.commands import Command, Play, RestoreDefaults, SetParam, SettleNow, SetTwin, SwitchSession
from app.live.frames import LoopStatus
from app.live.lab import Lab
from app.live.lessons import (
    DROP_WATCH_S,
    Lesson,
    Step,
    compare_strokes,
    delay_field,
    drop_claim,
    push_claim,
    side_by_side_claim,
    strokes_claim,
    thrash_claim,
)
from app.scenarios import SCENARIOS, get_scenario

THRASH_WATCH_S = 16.0  # the delayed λ = 500 drop: the thrashing lasts about 12 s, then τ₄ chatters
PUSH_DONE_S = 4.0  # the compliance preset's two pushes are over (compliance.DURATION_S)
LESSON_DELAY_MS = 5.0  # the torque delay of the dampers lesson (a real arm's motor driver and bus)
HIGH_LAMBDA = 500.0
FRICTION_MU = 1.0
SECOND_PERIOD_MS = 1.0  # the posture lesson's second window: one period of torque delay on the F/T reading's one
POLISH_PLOTS = ("force",)  # the force error with the margin's headroom under it
MARGIN_WARNING = (
    "where it falls below its dashed band, the margin predicts that the tool lifts off within the stroke, "
    "a fraction of a second ahead."
)
CONTACT_3D = (
    "the ring on the table around the tool, green in contact, turns red when the tool lifts off, and a red "
    "cross stays where it lifted."
)
FALL_3D = "the forearm falls under the payload; joint 4's link turns yellow, then red, as it nears its limit."
COMPARED = "drawn faint behind this run"  # the comparison trace (app.live.ui.lesson_view)


def polish_setup(
    objective: str, delay: str = "default", torque_delay_ms: float | None = None, twin: str | None = None
) -> Callable[[Lab | None], list[Command]]:
    """Polish from its defaults, μ = 1, the objective, the F/T delay (default / zero), the torque delay
    (None: its default), the twin arm with its objective (or none), Settle now (the main arm's settle
    phase; a twin settles at its own pace)."""

    def setup(lab: Lab | None) -> list[Command]:
        cmds: list[Command] = [
            RestoreDefaults(),  # first: the switch then keeps nothing of the person's earlier values
            SetTwin(None),
            SwitchSession(scenario="polish", robot="", variant="flow"),
            SetParam("contact", "mu", FRICTION_MU),
            SetParam("nullspace", "objective", objective),
        ]
        found = delay_field()
        if delay == "zero" and found is not None:
            cmds.append(SetParam(found[0], found[1], 0))
        if torque_delay_ms is not None:
            cmds.append(SetParam("world", "torque_delay_ms", torque_delay_ms))
        if twin is not None:
            cmds.append(SetTwin(twin))  # restarts both arms together, the twin with the values set above
        cmds.append(SettleNow())
        return cmds

    return setup


def drop_setup(lambda_: float, delay_ms: float) -> Callable[[Lab | None], list[Command]]:
    """The limit drop from its defaults with λ and the torque delay, then Play."""

    def setup(lab: Lab | None) -> list[Command]:
        return [
            RestoreDefaults(),
            SetTwin(None),
            SwitchSession(scenario="limit-drop", robot="", variant="position"),
            SetParam("damper", "lambda_", lambda_),
            SetParam("world", "torque_delay_ms", delay_ms),
            Play(),
        ]

    return setup


def compliance_setup(mode: str) -> Callable[[Lab | None], list[Command]]:
    """The compliance preset in one Γ mode, from its defaults, then Play."""

    def setup(lab: Lab | None) -> list[Command]:
        return [RestoreDefaults(), SetTwin(None), SwitchSession(scenario="compliance", robot="", variant=mode), Play()]

    return setup


def polish_done(st: LoopStatus) -> bool:
    """The zig-zag has run through its last stroke (signal "segment" past the preset's `segments`) and
    the margin's figures of every stroke are in (signal "margin_waiting": they come from the offload a
    little after their steps, later on a loaded machine)."""
    segments = get_scenario(st.scenario).segments if st.scenario in SCENARIOS else 0
    done = st.scenario == "polish" and segments > 0 and st.signals.get("segment", 0.0) > segments
    return done and not st.signals.get("margin_waiting", 0.0)


def both_polished(st: LoopStatus) -> bool:
    """The zig-zag of the main arm and of the twin arm have both run through their last strokes."""
    segments = get_scenario(st.scenario).segments if st.scenario in SCENARIOS else 0
    return polish_done(st) and st.twin_segment > segments


def after(scenario: str, seconds: float) -> Callable[[LoopStatus], bool]:
    """The preset has run `seconds` of simulated time since its reset."""
    return lambda st: st.scenario == scenario and st.t >= seconds


LESSONS: tuple[Lesson, ...] = (
    Lesson(
        "posture",
        "Posture and friction",
        "Which elbow posture the nullspace picks decides whether friction shakes the contact force ([T] §IV-B).",
        (
            Step(
                "wj",
                "W_j at μ = 1",
                "The polish preset with friction μ = 1 and the joint-space objective W_j; Settle now runs the "
                "settle phase, then the zig-zag S1…S6. **Plot:** the force error on the stretching strokes S2, "
                f"S4, S6, and under it the stroke headroom h: {MARGIN_WARNING} **3D view:** {CONTACT_3D}",
                polish_setup("j"),
                polish_done,
                strokes_claim("W_j, μ = 1"),
                POLISH_PLOTS,
            ),
            Step(
                "wa",
                "W_a at μ = 1",
                "The same with the dynamic-coupling objective W_a: the elbow flows to another posture first "
                "(almost a minute of simulated time; Settle now runs it fast). **Plot:** the stretching strokes "
                f"against W_j's, {COMPARED}, and the headroom h. **3D view:** the elbow's other posture; {CONTACT_3D}",
                polish_setup("a"),
                polish_done,
                compare_strokes("W_a, μ = 1", "wj", "W_j"),
                POLISH_PLOTS,
            ),
            Step(
                "wa2",
                "W_a with one more period of latency",
                "W_a again, with the torque reaching the joints 1 ms (one control period) late on top of the F/T "
                "reading's one period: two periods in all, as a drive that latches each command on its next bus "
                "cycle would add. Neither paper states its loop's delays. **Plot:** the stretching strokes against "
                f"W_a's at one period, {COMPARED}, and the headroom h. **3D view:** {CONTACT_3D}",
                polish_setup("a", torque_delay_ms=SECOND_PERIOD_MS),
                polish_done,
                compare_strokes("W_a, μ = 1", "wa", "W_a at one period"),
                POLISH_PLOTS,
            ),
            Step(
                "side",
                "W_j and W_a side by side",
                "One run of two arms at μ = 1: W_j on this arm, W_a on the twin arm (Run → Twin arm); W_a's elbow "
                "flows for almost a minute before its zig-zag, so the step runs about 70 s of simulated time. "
                "**Plot:** the force error of W_j (red) and of the twin (dashed orange) on their stretching strokes. "
                "**3D view:** the translucent orange twin's elbow leaves W_j's posture; the ring and the crosses at "
                "this arm's tool.",
                polish_setup("j", twin="a"),
                both_polished,
                side_by_side_claim("W_j", "W_a"),
                POLISH_PLOTS,
                compared=None,  # the twin's own trace is the comparison
            ),
        ),
    ),
    Lesson(
        "latency",
        "Latency",
        "A sampled controller answers a force reading at least one period late; that delay is what makes a "
        "coupled posture lose contact.",
        (
            Step(
                "delay0",
                "No sensing delay",
                "W_j at μ = 1 with the F/T reading's delay set to 0 periods (an ideal, instantaneous loop). "
                f"**Plot:** the force error on S2, S4, S6 and the headroom h: {MARGIN_WARNING} "
                f"**3D view:** {CONTACT_3D}",
                polish_setup("j", delay="zero"),
                polish_done,
                strokes_claim("W_j, μ = 1, no sensing delay"),
                POLISH_PLOTS,
            ),
            Step(
                "delay1",
                "The default delay",
                "The same with the reading's default delay back. **Plot:** the stretching strokes against the "
                f"step before, {COMPARED}, and the headroom h. **3D view:** {CONTACT_3D}",
                polish_setup("j"),
                polish_done,
                compare_strokes("W_j, μ = 1, default sensing delay", "delay0", "no delay"),
                POLISH_PLOTS,
            ),
        ),
    ),
    Lesson(
        "dampers",
        "Dampers at the joint limit",
        "Joint 4 falls into its limit under an unknown 1.25 kg; the [C24] damper's λ and the motors' delay "
        "decide how it stops.",
        (
            Step(
                "l100",
                "λ = 100, ideal motors",
                "The limit drop with the default damper; the step plays it. **Plot:** joint 4's phase plot, "
                "zoomed on the limit: q̇₄ brakes as q₄ reaches d_s (dotted) before the limit (solid). "
                f"**3D view:** {FALL_3D}",
                drop_setup(100.0, 0.0),
                after("limit-drop", DROP_WATCH_S),
                drop_claim(),
                ("phase", "torque"),
            ),
            Step(
                "l500",
                "λ = 500, ideal motors",
                "A five times stiffer damper: the joint brakes later and harder. **Plot:** τ₄'s peak in the torque "
                f"plot (% of its limit). **3D view:** {FALL_3D}",
                drop_setup(HIGH_LAMBDA, 0.0),
                after("limit-drop", DROP_WATCH_S),
                drop_claim(baseline="l100"),
                ("torque", "phase"),
            ),
            Step(
                "l500d",
                "λ = 500 with 5 ms of torque delay",
                "The motors now answer 5 ms late, as a real arm's drivers do; the step runs about 15 s. "
                "**Plot:** the torque plot: every joint's torque, not only τ₄. **3D view:** the whole arm, not "
                "only joint 4.",
                drop_setup(HIGH_LAMBDA, LESSON_DELAY_MS),
                after("limit-drop", THRASH_WATCH_S),
                thrash_claim,
                ("torque", "phase"),
            ),
            Step(
                "l100d",
                "λ = 100 with the same delay",
                "The default damper with the same 5 ms delay: does λ = 100 tolerate it? **Plot:** joint 4's phase "
                "plot: does q̇₄ reverse at d_s? **3D view:** the whole arm: does it stay calm?",
                drop_setup(100.0, LESSON_DELAY_MS),
                after("limit-drop", DROP_WATCH_S),
                drop_claim(delayed_stiff="l500d"),
                ("phase", "torque"),
            ),
        ),
    ),
    Lesson(
        "compliance",
        "Compliance under a push",
        "One pose task and one posture task; only Γ changes. 5 N pushes the TCP at 0.5 s and the elbow at 2 s ([C9]).",
        tuple(
            Step(
                f"gamma-{mode}",
                title,
                f"Case {mode}: {what} **Plot:** the deflection plot, TCP (blue) and elbow (green), at the push on "
                "the TCP (0.5 s) and on the elbow (2 s). **3D view:** which of the tool and the elbow gives way "
                "under each push.",
                compliance_setup(mode),
                after("compliance", PUSH_DONE_S),
                push_claim(title),
                ("deflection", "torque"),
            )
            for mode, title, what in (
                ("stiff", "Γ = 0, stiff", "the arm resists both pushes."),
                ("nullspace", "Γ₀ = I, nullspace-compliant", "the TCP holds, the elbow may yield."),
                ("full", "Γ = I, fully compliant", "the whole arm may move with the hand."),
            )
        ),
    ),
)
