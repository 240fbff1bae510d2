"""Watch mode: pages that see everything and steer nothing.

A page is a *watcher* when the server runs `--watch-only` (every page, or every page from another
machine with `--steer-local`), or when its websocket opening request carries `X-Torquelab-Role: watch`
(the classroom lobby sets it on the connections it opens for the teacher's read-only view and for the
spotlight; a browser cannot set it itself, and it can only take rights away). A watcher's messages are
checked where viser receives them, before any handler: only its own camera passes; a slider, a button,
a drag, a hotkey, an upload, a form, a transform gizmo are refused and change nothing. A refused input
is set back in that page alone, and the page says it is watching in a notice that stays.

A classroom seat is given a secret (`seat_secret`): a connection whose opening request lacks it in
`X-Torquelab-Seat` (one not opened by the lobby) is closed at once and none of its messages is
dispatched.
"""

from __future__ import annotations

import hmac
import ipaddress
from collections import Counter
from collections.abc import Callable, Coroutine
from typing import Any

import viser
from viser import _messages

from app.live.supervise import ErrorBudget
from app.live.ui.viser_seam import (
    close_connection,
    input_by_uuid,
    input_state,
    on_connection_close,
    on_connection_open,
    opening_request,
    queue_to_connection,
    wrap_dispatch,
)

ROLE_HEADER = "X-Torquelab-Role"
SEAT_HEADER = "X-Torquelab-Seat"
WATCH_ROLE = "watch"
PASSES = (_messages.ViewerCameraMessage, _messages.GetRenderResponseMessage)  # a watcher's own view only
WATCHING_TITLE = "Watching"
WATCHING_BODY = "This page shows the arm live and steers nothing: its sliders, buttons and drags change nothing."

Handler = Callable[[int, Any], Coroutine[Any, Any, None]]


def is_loopback(address: Any) -> bool:
    """True if a peer address (host, port, ...) is this machine's (127.0.0.0/8 or ::1)."""
    try:
        return ipaddress.ip_address(str(address[0]).split("%")[0]).is_loopback
    except (ValueError, TypeError, IndexError):
        return False


class WatchGate:
    """Decides each page's role when its websocket opens and refuses a watcher's steering messages."""

    def __init__(
        self, server: viser.ViserServer, watch_only: bool = False, steer_local: bool = False, seat_secret: str = ""
    ):
        self.server = server
        self.seat_secret = seat_secret
        self.shut: set[int] = set()  # connections closed for lacking the seat's secret
        self.watch_only = watch_only
        self.steer_local = steer_local
        self.watchers: set[int] = set()
        self.refused: Counter[str] = Counter()  # refused messages by type
        self.budget = ErrorBudget()
        self._connections: dict[int, Any] = {}
        wrap_dispatch(server, self._gated)
        on_connection_open(server, self._opened)
        on_connection_close(server, self._closed)
        server.on_client_connect(self._say_watching)

    def role_of(self, request_headers: Any, remote_address: Any) -> str:
        """ "watch" or "steer" for a websocket opened with these headers from this peer."""
        if request_headers is not None and str(request_headers.get(ROLE_HEADER, "")).lower() == WATCH_ROLE:
            return WATCH_ROLE
        if self.watch_only and not (self.steer_local and is_loopback(remote_address)):
            return WATCH_ROLE
        return "steer"

    def is_watcher(self, client_id: int) -> bool:
        """True if the page with this client id only watches."""
        return client_id in self.watchers

    def _opened(self, conn: Any) -> None:
        headers, address = opening_request(self.server, conn.client_id)
        if self.seat_secret and not hmac.compare_digest(
            str((headers or {}).get(SEAT_HEADER, "")).encode(), self.seat_secret.encode()
        ):
            self.shut.add(conn.client_id)
            self.watchers.add(conn.client_id)
            wrap_dispatch(conn, self._gated)
            close_connection(self.server, conn.client_id, "open this seat through the classroom's lobby")
            return
        if self.role_of(headers, address) == WATCH_ROLE:
            self.watchers.add(conn.client_id)
        self._connections[conn.client_id] = conn
        # the page's own handlers (its camera, client-scoped inputs) are behind the same gate
        wrap_dispatch(conn, self._gated)

    def _closed(self, conn: Any) -> None:
        self.watchers.discard(conn.client_id)
        self.shut.discard(conn.client_id)
        self._connections.pop(conn.client_id, None)

    def _gated(self, inner: Handler) -> Handler:
        async def handle(client_id: int, message: Any) -> None:
            if client_id in self.shut or (client_id in self.watchers and not isinstance(message, PASSES)):
                self._refuse(client_id, message)
                return
            await inner(client_id, message)

        return handle

    def _refuse(self, client_id: int, message: Any) -> None:
        kind = type(message).__name__
        self.refused[kind] += 1
        conn = self._connections.get(client_id)
        if conn is None:
            return
        if isinstance(message, _messages.GuiUpdateMessage):  # the page's input back to the value every page sees
            handle = input_by_uuid(self.server, message.uuid)
            if handle is not None and "value" in message.updates:
                value = input_state(handle).value
                queue_to_connection(conn, _messages.GuiUpdateMessage(message.uuid, {"value": value}))
        if self.budget.should_report(f"{client_id}: {kind}"):
            client = self.server.get_clients().get(client_id)
            if client is not None:
                try:
                    client.add_notification(
                        "Watching only", "This page steers nothing.", auto_close_seconds=4.0, color="yellow"
                    )
                except Exception:  # the tab may have closed meanwhile
                    pass

    async def _say_watching(self, client: viser.ClientHandle) -> None:
        # on the server's event loop, where a page's connection closes: viser runs a plain connect
        # callback on a thread of its own, which a page that left at once could outrun (the notice then
        # went to its closed connection, and viser warned)
        if client.client_id in self.watchers and client.client_id in self._connections:
            client.add_notification(WATCHING_TITLE, WATCHING_BODY, with_close_button=False, color="blue")


def install_watch_gate(
    server: viser.ViserServer, watch_only: bool = False, steer_local: bool = False, seat_secret: str = ""
) -> WatchGate:
    """Put the gate in front of every message a page sends (once, before any page connects)."""
    return WatchGate(server, watch_only=watch_only, steer_local=steer_local, seat_secret=seat_secret)
