"""The seats of a classroom: each an own `torquelab serve --seat` process, started when a student
arrives, watched while it runs, reclaimed when idle.

A seat is free or held by a student's token (the lobby's cookie, `secrets.token_urlsafe`: never the
seat's number). Holding one starts its process on a free loopback port with a secret of its own (the
lobby sends it with every connection it opens; the seat closes any other). The process's stdout
says its port (`open http://127.0.0.1:PORT`) and then a status line every 0.25 s (`seat.py`); a seat
whose process exits (a crash, kill -9) is marked stopped the moment the pool's wait on it returns,
one whose status lines stop for `STALE_S` is "not responding". What the process writes to stderr goes
to the lobby's stderr, each line headed `seat N: `, and its last `LOG_LINES` lines are kept in the
seat's `log`. A held seat with no page open for `idle_s` is reclaimed: its process stopped, its token
forgotten, the seat free again.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import re
import secrets
import signal
import sys
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from app.live.classroom.seat import SECRET_ENV, STATUS_PREFIX

STALE_S = 2.0  # a running seat whose status is older than this is "not responding"
STOP_GRACE_S = 5.0  # a reclaimed seat's process gets this long after SIGTERM before SIGKILL
URL_LINE = re.compile(r"open http://127\.0\.0\.1:(\d+) ")
LOG_LINES = 200  # the last lines of a seat's stderr kept in its `log`
SEAT_COMMAND = ("-c", "import sys; from app.cli import main; sys.exit(main())", "serve", "--seat", "--port", "0")


@dataclass
class SeatLog:
    """The last `LOG_LINES` lines one start of a seat's process wrote to stderr; `ended` once it closed it."""

    lines: deque[str] = field(default_factory=lambda: deque(maxlen=LOG_LINES))
    ended: bool = False


@dataclass
class Seat:
    """One seat: its number (the teacher's name for it), the student's token and its process."""

    number: int
    token: str = ""  # the student's cookie; "" while the seat is free
    secret: str = ""  # what the lobby sends the seat's process with every connection
    state: str = "free"  # free | starting | ready | stopped
    port: int = 0
    proc: asyncio.subprocess.Process | None = None
    status: dict[str, Any] = field(default_factory=dict)  # the process's latest status line
    status_at: float = 0.0  # monotonic time of that line
    started_at: float = 0.0
    stopped_at: float = 0.0  # monotonic time the pool noticed the process had exited
    stop_reason: str = ""
    pages: int = 0  # the student's pages open on the seat now (through the lobby)
    last_seen: float = 0.0  # monotonic: the student's last request or last page closed
    ready: asyncio.Event = field(default_factory=asyncio.Event)
    log: SeatLog = field(default_factory=SeatLog)  # the current (or last) process's stderr

    def health(self, now: float | None = None) -> str:
        """free | starting | healthy | not responding | stopped: … (what the teacher's view shows)."""
        now = time.monotonic() if now is None else now
        if self.state in ("free", "starting"):
            return self.state
        if self.state == "stopped":
            return f"stopped: {self.stop_reason}"
        if now - self.status_at > STALE_S:
            return "not responding"
        if self.status.get("failure"):
            return f"loop stopped: {self.status['failure']}"
        return "healthy"


def exit_reason(code: int | None) -> str:
    """A process's end in words: "killed by SIGKILL", "exit code 1"."""
    if code is None:
        return "running"
    if code < 0:
        try:
            return f"killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"killed by signal {-code}"
    return f"exit code {code}"


class SeatPool:
    """The classroom's seats (see the module docstring); every method runs on the lobby's event loop."""

    def __init__(
        self,
        seats: int,
        idle_s: float,
        serve_args: tuple[str, ...] = (),
        python: str = sys.executable,
        on_stop: Callable[[Seat], list[asyncio.Task[Any]]] | None = None,
        on_ready: Callable[[Seat], None] | None = None,
    ):
        if seats < 1:
            raise ValueError(f"a classroom needs at least 1 seat, got {seats}")
        if not idle_s > 0:
            raise ValueError(f"the idle time must be positive, got {idle_s} s")
        self.seats = [Seat(number=i + 1) for i in range(seats)]
        self.idle_s = idle_s
        self.serve_args = serve_args
        self.python = python
        self.on_stop = on_stop  # the lobby closes the seat's pages (the tasks closing them)
        self.on_ready = on_ready  # the lobby sets up the class's current lesson step on it
        self.reclaimed = 0  # seats reclaimed for idleness

    # ---- who holds what -------------------------------------------------------------------------
    def by_token(self, token: str | None) -> Seat | None:
        """The seat this student's token holds, None for an unknown token."""
        if not token:
            return None
        for seat in self.seats:
            if seat.token and secrets.compare_digest(seat.token, token):
                return seat
        return None

    def by_number(self, number: int) -> Seat | None:
        return self.seats[number - 1] if 1 <= number <= len(self.seats) else None

    def free_count(self) -> int:
        return sum(seat.state == "free" for seat in self.seats)

    def claim(self) -> Seat | None:
        """Hold the first free seat for a new student (its process starting); None when all are taken."""
        seat = next((s for s in self.seats if s.state == "free"), None)
        if seat is None:
            return None
        seat.token = secrets.token_urlsafe(24)
        seat.last_seen = time.monotonic()
        self.start(seat)
        return seat

    # ---- processes ------------------------------------------------------------------------------
    def start(self, seat: Seat) -> None:
        """Start (or start again, after it stopped) the seat's process; returns at once."""
        seat.secret = secrets.token_urlsafe(24)
        seat.state, seat.port, seat.status, seat.status_at = "starting", 0, {}, 0.0
        seat.stop_reason, seat.stopped_at, seat.started_at = "", 0.0, time.monotonic()
        seat.ready = asyncio.Event()
        seat.log = SeatLog()
        asyncio.get_running_loop().create_task(self._run(seat))

    async def _run(self, seat: Seat) -> None:
        env = {**os.environ, SECRET_ENV: seat.secret}
        try:
            proc = await asyncio.create_subprocess_exec(
                self.python,
                *SEAT_COMMAND,
                *self.serve_args,
                stdin=asyncio.subprocess.PIPE,
                stdout=asyncio.subprocess.PIPE,
                stderr=asyncio.subprocess.PIPE,
                env=env,
                start_new_session=True,  # its own session: a Ctrl-C meant for the lobby reaches it through the lobby
            )
        except OSError as exc:
            self._stopped(seat, None, f"could not start: {exc.strerror}")
            return
        seat.proc = proc
        loop = asyncio.get_running_loop()
        readers = [
            loop.create_task(self._read(seat, proc)),
            loop.create_task(self._read_errors(seat.number, proc, seat.log)),
        ]
        code = await proc.wait()
        if seat.proc is proc and seat.state in ("starting", "ready"):
            self._stopped(seat, proc, exit_reason(code))
        await asyncio.wait(readers, timeout=1.0)

    async def _read(self, seat: Seat, proc: asyncio.subprocess.Process) -> None:
        assert proc.stdout is not None
        while line := await proc.stdout.readline():
            if seat.proc is not proc:
                continue
            text = line.decode(errors="replace")
            if text.startswith(STATUS_PREFIX):
                with contextlib.suppress(ValueError):
                    seat.status = json.loads(text[len(STATUS_PREFIX) :])
                    seat.status_at = time.monotonic()
            elif seat.state == "starting" and (m := URL_LINE.search(text)):
                seat.port = int(m.group(1))
                seat.state, seat.status_at = "ready", time.monotonic()
                seat.ready.set()
                if self.on_ready is not None:
                    self.on_ready(seat)

    @staticmethod
    async def _read_errors(number: int, proc: asyncio.subprocess.Process, log: SeatLog) -> None:
        """Pass the process's stderr on to the lobby's, each line headed by the seat's number; keep the last."""
        assert proc.stderr is not None
        try:
            while True:
                try:
                    line = await proc.stderr.readline()
                except ValueError:  # longer than the stream's limit: dropped, and the pipe read on
                    line = b"(a line too long to pass on)"
                if not line:
                    break
                text = line.decode(errors="replace").rstrip("\n")
                log.lines.append(text)
                print(f"seat {number}: {text}", file=sys.stderr, flush=True)
        finally:
            log.ended = True

    def _stopped(self, seat: Seat, proc: asyncio.subprocess.Process | None, reason: str) -> None:
        seat.state, seat.stop_reason, seat.stopped_at = "stopped", reason, time.monotonic()
        seat.ready.set()  # whoever waits for the start learns it failed
        if self.on_stop is not None:
            self.on_stop(seat)

    async def free(self, seat: Seat) -> None:
        """Stop the seat's process (SIGTERM, then SIGKILL after `STOP_GRACE_S`) and free the seat."""
        proc, seat.proc = seat.proc, None
        seat.token, seat.secret, seat.state, seat.port, seat.status = "", "", "free", 0, {}
        seat.ready.set()  # a page waiting for the start learns the seat is gone
        closing = self.on_stop(seat) if self.on_stop is not None else []
        if closing:  # its pages closed first: the seat's server sees them go before it stops
            await asyncio.wait(closing, timeout=2.0)
        if proc is not None and proc.stdin is not None:
            proc.stdin.close()  # its command pipe closed (a seat ends when it is), and no transport left open
        if proc is not None and proc.returncode is None:
            with contextlib.suppress(ProcessLookupError):
                proc.terminate()
            try:
                await asyncio.wait_for(proc.wait(), STOP_GRACE_S)
            except asyncio.TimeoutError:
                with contextlib.suppress(ProcessLookupError):
                    proc.kill()
                await proc.wait()

    async def reclaim_idle(self, now: float | None = None) -> list[int]:
        """Free every held seat with no page open for `idle_s`; returns their numbers."""
        now = time.monotonic() if now is None else now
        idle = [
            s
            for s in self.seats
            if s.token and s.state != "starting" and s.pages == 0 and now - max(s.last_seen, s.started_at) > self.idle_s
        ]
        for seat in idle:
            await self.free(seat)
            self.reclaimed += 1
        return [s.number for s in idle]

    async def send(self, seat: Seat, command: dict[str, Any]) -> bool:
        """Write one command line to a running seat; False when it is not running."""
        proc = seat.proc
        if seat.state != "ready" or proc is None or proc.stdin is None:
            return False
        try:
            proc.stdin.write((json.dumps(command) + "\n").encode())
            await proc.stdin.drain()
        except (BrokenPipeError, ConnectionResetError):
            return False
        return True

    async def close(self) -> None:
        """Stop every seat's process."""
        await asyncio.gather(*(self.free(s) for s in self.seats if s.proc is not None))
