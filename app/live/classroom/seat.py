"""A seat's end of the lobby's pipes: its status out on stdout, the teacher's commands in on stdin.

`serve --seat` (the lobby starts each seat so) runs a `SeatChannel`: every `STATUS_PERIOD_S` it
prints one line `torquelab-seat {json}` (`seat_status`: simulated time, real-time factor, the lesson
and step shown, the last claim, whether the loop is alive); it reads one JSON command per line from
stdin (`{"cmd": "step", "lesson": KEY, "step": INDEX}`: show that lesson step and set it up, as the
student's "Set up this step" does). When stdin closes (the lobby is gone) the seat stops as on Ctrl-C,
so no seat outlives its lobby.
"""

from __future__ import annotations

import json
import os
import signal
import sys
import threading
import time
from typing import IO, Any

from app.live.curriculum import LESSONS
from app.live.ui.panels.lessons import LessonsPanel

STATUS_PREFIX = "torquelab-seat "
STATUS_PERIOD_S = 0.25
SECRET_ENV = "TORQUELAB_SEAT_SECRET"  # the header value the lobby sends with every connection it opens


def seat_status(app: Any) -> dict[str, Any]:
    """What the teacher's view shows of a seat, from its running app."""
    st = app.loop.status
    lessons = next((p for p in app.panels if isinstance(p, LessonsPanel)), None)
    out: dict[str, Any] = {
        "wall": time.monotonic(),  # the seat's clock (system-wide): Δt / Δwall is its real-time factor
        "cpu_s": time.process_time(),  # CPU seconds the seat's process used (all its threads): Δcpu / Δwall cores
        "t": round(st.t, 4),
        "running": st.running,
        "rtf": round(st.rtf, 4),
        "scenario": st.scenario,
        "halted": st.halted,
        "drag": st.drag_client is not None,  # a page holds the arm with the drag spring
        "alive": app.loop.alive,
        "failure": app.loop.failure,
        "pages": len(app.server.get_clients()),
    }
    if lessons is not None:
        out.update(
            lesson=lessons.lesson.key,
            lesson_title=lessons.lesson.title,
            step=lessons.index + 1,
            steps=len(lessons.lesson.steps),
            step_title=lessons.step.title,
            claim=lessons.last_claim,
        )
    return out


def apply_command(app: Any, command: dict[str, Any]) -> str:
    """Carry out one command from the lobby; "" when done, else why not (one line)."""
    if command.get("cmd") != "step":
        return f"unknown command {command.get('cmd')!r}"
    lesson = next((x for x in LESSONS if x.key == command.get("lesson")), None)
    if lesson is None:
        return f"unknown lesson {command.get('lesson')!r}"
    index = command.get("step")
    if not isinstance(index, int) or isinstance(index, bool) or not 0 <= index < len(lesson.steps):
        return f"lesson {lesson.key} has steps 0…{len(lesson.steps) - 1}, got {index!r}"
    panel = next((p for p in app.panels if isinstance(p, LessonsPanel)), None)
    if panel is None:
        return "no lessons panel"
    panel.select(lesson.key, index)
    panel.start_step()
    return ""


class SeatChannel:
    """The status writer and the command reader of a seat (see the module docstring)."""

    def __init__(self, app: Any, out: IO[str] | None = None, inp: IO[str] | None = None):
        self.app = app
        self.out = out if out is not None else sys.stdout
        self.inp = inp if inp is not None else sys.stdin
        self._stop = threading.Event()

    def start(self) -> None:
        """Start both threads (daemons: they end with the process)."""
        threading.Thread(target=self._write, name="torquelab-seat-status", daemon=True).start()
        threading.Thread(target=self._read, name="torquelab-seat-commands", daemon=True).start()

    def stop(self) -> None:
        self._stop.set()

    def _write(self) -> None:
        while not self._stop.wait(STATUS_PERIOD_S):
            try:
                line = STATUS_PREFIX + json.dumps(seat_status(self.app))
                print(line, file=self.out, flush=True)
            except (BrokenPipeError, ValueError):  # the lobby is gone: the reader stops the seat
                return
            except Exception as exc:  # a status that cannot be read is said, not fatal
                print(f"torquelab: seat status: {type(exc).__name__}: {exc}", file=sys.stderr, flush=True)
                time.sleep(1.0)

    def _read(self) -> None:
        for line in self.inp:
            if not line.strip():
                continue
            try:
                command = json.loads(line)
                why = apply_command(self.app, command) if isinstance(command, dict) else "not a JSON object"
            except Exception as exc:
                why = f"{type(exc).__name__}: {exc}"
            if why:
                print(f"torquelab: seat command refused: {why}", file=sys.stderr, flush=True)
        if not self._stop.is_set():  # stdin closed: the lobby is gone
            os.kill(os.getpid(), signal.SIGTERM)
