"""Motion–force panel: the [T] impedance law's gains, the force setpoint, friction, noise, sander."""

from __future__ import annotations

import viser

from app.live.loop import Settings, SimLoop
from app.live.ui.panels.base import KnobPanel

SUMMARY = "[T11–12] Impedance on the path (K_m^p, ζ) and force tracking (F̂, K_f^p, K_f^d, K_f^i); contact, sensor."
INTRO = (
    "Motion axes follow the path with stiffness K_m^p and damping ratio ζ (u_m, [T11]); force axes "
    "track the setpoint F̂ with K_f^p, K_f^d, K_f^i (u_f, [T12]). Friction μ and the sander disturb "
    "the contact; sensor noise is the ε of the F/T reading."
)

OTHER_EXECUTOR = "The scenario's force setpoint, contact and sensor (the [T] gains belong to the projection executor)."

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
    """The Motion–force folder: its prose belongs to the [T] executor (with the QP executor only the
    scenario's setpoint, contact and sensor knobs remain, under a line that says so)."""

    OWNER_GROUPS = ("motion_force",)

    def __init__(self, server: viser.ViserServer, loop: SimLoop, order: float | None = None):
        super().__init__(server, loop, "Motion–force", INTRO, FIELDS, order=order, summary=SUMMARY)
        with self.folder:
            self.other = server.gui.add_markdown(OTHER_EXECUTOR, order=-1.0, visible=False)

    def refresh(self, settings: Settings) -> None:
        """As every panel; the line for another executor shows when the [T] gains are absent."""
        super().refresh(settings)
        other = not self.prose_applies(settings)
        if self.other.visible != other:
            self.other.visible = other
