"""More gains: every other scalar setting the running executor accepts, found from its gains
dataclasses, so a new field appears here without GUI code. Values are checked by the executor."""

from __future__ import annotations

from typing import Any

import viser

from app.loop import Settings, SimLoop
from app.ui.panels.base import Knob, KnobPanel

INTRO = "Every other number or switch of the running controller (names as in its gains dataclass)."
LIMIT = 1e9


class MoreGainsPanel(KnobPanel):
    """A fold of inputs built on demand from the executor's configurable scalars."""

    hide_missing = True

    def __init__(self, server: viser.ViserServer, loop: SimLoop, claimed: set[str], order: float | None = None):
        self.claimed = set(claimed)
        self._by_key: dict[str, int] = {}
        super().__init__(server, loop, "More gains", INTRO, (), order=order, expand=False)

    def _ensure(self, key: str, value: Any) -> None:
        if key in self._by_key:
            return
        if isinstance(value, bool):
            knob = Knob(key, key, kind="checkbox")
        else:
            knob = Knob(key, key, kind="number", lo=-LIMIT, hi=LIMIT, step=1e-3)
        with self.folder:
            handle = self._add(knob)
        self.knobs.append(knob)
        self.handles[len(self.knobs) - 1] = handle
        self._by_key[key] = len(self.knobs) - 1

    def refresh(self, settings: Settings) -> None:
        """Add inputs for new scalars, hide those the executor lacks, show the values in force."""
        values = settings.values.get("executor", {})
        keys = [k for k in settings.values.get("meta", {}).get("executor_scalars", ()) if k not in self.claimed]
        for key in keys:
            if key in values:
                self._ensure(key, values[key])
        shown = set(keys)
        for key, i in self._by_key.items():
            handle = self.handles[i]
            if handle.visible != (key in shown):
                handle.visible = key in shown
        super().refresh(Settings(settings.version, {"executor": {k: values[k] for k in shown if k in values}}))
