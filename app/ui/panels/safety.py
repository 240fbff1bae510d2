"""Safety panel: joint-limit dampers (proposed [C24] / classic [C17–19]), velocity and torque limits."""

from __future__ import annotations

import viser

from app.loop import SimLoop
from app.ui.panels.base import Knob, KnobPanel
from control.qp import BACKENDS

INTRO = (
    "Near a joint limit the damper bounds the acceleration: proposed ë_p = −λė − λ²/(4M²)(e − d_s) "
    "[C24] or classic δt form [C17–19]; it acts inside d_i and stops at d_s. Torque limits add [C10]. "
    "For the projection executor the nullspace QP uses first-order dampers with d_i, d_s in rad. "
    "Torque delay is the simulated actuator latency (0 = ideal torque source)."
)

FORMS = ("proposed", "classic")

KNOBS: tuple[Knob, ...] = (
    Knob(
        "form",
        "Damper form",
        kind="dropdown",
        options=FORMS,
        read=("damper.gains.form",),
        hint="proposed [C24] or classic [C17–19]",
    ),
    Knob(
        "lambda_",
        "λ (1/s)",
        lo=1.0,
        hi=1000.0,
        step=1.0,
        read=("damper.gains.lambda_",),
        hint="Damper gain λ [C24] (default 100)",
    ),
    Knob(
        "M",
        "M (overdamping)",
        lo=0.5,
        hi=10.0,
        step=0.1,
        read=("damper.gains.M",),
        hint="M > 1 is overdamped [C24] (default 2)",
    ),
    Knob(
        "influence_fraction",
        "d_i (fraction of range)",
        lo=0.01,
        hi=0.45,
        step=0.01,
        read=("damper.gains.influence_fraction",),
        hint="Distance where the damper starts acting",
    ),
    Knob(
        "safety_fraction",
        "d_s (fraction of range)",
        lo=0.0,
        hi=0.2,
        step=0.005,
        read=("damper.gains.safety_fraction",),
        hint="Distance kept from the limit ([C]: 1 %)",
    ),
    Knob(
        "damper_influence",
        "d_i (rad)",
        lo=0.01,
        hi=1.0,
        step=0.01,
        read=("nullspace.damper_influence",),
        hint="Nullspace QP: distance where the damper starts acting",
    ),
    Knob(
        "damper_safety",
        "d_s (rad)",
        lo=0.0,
        hi=0.5,
        step=0.005,
        read=("nullspace.damper_safety",),
        hint="Nullspace QP: distance where approach velocity reaches zero",
    ),
    Knob(
        "velocity_scale",
        "Velocity limit (%)",
        lo=5.0,
        hi=100.0,
        step=1.0,
        read=("damper.gains.velocity_scale", "nullspace.velocity_scale"),
        show=lambda s: 100.0 * float(s),
        changes=lambda v, s: {"velocity_scale": float(v) / 100.0},
        hint="Share of the joint velocity limits the controller may use",
    ),
    Knob(
        "torque_limits",
        "Torque limits",
        kind="checkbox",
        read=("settings.torque_limits",),
        hint="Torque limits on τ_d including τ̂_e as QP constraints [C10]",
    ),
    Knob(
        "qp_backend",
        "QP solver",
        kind="dropdown",
        options=BACKENDS,
        read=("qp_backend",),
        hint="dense: DAQP active set (exact, a few µs); osqp: the ADMM reference. Both executors' QPs.",
    ),
    Knob(
        "torque_delay_ms",
        "Torque delay (ms)",
        target="world",
        lo=0.0,
        hi=20.0,
        step=1.0,
        hint="Simulated actuator latency: the joints get each torque this late. A few ms make a high λ ring.",
    ),
)


class SafetyPanel(KnobPanel):
    """The Safety folder."""

    def __init__(self, server: viser.ViserServer, loop: SimLoop, order: float | None = None):
        super().__init__(server, loop, "Safety", INTRO, KNOBS, order=order)
