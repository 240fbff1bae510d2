"""The phase a preset is in, in words, for the status line: read from the scenario's own signals.

polish: contact, settling (objective W, swivel, seconds; a planned case: the swivel and the planned
one), S1…S6, done (signals "segment",
"settle_s", "swivel_deg"); mass-drop: holding, dropped (signal "mass_released"); limit-drop: the
drop while the falling joint moves, at rest once it has stopped (its speed, from the posture of
successive frames). Presets that are over in a few seconds start paused (`starts_paused`, the
scenario's own flag).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from app.scenarios import SCENARIOS, get_scenario

POLISH_CONTACT_S = 1.0  # app.scenarios.polish.CONTACT_TIME_S: approach and 20 N press
SEGMENTS = 6
REST_SPEED_RAD_S = 0.02  # a falling joint slower than this counts as at rest


def starts_paused(preset: str) -> bool:
    """True for a preset that is over in seconds (`Scenario.starts_paused`): it starts paused, and
    Reset re-arms it."""
    return preset in SCENARIOS and get_scenario(preset).starts_paused


class PhaseReader:
    """Turns frames into a one-line phase; keeps the falling joint's last position to tell its speed."""

    def __init__(self) -> None:
        self._last_q: tuple[float, float] | None = None  # (t, q of the preset's joint)
        self._moved = False

    def text(self, status: Any, scene: Any = None) -> str:
        """The phase of the preset now ("" when it has none)."""
        sig = status.signals
        name = status.scenario
        if name == "polish":
            return _polish(status.t, sig, scene, str(getattr(status, "variant", "") or ""))
        if "mass_released" in sig:
            return "dropped: the mass hangs on the rope" if sig["mass_released"] > 0.5 else "holding the mass"
        if name == "limit-drop":
            return self._limit_drop(status, scene)
        return ""

    def _limit_drop(self, status: Any, scene: Any) -> str:
        joint = status.focus_joint
        q = getattr(scene, "q", None)
        if joint is None or q is None:
            return "drop"
        now = (float(status.t), float(q[joint]))
        last, self._last_q = self._last_q, now
        if last is None or now[0] <= last[0]:
            self._moved = False
            return f"drop: joint {joint + 1} falls" if status.t < 0.05 else "drop"
        speed = abs(now[1] - last[1]) / (now[0] - last[0])
        self._moved = self._moved or speed > REST_SPEED_RAD_S
        if speed > REST_SPEED_RAD_S or not self._moved:
            return f"drop: joint {joint + 1} falls ({speed:.2f} rad/s)"
        return f"done: joint {joint + 1} at rest"


def _polish(t: float, sig: dict[str, float], scene: Any, variant: str = "") -> str:
    segment = sig.get("segment", math.nan)
    if math.isfinite(segment) and 1 <= segment <= SEGMENTS:
        stroke = "back" if int(segment) % 2 == 1 else "forward"
        return f"S{int(segment)} ({stroke} stroke)"
    if math.isfinite(segment) and segment > SEGMENTS:
        return "done: the zig-zag is over"
    if t < POLISH_CONTACT_S:
        return "contact: pressing onto the table"
    swivel = sig.get("swivel_deg", math.nan)
    seconds = sig.get("settle_s", max(t - POLISH_CONTACT_S, 0.0))
    if variant.startswith("planned"):  # the posture follows the planned swivel path, no objective's gradient
        planned = sig.get("swivel_plan_deg", math.nan)
        parts = [f"moving to the {variant} path's start"]
        if math.isfinite(swivel):
            parts.append(f"swivel {swivel:+.0f}°" + (f" (planned {planned:+.0f}°)" if math.isfinite(planned) else ""))
        parts.append(f"{seconds:.1f} s")
        return parts[0] + ": " + ", ".join(parts[1:])
    parts = ["settling"]
    objective = getattr(scene, "objective", None)
    W = (getattr(scene, "W", None) or {}).get(f"W_{objective}", sig.get(f"W_{objective}")) if objective else None
    if W is not None and np.isfinite(W):
        parts.append(f"W_{objective} = {W:.3g}")
    if math.isfinite(swivel):
        parts.append(f"swivel {swivel:+.0f}°")
    parts.append(f"{seconds:.1f} s")
    return parts[0] + ": " + ", ".join(parts[1:])
