"""Free drag: drag any link and watch the coupling; the executor decides what holds."""

from __future__ import annotations

from app.scenarios import Scenario


class FreeScenario(Scenario):
    name = "free"
    title = "Free drag"
    description = (
        "Drag any link: the coupling overlay shows how the posture changes the motion/force coupling. "
        "It starts with a stiff joint hold, so every joint springs back; pick Executor → projection to "
        "hold the TCP with the task-space spring of [T] and only damp the nullspace: the elbow follows a pull "
        "(and a hard pull moves the TCP too)."
    )
    default_robot = "rizon4s"
    default_executor = "joint-hold"


SCENARIO = FreeScenario()
