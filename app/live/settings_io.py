"""Settings files over a running loop: the running session's overrides as TOML, and a TOML text applied."""

from __future__ import annotations

from app.core.params import save_settings, settings_commands
from app.live.loop import SimLoop

__all__ = ["apply_settings_text", "load_settings_text", "save_settings_text"]


def save_settings_text(loop: SimLoop, timeout: float = 60.0) -> str:
    """The running session's parameter overrides as TOML (for the page's "save settings")."""
    return loop.call(save_settings, timeout)


def load_settings_text(loop: SimLoop, text: str, timeout: float = 60.0) -> list[str]:
    """Apply a TOML settings text to the running session through the loop (each value validated by
    its group, remembered like any change); returns one line per refused entry."""
    return apply_settings_text(loop, text, timeout)[1]


def apply_settings_text(loop: SimLoop, text: str, timeout: float = 60.0) -> tuple[int, list[str]]:
    """`load_settings_text`, with the number of entries applied: (applied, one line per refused entry)."""
    commands, refused = loop.call(lambda s: settings_commands(s.params(), text), timeout)
    for cmd in commands:
        loop.submit(cmd)
    loop.sync(timeout)
    return len(commands), refused
