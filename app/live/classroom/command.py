"""`torquelab classroom`: start the lobby, print the class's link and the teacher's, run until Ctrl-C."""

from __future__ import annotations

import argparse
import asyncio
import signal

import robots
from app.live.classroom.lobby import Lobby
from app.live.classroom.seats import SeatPool
from app.live.server import port_is_free
from app.scenarios import SCENARIOS


def pool_from_args(args: argparse.Namespace) -> SeatPool:
    """The seats the command line asks for; ValueError (one line) on bad input."""
    if args.scenario not in SCENARIOS:
        raise ValueError(f"unknown scenario {args.scenario!r}; choose one of {', '.join(SCENARIOS)}")
    serve_args: tuple[str, ...] = ("--scenario", args.scenario)
    robot = robots.spec_from_args(args)
    if robot:
        robots.load(robot)  # a wrong name or path is said now, not by every seat
        serve_args += ("--robot", robot) if robot in robots.available() else ("--urdf", robot)
    return SeatPool(args.seats, args.idle, serve_args)


def run_classroom(args: argparse.Namespace) -> int:
    """Serve the lobby until Ctrl-C (or SIGTERM); every seat's process is stopped on the way out."""
    if not 0 <= args.port <= 65535:
        raise ValueError(f"port must be 0…65535, got {args.port}")
    if not port_is_free(args.host, 0):
        raise ValueError(f"cannot listen on host {args.host!r} (not an address of this machine)")
    if args.port and not port_is_free(args.host, args.port):
        raise ValueError(f"port {args.port} is busy (--port 0 picks a free one)")
    lobby = Lobby(pool_from_args(args), host=args.host, port=args.port)

    def ready(lb: Lobby) -> None:
        shown = "127.0.0.1" if args.host in ("0.0.0.0", "") else args.host
        base = f"http://{shown}:{lb.bound_port}"
        print(f"torquelab: classroom of {args.seats} seats: students open {base}/ (Ctrl-C to stop)", flush=True)
        print(
            f"torquelab: teacher's view (keep this link to yourself): {base}/teacher?token={lb.teacher_token}",
            flush=True,
        )
        print(f"torquelab: a seat with no page open for {args.idle:g} s is freed", flush=True)
        if args.host not in ("127.0.0.1", "localhost", "::1"):
            print(f"torquelab: listening on {args.host}: reachable from other machines", flush=True)

    async def main() -> None:
        loop = asyncio.get_running_loop()
        for signum in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(signum, lobby.stop)
        await lobby.run(ready)

    asyncio.run(main())
    print("torquelab: classroom stopped; every seat's lab stopped", flush=True)
    return 0
