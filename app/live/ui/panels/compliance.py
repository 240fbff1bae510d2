"""Compliance panel: Γ of the task and Γ₀ of the posture, the τ̂_e source and its feedback."""

from __future__ import annotations

from typing import Any

import numpy as np
import viser

from app.live.loop import Settings, SimLoop
from app.live.ui.panels.base import KnobPanel, knob
from control.gains import PostureTaskGains

SUMMARY = "[C9, C25–26] How much of a push each task lets through (Γ) and where τ̂_e comes from."
INTRO = (
    "Γ scales how much of the estimated external acceleration q̈_e = M⁻¹τ̂_e each task lets through "
    "(0 stiff, 1 compliant) [C9]; τ̂_e comes from the momentum observer [C25], its fusion with the F/T "
    "sensor [C26], or the simulation (oracle). Feedback off drops τ̂_e from [C8, C10] (Fig. 4)."
)
GAMMA_X_HELP = (
    "With the [T] projection executor the task's response to a push is Γ_x = Λ̂x⁻¹Λx, written in [C]'s "
    "form but not a [C] compliance: a full, non-symmetric matrix that couples the axes, whose symmetric "
    "part can have eigenvalues below 0 or above 1."
)
GAMMA_X_OFF = "**Γ_x** (projection executor only): –"

N_JOINTS = 7
FIELDS: tuple[str, ...] = (
    "pose_task.compliance",
    "posture_task.compliance",
    "estimator.source",
    "compliance_qp.feedback",
)
JOINT_FIELDS: tuple[str, ...] = tuple(f"posture_task.compliance[{i}]" for i in range(N_JOINTS))


class CompliancePanel(KnobPanel):
    """The Compliance folder with per-joint Γ₀ in an advanced fold. Its knobs and prose belong to the
    [C] QP executor; with the [T] projection executor only the read-only Γ_x line (and its help) shows."""

    OWNER_GROUPS = ("pose_task", "posture_task", "estimator", "compliance_qp")

    def __init__(self, server: viser.ViserServer, loop: SimLoop, order: float | None = None):
        super().__init__(server, loop, "Compliance", INTRO, FIELDS, order=order, summary=SUMMARY)

    def has_content(self, settings: Settings) -> bool:
        """The Γ_x line, with the [T] projection executor."""
        return "motion_force" in settings.groups

    def refresh(self, settings: Settings) -> None:
        """As every panel; the Γ_x lines only with the projection executor."""
        super().refresh(settings)
        projection = self.has_content(settings)
        for handle in (self.gamma_x_help, self.gamma_x):
            if handle.visible != projection:
                handle.visible = projection
        group = settings.groups.get("posture_task")
        text = gamma0_text(group.compliance) if isinstance(group, PostureTaskGains) else ""
        if self.gamma0.content != text:
            self.gamma0.content = text
        if self.gamma0.visible != bool(text):
            self.gamma0.visible = bool(text)

    def build_extra_bottom(self) -> None:
        """The per-joint Γ₀ line, the read-only Γ_x line and the per-joint Γ₀ fold (each slider changes one
        element, on the loop thread)."""
        self.gamma0 = self.server.gui.add_markdown("")
        self.gamma_x = self.server.gui.add_markdown(GAMMA_X_OFF)
        with self.server.gui.add_folder("Γ_x ?", expand_by_default=False) as fold:
            self.server.gui.add_markdown(GAMMA_X_HELP)
        self.gamma_x_help = fold
        with self.server.gui.add_folder("Per-joint Γ₀", expand_by_default=False):
            for path in JOINT_FIELDS:
                self.add(knob(path))

    def live(self, frame: Any) -> None:
        """Γ_x of the running projection executor: real eigenvalues of its symmetric part, skew size."""
        scene = getattr(frame, "scene", None)
        eigs = getattr(scene, "gamma_x_sym_eigs", None)
        skew = getattr(scene, "gamma_x_skew", None)
        text = GAMMA_X_OFF if eigs is None or skew is None else gamma_x_text(eigs, skew)
        if self.gamma_x.content != text:
            self.gamma_x.content = text


def gamma0_text(value: Any) -> str:
    """The per-joint Γ₀ line: each joint's value (the Γ₀ slider above sets all of them to one value and
    shows their mean when they differ)."""
    if value is None:
        return ""
    arr = np.asarray(value, dtype=float)
    diag = np.diag(arr) if arr.ndim == 2 else np.atleast_1d(arr)
    if diag.size == 1:  # one value for every joint
        return f"**Γ₀:** {float(diag[0]):.2f} on every joint"
    same = bool(np.allclose(diag, diag[0]))
    listed = " · ".join(f"{x:.2f}" for x in diag)
    note = "" if same else " (they differ: the slider shows their mean; set each one in Per-joint Γ₀)"
    return f"**Γ₀ by joint 1…{len(diag)}:** {listed}{note}"


def gamma_x_text(eigs: np.ndarray, skew: float) -> str:
    """The Γ_x line: symmetric-part eigenvalues (min…max, all six) and ‖skew‖."""
    e = np.sort(np.asarray(eigs, dtype=float))
    listed = ", ".join(f"{x:.2f}" for x in e)
    verdict = "a compliance (0…1)" if e[0] >= -1e-9 and e[-1] <= 1 + 1e-9 and skew < 1e-9 else "not a [C] compliance"
    return f"**Γ_x = Λ̂x⁻¹Λx:** sym. eigenvalues {e[0]:.2f} … {e[-1]:.2f} ({listed}) · ‖skew‖ = {skew:.2f} — {verdict}"
