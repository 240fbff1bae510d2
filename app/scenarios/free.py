"""Free drag: drag any link and watch the coupling; the executor decides what holds."""

from __future__ import annotations

from app.scenarios import Scenario


class FreeScenario(Scenario):
    name = "free"
    title = "Free drag"
    description = (
        "Drag any link: the coupling overlay shows how the posture changes the motion/force coupling. "
        "It starts with a stiff joint hold, so every joint springs back; pick Executor → projection to "
        "hold only the TCP pose and let the elbow move in the nullspace."
    )
    default_robot = "rizon4s"
    default_executor = "joint-hold"


SCENARIO = FreeScenario()
