"""The page while the kernels compile: what is happening, a progress bar and the line
`app.live.warm_workers.progress_text` writes (which kernel of how many, the time left).

`serve` shows it on the server it starts at once, before the warm-up; `remove()` takes it away when
the lab is built on the same server, and the arm starts by itself.
"""

from __future__ import annotations

from typing import Any

from app.live.warm_workers import WarmProgress, progress_text

TITLE = "torquelab is getting ready"
INTRO = (
    "The controllers' kernels are being compiled (the first start after an install or an update: "
    "about half a minute on two free cores) or loaded (seconds). The arm starts by itself when they are ready."
)


class WarmupPage:
    """The warm-up's panel on a viser server (built in the constructor)."""

    def __init__(self, server: Any):
        self.title = server.gui.add_markdown(f"### {TITLE}\n\n{INTRO}")
        self.bar = server.gui.add_progress_bar(0.0, animated=True)
        self.line = server.gui.add_markdown("starting the compiler processes …")
        self.last = ""

    def show(self, progress: WarmProgress) -> None:
        """Show one progress report (a line that did not change is not sent again)."""
        self.bar.value = round(100.0 * progress.fraction, 1)
        line = progress_text(progress)
        if line != self.last:
            self.line.content = line
            self.last = line

    def remove(self) -> None:
        """Take the panel away."""
        for handle in (self.title, self.bar, self.line):
            handle.remove()
