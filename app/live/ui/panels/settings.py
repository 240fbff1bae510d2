"""Settings buttons of the Scenario panel: save the overrides as a TOML download, load a TOML file
(refused entries shown one line each), restore the preset's defaults."""

from __future__ import annotations

from typing import Any

import viser

from app.core.commands import RestoreDefaults
from app.live.loop import SimLoop
from app.live.settings_io import load_settings_text, save_settings_text
from app.live.ui.panels.base import notify

FILENAME = "torquelab-settings.toml"
MAX_NOTICES = 8  # one notice per refused entry, up to this many


class SettingsButtons:
    """Save / Load / Restore defaults, built into the current GUI container."""

    def __init__(self, server: viser.ViserServer, loop: SimLoop):
        self.server, self.loop = server, loop
        gui = server.gui
        self.save_button = gui.add_button(
            "Save settings", icon=viser.Icon.DOWNLOAD, hint="Download the values you changed as a TOML file"
        )
        self.load_button = gui.add_upload_button(
            "Load settings", icon=viser.Icon.UPLOAD, mime_type=".toml", hint="Apply a TOML settings file"
        )
        self.restore_button = gui.add_button(
            "Restore defaults", icon=viser.Icon.ARROW_BACK_UP, hint="Every parameter back to the preset's defaults"
        )
        self.save_button.on_click(self._on_save)
        self.load_button.on_upload(self._on_load)
        self.restore_button.on_click(lambda e: self.restore(e.client_id))

    def _on_save(self, event: viser.GuiEvent) -> None:
        self.save(event.client)

    def _on_load(self, event: viser.GuiEvent) -> None:
        self.load(event.client_id, event.target.value.content)

    def save(self, client: Any) -> str:
        """Send the running session's overrides to `client` as a TOML download; returns the text."""
        text = save_settings_text(self.loop)
        if client is not None:
            client.send_file_download(FILENAME, text.encode("utf-8"), save_immediately=True)
        return text

    def load(self, client_id: int | None, content: bytes) -> list[str]:
        """Apply an uploaded settings file; refused entries (one line each) go to the client as a notice."""
        try:
            text = content.decode("utf-8")
        except UnicodeDecodeError:
            refused = ["not a TOML settings file: not UTF-8 text"]
        else:
            refused = load_settings_text(self.loop, text)
        for i, line in enumerate(refused[:MAX_NOTICES]):
            notify(self.server, client_id, f"Settings: refused {i + 1}/{len(refused)}", line)
        if len(refused) > MAX_NOTICES:
            notify(self.server, client_id, "Settings", f"{len(refused) - MAX_NOTICES} more refused entries")
        if not refused:
            notify(self.server, client_id, "Settings loaded", "every entry applied", error=False)
        return refused

    def restore(self, client_id: int | None) -> None:
        """Every parameter back to the preset's defaults (the run restarts)."""
        self.loop.submit(RestoreDefaults(client_id=client_id))
