"""Nullspace panel: the objective W the nullspace QP minimises, its gain k0, live W values."""

from __future__ import annotations

import time
from typing import Any

import viser

from app.commands import Configure, SetTwin
from app.loop import Frame, SimLoop
from app.ui.panels.base import TOUCH_HOLD_S, Knob, KnobPanel, coerce, notify
from app.ui.selfmotion import SelfMotionPreview

INTRO = (
    "The nullspace QP moves the elbow at q̂̇ = argmin ½‖q̂̇‖² + k0 ∇Wᵀq̂̇ with J q̂̇ = 0 [T15–17]. "
    "W_j keeps the start posture [T18]; W_f, W_a, W_d = ‖P‖²_F reduce the motion/force coupling [T22]."
)

OBJECTIVES = ("W_j", "W_f", "W_a", "W_d")
TWIN_OFF = "off"
TWIN_CHOICES = (TWIN_OFF, *OBJECTIVES)
K0_RANGE_FACTOR = 20.0  # the k0 slider spans 0 … 20 × the objective's default k0


def _k0_defaults() -> dict[str, float]:
    """Default k0 per objective from the gains dataclass (empty if the [T] gains are absent)."""
    try:
        from control.gains import NullspaceGains
    except ImportError:
        return {}
    g = NullspaceGains()
    return {o: float(getattr(g, f"k0_{o}")) for o in "jfad" if hasattr(g, f"k0_{o}")}


def _objective_label(stored: Any) -> str:
    return f"W_{stored}"


KNOBS: tuple[Knob, ...] = (
    Knob(
        "objective",
        "Objective",
        kind="dropdown",
        options=OBJECTIVES,
        show=_objective_label,
        changes=lambda v, s: {"objective": str(v)[2:]},
        read=("nullspace.objective",),
        hint="Which W the nullspace QP minimises",
    ),
)


class NullspacePanel(KnobPanel):
    """The Nullspace folder; the k0 slider edits k0 of the selected objective."""

    def __init__(self, server: viser.ViserServer, loop: SimLoop, order: float | None = None):
        super().__init__(server, loop, "Nullspace", INTRO, KNOBS, order=order)

    def build_extra_bottom(self) -> None:
        """The k0 slider, the live W line and the self-motion preview."""
        gui = self.server.gui
        self.k0: Any = gui.add_slider("k0", 0.0, 1.0, 0.001, 0.0, hint="Gradient gain of the selected objective [T15]")
        self.k0.disabled = True
        self._k0_key = ""
        self.k0.on_update(self._on_k0)
        self.values = gui.add_markdown("")
        self.twin: Any = gui.add_dropdown(
            "Twin arm",
            TWIN_CHOICES,
            initial_value=TWIN_OFF,
            hint="Run the scenario a second time, in lockstep, with this objective (orange, translucent). "
            "Switching it on restarts the scenario; it doubles the work per step.",
        )
        self.twin.on_update(self._on_twin)
        self.preview = SelfMotionPreview(self.server)

    def _on_twin(self, event: viser.GuiEvent) -> None:
        if event.client_id is None:  # our own refresh, not a person
            return
        value = str(event.target.value)
        if value not in TWIN_CHOICES:
            notify(self.server, event.client_id, "Value refused", f"Twin arm must be one of {', '.join(TWIN_CHOICES)}")
            return
        self.loop.submit(SetTwin(None if value == TWIN_OFF else value[2:], event.client_id))

    def stop(self) -> None:
        """End the preview's worker thread."""
        self.preview.stop()

    def _on_k0(self, event: viser.GuiEvent) -> None:
        if event.client_id is None or not self._k0_key:
            return
        knob = Knob(self._k0_key, "k0", lo=0.0, hi=float(self.k0.max))
        try:
            value = coerce(knob, event.target.value)
        except ValueError as exc:
            notify(self.server, event.client_id, "Value refused", str(exc))
            return
        self.loop.submit(Configure("executor", {self._k0_key: value}, event.client_id))

    def refresh(self, settings) -> None:
        """Objective and k0 of the selected objective (range 0 … 20× its default)."""
        super().refresh(settings)
        values = settings.values.get("executor", {})
        objective = values.get("objective")
        key = f"k0_{objective}"
        present = isinstance(objective, str) and key in values
        if self.k0.disabled == present:
            self.k0.disabled = not present
        if not present:
            return
        if key != self._k0_key:
            self._k0_key = key
            default = _k0_defaults().get(objective) or abs(float(values[key])) or 1.0
            hi = K0_RANGE_FACTOR * default
            self.k0.max = hi
            self.k0.step = hi / 1000.0
            self.k0.label = f"k0 (W_{objective})"
        if self.k0.value != float(values[key]) and not self._recently_touched(self.k0):
            self.k0.value = min(float(values[key]), float(self.k0.max))

    @staticmethod
    def _recently_touched(handle: Any) -> bool:
        return time.time() - handle.update_timestamp < TOUCH_HOLD_S

    def live(self, frame: Frame) -> None:
        """W_j, W_f, W_a, W_d now; the twin's objective; the newest posture for the self-motion preview."""
        self.preview.feed(frame)
        twin = f"W_{frame.status.twin}" if frame.status.twin else TWIN_OFF
        if self.twin.value != twin and not self._recently_touched(self.twin):
            self.twin.value = twin
        has_objective = "objective" in frame.settings.values.get("executor", {})
        if self.twin.disabled == has_objective:
            self.twin.disabled = not has_objective
        sig = frame.status.signals
        scene_W = getattr(frame.scene, "W", None) or {}
        parts = []
        for name in ("W_j", "W_f", "W_a", "W_d"):
            value = sig.get(name, scene_W.get(name))
            parts.append(f"{name} = {value:.4g}" if value is not None else f"{name} = –")
        text = "**Live:** " + " · ".join(parts) + _polish_lines(sig)
        if self.values.content != text:
            self.values.content = text


def _polish_lines(sig: dict) -> str:
    """Settle progress and the force-loop margin (polish preset signals), or "" elsewhere."""
    out = ""
    margin = sig.get("margin_kd")
    if margin is not None and margin == margin:  # not NaN
        verdict = "stays on the table" if margin > 0 else "predicted to lose contact when sliding"
        out += f"  \n**Force-loop margin:** {margin:+.0f} N s/m (K_f^d − critical K_f^d; {verdict})"
    settle = sig.get("settle_s")
    if settle is not None:
        converged = sig.get("settle_converged")
        swivel = sig.get("swivel_deg", float("nan"))
        if converged is None or converged != converged:  # NaN: still settling
            out += (
                f"  \n**Settling:** {settle:.1f} s, swivel {swivel:+.0f}°, q̂̇n quiet "
                f"{sig.get('settle_quiet_s', 0.0):.1f} s, ΔW/W {sig.get('settle_dW_rel', float('nan')):.1e} per s"
            )
        else:
            state = "converged" if converged else "cap reached, not converged"
            out += f"  \n**Settle:** {state} after {settle:.1f} s; swivel now {swivel:+.0f}°"
        plan = sig.get("swivel_plan_deg")
        if plan is not None and plan == plan:
            out += f" (planned {plan:+.0f}°)"
    return out
