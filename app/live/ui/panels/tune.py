"""The Tune tab's order: the folders of the running preset's experiment first.

Each preset is about one part of a controller and names the folders of that part
(`Scenario.tune_first`: e.g. the [T] motion–force law and the nullspace, or the [C] dampers), so
the Tune tab puts those folders on top when the preset changes and the rest below in their usual
order. Only the folders' `order` changes; nothing is rebuilt.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from app.scenarios import SCENARIOS, get_scenario


def tune_order(scenario: str, titles: Sequence[str]) -> list[str]:
    """The folder titles in the order the Tune tab shows them for `scenario`: its own first (in the
    order its `Scenario.tune_first` gives), then the others in their usual order."""
    own = get_scenario(scenario).tune_first if scenario in SCENARIOS else ()
    first = [t for t in own if t in titles]
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
