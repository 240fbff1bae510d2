"""Every use of viser's private API, in one place: what the app relies on beyond the `add_*` handles.

viser's public surface is the handles `add_*` returns and their properties. Three jobs of the app
need more, and each reaches past that surface only through the functions here:
- checking a client's GUI update before viser applies it (`app.live.ui.inputs`): the websocket
  interface's list of handlers for `GuiUpdateMessage` (`gui_update_handlers`), and an input's
  state by its uuid (`input_by_uuid`, `input_state`);
- the typed-number channel (`app.live.ui.typed`): an input's uuid and props (`input_uuid`,
  `input_state`, `input_by_uuid`);
- the publisher's per-frame node writes (`app.live.ui.node_writes`): a scene node's state
  (`node_state`), its position and orientation messages queued directly (`queue_position`,
  `queue_orientation`) and a property update queued the way the setters queue it
  (`queue_prop_update`);
- junk from a page (`app.live.ui.junk`): each frame a connection receives is decoded by
  `guard_frames`' consumer in place of viser's (`viser.infra._infra._message_consumer`, which let a
  frame that is no message end the connection with a logged traceback), so a malformed frame is
  handed to the app's policy and skipped, or ends the connection when the policy says so;
- watch mode (`app.live.watch`): each websocket's opening request (`opening_request`), a callback
  when one opens or closes (`on_connection_open`, `on_connection_close`), the dispatch of every
  message a page sends, server-wide and per connection (`wrap_dispatch`), and a message queued to
  one connection (`queue_to_connection`), and a connection closed by the server (`close_connection`);
- the classroom lobby: the page viser serves (`client_page_bytes`), and that page made to reconnect
  in a frame without focus (`framed_client_page_bytes`: viser's client reconnects only a focused
  document); headless clients: the first message a browser sends (`camera_message`);
- what viser keeps per connection (`connection_state`): the counts the fault suite holds at zero
  once every page has gone.

`VISER_RANGE` is the version range pinned in `pyproject.toml` (`tests/test_viser_seam.py` holds the
two equal and the installed viser inside it). The same tests check each attribute, message field
and method named here on a real server, so an upgrade that renames or reshapes one fails there,
by name, instead of breaking a page silently; `tests/test_node_writes.py` holds the queued
messages and the state equal to those of viser's own setters.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from typing import Any

import viser
import websockets.exceptions
from viser import _messages
from viser.infra import _infra

VISER_RANGE = ">=1.1.1,<1.2"  # as pinned in pyproject.toml; checked against the installed viser

GuiUpdateMessage = _messages.GuiUpdateMessage  # a client's new property values for one input: uuid, updates


def gui_update_handlers(server: viser.ViserServer) -> list[Callable[..., Any]]:
    """The list (viser's own, mutable in place) of handlers the server runs on each `GuiUpdateMessage`."""
    handlers: dict[type, list[Callable[..., Any]]] = server.scene._websock_interface._incoming_handlers
    return handlers.setdefault(GuiUpdateMessage, [])


def input_by_uuid(server: viser.ViserServer, uuid: str) -> Any | None:
    """The GUI input handle with this uuid, None when there is none or it was removed."""
    handle = server.gui._gui_input_handle_from_uuid.get(uuid, None)
    if handle is None or handle._impl.removed:
        return None
    return handle


def input_uuid(handle: Any) -> str:
    """The uuid that names a GUI input in the messages between the page and the server."""
    return str(handle._impl.uuid)


def input_state(handle: Any) -> Any:
    """A GUI input's state as viser keeps it: `value`, `props` (label, options, min, max, …),
    `is_button`, `removed` and the callbacks `update_cb`."""
    return handle._impl


def node_state(handle: viser.SceneNodeHandle, name: str) -> Any:
    """A scene node's state as viser keeps it: the `position` and `wxyz` arrays, `props` (its
    properties, arrays stored as given) and `name`; RuntimeError naming the property `name` being
    written when the node was removed."""
    impl = handle._impl
    if impl.removed:
        raise RuntimeError(f"Cannot assign to {name!r} on a removed {type(handle).__name__}.")
    return impl


def queue_position(state: Any, value: tuple[float, float, float]) -> None:
    """Store and send a node's position (`node_state`'s), as `handle.position = value` does."""
    state.position[:] = value
    state.api._queue_scene_message(_messages.SetPositionMessage(state.name, value))


def queue_orientation(state: Any, value: tuple[float, float, float, float]) -> None:
    """Store and send a node's orientation (`node_state`'s), as `handle.wxyz = value` does."""
    state.wxyz[:] = value
    state.api._queue_scene_message(_messages.SetOrientationMessage(state.name, value))


def queue_prop_update(handle: viser.SceneNodeHandle, name: str, value: Any) -> None:
    """Send a property already stored in the node's props, as viser's generic setter does after storing."""
    handle._queue_update(name, value)
    handle._on_prop_assigned(name)


# the dispatch of one incoming message: (client id, message) -> awaitable
Dispatch = Callable[[int, Any], Any]


def wrap_dispatch(target: Any, wrap: Callable[[Dispatch], Dispatch]) -> None:
    """Put `wrap(dispatch)` in front of every message `target` dispatches: `target` is a server (the
    handlers every page shares) or a connection from `on_connection_open` (that page's own: its camera,
    client-scoped inputs). A message the wrapper does not pass on reaches no handler."""
    interface = target._websock_server if isinstance(target, viser.ViserServer) else target
    interface._handle_incoming_message = wrap(interface._handle_incoming_message)  # type: ignore[method-assign,arg-type]


def on_connection_open(server: viser.ViserServer, cb: Callable[[Any], None]) -> None:
    """Run `cb(connection)` as a page's websocket opens, before any of its messages is dispatched
    (`connection.client_id` is the page's client id)."""
    server._websock_server.on_client_connect(cb)


def on_connection_close(server: viser.ViserServer, cb: Callable[[Any], None]) -> None:
    """Run `cb(connection)` when a page's websocket closes."""
    server._websock_server.on_client_disconnect(cb)


def opening_request(server: viser.ViserServer, client_id: int) -> tuple[Any, Any]:
    """(headers, peer address) of the websocket opening request of an open page; (None, None) when gone."""
    live = server._websock_server._live_connections.get(client_id)
    request = getattr(live, "request", None)
    return getattr(request, "headers", None), getattr(live, "remote_address", None)


def queue_to_connection(connection: Any, message: Any) -> bool:
    """Send a message to that one page (a connection from `on_connection_open`); False, sending nothing,
    when its connection has closed (viser would keep the message and warn that it is never delivered)."""
    if connection.get_message_buffer().done:
        return False
    connection.queue_message(message)
    return True


# a malformed frame's fate: (the connection's websocket, the error decoding it) -> keep the connection?
FrameHook = Callable[[Any, BaseException], bool]
_frame_hooks: dict[int, FrameHook] = {}  # server port -> its hook (a process may run several servers)
_viser_consumer = _infra._message_consumer
JUNK_CLOSE_CODE = 1008  # websocket close code "policy violation": the connection sent too much junk
_closing: set[asyncio.Task] = set()  # the close handshakes under way of connections dropped for junk


def frame_port(websocket: Any) -> int | None:
    """The server port a connection came in on (None when its socket is gone)."""
    address = getattr(websocket, "local_address", None)
    return int(address[1]) if address else None


async def _guarded_consumer(websocket: Any, handle_message: Callable[[Any], None], message_class: Any) -> None:
    """viser's per-connection receive loop, with each frame's decoding in an error boundary: a frame that
    is no message goes to the server's hook and is skipped, or closes the connection (JUNK_CLOSE_CODE)
    when the hook answers False."""
    hook = _frame_hooks.get(frame_port(websocket) or -1)
    if hook is None:
        await _viser_consumer(websocket, handle_message, message_class)
        return
    while True:
        raw = await websocket.recv()
        try:
            if not isinstance(raw, bytes):
                raise TypeError("a text frame (a page sends binary MessagePack frames)")
            message = message_class.deserialize(raw)
        except Exception as exc:
            if hook(websocket, exc):
                continue
            # the close handshake in a task of its own (a producer may be waiting to send), and the
            # handler ended as by a closed connection: viser tears the page down without a traceback
            closing = asyncio.get_running_loop().create_task(
                websocket.close(code=JUNK_CLOSE_CODE, reason="too many malformed messages")
            )
            _closing.add(closing)  # kept until done (the loop holds tasks weakly)
            closing.add_done_callback(_closing.discard)
            raise websockets.exceptions.ConnectionClosedOK(None, None) from None
        handle_message(message)


def guard_frames(server: viser.ViserServer, hook: FrameHook) -> None:
    """Decode every frame that comes in on `server`'s port in an error boundary, `hook` deciding a malformed
    one's fate (see `_guarded_consumer`); connections opened from now on."""
    _frame_hooks[server.get_port()] = hook
    _infra._message_consumer = _guarded_consumer


def close_connection(server: viser.ViserServer, client_id: int, reason: str) -> None:
    """Close an open page's websocket from the server side (policy violation, with `reason`); from any thread."""
    live = server._websock_server._live_connections.get(client_id)
    if live is not None:
        asyncio.run_coroutine_threadsafe(live.close(1008, reason), server.get_event_loop())


def client_page_bytes() -> bytes:
    """viser's page (one self-contained HTML file, the same every server serves): the classroom's lobby
    serves it for the seats it proxies. Its websocket opens on the page's own path."""
    from pathlib import Path

    return (Path(viser.__file__).parent / "client" / "build" / "index.html").read_bytes()


# Run first in viser's page shown in a frame of another page: viser's client opens a dropped websocket
# again only while its document has focus (so that a tab in the background leaves the server alone), and
# a frame's document has focus only after a click into it. In a frame, the page takes itself as focused.
FRAMED_RECONNECT_JS = "if (window !== window.top) { Document.prototype.hasFocus = function () { return true; }; }"


def framed_client_page_bytes() -> bytes:
    """viser's page (`client_page_bytes`) for a frame of another page (the classroom's lab and spotlight):
    shown in a frame, it opens its websocket again when the connection drops, with or without focus,
    as viser's client does in a focused tab (at once, then every second). Shown on its own, it is
    viser's page unchanged in behaviour."""
    page = client_page_bytes()
    head = b"<head>"
    if page.count(head) != 1:
        raise RuntimeError("viser's page has no single <head> to put the frame's reconnect script in")
    return page.replace(head, head + b"<script>" + FRAMED_RECONNECT_JS.encode() + b"</script>", 1)


def camera_message() -> bytes:
    """The first message a browser sends on viser's websocket (its camera, msgpack as viser's client
    encodes it): viser counts a connection as a client after it. For headless clients (the classroom
    bench, the tests)."""
    import msgspec

    return msgspec.msgpack.encode(
        {
            "type": "ViewerCameraMessage",
            "wxyz": [1.0, 0.0, 0.0, 0.0],
            "position": [1.5, 1.5, 1.0],
            "fov": 0.9,
            "near": 0.01,
            "far": 100.0,
            "image_height": 600,
            "image_width": 800,
            "look_at": [0.0, 0.0, 0.3],
            "up_direction": [0.0, 0.0, 1.0],
        }
    )


def connection_state(server: viser.ViserServer) -> dict[str, int]:
    """What viser keeps per open connection, counted: its pages ("clients", those that sent their camera),
    each connection's state and message buffer ("client_states"), its websocket ("live_connections")
    and its cursor in the broadcast buffer ("broadcast_cursors"). All zero once every connection closed."""
    websock = server._websock_server
    return {
        "clients": len(server._connected_clients),
        "client_states": len(websock._client_state_from_id),
        "live_connections": len(websock._live_connections),
        "broadcast_cursors": len(websock._broadcast_buffer.generator_cursors),
    }
