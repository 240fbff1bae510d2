"""Motion–force panel: the [T] impedance law's gains, the force setpoint, friction, noise, sander."""

from __future__ import annotations

import viser

from app.loop import SimLoop
from app.ui.panels.base import KnobPanel

INTRO = (
    "Motion axes follow the path with stiffness K_m^p and damping ratio ζ (u_m, [T11]); force axes "
    "track the setpoint F̂ with K_f^p, K_f^d, K_f^i (u_f, [T12]). Friction μ and the sander disturb "
    "the contact; sensor noise is the ε of the F/T reading."
)

FIELDS: tuple[str, ...] = (
    "target.force_setpoint_n",
    "motion_force.force_axes",
    "motion_force.motion_kp[0:3]",
    "motion_force.motion_kp[3:6]",
    "motion_force.motion_zeta",
    "motion_force.force_kp",
    "motion_force.force_kd",
    "motion_force.force_ki",
    "motion_force.shaping",
    "contact.mu",
    "sensor.noise",
    "sander.enabled",
    "sander.amplitude_n",
)


class MotionForcePanel(KnobPanel):
    """The Motion–force folder."""

    def __init__(self, server: viser.ViserServer, loop: SimLoop, order: float | None = None):
        super().__init__(server, loop, "Motion–force", INTRO, FIELDS, order=order)
