"""Safety panel: joint-limit dampers (proposed [C24] / classic [C17–19]), velocity and torque limits."""

from __future__ import annotations

import viser

from app.live.loop import SimLoop
from app.live.ui.panels.base import KnobPanel

SUMMARY = "[C17–24] Joint-limit dampers, velocity and torque limits."
INTRO = (
    "Near a joint limit the damper bounds the acceleration: proposed ë_p = −λė − λ²/(4M²)(e − d_s) "
    "[C24] or classic δt form [C17–19]; it acts inside d_i and stops at d_s. Torque limits add [C10]. "
    "For the projection executor the nullspace QP uses first-order dampers with d_i, d_s in rad. "
    "The simulated actuator latency (Torque delay) is in the Latency folder."
)

FIELDS: tuple[str, ...] = (
    "damper.form",
    "damper.lambda_",
    "damper.M",
    "damper.influence_fraction",
    "damper.safety_fraction",
    "nullspace.damper_influence",
    "nullspace.damper_safety",
    "damper.velocity_scale",
    "nullspace.velocity_scale",
    "compliance_qp.torque_limits",
    "solver.qp_backend",
)


class SafetyPanel(KnobPanel):
    """The Safety folder."""

    def __init__(self, server: viser.ViserServer, loop: SimLoop, order: float | None = None):
        super().__init__(server, loop, "Safety", INTRO, FIELDS, order=order, summary=SUMMARY)
