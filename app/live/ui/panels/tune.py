"""The Tune tab's order: the folders of the running preset's experiment first.

Each preset is about one part of a controller (polish: the [T] motion–force law and the nullspace;
the limit drop: the [C] dampers; the compliance and mass-drop presets: Γ and the τ̂_e source), so
the Tune tab puts those folders on top when the preset changes and the rest below in their usual
order. Only the folders' `order` changes; nothing is rebuilt.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

FIRST: dict[str, tuple[str, ...]] = {
    "polish": ("Motion–force", "Nullspace", "Latency"),
    "free": ("Nullspace", "Motion–force"),
    "limit-drop": ("Safety", "Latency", "Compliance"),
    "mass-drop": ("Compliance", "Safety"),
    "compliance": ("Compliance", "Safety"),
}


def tune_order(scenario: str, titles: Sequence[str]) -> list[str]:
    """The folder titles in the order the Tune tab shows them for `scenario`: its own first (in the
    order FIRST gives), then the others in their usual order."""
    first = [t for t in FIRST.get(scenario, ()) if t in titles]
    return first + [t for t in titles if t not in first]


class TuneOrder:
    """Reorders the Tune tab's panels (each with `.title` and `.folder`) when the preset changes;
    the publisher calls it like a panel."""

    def __init__(self, panels: Sequence[Any], base_order: float = 1.0):
        self.panels = {p.title: p for p in panels}
        self.base_order = base_order
        self.scenario: str | None = None
        self.shown: list[str] = list(self.panels)

    def refresh(self, settings: Any) -> None:
        """Nothing: the order follows the preset, not the parameters."""

    def live(self, frame: Any) -> None:
        """Reorder when the frame's preset is not the one ordered for."""
        scenario = frame.status.scenario
        if scenario == self.scenario:
            return
        self.scenario = scenario
        self.shown = tune_order(scenario, list(self.panels))
        for i, title in enumerate(self.shown):
            folder = self.panels[title].folder
            order = self.base_order + 0.1 * i
            if folder.order != order:
                folder.order = order
