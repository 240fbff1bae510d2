"""Keyboard shortcuts (viser's command palette, Ctrl/Cmd+K, lists them too).

Space plays or pauses, → steps 1 ms and Shift+→ 10 ms, R resets, F frames the robot. They send the
same commands as the buttons; nothing here touches the session.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import viser

from app.core.commands import StepOnce
from app.live.loop import SimLoop


def add_hotkeys(
    server: viser.ViserServer,
    loop: SimLoop,
    toggle_run: Callable[[], None],
    reset: Callable[[], None],
    frame_view: Callable[[viser.ClientHandle | None], Any],
) -> dict[str, viser.CommandHandle]:
    """Register the shortcuts; returns their handles by name (tests trigger them through the page)."""
    gui = server.gui
    handles = {
        "play_pause": gui.add_command(
            "Play / pause", description="Run or hold the simulation", hotkey="space", icon=viser.Icon.PLAYER_PLAY
        ),
        "step_1ms": gui.add_command("Step 1 ms", description="One control step", hotkey="arrowright"),
        "step_10ms": gui.add_command(
            "Step 10 ms", description="Ten control steps", hotkey="arrowright", modifier="shift"
        ),
        "reset": gui.add_command("Reset", description="Start the preset again", hotkey="R", icon=viser.Icon.REFRESH),
        "frame": gui.add_command(
            "Frame the robot", description="Point the camera at the arm", hotkey="F", icon=viser.Icon.FOCUS_CENTERED
        ),
    }
    handles["play_pause"].on_trigger(lambda _: toggle_run())
    handles["step_1ms"].on_trigger(lambda _: loop.submit(StepOnce(1)))
    handles["step_10ms"].on_trigger(lambda _: loop.submit(StepOnce(10)))
    handles["reset"].on_trigger(lambda _: reset())
    handles["frame"].on_trigger(lambda event: frame_view(event.client))
    return handles
