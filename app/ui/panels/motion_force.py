"""Motion–force panel: the [T] impedance law's gains, the force setpoint, friction, noise, sander."""

from __future__ import annotations

from typing import Any

import viser

from app.loop import SimLoop
from app.ui.panels.base import Knob, KnobPanel

INTRO = (
    "Motion axes follow the path with stiffness K_m^p and damping ratio ζ (u_m, [T11]); force axes "
    "track the setpoint F̂ with K_f^p, K_f^d, K_f^i (u_f, [T12]). Friction μ and the sander disturb "
    "the contact; sensor noise is the ε of the F/T reading."
)

FORCE_AXES = ("pz", "px", "py", "px py", "pz rz", "px py pz")


def _vec(stored: Any, n: int) -> list[float]:
    values = list(stored) if isinstance(stored, (list, tuple)) else [float(stored)] * n
    return [float(v) for v in values]


def _set_part(key: str, part: slice, n: int):
    """changes() writing one value into a slice of a vector gain."""

    def changes(value: float, stored: Any) -> dict[str, Any]:
        vec = _vec(stored, n)
        vec[part] = [value] * len(vec[part])
        return {key: tuple(vec)}

    return changes


def _axes_text(stored: Any) -> str:
    names = ("px", "py", "pz", "rx", "ry", "rz")
    return " ".join(names[int(i)] for i in stored)


def _noise_on(stored: Any) -> bool:
    return float(stored) > 0.0


def _noise_changes(on: bool, stored: Any) -> dict[str, Any]:
    # [T] §IV-A: zero-mean noise of variance 5 N² plus a 1 Hz, 2 N sinusoid; off = ideal sensor
    return {"force_noise_var": 5.0 if on else 0.0, "sine_amplitude_n": 2.0 if on else 0.0}


KNOBS: tuple[Knob, ...] = (
    Knob(
        "force_setpoint_n",
        "Force setpoint F̂ (N)",
        target="target",
        lo=0.0,
        hi=60.0,
        step=0.5,
        read=("wrench.2",),
        hint="Desired force the table exerts on the tool, +z (Table II: 20 N)",
    ),
    Knob(
        "force_axes",
        "Force axes",
        kind="dropdown",
        options=FORCE_AXES,
        show=_axes_text,
        changes=lambda v, s: {"force_axes": tuple(str(v).split())},
        read=("sub.force_axes",),
        hint="Task axes under force control [T19]; the rest are motion axes",
    ),
    Knob(
        "motion_kp",
        "K_m^p translation (N/m)",
        lo=0.0,
        hi=10000.0,
        step=50.0,
        show=lambda s: _vec(s, 6)[0],
        changes=_set_part("motion_kp", slice(0, 3), 6),
        hint="Motion stiffness along x, y, z [T11]",
    ),
    Knob(
        "motion_kp_rot",
        "K_m^p rotation (N m/rad)",
        lo=0.0,
        hi=1000.0,
        step=10.0,
        read=("gains.motion_kp",),
        show=lambda s: _vec(s, 6)[3],
        changes=_set_part("motion_kp", slice(3, 6), 6),
        hint="Motion stiffness about x, y, z [T11]",
    ),
    Knob(
        "motion_zeta",
        "ζ damping ratio",
        lo=0.0,
        hi=2.0,
        step=0.05,
        show=lambda s: _vec(s, 6)[0],
        changes=lambda v, s: {"motion_zeta": (v,) * 6},
        hint="K_m^d = 2ζ√(K_m^p A_ii) [T11]",
    ),
    Knob("force_kp", "K_f^p", lo=0.0, hi=5.0, step=0.05, hint="Proportional force gain [T12]"),
    Knob("force_kd", "K_f^d (N s/m)", lo=0.0, hi=1000.0, step=10.0, hint="Velocity damping along force axes [T12]"),
    Knob("force_ki", "K_f^i (1/s)", lo=0.0, hi=50.0, step=0.5, hint="Integral force gain [T12], clamped"),
    Knob(
        "shaping",
        "Inertia shaping Λ̂x",
        kind="checkbox",
        hint="On: partially decoupled Λ̂x [T9] in F_x [T7]; off: natural Λx (no decoupling)",
    ),
    Knob(
        "mu",
        "Friction μ",
        target="environment",
        lo=0.0,
        hi=1.5,
        step=0.05,
        read=("contact.mu",),
        hint="Coulomb friction of the table, F_t = μ F_n (0.25 or 1.0 in [T])",
    ),
    Knob(
        "force_noise_var",
        "Sensor noise",
        target="sensor",
        kind="checkbox",
        read=("ft.force_noise_var",),
        show=_noise_on,
        changes=_noise_changes,
        hint="F/T noise: variance 5 N² + 1 Hz 2 N sine, 25 Hz low-pass",
    ),
    Knob(
        "sander_enabled",
        "Sander",
        target="environment",
        kind="checkbox",
        read=("sander.enabled",),
        hint="Eccentric rotating force at 7000 RPM on the tool",
    ),
    Knob(
        "sander_amplitude_n",
        "Sander amplitude (N)",
        target="environment",
        lo=0.0,
        hi=40.0,
        step=1.0,
        read=("sander.amplitude_n",),
    ),
)


class MotionForcePanel(KnobPanel):
    """The Motion–force folder."""

    def __init__(self, server: viser.ViserServer, loop: SimLoop, order: float | None = None):
        super().__init__(server, loop, "Motion–force", INTRO, KNOBS, order=order)
