"""Latency panel: where the simulated 1 kHz loop loses time (the F/T reading's age, the actuator's
delay), so a person can set the delay to 0 and watch the coupled posture's oscillation vanish."""

from __future__ import annotations

import viser

from app.live.loop import SimLoop
from app.live.ui.panels.base import KnobPanel

SUMMARY = "[T] §IV-B The loop's latency: how old the F/T reading is, how late the joints get each torque."
INTRO = (
    "A sampled controller reads, computes, then writes: a torque answers a measurement one control "
    "period after it was taken at the earliest. *F/T reading age* is that delay on the force path "
    "(default 1 period of 1 ms); *Torque delay* delays every torque on its way to the joints "
    "(default 0 ms). [T] names time delays in the force sensing as what makes the coupled posture "
    "oscillate under friction: at μ = 1 with W_j, an age of 0 is the ideal loop that no arm has."
)

FIELDS: tuple[str, ...] = (
    "sensor.reading_delay_steps",
    "world.torque_delay_ms",
)


class LatencyPanel(KnobPanel):
    """The Latency folder."""

    def __init__(self, server: viser.ViserServer, loop: SimLoop, order: float | None = None):
        super().__init__(server, loop, "Latency", INTRO, FIELDS, order=order, summary=SUMMARY)
