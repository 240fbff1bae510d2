"""The classroom's lobby: the one port a class opens.

Routes (every one a GET; a websocket opens on the same paths without the trailing slash):
- `/`: a student arrives. With the cookie of a seat held: on to `/lab/`; else the first free seat is
  held for them (a fresh unguessable token in an HttpOnly cookie) and its lab starts; when every seat
  is taken the page says so and takes the first one that frees up.
- `/lab/`: the student's page: their seat's lab in a frame, a bar saying the seat's state and,
  when the teacher spotlights a seat, that seat read-only beside a button back to their own arm.
- `/lab/view/`, websocket `/lab/view`: the lab itself (viser's page; its websocket proxied to the
  seat's process, which only the lobby can open: seat ports are loopback and need the seat's secret).
- `/spotlight/view/`: the spotlit seat, read-only (watch mode), for any student holding a seat.
- `/status.json`: the student's seat state, the free seats, whether a spotlight is on.
- `/teacher?token=T`: the teacher's link (printed at start, never sent to a student's page) sets a
  teacher cookie; `/teacher/` then shows every seat live (websocket `/teacher/ws`: state, lesson,
  step, last claim, real-time factor, health every 0.5 s; push a lesson step to every seat;
  spotlight a seat); `/teacher/seat/N/view/` opens seat N read-only. Without the cookie: 403.

A websocket must come from the lobby's own origin (Origin = Host). The lobby binds 127.0.0.1 unless
told otherwise.
"""

from __future__ import annotations

import asyncio
import contextlib
import http
import json
import secrets
import threading
import time
from collections.abc import Callable, Coroutine
from dataclasses import dataclass, field
from http.cookies import CookieError, SimpleCookie
from typing import Any
from urllib.parse import parse_qs, urlsplit

import websockets
from websockets.asyncio.client import connect
from websockets.asyncio.server import ServerConnection, serve
from websockets.datastructures import Headers
from websockets.http11 import Request, Response

from app.live.classroom import pages
from app.live.classroom.seats import Seat, SeatPool
from app.live.curriculum import LESSONS
from app.live.ui.viser_seam import framed_client_page_bytes
from app.live.watch import ROLE_HEADER, SEAT_HEADER, WATCH_ROLE

SEAT_COOKIE = "torquelab_seat"
TEACHER_COOKIE = "torquelab_teacher"
TEACHER_PERIOD_S = 0.5  # the teacher's view is refreshed this often
REAP_PERIOD_S = 0.5  # idle seats are looked for this often
SEAT_START_TIMEOUT_S = 120.0  # a page waits this long for its seat's process to serve
MAX_MESSAGE = 50 * 1024 * 1024  # as viser's own server


@dataclass
class Lobby:
    """The lobby's state and handlers (see the module docstring); `run()` serves until `stop()`."""

    pool: SeatPool
    host: str = "127.0.0.1"
    port: int = 8080
    teacher_token: str = field(default_factory=lambda: secrets.token_urlsafe(24))
    spotlight: int | None = None  # the seat shown read-only to every student, None when none
    pages: dict[int, set[Any]] = field(default_factory=dict)  # seat number → its proxied connections
    events: list[tuple[float, str]] = field(default_factory=list)  # (monotonic time, what happened)
    bound_port: int = 0
    pushed: dict[str, Any] | None = None  # the lesson step the teacher last pushed: a seat that starts later gets it
    _stop: asyncio.Event | None = None
    _loop: asyncio.AbstractEventLoop | None = None

    def __post_init__(self) -> None:
        self.pool.on_stop = self._seat_stopped
        self.pool.on_ready = self._seat_ready
        self._page = framed_client_page_bytes()  # shown in the lab's frames: reconnects without focus

    # ---- running --------------------------------------------------------------------------------
    async def run(self, ready: Callable[[Lobby], None] | None = None) -> None:
        """Serve until `stop()`; `ready(self)` once the port is bound (`bound_port`)."""
        self._stop = asyncio.Event()
        self._loop = asyncio.get_running_loop()
        async with serve(
            self._socket,
            self.host,
            self.port,
            process_request=self._http,
            select_subprotocol=_viser_subprotocol,
            compression=None,
            max_size=MAX_MESSAGE,
        ) as server:
            self.bound_port = server.sockets[0].getsockname()[1] if server.sockets else self.port
            reaper = asyncio.get_running_loop().create_task(self._reap())
            if ready is not None:
                ready(self)
            try:
                await self._stop.wait()
            finally:
                reaper.cancel()
                for conns in self.pages.values():
                    for conn in list(conns):
                        with contextlib.suppress(Exception):
                            await conn.close(1001, "the classroom stopped")
                await self.pool.close()

    def stop(self) -> None:
        """Stop serving and every seat (from any thread)."""
        if self._loop is not None and self._stop is not None:
            self._loop.call_soon_threadsafe(self._stop.set)

    def call(self, fn: Callable[[], Coroutine[Any, Any, Any]], timeout: float = 30.0) -> Any:
        """Run a coroutine function on the lobby's event loop from another thread (tests, bench)."""
        assert self._loop is not None
        return asyncio.run_coroutine_threadsafe(fn(), self._loop).result(timeout)

    def note(self, text: str) -> None:
        self.events.append((time.monotonic(), text))
        del self.events[:-200]

    async def _reap(self) -> None:
        while True:
            await asyncio.sleep(REAP_PERIOD_S)
            for number in await self.pool.reclaim_idle():
                self.note(f"seat {number} reclaimed after {self.pool.idle_s:g} s without a page")
                if self.spotlight == number:
                    self.spotlight = None

    def _seat_ready(self, seat: Seat) -> None:
        if self.pushed is not None:  # a late arrival joins the class where it is
            command = self.pushed
            asyncio.get_running_loop().create_task(self.pool.send(seat, command))
            self.note(f"seat {seat.number} started on the class's step")

    def _seat_stopped(self, seat: Seat) -> list[asyncio.Task[Any]]:
        if seat.state == "stopped":
            self.note(f"seat {seat.number} stopped: {seat.stop_reason}")
        why = f"seat {seat.number} stopped" if seat.state == "stopped" else f"seat {seat.number} freed"
        loop = asyncio.get_running_loop()
        return [loop.create_task(conn.close(1011, why)) for conn in list(self.pages.get(seat.number, ()))]

    # ---- HTTP -----------------------------------------------------------------------------------
    async def _http(self, connection: ServerConnection, request: Request) -> Response | None:
        url = urlsplit(request.path)
        path = url.path
        is_socket = request.headers.get("Upgrade", "").lower() == "websocket"
        cookies = _cookies(request)
        seat = self.pool.by_token(cookies.get(SEAT_COOKIE))
        teacher = _same(cookies.get(TEACHER_COOKIE), self.teacher_token)
        if seat is not None:
            seat.last_seen = time.monotonic()
        if is_socket:
            return self._check_socket(request, path, seat, teacher)
        if path == "/":
            return self._arrive(seat)
        if path == "/lab/":
            if seat is None:
                return _redirect("/")
            if seat.state == "stopped":  # back after a crash: a fresh lab on the same seat
                self.pool.start(seat)
                self.note(f"seat {seat.number} started again")
            return _html(pages.lab_page(seat.number, self.pool.idle_s))
        if path in ("/lab/view/", "/spotlight/view/"):
            return _html_bytes(self._page) if seat is not None or teacher else _forbidden("no seat")
        if path == "/classroom.css":
            return _text(pages.style_sheet(), "text/css; charset=utf-8")
        if path == "/status.json":
            return _json(self.student_status(seat))
        if path in ("/teacher", "/teacher/"):
            token = parse_qs(url.query).get("token", [""])[0]
            if token:
                if not _same(token, self.teacher_token):
                    return _forbidden("wrong teacher token")
                return _redirect("/teacher/", cookie=f"{TEACHER_COOKIE}={self.teacher_token}")
            return _html(pages.teacher_page()) if teacher else _forbidden("the teacher's view needs the teacher's link")
        if path.startswith("/teacher/seat/") and path.endswith("/view/"):
            return _html_bytes(self._page) if teacher else _forbidden("the teacher's view needs the teacher's link")
        return Response(http.HTTPStatus.NOT_FOUND, "Not Found", Headers([("Content-Type", "text/plain")]), b"")

    def _arrive(self, seat: Seat | None) -> Response:
        if seat is not None:
            return _redirect("/lab/")
        seat = self.pool.claim()
        if seat is None:
            return _html(pages.full_page(len(self.pool.seats)))
        self.note(f"seat {seat.number} taken")
        return _redirect("/lab/", cookie=f"{SEAT_COOKIE}={seat.token}")

    def _check_socket(self, request: Request, path: str, seat: Seat | None, teacher: bool) -> Response | None:
        origin = request.headers.get("Origin")
        if origin is not None and urlsplit(origin).netloc != request.headers.get("Host", ""):
            return _forbidden("another site's page")
        if path == "/lab/view":
            return None if seat is not None else _forbidden("no seat")
        if path == "/spotlight/view":
            return None if (seat is not None or teacher) else _forbidden("no seat")
        if path == "/teacher/ws" or path.startswith("/teacher/seat/"):
            return None if teacher else _forbidden("the teacher's view needs the teacher's link")
        return _forbidden("no such socket")

    # ---- websockets -----------------------------------------------------------------------------
    async def _socket(self, conn: ServerConnection) -> None:
        request = conn.request
        assert request is not None
        path = urlsplit(request.path).path
        cookies = _cookies(request)
        if path == "/teacher/ws":
            await self._teacher_socket(conn)
            return
        if path == "/lab/view":
            seat = self.pool.by_token(cookies.get(SEAT_COOKIE))
            role = "steer"
        elif path == "/spotlight/view":
            seat = self.pool.by_number(self.spotlight) if self.spotlight else None
            role = WATCH_ROLE
        else:  # /teacher/seat/N/view (checked in `_check_socket`)
            number = path.removeprefix("/teacher/seat/").removesuffix("/view")
            seat = self.pool.by_number(int(number)) if number.isdigit() else None
            role = WATCH_ROLE
        if seat is None:
            await conn.close(1008, "no such seat")
            return
        await self._proxy(conn, seat, role)

    async def _proxy(self, conn: ServerConnection, seat: Seat, role: str) -> None:
        """Pass every message both ways between a page and its seat's process until either closes."""
        mine = role != WATCH_ROLE
        number = seat.number
        self.pages.setdefault(number, set()).add(conn)
        if mine:
            seat.pages += 1  # from now on: a page waiting for its seat's start keeps it too
        try:
            if seat.state == "starting":
                with contextlib.suppress(asyncio.TimeoutError):
                    await asyncio.wait_for(seat.ready.wait(), SEAT_START_TIMEOUT_S)
            if seat.state != "ready":
                await conn.close(1011, f"seat {number} is {seat.health()}")
                return
            headers = {SEAT_HEADER: seat.secret}
            if role == WATCH_ROLE:
                headers[ROLE_HEADER] = WATCH_ROLE
            async with connect(
                f"ws://127.0.0.1:{seat.port}",
                subprotocols=[conn.subprotocol] if conn.subprotocol else None,  # type: ignore[list-item]
                additional_headers=headers,
                compression=None,
                max_size=MAX_MESSAGE,
                open_timeout=10,
            ) as upstream:
                await _pump_both(conn, upstream)
        except (OSError, websockets.exceptions.WebSocketException, asyncio.TimeoutError):
            pass
        finally:
            self.pages.get(number, set()).discard(conn)
            if mine:
                seat.pages -= 1
                seat.last_seen = time.monotonic()
            with contextlib.suppress(Exception):
                await conn.close()

    async def _teacher_socket(self, conn: ServerConnection) -> None:
        sender = asyncio.get_running_loop().create_task(self._teacher_feed(conn))
        try:
            async for raw in conn:
                with contextlib.suppress(ValueError, TypeError):
                    reply = await self.teacher_action(json.loads(raw))
                    if reply:
                        await conn.send(json.dumps({"notice": reply}))
        except websockets.exceptions.ConnectionClosed:
            pass
        finally:
            sender.cancel()

    async def _teacher_feed(self, conn: ServerConnection) -> None:
        with contextlib.suppress(websockets.exceptions.ConnectionClosed):
            await conn.send(json.dumps({"lessons": lessons_outline()}))
            while True:
                await conn.send(json.dumps(self.teacher_status()))
                await asyncio.sleep(TEACHER_PERIOD_S)

    async def teacher_action(self, action: dict[str, Any]) -> str:
        """Carry out one of the teacher's actions; returns what to tell them (one line)."""
        kind = action.get("action")
        if kind == "spotlight":
            number = action.get("seat")
            if number is None:
                self.spotlight = None
                return "spotlight off"
            seat = self.pool.by_number(number) if isinstance(number, int) else None
            if seat is None or seat.state != "ready":
                return f"seat {number} is not running"
            self.spotlight = number
            return f"every student now sees seat {number} (read-only)"
        if kind == "push":
            lesson = next((x for x in LESSONS if x.key == action.get("lesson")), None)
            step = action.get("step")
            if lesson is None or not isinstance(step, int) or not 0 <= step < len(lesson.steps):
                return "no such lesson step"
            command = {"cmd": "step", "lesson": lesson.key, "step": step}
            self.pushed = command
            sent = [s.number for s in self.pool.seats if await self.pool.send(s, command)]
            starting = sum(s.state == "starting" for s in self.pool.seats)
            self.note(f"step {step + 1} of {lesson.title!r} pushed to seats {sent}")
            later = f"; {starting} starting seat(s) get it when they start" if starting else ""
            return (
                f"{lesson.title}, step {step + 1}: set up on {len(sent)} seat(s){later}; seats taken later get it too"
            )
        return f"unknown action {kind!r}"

    # ---- what the pages show --------------------------------------------------------------------
    def student_status(self, seat: Seat | None) -> dict[str, Any]:
        """A student's view of the classroom: their seat, the free seats, the spotlight."""
        return {
            "seat": seat.number if seat else None,
            "state": seat.state if seat else None,
            "health": seat.health() if seat else None,
            "seats": len(self.pool.seats),
            "free": self.pool.free_count(),
            "spotlight": self.spotlight
            if (self.spotlight and (seat is None or seat.number != self.spotlight))
            else None,
            "idle_s": self.pool.idle_s,
        }

    def teacher_status(self) -> dict[str, Any]:
        """Every seat's state for the teacher's view."""
        now = time.monotonic()
        rows = []
        for seat in self.pool.seats:
            st = seat.status
            rows.append(
                {
                    "seat": seat.number,
                    "state": seat.state,
                    "health": seat.health(now),
                    "pages": seat.pages,
                    "watchers": len(self.pages.get(seat.number, ())) - seat.pages,
                    "lesson": st.get("lesson_title", ""),
                    "step": f"{st['step']}/{st['steps']}: {st['step_title']}" if "step" in st else "",
                    "claim": st.get("claim", ""),
                    "rtf": st.get("rtf"),
                    "running": st.get("running"),
                    "t": st.get("t"),
                    "wall": st.get("wall"),
                    "cpu_s": st.get("cpu_s"),
                    "scenario": st.get("scenario", ""),
                    "idle_s": round(now - seat.last_seen, 1) if seat.token and seat.pages == 0 else 0.0,
                }
            )
        return {
            "seats": rows,
            "spotlight": self.spotlight,
            "free": self.pool.free_count(),
            "idle_limit_s": self.pool.idle_s,
            "events": [f"{now - t:5.0f} s ago: {text}" for t, text in self.events[-8:]][::-1],
        }


def lessons_outline() -> list[dict[str, Any]]:
    """Each lesson's key, title and step titles (the teacher's push menu)."""
    return [{"key": x.key, "title": x.title, "steps": [s.title for s in x.steps]} for x in LESSONS]


async def _pump_both(a: Any, b: Any) -> None:
    async def pump(src: Any, dst: Any) -> None:
        async for message in src:
            await dst.send(message)

    tasks = [asyncio.ensure_future(pump(a, b)), asyncio.ensure_future(pump(b, a))]
    try:
        await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
    finally:
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)


def _viser_subprotocol(conn: ServerConnection, offered: Any) -> Any:
    return next((p for p in offered if str(p).startswith("viser-v")), None)


def _cookies(request: Request) -> dict[str, str]:
    jar: SimpleCookie = SimpleCookie()
    for header in request.headers.get_all("Cookie"):
        with contextlib.suppress(CookieError):
            jar.load(header)
    return {k: v.value for k, v in jar.items()}


def _same(given: str | None, expected: str) -> bool:
    return bool(given) and secrets.compare_digest(str(given).encode(), expected.encode())


def _html(text: str) -> Response:
    return _html_bytes(text.encode())


def _text(text: str, kind: str) -> Response:
    return _html_bytes(text.encode(), kind)


def _html_bytes(body: bytes, kind: str = "text/html; charset=utf-8") -> Response:
    headers = Headers([("Content-Type", kind), ("Cache-Control", "no-store")])
    headers["Content-Length"] = str(len(body))
    return Response(http.HTTPStatus.OK, "OK", headers, body)


def _json(data: Any) -> Response:
    body = json.dumps(data).encode()
    headers = Headers([("Content-Type", "application/json"), ("Cache-Control", "no-store")])
    headers["Content-Length"] = str(len(body))
    return Response(http.HTTPStatus.OK, "OK", headers, body)


def _redirect(location: str, cookie: str = "") -> Response:
    headers = Headers([("Location", location), ("Cache-Control", "no-store"), ("Content-Length", "0")])
    if cookie:
        headers["Set-Cookie"] = f"{cookie}; Path=/; HttpOnly; SameSite=Strict"
    return Response(http.HTTPStatus.FOUND, "Found", headers, b"")


def _forbidden(why: str) -> Response:
    body = f"403 Forbidden: {why}\n".encode()
    headers = Headers([("Content-Type", "text/plain; charset=utf-8"), ("Content-Length", str(len(body)))])
    return Response(http.HTTPStatus.FORBIDDEN, "Forbidden", headers, body)


def start_lobby_thread(lobby: Lobby, timeout: float = 10.0) -> threading.Thread:
    """Run the lobby on an event loop of its own in a daemon thread; returns once its port is bound."""
    bound = threading.Event()
    failed: list[BaseException] = []

    def main() -> None:
        try:
            asyncio.run(lobby.run(lambda _: bound.set()))
        except BaseException as exc:  # said to the caller waiting for the start
            failed.append(exc)
            bound.set()

    thread = threading.Thread(target=main, name="torquelab-lobby", daemon=True)
    thread.start()
    if not bound.wait(timeout) or failed:
        raise RuntimeError(f"the lobby did not start: {failed[0] if failed else 'timeout'}")
    return thread
