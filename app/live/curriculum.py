"""The lessons' curriculum: which preset, case and parameters each step sets up, and when it has run
far enough. A lesson step is a script over named presets, as a person picks them from the menu; this
module is the one place of the live app that names presets (`tests/test_scenario_contract.py`), the
machinery it uses (steps, measurements, claims) is `app.live.lessons`.
"""

from __future__ import annotations

from collections.abc import Callable

from app.core.commands import Command, Play, RestoreDefaults, SetParam, SettleNow, SwitchSession
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


def polish_setup(
    objective: str, delay: str = "default", torque_delay_ms: float | None = None
) -> Callable[[Lab | None], list[Command]]:
    """Polish from its defaults, μ = 1, the objective, the F/T delay (default / zero), the torque delay
    (None: its default), Settle now."""

    def setup(lab: Lab | None) -> list[Command]:
        cmds: list[Command] = [
            RestoreDefaults(),  # first: the switch then keeps nothing of the person's earlier values
            SwitchSession(scenario="polish", robot="", variant="flow"),
            SetParam("contact", "mu", FRICTION_MU),
            SetParam("nullspace", "objective", objective),
        ]
        found = delay_field()
        if delay == "zero" and found is not None:
            cmds.append(SetParam(found[0], found[1], 0))
        if torque_delay_ms is not None:
            cmds.append(SetParam("world", "torque_delay_ms", torque_delay_ms))
        cmds.append(SettleNow())
        return cmds

    return setup


def drop_setup(lambda_: float, delay_ms: float) -> Callable[[Lab | None], list[Command]]:
    """The limit drop from its defaults with λ and the torque delay, then Play."""

    def setup(lab: Lab | None) -> list[Command]:
        return [
            RestoreDefaults(),
            SwitchSession(scenario="limit-drop", robot="", variant="position"),
            SetParam("damper", "lambda_", lambda_),
            SetParam("world", "torque_delay_ms", delay_ms),
            Play(),
        ]

    return setup


def compliance_setup(mode: str) -> Callable[[Lab | None], list[Command]]:
    """The compliance preset in one Γ mode, from its defaults, then Play."""

    def setup(lab: Lab | None) -> list[Command]:
        return [RestoreDefaults(), SwitchSession(scenario="compliance", robot="", variant=mode), Play()]

    return setup


def polish_done(st: LoopStatus) -> bool:
    """The zig-zag has run through its last stroke (signal "segment" past the preset's `segments`)."""
    segments = get_scenario(st.scenario).segments if st.scenario in SCENARIOS else 0
    return st.scenario == "polish" and segments > 0 and st.signals.get("segment", 0.0) > segments


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
                "settle phase, then the zig-zag S1…S6. Watch the force-error plot on the stretching strokes "
                "S2, S4, S6.",
                polish_setup("j"),
                polish_done,
                strokes_claim("W_j, μ = 1"),
            ),
            Step(
                "wa",
                "W_a at μ = 1",
                "The same with the dynamic-coupling objective W_a: the elbow flows to another posture first "
                "(almost a minute of simulated time; Settle now runs it fast). Compare the stretching strokes.",
                polish_setup("a"),
                polish_done,
                compare_strokes("W_a, μ = 1", "wj", "W_j"),
            ),
            Step(
                "wa2",
                "W_a with one more period of latency",
                "W_a again, with the torque reaching the joints 1 ms (one control period) late on top of the F/T "
                "reading's one period: two periods in all, as a drive that latches each command on its next bus "
                "cycle would add. Neither paper states its loop's delays. Compare the stretching strokes with W_a's.",
                polish_setup("a", torque_delay_ms=SECOND_PERIOD_MS),
                polish_done,
                compare_strokes("W_a, μ = 1", "wa", "W_a at one period"),
            ),
        ),
    ),
    Lesson(
        "latency",
        "Latency",
        "A sampled controller answers a force reading at least one period late; that delay is what makes a "
        "coupled posture oscillate.",
        (
            Step(
                "delay0",
                "No sensing delay",
                "W_j at μ = 1 with the F/T reading's delay set to 0 periods (an ideal, instantaneous loop). "
                "Watch S2, S4, S6.",
                polish_setup("j", delay="zero"),
                polish_done,
                strokes_claim("W_j, μ = 1, no sensing delay"),
            ),
            Step(
                "delay1",
                "The default delay",
                "The same with the reading's default delay back. Compare the stretching strokes with the step before.",
                polish_setup("j"),
                polish_done,
                compare_strokes("W_j, μ = 1, default sensing delay", "delay0", "no delay"),
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
                "The limit drop with the default damper. Press Play if it waits; watch the phase plot of joint 4 "
                "reach d_s (dotted) before the limit.",
                drop_setup(100.0, 0.0),
                after("limit-drop", DROP_WATCH_S),
                drop_claim(),
            ),
            Step(
                "l500",
                "λ = 500, ideal motors",
                "A five times stiffer damper: the joint brakes later and harder. Watch the torque plot.",
                drop_setup(HIGH_LAMBDA, 0.0),
                after("limit-drop", DROP_WATCH_S),
                drop_claim(baseline="l100"),
            ),
            Step(
                "l500d",
                "λ = 500 with 5 ms of torque delay",
                "The motors now answer 5 ms late, as a real arm's drivers do. Watch the whole arm, not only "
                "joint 4, for about 15 s.",
                drop_setup(HIGH_LAMBDA, LESSON_DELAY_MS),
                after("limit-drop", THRASH_WATCH_S),
                thrash_claim,
            ),
            Step(
                "l100d",
                "λ = 100 with the same delay",
                "The default damper with the same 5 ms delay. Watch joint 4's phase plot and the whole arm: "
                "does λ = 100 tolerate the delay?",
                drop_setup(100.0, LESSON_DELAY_MS),
                after("limit-drop", DROP_WATCH_S),
                drop_claim(delayed_stiff="l500d"),
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
                f"Case {mode}: {what} Watch the deflection plot: TCP (blue) and elbow (green).",
                compliance_setup(mode),
                after("compliance", PUSH_DONE_S),
                push_claim(title),
            )
            for mode, title, what in (
                ("stiff", "Γ = 0, stiff", "the arm resists both pushes."),
                ("nullspace", "Γ₀ = I, nullspace-compliant", "the TCP holds, the elbow may yield."),
                ("full", "Γ = I, fully compliant", "the whole arm may move with the hand."),
            )
        ),
    ),
)
