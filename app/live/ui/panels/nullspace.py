"""Nullspace panel: the objective W the nullspace QP minimises, its gain k0, live W values."""

from __future__ import annotations

import time
from typing import Any

import viser

from app.core.commands import SetTwin
from app.live.loop import Frame, Settings, SimLoop
from app.live.ui.panels.base import TOUCH_HOLD_S, Knob, KnobPanel, notify
from app.live.ui.selfmotion import SelfMotionPreview
from app.scenarios.stroke_outcomes import StrokeOutcome, band_words, headroom_statement
from control.gains import TANG_OBJECTIVES, NullspaceGains

SUMMARY = "[T15–22] What the elbow does while the tool is held: the objective W and its gain k0."
INTRO = (
    "The nullspace QP moves the elbow at q̂̇ = argmin ½‖q̂̇‖² + k0 ∇Wᵀq̂̇ with J q̂̇ = 0 [T15–17]. "
    "W_j keeps the start posture [T18]; W_f, W_a, W_d = ‖P‖²_F reduce the motion/force coupling [T22]."
)

OBJECTIVES = tuple(f"W_{o}" for o in TANG_OBJECTIVES)
TWIN_OFF = "off"
TWIN_CHOICES = (TWIN_OFF, *OBJECTIVES)
K0_FIELDS = tuple(NullspaceGains.k0_field(o) for o in TANG_OBJECTIVES)
UNIT_FIELDS = ("unit_length_m", "unit_mass_kg")  # the units of W_f, W_a, W_d (`control.coupling.task_scale`)
# the objective, then the k0 of each objective (only the selected objective's k0 is shown), then the
# characteristic length and mass of the coupling objectives (shown for W_f, W_a, W_d)
FIELDS: tuple[str, ...] = (
    "nullspace.objective",
    *(f"nullspace.{k0}" for k0 in K0_FIELDS),
    *(f"nullspace.{f}" for f in UNIT_FIELDS),
)


class NullspacePanel(KnobPanel):
    """The Nullspace folder; only the selected objective's k0 slider is shown. The whole folder (its
    prose, live lines, twin arm and self-motion preview) belongs to the [T] executor's nullspace QP:
    with another executor it is hidden and the preview switched off."""

    OWNER_GROUPS = ("nullspace",)

    def __init__(self, server: viser.ViserServer, loop: SimLoop, order: float | None = None):
        super().__init__(server, loop, "Nullspace", INTRO, FIELDS, order=order, summary=SUMMARY)

    def build_extra_bottom(self) -> None:
        """The live W line, the twin arm and the self-motion preview."""
        gui = self.server.gui
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

    def wanted(self, k: Knob, settings: Settings) -> bool:
        """A k0 knob only for the objective in force."""
        group = settings.groups.get(k.group)
        if group is None:
            return False
        if k.field in K0_FIELDS and isinstance(group, NullspaceGains):
            return k.field == NullspaceGains.k0_field(group.objective)
        if k.field in UNIT_FIELDS and isinstance(group, NullspaceGains):
            return group.objective != "j"
        return True

    def refresh(self, settings: Settings) -> None:
        """Values in force; only the selected objective's k0 is visible; no nullspace QP: no preview."""
        super().refresh(settings)
        if "nullspace" not in settings.groups and self.preview.enabled.value:
            self.preview.set_enabled(False)

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

    @staticmethod
    def _recently_touched(handle: Any) -> bool:
        return time.time() - handle.update_timestamp < TOUCH_HOLD_S

    def live(self, frame: Frame) -> None:
        """W_j, W_f, W_a, W_d now; the twin's objective; the newest posture for the self-motion preview."""
        self.preview.feed(frame)
        twin = f"W_{frame.status.twin}" if frame.status.twin else TWIN_OFF
        if self.twin.value != twin and not self._recently_touched(self.twin):
            self.twin.value = twin
        has_objective = "nullspace" in frame.settings.groups
        if self.twin.disabled == has_objective:
            self.twin.disabled = not has_objective
        sig = frame.status.signals
        scene_W = getattr(frame.scene, "W", None) or {}
        singular = bool(getattr(frame.scene, "near_singular", False))
        parts = []
        for name in ("W_j", "W_f", "W_a", "W_d"):
            value = sig.get(name, scene_W.get(name))
            parts.append(w_text(name, value, singular))
        strokes = frame.plot.strokes if frame.plot is not None else ()
        text = "**Live:** " + " · ".join(parts) + _polish_lines(sig, strokes)
        if self.values.content != text:
            self.values.content = text


def w_text(name: str, value: float | None, singular: bool) -> str:
    """One entry of the live W line: W_f, W_a, W_d read "singular" near a singularity (Λx there is
    ill-conditioned and they run into the 1e8s and beyond); W_j = ½‖q − q_d‖² has no such problem."""
    if value is None or value != value:
        return f"{name} = –"
    if singular and name != "W_j":
        return f"{name}: singular"
    return f"{name} = {value:.4g}"


def _polish_lines(sig: dict, strokes: tuple[StrokeOutcome, ...] = ()) -> str:
    """Settle progress and the force-loop margin (polish preset signals), or "" elsewhere: on a stroke what
    the margin predicts for it in words (the sign of its least headroom so far with its band, no magnitude:
    `stroke_outcomes`), and for the last stroke that is over whether that came true (`strokes`)."""
    out = ""
    headroom = sig.get("margin_headroom_np")
    if headroom is not None and headroom == headroom:  # not NaN: on a stroke
        least = sig.get("margin_headroom_stroke_min_np")
        h = least if least is not None and least == least else headroom
        statement = headroom_statement(h)
        segment = sig.get("margin_headroom_segment", sig.get("segment"))  # the figures' stroke (they come later)
        on = f" on S{int(segment)}" if segment is not None and segment == segment else ""
        out += (
            f"  \n**Force-loop margin{on}:** {statement.words} (so far on this stroke; {band_words()}; "
            "it predicts whether a disturbance at the sensor's noise floor grows to F̂, lifting the tool)"
        )
    if strokes:
        last = strokes[-1]
        rate_words = last.rate_text()
        out += f"  \n**Last stroke:** {last.text()}" + (f"; {rate_words}" if rate_words else "")
    # no K_f^d margin line: it is the worst case over both stroke directions, at rest and at full speed, so it
    # read "unstable" through calm strokes beside σ's "decays"; the signal stays in the log and the reports
    rate = sig.get("margin_rate")
    if rate is not None and rate == rate:
        worst = sig.get("margin_rate_stroke_min")
        stroke = f", worst on this stroke {worst:+.1f} 1/s" if worst is not None and worst == worst else ""
        state = "decays" if rate > 0 else "grows"
        out += (
            f"  \n**Force-loop decay rate σ:** {rate:+.1f} 1/s now (the linearised loop at this posture predicts that "
            f"a disturbance {state}){stroke}"
        )
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
