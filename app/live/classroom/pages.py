"""The lobby's own pages (static/classroom/): the waiting room when every seat is taken, a student's
page around their lab, the teacher's view and their style sheet. No page a student gets holds the
teacher's token: the teacher's page reads everything over its websocket, after the cookie."""

from __future__ import annotations

import html
from importlib import resources


def _text(name: str) -> str:
    return (resources.files("static") / "classroom" / name).read_text(encoding="utf-8")


def style_sheet() -> str:
    """The pages' CSS (served at /classroom.css)."""
    return _text("classroom.css")


def full_page(seats: int) -> str:
    """Every seat is taken: the page says so and takes the first seat that frees up."""
    return _text("full.html").replace("__SEATS__", str(int(seats)))


def lab_page(seat: int, idle_s: float) -> str:
    """A student's page: their lab in a frame, a bar with the seat's state, and the spotlight."""
    idle = f"{idle_s / 60:g} min" if idle_s >= 60 else f"{idle_s:g} s"
    return _text("lab.html").replace("__SEAT__", str(int(seat))).replace("__IDLE__", html.escape(idle))


def teacher_page() -> str:
    """The teacher's view: every seat live, a lesson step to push to every seat, the spotlight."""
    return _text("teacher.html")
