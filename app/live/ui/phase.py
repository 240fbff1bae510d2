"""The phase a preset is in, in words, for the status line: the preset's own `Scenario.phase_text`
over the loop's status and the frame's scene (polish: contact, settling, S1…S6, done; mass-drop:
holding, dropped; limit-drop: the drop, at rest). Presets that are over in a few seconds start
paused (`starts_paused`, the scenario's own flag).
"""

from __future__ import annotations

from typing import Any

from app.scenarios import SCENARIOS, get_scenario


def starts_paused(preset: str) -> bool:
    """True for a preset that is over in seconds (`Scenario.starts_paused`): it starts paused, and
    Reset re-arms it."""
    return preset in SCENARIOS and get_scenario(preset).starts_paused


class PhaseReader:
    """Turns frames into a one-line phase; keeps the preset's memory between frames of one preset
    (e.g. the falling joint's last position, to tell its speed)."""

    def __init__(self) -> None:
        self._preset: str | None = None
        self._memory: dict[str, Any] = {}

    def text(self, status: Any, scene: Any = None) -> str:
        """The phase of the preset now ("" when it has none)."""
        name = status.scenario
        if name not in SCENARIOS:
            return ""
        if name != self._preset:
            self._preset, self._memory = name, {}
        return get_scenario(name).phase_text(status, scene, self._memory)
