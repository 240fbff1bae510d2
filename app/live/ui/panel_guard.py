"""Each panel's updates in an error boundary of its own, with a visible "stopped updating" state.

The publisher refreshes every panel's inputs and live numbers each few frames. Run in one boundary, one
panel that raised skipped every panel after it (Lessons and Replay among them). A `PanelGuard` runs one
panel's `refresh` and `live` in its own stage of the publisher's `Stages` (`app.live.supervise`): a
failure is reported once per distinct error per minute, the panel is tried again with the next frame,
and the panels after it update as before. While its last update failed, the panel's folder shows one
line at its top saying it stopped updating and why; the line goes once an update works again.
"""

from __future__ import annotations

from typing import Any

from app.live.supervise import Stages

STALE_ORDER = -1000.0  # the "stopped updating" line sits above everything else in the panel's folder
_FAILED = object()


def panel_name(panel: Any) -> str:
    """The name a person sees for a panel: its folder's title, else its class name."""
    title = getattr(panel, "title", None)
    if isinstance(title, str) and title:
        return title
    folder = getattr(panel, "folder", None)
    label = getattr(folder, "label", None)
    return label if isinstance(label, str) and label else type(panel).__name__


def stale_text(error: str) -> str:
    """The line a failing panel shows at its top."""
    return f"⚠ **This panel stopped updating** ({error}); it is tried again with each frame."


class PanelGuard:
    """One panel's `refresh` and `live` inside the stage `panel <name>` of `stages`."""

    def __init__(self, panel: Any, stages: Stages, gui: Any):
        self.panel = panel
        self.stages = stages
        self.gui = gui
        self.name = panel_name(panel)
        self.stage = f"panel {self.name}"
        self.stale: Any = None  # the "stopped updating" markdown in the panel's folder (built on first failure)

    @property
    def failing(self) -> bool:
        """True while the panel's last update failed."""
        return self.stage in self.stages.failing

    def refresh(self, settings: Any) -> None:
        """The panel's `refresh(settings)` in its boundary."""
        self._run("refresh", settings)

    def live(self, frame: Any) -> None:
        """The panel's `live(frame)` in its boundary (panels without one are skipped)."""
        if hasattr(self.panel, "live"):
            self._run("live", frame)

    def _run(self, method: str, arg: Any) -> None:
        # looked up at each call: a method replaced on the panel is the one run
        result = self.stages.run(self.stage, getattr(self.panel, method), arg, default=_FAILED)
        if result is _FAILED:
            self._show_stale(self.stages.last_error.get(self.stage, "an error"))
        elif self.stale is not None and self.stale.visible:
            self.stale.visible = False

    def _show_stale(self, error: str) -> None:
        """Show the "stopped updating" line (built inside the panel's folder the first time)."""
        text = stale_text(error)
        if self.stale is None:
            folder = getattr(self.panel, "folder", None)
            if folder is None:  # a panel with nothing of its own on the page: the notice says it
                return
            with folder:
                self.stale = self.gui.add_markdown(text, order=STALE_ORDER)
            return
        if self.stale.content != text:
            self.stale.content = text
        if not self.stale.visible:
            self.stale.visible = True
