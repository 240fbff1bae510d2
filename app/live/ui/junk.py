"""Junk from a page: frames that are no message, and messages no handler can take, in bounded log lines.

A browser sends viser's messages as binary MessagePack frames. A raw websocket can send anything: text
frames, bytes that are not MessagePack, a message of no known type or with wrong fields, a message its
handler raises on. viser logged each such frame's full traceback and dropped the connection (hundreds
of tracebacks from one client, no cap). Now (`guard_junk`) each is skipped and counted: the log gets one
line per client (peer address) and kind of junk per minute, with the count since the kind's last line,
and a connection that sends DROP_AFTER malformed frames within DROP_WINDOW_S is dropped (close code
1008, one line too). What the log remembers is bounded (KINDS_KEPT client × kind pairs, oldest
forgotten first), so junk that varies costs bounded memory and lines.
"""

from __future__ import annotations

import inspect
import sys
import time
import weakref
from collections import OrderedDict, deque
from collections.abc import Callable
from typing import Any

import msgspec
import viser

from app.live.ui.viser_seam import guard_frames, on_connection_open, opening_request, wrap_dispatch

JUNK_PERIOD_S = 60.0  # one line per client and kind of junk per this many seconds
DROP_AFTER = 20  # malformed frames from one connection within DROP_WINDOW_S that end it
DROP_WINDOW_S = 10.0
KINDS_KEPT = 64  # client × kind pairs the log remembers at most


def junk_kind(exc: BaseException) -> str:
    """The kind of junk a frame's decoding error says it was (a few fixed kinds, so the log stays bounded)."""
    if isinstance(exc, TypeError) and "text frame" in str(exc):
        return "text frames"
    if isinstance(exc, msgspec.DecodeError):
        return "frames that are not MessagePack"
    if isinstance(exc, (KeyError, AttributeError)):
        return "messages of no known type"
    return f"malformed messages ({type(exc).__name__})"


def peer(address: Any) -> str:
    """A client as the log names it: its peer's host (a reconnecting client is the same client)."""
    if isinstance(address, (tuple, list)) and address:
        return str(address[0])
    return "an unknown peer"


def _stderr_line(line: str) -> None:
    print(line, file=sys.stderr, flush=True)


class JunkLog:
    """Counts junk per (client, kind) and writes one line per pair per `period_s` (see the module docstring)."""

    def __init__(
        self,
        write: Callable[[str], None] = _stderr_line,
        clock: Callable[[], float] = time.monotonic,
        period_s: float = JUNK_PERIOD_S,
        capacity: int = KINDS_KEPT,
    ):
        self.write = write
        self.clock = clock
        self.period_s = period_s
        self.capacity = capacity
        self._pairs: OrderedDict[tuple[str, str], list[float]] = OrderedDict()  # → [last line at, count since]
        self.received = 0  # junk recorded
        self.lines = 0  # lines written

    def record(self, client: str, kind: str) -> None:
        """Count one piece of junk; write its pair's line when the pair had none within the period."""
        self.received += 1
        now = self.clock()
        key = (client, kind)
        entry = self._pairs.get(key)
        if entry is not None and now - entry[0] < self.period_s:
            entry[1] += 1
            return
        count = 1 + (int(entry[1]) if entry is not None else 0)
        self._pairs[key] = [now, 0.0]
        self._pairs.move_to_end(key)
        while len(self._pairs) > self.capacity:
            self._pairs.popitem(last=False)
        self.lines += 1
        self.write(
            f"torquelab: junk from {client}: {kind}, {count} since this line last came (at most once a minute); "
            f"skipped, and a connection sending {DROP_AFTER} within {DROP_WINDOW_S:g} s is dropped"
        )


class JunkGuard:
    """The server's policy for malformed frames and for messages whose handler raises (see the module docstring)."""

    def __init__(
        self, server: viser.ViserServer, log: JunkLog | None = None, clock: Callable[[], float] = time.monotonic
    ):
        self.server = server
        self.log = log if log is not None else JunkLog(clock=clock)
        self.clock = clock
        self._recent: weakref.WeakKeyDictionary[Any, deque[float]] = weakref.WeakKeyDictionary()
        self.dropped = 0  # connections ended for junk

    def on_frame(self, websocket: Any, error: BaseException) -> bool:
        """A malformed frame from `websocket`: counted and skipped (True), or the connection is to be
        dropped (False) when it is the DROP_AFTER-th within DROP_WINDOW_S."""
        client = peer(getattr(websocket, "remote_address", None))
        self.log.record(client, junk_kind(error))
        now = self.clock()
        times = self._recent.get(websocket)
        if times is None:
            times = self._recent[websocket] = deque(maxlen=DROP_AFTER)
        times.append(now)
        if len(times) == DROP_AFTER and now - times[0] <= DROP_WINDOW_S:
            self.dropped += 1
            self.log.record(client, f"connections dropped for {DROP_AFTER} malformed frames within {DROP_WINDOW_S:g} s")
            return False
        return True

    def caught(self, dispatch: Callable[[int, Any], Any]) -> Callable[[int, Any], Any]:
        """`dispatch` with a message its handler raises on counted as junk instead of a logged traceback."""

        async def dispatched(client_id: int, message: Any) -> None:
            try:
                result = dispatch(client_id, message)
                if inspect.isawaitable(result):
                    await result
            except Exception as exc:
                client = peer(opening_request(self.server, client_id)[1])
                self.log.record(client, f"{type(message).__name__}s its handler could not take ({type(exc).__name__})")

        return dispatched


def guard_junk(server: viser.ViserServer) -> JunkGuard:
    """Install the junk policy on a server (its connections opened from now on)."""
    guard = JunkGuard(server)
    guard_frames(server, guard.on_frame)
    wrap_dispatch(server, guard.caught)
    on_connection_open(server, lambda connection: wrap_dispatch(connection, guard.caught))
    return guard
