"""Settings files: a TOML text checked against a preset's defaults before anything starts, and over a
running loop the session's overrides as TOML and a TOML text applied."""

from __future__ import annotations

from app.core.params import save_settings, settings_commands
from app.core.session import Session
from app.live.loop import SimLoop

__all__ = ["check_settings_text", "load_settings_text", "save_settings_text"]


def check_settings_text(scenario: str, robot: str | None, text: str) -> tuple[int, list[str]]:
    """(entries applied, one line per refused entry) of a TOML settings text on a fresh session of
    `scenario` on `robot` (its default parameters): what the app would apply at start, told before it starts."""
    commands, refused = settings_commands(Session(scenario, robot=robot).params(), text)
    return len(commands), refused


def save_settings_text(loop: SimLoop, timeout: float = 60.0) -> str:
    """The running session's parameter overrides as TOML (for the page's "save settings")."""
    return loop.call(save_settings, timeout)


def load_settings_text(loop: SimLoop, text: str, timeout: float = 60.0) -> list[str]:
    """Apply a TOML settings text to the running session (each value validated by its group, remembered
    like any change); returns one line per refused entry. The text is parsed and checked here, on the
    caller's thread, against the parameters in force (the loop's published `Settings`, taken once every
    command queued before has applied): the loop thread receives only the ready `SetParam` commands, one
    per accepted entry, each validated again when it applies (a megabyte of TOML parsed on the loop
    thread stopped the 1 kHz loop for over a second)."""
    loop.sync(timeout)  # the parameters in force include every change queued before this load
    commands, refused = settings_commands(loop.settings.groups, text)
    for cmd in commands:
        loop.submit(cmd)
    loop.sync(timeout)
    return refused
