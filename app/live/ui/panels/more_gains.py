"""More gains: every other parameter of the running session, generated from the metadata of its
groups (`Session.params()`), so a new field appears here without GUI code. Values are checked by
the group's dataclass on the loop thread."""

from __future__ import annotations

import viser

from app.core.params import group_types
from app.live.loop import Settings, SimLoop
from app.live.ui.panels.base import Knob, KnobPanel, knob
from control.params import specs

INTRO = "Every other parameter of the running session, by group (range and help from its dataclass)."


class MoreGainsPanel(KnobPanel):
    """A fold of inputs built on demand for the fields no other panel shows (`claimed`: "group.field")."""

    hide_missing = True

    def __init__(self, server: viser.ViserServer, loop: SimLoop, claimed: set[str], order: float | None = None):
        self.claimed = set(claimed)
        self._paths: set[str] = set()
        super().__init__(server, loop, "More gains", INTRO, (), order=order, expand=False)

    def refresh(self, settings: Settings) -> None:
        """Add inputs for the unclaimed fields of groups in force; hide those of absent groups."""
        for group, current in settings.groups.items():
            if not group_types(group):
                continue
            for field in specs(current):
                path = f"{group}.{field}"
                if path in self.claimed or path in self._paths:
                    continue
                self._paths.add(path)
                with self.folder:
                    self.add(knob(path))
        super().refresh(settings)


def claimed_fields(*panels: tuple[str, ...]) -> set[str]:
    """The "group.field" names the given panel lists show (elements count for their field)."""
    out = set()
    for fields in panels:
        for path in fields:
            k: Knob = knob(path)
            out.add(f"{k.group}.{k.field}")
    return out
