"""What the app relies on of viser's private API (`app.live.ui.viser_seam`) holds on the installed viser.

Each test names one thing the seam reads or writes past viser's public handles and checks it on a
real server, so that an upgrade that renames or reshapes it fails here by name. The queued node
writes are held equal to viser's own setters in `tests/test_node_writes.py`.
"""

from __future__ import annotations

import asyncio
import sys
import warnings
from importlib import metadata
from pathlib import Path

import numpy as np
import pytest
import viser
from packaging.requirements import Requirement
from packaging.version import Version

from app.live.ui.viser_seam import (
    FRAMED_RECONNECT_JS,
    VISER_RANGE,
    GuiUpdateMessage,
    client_page_bytes,
    connection_state,
    framed_client_page_bytes,
    gui_update_handlers,
    input_by_uuid,
    input_state,
    input_uuid,
    node_state,
    on_connection_close,
    on_connection_open,
    opening_request,
    queue_orientation,
    queue_position,
    queue_to_connection,
    wrap_dispatch,
)

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[1]


def test_the_pinned_range_is_the_seams_and_the_installed_viser_is_inside_it():
    deps = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["dependencies"]
    (viser_dep,) = [Requirement(d) for d in deps if Requirement(d).name == "viser"]
    assert str(viser_dep.specifier) == str(Requirement("viser" + VISER_RANGE).specifier)
    installed = Version(metadata.version("viser"))
    assert viser_dep.specifier.contains(installed), f"viser {installed} is outside {VISER_RANGE}"


def _dispatch(server: viser.ViserServer, message: object, client_id: int = 7) -> None:
    """Hand a message to the server as its websocket does for a client's message."""
    asyncio.run(server.scene._websock_interface._handle_incoming_message(client_id, message))


def test_gui_update_handlers_are_the_list_the_server_runs_on_a_clients_update(server):
    slider = server.gui.add_slider("seam slider", min=0.0, max=10.0, step=0.5, initial_value=1.0)
    handlers = gui_update_handlers(server)
    assert len(handlers) >= 1 and all(callable(h) for h in handlers)  # viser's own (and a guard's)
    seen: list[tuple[int, str, dict]] = []
    inner = list(handlers)

    async def recorder(client_id, message):
        seen.append((client_id, message.uuid, dict(message.updates)))
        for h in inner:
            result = h(client_id, message)
            if asyncio.iscoroutine(result):
                await result

    handlers[:] = [recorder]
    try:
        _dispatch(server, GuiUpdateMessage(input_uuid(slider), {"value": 3.5}))
    finally:
        handlers[:] = inner
    assert seen == [(7, input_uuid(slider), {"value": 3.5})]  # the message's fields: uuid, updates
    assert slider.value == pytest.approx(3.5)  # and viser's handler, run from the list, applied it
    slider.remove()


def test_an_input_is_found_by_its_uuid_and_its_state_has_what_the_checks_read(server):
    slider = server.gui.add_slider("seam state", min=-1.0, max=1.0, step=0.1, initial_value=0.2)
    dropdown = server.gui.add_dropdown("seam choice", ("a", "b"), initial_value="b")
    button = server.gui.add_button("seam button")
    for handle in (slider, dropdown, button):
        uuid = input_uuid(handle)
        assert isinstance(uuid, str) and input_by_uuid(server, uuid) is handle
    state = input_state(slider)
    assert state.value == pytest.approx(0.2) and state.props.label == "seam state"
    assert (state.props.min, state.props.max) == (-1.0, 1.0) and state.is_button is False
    assert tuple(input_state(dropdown).props.options) == ("a", "b") and input_state(button).is_button is True
    calls: list[float] = []
    slider.on_update(lambda event: calls.append(event.target.value))
    assert len(state.update_cb) == 1  # the callbacks a test runs for a browser's update
    uuid = input_uuid(slider)
    for handle in (slider, dropdown, button):
        handle.remove()
    assert input_by_uuid(server, uuid) is None
    assert input_by_uuid(server, "no such input") is None


def test_a_nodes_state_is_its_pose_and_props_and_a_removed_node_says_so(server):
    label = server.scene.add_label("/seam_label", "x", position=(0.1, 0.2, 0.3))
    state = node_state(label, "position")
    assert isinstance(state.position, np.ndarray) and state.position.tolist() == pytest.approx([0.1, 0.2, 0.3])
    assert isinstance(state.wxyz, np.ndarray) and state.wxyz.shape == (4,)
    assert state.name == label.name and state.props.text == "x"
    queue_position(state, (1.0, 2.0, 3.0))
    queue_orientation(state, (0.0, 1.0, 0.0, 0.0))
    assert label.position.tolist() == [1.0, 2.0, 3.0] and label.wxyz.tolist() == [0.0, 1.0, 0.0, 0.0]
    label.remove()
    with pytest.raises(RuntimeError, match="'wxyz' on a removed"):
        node_state(label, "wxyz")


def test_a_connection_is_seen_opening_with_its_request_its_messages_pass_the_wrappers_and_it_can_be_sent_to(server):
    """`on_connection_open` runs before the page's first message with its client id; `opening_request`
    gives the opening request's headers and peer; `wrap_dispatch` on the server and on the connection
    sees the page's messages (and a wrapper that drops one stops it); `queue_to_connection` reaches that
    page, and nothing (no warning) once it has closed; `on_connection_close` runs when it closes."""
    import time

    import msgspec
    import zstandard
    from websockets.sync.client import connect

    from tests.conftest import camera_message, wait_until

    opened: list[tuple[int, object, object]] = []
    closed: list[int] = []
    seen: list[tuple[str, int, str]] = []

    def wrapper(where: str):
        def wrap(inner):
            async def dispatch(client_id, message):
                seen.append((where, client_id, type(message).__name__))
                if not (client_id in conns and type(message).__name__ == "CommandTriggerMessage"):  # dropped
                    await inner(client_id, message)

            return dispatch

        return wrap

    conns: dict[int, object] = {}

    def on_open(conn):
        opened.append((conn.client_id, *opening_request(server, conn.client_id)))
        conns[conn.client_id] = conn
        wrap_dispatch(conn, wrapper("page"))

    wrap_dispatch(server, wrapper("server"))
    on_connection_open(server, on_open)
    on_connection_close(server, lambda conn: closed.append(conn.client_id))
    triggered: list[int] = []
    command = server.gui.add_command("seam command")
    command.on_trigger(lambda event: triggered.append(1))
    ws = connect(
        f"ws://127.0.0.1:{server.get_port()}",
        subprotocols=[f"viser-v{viser.__version__}"],
        additional_headers={"X-Seam": "yes"},
        open_timeout=10,
    )
    try:
        ws.send(camera_message())
        assert wait_until(lambda: len(opened) == 1 and ("page", opened[0][0], "ViewerCameraMessage") in seen)
        client_id, headers, peer = opened[0]
        assert headers is not None and headers.get("X-Seam") == "yes" and peer[0] == "127.0.0.1"
        assert ("server", client_id, "ViewerCameraMessage") in seen
        ws.send(msgspec.msgpack.encode({"type": "CommandTriggerMessage", "uuid": command._impl.uuid}))
        assert wait_until(lambda: ("server", client_id, "CommandTriggerMessage") in seen)
        time.sleep(0.3)
        assert triggered == []  # the wrapper dropped it
        assert queue_to_connection(conns[client_id], GuiUpdateMessage("seam-uuid", {"value": 42}))
        got: list[dict] = []
        deadline = time.monotonic() + 5.0
        while not any(m.get("uuid") == "seam-uuid" for m in got) and time.monotonic() < deadline:
            data = ws.recv(timeout=max(0.01, deadline - time.monotonic()))
            size, packed = int.from_bytes(data[:8], "little"), int.from_bytes(data[8:16], "little")
            inner = zstandard.ZstdDecompressor().decompress(data[16 : 16 + packed], max_output_size=size)
            got.extend(msgspec.msgpack.decode(inner)["messages"])
        (sent,) = [m for m in got if m.get("uuid") == "seam-uuid"]
        assert sent["type"] == "GuiUpdateMessage" and sent["updates"] == {"value": 42}
    finally:
        ws.close()
    assert wait_until(lambda: closed == [client_id])
    with warnings.catch_warnings(record=True) as caught:  # a page that left is sent nothing, and no warning
        warnings.simplefilter("always")
        assert queue_to_connection(conns[client_id], GuiUpdateMessage("seam-uuid", {"value": 43})) is False
    assert not [str(w.message) for w in caught if "closed connection" in str(w.message)]


def test_the_per_connection_receive_loop_guard_frames_replaces_is_viser_s_and_takes_what_it_passes():
    """`guard_frames` puts its consumer in place of viser's module-level `_message_consumer`, which viser's
    connection handler looks up at each connection with (websocket, handle_message, message_class)."""
    import inspect

    from viser.infra import _infra

    from app.live.ui import viser_seam

    original = viser_seam._viser_consumer
    assert inspect.iscoroutinefunction(original)
    assert list(inspect.signature(original).parameters) == ["websocket", "handle_message", "message_class"]
    assert "_message_consumer(" in inspect.getsource(_infra.WebsockServer._background_worker)
    assert _infra._message_consumer in (original, viser_seam._guarded_consumer)


def test_connection_state_counts_what_viser_keeps_for_an_open_page_and_nothing_after_it_closed(server):
    """`connection_state` reads viser's client table, per-connection states, live websockets and broadcast
    cursors: all 0 on an idle server, 1 each while one page is open (after its camera), 0 after it closed."""
    from websockets.sync.client import connect

    from tests.conftest import camera_message, wait_until

    keys = {"clients", "client_states", "live_connections", "broadcast_cursors"}
    assert connection_state(server) == dict.fromkeys(keys, 0)
    ws = connect(f"ws://127.0.0.1:{server.get_port()}", subprotocols=[f"viser-v{viser.__version__}"], open_timeout=10)
    try:
        ws.send(camera_message())
        assert wait_until(lambda: connection_state(server) == dict.fromkeys(keys, 1)), connection_state(server)
    finally:
        ws.close()
    assert wait_until(lambda: connection_state(server) == dict.fromkeys(keys, 0)), connection_state(server)


def test_the_framed_page_is_viser_s_page_with_the_reconnect_script_run_before_viser_s_own():
    """The lobby's frames get viser's page with one script put first in its head (the reconnect without
    focus: `tests/test_classroom_browser.py` holds what it does)."""
    page, framed = client_page_bytes(), framed_client_page_bytes()
    script = b"<script>" + FRAMED_RECONNECT_JS.encode() + b"</script>"
    assert framed.count(script) == 1 and framed.replace(script, b"", 1) == page
    assert framed.index(b"<script") == framed.index(script)  # before viser's own script
