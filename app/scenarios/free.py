"""Free drag: the TCP holds its pose, the nullspace is free; drag any link and watch the coupling."""

from __future__ import annotations

from app.scenarios import Scenario


class FreeScenario(Scenario):
    name = "free"
    title = "Free drag"
    description = (
        "The TCP holds its pose while the elbow is free to move in the nullspace. Drag any link: "
        "the coupling overlay shows how the posture changes the motion/force coupling."
    )
    default_robot = "rizon4s"
    default_executor = "joint-hold"


SCENARIO = FreeScenario()
