"""A connection that closes leaves nothing behind: what viser and the app keep per page or per junk client.

Pages (raw websockets that send their camera, as a browser does) and junk clients (malformed frames,
one flood that gets its connection dropped) connect and leave; afterwards every per-connection record
is counted, objects not time: viser's (`connection_state`, the client handles and connections alive)
and the app's (the watch gate, the junk guard, the framed pages, the input guard's notices, the
loop's drags) are back to what they were before the first one opened.
"""

from __future__ import annotations

import gc

import msgspec
import viser
from viser.infra import WebsockClientConnection
from websockets.asyncio.server import ServerConnection
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect

from app.live.ui.junk import DROP_AFTER
from app.live.ui.viser_seam import connection_state, input_uuid
from tests.conftest import camera_message, wait_until

JUNK = (
    "a text frame",
    b"\xc1\xc1 not msgpack",
    msgspec.msgpack.encode({"type": "NoSuchMessage", "x": 1}),
    msgspec.msgpack.encode({"type": "ViewerCameraMessage", "wxyz": "junk"}),
)
PER_CONNECTION = (viser.ClientHandle, WebsockClientConnection, ServerConnection)


def _alive(cls: type) -> int:
    """Instances of `cls` the collector can still reach after a full pass."""
    gc.collect()
    return sum(1 for o in gc.get_objects() if isinstance(o, cls))


def _app_state(app) -> dict[str, int]:
    """What the app keeps per connection, counted (after a full collection: cyclic garbage is not kept)."""
    gc.collect()
    return {
        "watch connections": len(app.watch_gate._connections),
        "watchers": len(app.watch_gate.watchers),
        "junk guard's recent frames": len(app.junk_guard._recent),
        "framed pages": len(app.publisher.framed_clients),
        "input notices": len(app.input_guard.notified),
        "drags": len(app.loop._drag_seen),
    }


def _open(app):
    return connect(f"ws://127.0.0.1:{app.port}", subprotocols=[f"viser-v{viser.__version__}"], open_timeout=10)


def test_pages_and_junk_clients_that_leave_leave_no_per_connection_state(app):
    """6 pages (each refused one input and grabbing the arm, then closing) and 12 junk connections
    (malformed frames of each kind; 2 of them floods the server drops): afterwards viser keeps no client,
    connection state, websocket or broadcast cursor, no client handle or connection object is alive,
    and the app's per-connection records are as before."""
    from app.core.commands import DragCommand

    viser_before, app_before = connection_state(app.server), _app_state(app)
    alive_before = {cls.__name__: _alive(cls) for cls in PER_CONNECTION}
    assert viser_before == dict.fromkeys(viser_before, 0), viser_before
    dropped = app.junk_guard.dropped
    refused = {"type": "GuiUpdateMessage", "uuid": input_uuid(app.publisher.plots.joint), "updates": {"nope": 1}}
    for _ in range(6):
        before = set(app.server.get_clients())
        ws = _open(app)
        try:
            ws.send(camera_message())
            assert wait_until(lambda b=before: set(app.server.get_clients()) - b)
            (page,) = set(app.server.get_clients()) - before
            # one refused input (a notice to this page) and a grab the loop keeps until the page goes
            ws.send(msgspec.msgpack.encode(refused))
            link = app.loop.call(lambda s: s.robot.link_names[-1])
            app.loop.submit(DragCommand("grab", page, body_name=link, point_world=(0.4, 0.0, 0.6)))
            assert wait_until(lambda p=page: p in app.loop._drag_seen and app.input_guard.notified[p] == 1)
            ws.send(JUNK[1])
        finally:
            ws.close()
        assert wait_until(lambda p=page: p not in app.server.get_clients())
    for k in range(12):
        ws = _open(app)
        flood = k % 6 == 5
        try:
            for frame in [JUNK[1]] * (DROP_AFTER + 5) if flood else JUNK:
                ws.send(frame)
        except ConnectionClosed:  # a flood's send after its drop
            pass
        finally:
            ws.close()
    assert wait_until(lambda: app.junk_guard.dropped - dropped == 2)
    assert wait_until(lambda: connection_state(app.server) == viser_before), connection_state(app.server)
    assert wait_until(lambda: _app_state(app) == app_before, 30.0), (sorted(_app_state(app).items()), app_before)
    alive_after = {cls.__name__: _alive(cls) for cls in PER_CONNECTION}
    assert alive_after == alive_before, (alive_after, alive_before)


def _tracked(cls: type) -> int:
    """Instances of `cls` the collector tracks, garbage in reference cycles included (no pass run)."""
    return sum(1 for o in gc.get_objects() if isinstance(o, cls))


def test_what_a_closed_connection_held_is_freed_soon_by_the_apps_own_collection(app):
    """viser's teardown leaves a closed connection in reference cycles (its cancelled tasks' tracebacks).
    With the collector's automatic passes off, a page and three junk clients that leave are freed by the
    app's own full pass (`CollectAfterClose`) within its delay: no websocket connection of theirs is left,
    reachable or not, and the pass found what they held."""
    from app.live.memory import COLLECT_AFTER_CLOSE_S, COLLECT_EVERY_S

    gc.collect()
    before, passes, collected = _tracked(ServerConnection), app.collector.passes, app.collector.collected
    gc.disable()
    try:
        clients = set(app.server.get_clients())
        ws = _open(app)
        ws.send(camera_message())
        assert wait_until(lambda: set(app.server.get_clients()) - clients)
        ws.close()
        for frames in (JUNK, JUNK[:2], JUNK[2:]):
            ws = _open(app)
            for frame in frames:
                ws.send(frame)
            ws.close()
        opened = _tracked(ServerConnection)
        within = COLLECT_AFTER_CLOSE_S + COLLECT_EVERY_S + 5.0
        freed = wait_until(lambda: _tracked(ServerConnection) == before, within)
        assert freed, f"{_tracked(ServerConnection) - before} closed connections held ({opened - before} at close)"
        assert app.collector.passes > passes and app.collector.collected - collected > 4 * 100
    finally:
        gc.enable()
