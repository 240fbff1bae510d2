"""Watch mode: a watching page's slider, button and drag change nothing in the simulation; the same
messages from a steering page do (so the refusal is the gate's, not a message the server ignores)."""

from __future__ import annotations

import time

import msgspec
import pytest
import viser
import zstandard
from websockets.sync.client import connect

from app.live.server import start_app
from app.live.ui.panels.base import KnobPanel
from app.live.watch import ROLE_HEADER, WATCHING_TITLE, is_loopback
from tests.conftest import camera_message, wait_until

pytestmark = pytest.mark.usefixtures("warm_kernels")


@pytest.fixture(scope="module")
def watched():
    """The free preset, paused, every page watching (`serve --watch-only`)."""
    a = start_app(port=0, scenario="free", running=False, watch_only=True)
    yield a
    a.stop()


def _force_handle(app):
    for panel in app.panels:
        if isinstance(panel, KnobPanel):
            for i, knob in enumerate(panel.knobs):
                if knob.field == "max_force_n":
                    return panel.handles[i]
    raise KeyError("max_force_n")


def _open_page(app, headers=None):
    """A raw viser page (websocket + first camera message); returns it and its client id."""
    before = set(app.server.get_clients())
    ws = connect(
        f"ws://127.0.0.1:{app.port}",
        subprotocols=[f"viser-v{viser.__version__}"],
        additional_headers=headers,
        open_timeout=10,
    )
    ws.send(camera_message())
    assert wait_until(lambda: len(set(app.server.get_clients()) - before) == 1)
    (client_id,) = set(app.server.get_clients()) - before
    return ws, client_id


def _steer(app, ws, force_n: float) -> None:
    """What a person does on the page: a slider moved, Play clicked, the wrist dragged 10 cm."""
    send = lambda m: ws.send(msgspec.msgpack.encode(m))  # noqa: E731
    send({"type": "GuiUpdateMessage", "uuid": _force_handle(app)._impl.uuid, "updates": {"value": force_n}})
    send({"type": "GuiUpdateMessage", "uuid": app.panels[0].run._impl.uuid, "updates": {"value": True}})
    s = app.loop.session
    mesh = app.publisher.scene.meshes[s.world.model.body(s.world.wrist_body).name]
    p0 = [float(x) for x in s.world.site_pose(s.world.tcp_site)[0]]
    for phase, end in (("start", p0), ("update", [p0[0], p0[1] + 0.1, p0[2]])):
        send(
            {
                "type": "SceneNodeDragMessage",
                "phase": phase,
                "name": mesh.name,
                "instance_index": None,
                "start_position": p0,
                "start_screen_pos": [400.0, 300.0],
                "end_position": end,
                "end_screen_pos": [420.0, 300.0],
                "button": "left",
                "modifier": None,
                "owner": "",
            }
        )


def _received(ws, seconds: float) -> list[dict]:
    """Every message a raw page received within `seconds`."""
    out: list[dict] = []
    deadline = time.monotonic() + seconds
    while (left := deadline - time.monotonic()) > 0:
        try:
            data = ws.recv(timeout=left)
        except TimeoutError:
            break
        size, packed = int.from_bytes(data[:8], "little"), int.from_bytes(data[8:16], "little")
        inner = zstandard.ZstdDecompressor().decompress(data[16 : 16 + packed], max_output_size=size)
        out.extend(msgspec.msgpack.decode(inner)["messages"])
    return out


def test_a_watching_pages_slider_button_and_drag_change_nothing_and_a_steering_pages_do(watched):
    app = watched
    assert wait_until(lambda: app.publisher.scene is not None, 30.0)
    force = app.loop.settings.values["drag"]["max_force_n"]
    target = force + 17.0
    ws, client_id = _open_page(app)
    try:
        assert app.watch_gate.is_watcher(client_id)
        _steer(app, ws, target)
        got = _received(ws, 1.5)
        status = app.loop.sync()
        assert app.loop.settings.values["drag"]["max_force_n"] == pytest.approx(force, abs=1e-12)
        assert not status.running and status.drag_client is None and not app.loop.session.drag.active
        assert app.watch_gate.refused["GuiUpdateMessage"] >= 2 and app.watch_gate.refused["SceneNodeDragMessage"] >= 2
        titles = [m["props"]["title"] for m in got if m.get("type") == "NotificationShowMessage"]
        assert WATCHING_TITLE in titles  # the page says it watches
        uuid = _force_handle(app)._impl.uuid
        reverts = [m for m in got if m.get("type") == "GuiUpdateMessage" and m.get("uuid") == uuid]
        assert reverts and reverts[-1]["updates"]["value"] == pytest.approx(force)  # the slider set back
    finally:
        ws.close()
    app.watch_gate.watch_only = False  # the same messages from a steering page change the run
    ws, client_id = _open_page(app)
    try:
        assert not app.watch_gate.is_watcher(client_id)
        _steer(app, ws, target)
        assert wait_until(lambda: app.loop.settings.values["drag"]["max_force_n"] == pytest.approx(target))
        assert wait_until(lambda: app.loop.sync().running and app.loop.sync().drag_client == client_id)
    finally:
        ws.close()
        app.watch_gate.watch_only = True
        app.panels[0].toggle_run()  # paused again for the next test
        assert wait_until(lambda: not app.loop.sync().running)


def test_a_page_the_lobby_opens_as_a_watcher_watches_on_a_steering_server(watched):
    """The role header (set by the classroom lobby, never by a browser) makes a page watch even where
    every other page steers; a page from this machine steers under `--steer-local`, one from elsewhere
    watches."""
    app = watched
    gate = app.watch_gate
    gate.watch_only = False
    try:
        force = app.loop.settings.values["drag"]["max_force_n"]
        ws, client_id = _open_page(app, headers={ROLE_HEADER: "watch"})
        try:
            assert gate.is_watcher(client_id)
            _steer(app, ws, force + 5.0)
            time.sleep(1.0)
            assert app.loop.settings.values["drag"]["max_force_n"] == pytest.approx(force, abs=1e-12)
            assert app.loop.sync().drag_client is None
        finally:
            ws.close()
    finally:
        gate.watch_only = True
    gate.steer_local = True
    try:
        assert gate.role_of({}, ("127.0.0.1", 5000)) == "steer" and gate.role_of({}, ("::1", 5000, 0, 0)) == "steer"
        assert gate.role_of({}, ("192.168.1.20", 5000)) == "watch"
        assert gate.role_of({ROLE_HEADER: "watch"}, ("127.0.0.1", 5000)) == "watch"
    finally:
        gate.steer_local = False
    assert is_loopback(("127.0.0.5", 1)) and not is_loopback(("10.0.0.1", 1)) and not is_loopback(None)
