"""Compliance panel: Γ of the task and Γ₀ of the posture, the τ̂_e source and its feedback."""

from __future__ import annotations

from typing import Any

import numpy as np
import viser

from app.loop import SimLoop
from app.ui.panels.base import Knob, KnobPanel

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
SOURCES = ("none", "residual", "fusion", "oracle")


def _diag(stored: Any, n: int) -> np.ndarray:
    """Diagonal of a compliance given as a scalar, n values or an n×n matrix."""
    arr = np.asarray(stored, dtype=float)
    if arr.ndim == 0:
        return np.full(n, float(arr))
    if arr.ndim == 1:
        return arr.copy()
    return np.diag(arr).copy()


def _scalar(n: int):
    def show(stored: Any) -> float:
        return float(np.mean(_diag(stored, n)))

    return show


def _joint(i: int):
    def show(stored: Any) -> float:
        return float(_diag(stored, N_JOINTS)[i])

    def changes(value: float, stored: Any) -> dict[str, Any]:
        d = _diag(stored if stored is not None else 0.0, N_JOINTS)
        d[i] = value
        return {"posture_compliance": tuple(float(x) for x in d)}

    return show, changes


def _joint_knob(i: int) -> Knob:
    show, changes = _joint(i)
    return Knob(
        "posture_compliance",
        f"Γ₀ joint {i + 1}",
        lo=0.0,
        hi=1.2,
        step=0.05,
        read=("posture.gains.compliance",),
        show=show,
        changes=changes,
    )


KNOBS: tuple[Knob, ...] = (
    Knob(
        "task_compliance",
        "Γ task",
        lo=0.0,
        hi=1.2,
        step=0.05,
        read=("tasks.0.gains.compliance",),
        show=_scalar(6),
        hint="Compliance of the TCP pose task [C9], same on all six axes",
    ),
    Knob(
        "posture_compliance",
        "Γ₀ posture",
        lo=0.0,
        hi=1.2,
        step=0.05,
        read=("posture.gains.compliance",),
        show=_scalar(N_JOINTS),
        hint="Compliance of the posture (nullspace) task [C9], all joints",
    ),
    Knob(
        "source",
        "τ̂_e source",
        kind="dropdown",
        options=SOURCES,
        read=("estimator.gains.source",),
        hint="External-torque estimate: none, momentum observer [C25], fusion with F/T [C26], sim truth",
    ),
    Knob(
        "feedback",
        "External-force feedback",
        kind="checkbox",
        read=("settings.feedback",),
        hint="Keep τ̂_e in the inverse dynamics [C8] and the torque limits [C10]",
    ),
)

JOINT_KNOBS: tuple[Knob, ...] = tuple(_joint_knob(i) for i in range(N_JOINTS))


class CompliancePanel(KnobPanel):
    """The Compliance folder with per-joint Γ₀ in an advanced fold."""

    def __init__(self, server: viser.ViserServer, loop: SimLoop, order: float | None = None):
        super().__init__(server, loop, "Compliance", INTRO, KNOBS, order=order)

    def build_extra_bottom(self) -> None:
        """The read-only Γ_x line and the per-joint Γ₀ fold."""
        self.gamma_x_help = self.server.gui.add_markdown(GAMMA_X_HELP)
        self.gamma_x = self.server.gui.add_markdown(GAMMA_X_OFF)
        base = len(self.knobs)
        with self.server.gui.add_folder("Per-joint Γ₀", expand_by_default=False):
            for j, knob in enumerate(JOINT_KNOBS):
                self.knobs.append(knob)
                self.handles[base + j] = self._add(knob)

    def live(self, frame: Any) -> None:
        """Γ_x of the running projection executor: real eigenvalues of its symmetric part, skew size."""
        scene = getattr(frame, "scene", None)
        eigs = getattr(scene, "gamma_x_sym_eigs", None)
        skew = getattr(scene, "gamma_x_skew", None)
        text = GAMMA_X_OFF if eigs is None or skew is None else gamma_x_text(eigs, skew)
        if self.gamma_x.content != text:
            self.gamma_x.content = text


def gamma_x_text(eigs: np.ndarray, skew: float) -> str:
    """The Γ_x line: symmetric-part eigenvalues (min…max, all six) and ‖skew‖."""
    e = np.sort(np.asarray(eigs, dtype=float))
    listed = ", ".join(f"{x:.2f}" for x in e)
    verdict = "a compliance (0…1)" if e[0] >= -1e-9 and e[-1] <= 1 + 1e-9 and skew < 1e-9 else "not a [C] compliance"
    return f"**Γ_x = Λ̂x⁻¹Λx:** sym. eigenvalues {e[0]:.2f} … {e[-1]:.2f} ({listed}) · ‖skew‖ = {skew:.2f} — {verdict}"
