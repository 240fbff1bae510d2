"""Record/Export panel: download the last N seconds of logged signals, take a screenshot."""

from __future__ import annotations

import time

import viser

from app.core.export import MAX_EXPORT_S, to_csv, to_json
from app.live.loop import SimLoop
from app.live.ui.panels.base import notify, number_in_range

INTRO = (
    "The app logs every 1 ms step (q, q̇, τ, F/T reading, desired force and the controller's signals) "
    "for the last minute. Download the last N seconds as CSV or JSON; the screenshot saves the 3D view."
)


class RecordPanel:
    """The Record/Export folder."""

    def __init__(self, server: viser.ViserServer, loop: SimLoop, order: float | None = None):
        self.server = server
        self.loop = loop
        gui = server.gui
        with gui.add_folder("Record/Export", order=order, expand_by_default=True):
            gui.add_markdown(INTRO)
            self.seconds = gui.add_number("Seconds", 10.0, min=0.1, max=MAX_EXPORT_S, step=0.5)
            self.csv = gui.add_button("Download CSV", icon=viser.Icon.DOWNLOAD)
            self.json = gui.add_button("Download JSON", icon=viser.Icon.DOWNLOAD)
            self.shot = gui.add_button("Screenshot", icon=viser.Icon.CAMERA)
        self.csv.on_click(lambda e: self._download(e, "csv"))
        self.json.on_click(lambda e: self._download(e, "json"))
        self.shot.on_click(self._screenshot)

    def _download(self, event: viser.GuiEvent, kind: str) -> None:
        client = event.client
        if client is None:
            return
        try:
            seconds = number_in_range("Seconds", self.seconds.value, 0.001, MAX_EXPORT_S)
        except ValueError as exc:
            notify(self.server, event.client_id, "Value refused", str(exc))
            return
        export = self.loop.export(seconds)
        stamp = time.strftime("%Y%m%d-%H%M%S")
        name = f"torquelab-{export['scenario']}-{stamp}.{kind}"
        content = to_csv(export["columns"]) if kind == "csv" else to_json(export)
        client.send_file_download(name, content, save_immediately=True)

    def _screenshot(self, event: viser.GuiEvent) -> None:
        client = event.client
        if client is None:
            return
        try:
            import imageio.v3 as iio  # viser depends on imageio

            height = int(getattr(client.camera, "image_height", 0) or 720)
            width = int(getattr(client.camera, "image_width", 0) or 1280)
            image = client.get_render(height=height, width=width, transport_format="png")
            png = iio.imwrite("<bytes>", image, extension=".png")
        except Exception as exc:  # the browser may not answer (closed tab, no WebGL)
            notify(self.server, event.client_id, "Screenshot failed", str(exc))
            return
        client.send_file_download(f"torquelab-{time.strftime('%Y%m%d-%H%M%S')}.png", png, save_immediately=True)
