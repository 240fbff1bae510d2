"""The Visuals panel: which overlays the 3D scene draws and how big.

`VisualSettings` is the one object the scene reads; the panel's callbacks write single fields
of it (an attribute assignment is atomic, so the publisher thread never sees a torn value).
Robot switches keep the same settings object, so the user's choices survive them.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any, Literal

import viser

CouplingKind = Literal["objective", "P_a", "P_f", "P_d"]
COUPLING_KINDS: tuple[CouplingKind, ...] = ("objective", "P_a", "P_f", "P_d")

# Tilt of the coupling ellipse per unit of P (so that typical couplings of both arms read as
# 10–40°): P_a in kg, P_f in 1/kg, P_d dimensionless ([T] Table I).
COUPLING_REFERENCE: dict[str, float] = {"P_a": 5.0, "P_f": 0.5, "P_d": 1.0}


@dataclass
class VisualSettings:
    """Toggles and scales of every overlay (lengths in m in the scene)."""

    coupling: bool = True
    coupling_kind: CouplingKind = "objective"  # "objective": the P of the nullspace objective (P_a for W_j)
    coupling_radius_m: float = 0.08  # radius of the unit motion circle at the TCP
    coupling_gain: float = 1.0  # multiplies s = 1 / COUPLING_REFERENCE[kind]
    ppt_ellipsoid: bool = True
    inertia_ellipsoid: bool = False
    inertia_m_per_kg: float = 0.01
    drag_force: bool = True
    measured_force: bool = True
    coupled_response: bool = True
    force_m_per_n: float = 0.003
    response_m_per_mps2: float = 0.05
    trail: bool = True
    trail_seconds: float = 4.0
    path: bool = True
    contact: bool = True  # contact point, normal and friction arrows, the ring at the tool, lift marks
    limit_colors: bool = True
    limit_zone_rad: float = 0.2  # d_i for controllers without a joint-limit damper of their own
    labels: bool = True

    def projection_name(self, objective: str | None) -> str:
        """ "P_f", "P_a" or "P_d": the chosen one, or the running objective's ("j", none → P_a)."""
        if self.coupling_kind != "objective":
            return self.coupling_kind
        return f"P_{objective}" if objective in ("f", "a", "d") else "P_a"

    def coupling_scale(self, objective: str | None = None) -> float:
        """s of v ↦ (v, s·P v) for the shown P (per unit of P)."""
        return self.coupling_gain / COUPLING_REFERENCE[self.projection_name(objective)]

    def update(self, **changes: Any) -> None:
        """Set fields by name; ValueError for an unknown field or a negative scale."""
        names = {f.name for f in fields(self)}
        for key, value in changes.items():
            if key not in names:
                raise ValueError(f"unknown visual setting {key!r}")
            if key == "coupling_kind" and value not in COUPLING_KINDS:
                raise ValueError(f"coupling_kind must be one of {', '.join(COUPLING_KINDS)}")
            if isinstance(value, float) and not value >= 0.0:
                raise ValueError(f"{key} must be a non-negative number")
            setattr(self, key, value)


# Every object the 3D view can draw, in words (the objects without a label of their own are named here).
LEGEND = (
    "- **Green disc / outline** (label W = …): the coupling ellipse, drawn beside the tool; with no "
    "force axis (a free pose) there is nothing to lift and it is hidden.\n"
    "- **Purple ellipsoid**: P Pᵀ in the force subspace [T21]. **Blue ellipsoid**: the task inertia Λx.\n"
    "- **Orange arrow and line**: your drag's spring force and the grabbed point; **magenta arrow**: the "
    "F/T reading; **red arrow**: the coupled response P_f·F_m.\n"
    "- **Contact** (polish): a **black dot** at the contact point, a **teal arrow** (the table's normal force) "
    "and a **yellow arrow** (friction) from it, at the force scale (0.003 m/N: the 20 N setpoint is 6 cm); "
    "a **green ring** on the table around the tool while it touches, **red** while contact is lost (and 0.5 s "
    "after), and a **red cross** (label *contact lost*) left on the table where it lifted, each time.\n"
    "- **Blue line**: the tool's trail; **grey line**: the commanded path; **small grey ball** (label *task "
    "target*): where the controller wants the tool now.\n"
    "- **Dark ball** (label: its mass): a payload hanging from the tool (mass-drop, limit-drop).\n"
    "- **Translucent blue arm**: the self-motion preview's ghost (hidden while it stands within a few "
    "degrees of the arm). **Red links**: a joint inside its damper zone d_i."
)


class VisualsPanel:
    """GUI folder with one control per overlay; each control's hint says what it shows."""

    def __init__(self, gui: viser.GuiApi, settings: VisualSettings, order: float | None = None):
        self.settings = settings
        self.folder = gui.add_folder("Visuals", order=order, expand_by_default=True)
        with self.folder:
            gui.add_markdown(
                "Overlays at the tool: the **coupling ellipse** is the unit motion circle lifted by "
                "s·P into the force direction — flat means decoupled ([T] Table I, eq. 21)."
            )
            with gui.add_folder("What the scene shows", expand_by_default=False):
                gui.add_markdown(LEGEND)
            self.handles: dict[str, Any] = {}
            self._check(gui, "coupling", "Coupling ellipse", "Image of the unit motion sphere under v ↦ (v, s·P v).")
            self._dropdown(gui)
            self._slider(gui, "coupling_radius_m", "Ellipse size (m)", 0.02, 0.4, 0.01, "Radius of the unit circle.")
            self._slider(gui, "coupling_gain", "Tilt gain", 0.0, 5.0, 0.1, "Multiplies s; 1 = 45° at the reference P.")
            self._check(gui, "ppt_ellipsoid", "P Pᵀ ellipsoid", "Eq. 21 in the force subspace (≥ 2 force axes).")
            self._check(gui, "inertia_ellipsoid", "Task inertia", "Translational Λx: principal masses as axes.")
            self._slider(gui, "inertia_m_per_kg", "Inertia scale (m/kg)", 0.001, 0.05, 0.001, "Axis length per kg.")
            self._check(gui, "drag_force", "Drag force", "Arrow of the spring force at the grabbed point.")
            self._check(gui, "measured_force", "Measured force", "F/T reading at the tool (what the controller sees).")
            self._check(gui, "coupled_response", "Coupled response", "P_f·F_m: force-axis acceleration from F_m.")
            self._check(
                gui, "contact", "Contact", "Contact point, normal and friction arrows; ring red and a cross where lost."
            )
            self._slider(
                gui,
                "force_m_per_n",
                "Force scale (m/N)",
                0.001,
                0.03,
                0.001,
                "Arrow length per newton of every force arrow (drag, F/T, contact): at 0.003, 20 N is 6 cm.",
            )
            self._slider(gui, "response_m_per_mps2", "Response scale (m per m/s²)", 0.005, 0.5, 0.005, "Arrow length.")
            self._check(gui, "trail", "Tool trail", "Where the tool has been in the last seconds.")
            self._slider(gui, "trail_seconds", "Trail length (s)", 0.5, 20.0, 0.5, "Seconds of trail kept.")
            self._check(gui, "path", "Commanded path", "The task target over the next seconds.")
            self._check(gui, "limit_colors", "Joint-limit colours", "Link turns red inside the damper's d_i.")
            self._slider(
                gui, "limit_zone_rad", "Colour zone (rad)", 0.02, 0.6, 0.01, "d_i when the controller has no damper."
            )
            self._check(gui, "labels", "Labels", "W value beside the coupling ellipse, the payload's mass.")

    def _check(self, gui: viser.GuiApi, key: str, label: str, hint: str) -> None:
        handle = gui.add_checkbox(label, bool(getattr(self.settings, key)), hint=hint)

        def on_change(_event: object) -> None:
            self.settings.update(**{key: bool(handle.value)})

        handle.on_update(on_change)
        self.handles[key] = handle

    def _slider(self, gui: viser.GuiApi, key: str, label: str, lo: float, hi: float, step: float, hint: str) -> None:
        value = min(max(float(getattr(self.settings, key)), lo), hi)
        handle = gui.add_slider(label, min=lo, max=hi, step=step, initial_value=value, hint=hint)

        def on_change(_event: object) -> None:
            self._set_number(key, handle.value, lo, hi)

        handle.on_update(on_change)
        self.handles[key] = handle

    def _set_number(self, key: str, value: object, lo: float, hi: float) -> None:
        try:
            number = float(value)  # type: ignore[arg-type]
        except (TypeError, ValueError):
            return
        if number == number:  # not NaN
            self.settings.update(**{key: min(max(number, lo), hi)})

    def _dropdown(self, gui: viser.GuiApi) -> None:
        handle = gui.add_dropdown(
            "Coupling shown",
            COUPLING_KINDS,
            initial_value=self.settings.coupling_kind,
            hint="objective = the P the nullspace minimises; P_a = Bᵀ (kg), P_f = S_f Λx⁻¹ S_mᵀ (1/kg), P_d = Bᵀ A⁻¹.",
        )

        def on_change(_event: object) -> None:
            if handle.value in COUPLING_KINDS:
                self.settings.update(coupling_kind=handle.value)

        handle.on_update(on_change)
        self.handles["coupling_kind"] = handle

    def remove(self) -> None:
        """Remove the folder and its controls."""
        self.folder.remove()


def field_names() -> tuple[str, ...]:
    """Names of all visual settings (for tests and the record/export panel)."""
    return tuple(f.name for f in fields(VisualSettings))
