"""The classroom with real pages: headless Chromium students of a two-seat lobby on the free preset.

Each student is a browser context of their own (their own cookies, as two browsers are). Two pages
get two seats whose arms move independently: a mouse drag on the arm in one page moves that seat's
TCP by centimetres while the other seat's stays put to a fraction of a millimetre, each TCP read from
the poses its own page receives. A reload returns to the same seat's process. A page without the
teacher's token is refused the teacher's view, and the teacher's link opens it. A lab whose
connection drops opens it again, though its frame has no focus, and receives frames. A seat stopped while
its page is connected (freed by the lobby; given SIGTERM again and again) exits cleanly, with no
traceback on its stderr.

The page's websocket is watched through the browser (what it sends: its camera, for projecting a
link to the pixel to press; what it receives: every link's pose). Events from the browser reach
this process only while it waits on the browser, so every wait here is the page's
`wait_for_timeout`.
"""

from __future__ import annotations

import os
import signal
import time
from collections.abc import Callable, Iterator
from types import SimpleNamespace
from typing import Any

import msgspec
import numpy as np
import pytest
import viser.transforms as vtf
import zstandard

import robots
from app.live.classroom.lobby import TEACHER_COOKIE, Lobby, start_lobby_thread
from app.live.classroom.seats import SeatPool
from app.tools.bench_classroom import LAB_COUNTS_JS, PAGE_COUNTERS_JS
from app.tools.bench_serve import CHROMIUM_ARGS
from tests.test_browser import SCENE_CANVAS, chromium_path

pytestmark = [pytest.mark.browser, pytest.mark.usefixtures("warm_kernels")]

VIEWPORT = {"width": 1280, "height": 800}
PRESS_LINK = "link6"  # the wrist: the TCP follows it
MOVED_M = 0.03  # the dragged seat's TCP moves at least this far
AT_REST_M = 0.001  # the other seat's TCP moves less than this meanwhile
SEAT_START_S = 120.0  # a seat's process starts with its first page (kernels from the disk cache)


# the 3D view's box in the student's page (CSS px of the top page): the lab's frame is of the same origin
CANVAS_BOX_JS = """selector => {
    const frame = document.getElementById("mine");
    const canvas = frame && frame.contentDocument && frame.contentDocument.querySelector(selector);
    if (!canvas) return null;
    const outer = frame.getBoundingClientRect(), inner = canvas.getBoundingClientRect();
    return {x: outer.x + frame.clientLeft + inner.x, y: outer.y + frame.clientTop + inner.y,
            width: inner.width, height: inner.height};
}"""


def poll(page: Any, condition: Callable[[], Any], timeout: float, what: str) -> Any:
    """Wait (on the page, so that the browser's events arrive) until `condition()` is truthy."""
    deadline = time.monotonic() + timeout
    while True:
        value = condition()
        if value:
            return value
        if time.monotonic() > deadline:
            pytest.fail(f"timed out after {timeout:.0f} s waiting for {what}", pytrace=False)
        page.wait_for_timeout(100)


def scene_messages(data: bytes) -> list[dict[str, Any]]:
    """The messages of one frame viser sends a page (length-prefixed zstd msgpack)."""
    size, packed = int.from_bytes(data[:8], "little"), int.from_bytes(data[8:16], "little")
    inner = zstandard.ZstdDecompressor().decompress(data[16 : 16 + packed], max_output_size=size)
    return msgspec.msgpack.decode(inner)["messages"]


class LabSocket:
    """A student's page as its lab's websocket (/lab/view) shows it: the camera the page reports and the
    pose of each robot frame as the page last received it; `opened` counts the sockets it opened,
    `frames` the frames it received."""

    def __init__(self, page: Any):
        self.page = page
        self.camera: dict[str, Any] | None = None
        self.positions: dict[str, np.ndarray] = {}
        self.wxyz: dict[str, np.ndarray] = {}
        self.opened = 0
        self.frames = 0
        page.on("websocket", self._socket)

    def _socket(self, ws: Any) -> None:
        if not ws.url.endswith("/lab/view"):
            return
        self.opened += 1
        ws.on("framesent", self._sent)
        ws.on("framereceived", self._received)

    def _sent(self, payload: Any) -> None:
        if isinstance(payload, bytes | bytearray):
            msg = msgspec.msgpack.decode(payload)
            if isinstance(msg, dict) and msg.get("type") == "ViewerCameraMessage":
                self.camera = msg

    def _received(self, payload: Any) -> None:
        if not isinstance(payload, bytes | bytearray):
            return
        self.frames += 1
        for m in scene_messages(bytes(payload)):
            name = m.get("name")
            if not isinstance(name, str) or not name.startswith("/robot/"):
                continue
            if m.get("type") == "SetPositionMessage":
                self.positions[name.removeprefix("/robot/")] = np.array(m["position"], dtype=float)
            elif m.get("type") == "SetOrientationMessage":
                self.wxyz[name.removeprefix("/robot/")] = np.array(m["wxyz"], dtype=float)

    def point_world(self, link: str, local: np.ndarray) -> np.ndarray | None:
        """A point given in a link's frame, in the world, from the link's pose as the page has it."""
        if link not in self.positions or link not in self.wxyz:
            return None
        return self.positions[link] + vtf.SO3(self.wxyz[link]).as_matrix() @ local


def tcp_in_link(robot: Any) -> tuple[str, np.ndarray]:
    """The link whose frame carries the TCP, and the TCP's position in that frame."""
    model = robot.model
    tcp = model.frames[model.getFrameId(robots.TCP_FRAME)]
    link = next(f for f in model.frames if f.name in robot.link_names and f.parentJoint == tcp.parentJoint)
    return link.name, (link.placement.inverse() * tcp.placement).translation.copy()


@pytest.fixture(scope="module")
def lobby() -> Iterator[Lobby]:
    lb = Lobby(SeatPool(2, 600.0, ("--scenario", "free")), port=0)
    start_lobby_thread(lb)
    yield lb
    lb.stop()
    deadline = time.monotonic() + 20.0
    while time.monotonic() < deadline and any(s.proc is not None for s in lb.pool.seats):
        time.sleep(0.1)


@pytest.fixture(scope="module")
def browser() -> Iterator[Any]:
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=chromium_path(), headless=True, args=CHROMIUM_ARGS)
        try:
            yield b
        finally:
            b.close()


class Student(SimpleNamespace):
    context: Any
    page: Any
    lab: LabSocket
    seat: int


def seat_of(page: Any) -> int | None:
    """The seat the page's cookie holds, as the lobby tells the page."""
    return page.evaluate("fetch('/status.json', {cache: 'no-store'}).then(r => r.json()).then(s => s.seat)")


def arm_missing(student: Student, lobby: Lobby) -> str:
    """What the page's lab lacks of being connected, reporting its camera and holding the poses of the
    link pressed and the TCP's link ("" when nothing)."""
    robot = robots.load(robots.DEFAULT_ROBOT)
    lab = student.lab
    seat = lobby.pool.by_number(student.seat)
    if seat is None or seat.state != "ready":
        return f"seat {student.seat} is {seat and seat.health()}"
    if not seat.status.get("pages"):
        return f"seat {student.seat} has no page (the page opened {lab.opened} lab socket(s))"
    if lab.camera is None:
        return "the page has reported no camera"
    lacking = [n for n in (PRESS_LINK, tcp_in_link(robot)[0]) if n not in lab.positions or n not in lab.wxyz]
    return f"the page has no pose of {lacking}" if lacking else ""


def arm_shown(student: Student, lobby: Lobby) -> bool:
    """The page's lab is connected, reports its camera and has the poses the test reads."""
    return not arm_missing(student, lobby)


@pytest.fixture(scope="module")
def students(lobby: Lobby, browser: Any) -> Iterator[list[Student]]:
    """Two students, each in a browser context of their own, each with the lab page open."""
    out = []
    for _ in range(2):
        context = browser.new_context(viewport=VIEWPORT)
        context.add_init_script(PAGE_COUNTERS_JS)  # bench --classroom --chromium-pages's counters
        page = context.new_page()
        lab = LabSocket(page)
        page.goto(f"http://127.0.0.1:{lobby.bound_port}/", wait_until="commit")
        out.append(Student(context=context, page=page, lab=lab, seat=0))
    for s in out:  # both seats start at once
        s.seat = poll(s.page, lambda s=s: seat_of(s.page), 30, "the page's seat")
    for s in out:
        try:
            poll(s.page, lambda s=s: arm_shown(s, lobby), SEAT_START_S, f"seat {s.seat}'s arm in its page")
        except pytest.fail.Exception:
            pytest.fail(f"seat {s.seat}'s arm is not in its page: {arm_missing(s, lobby)}", pytrace=False)
    yield out
    for s in out:
        s.context.close()


def tcp(lab: LabSocket) -> np.ndarray:
    link, offset = tcp_in_link(robots.load(robots.DEFAULT_ROBOT))
    point = lab.point_world(link, offset)
    assert point is not None, f"the page has no pose of {link}"
    return point


PRESSES = 3  # presses on the link before a drag that takes no hold fails

# where the lab's page draws a link: the centre of its meshes' bounding box in the world, through the page's own
# camera (not the camera it last reported: a press computed from a report made before the page framed its view
# missed the arm); CSS px of the lab's frame, with what lies under that point in the frame
LINK_ON_SCREEN_JS = """(node) => {
    const m = window.__viserMutable, obj = m && m.nodeRefFromName[node];
    if (!m || !m.camera || !m.canvas || !obj) return null;
    obj.updateWorldMatrix(true, true);
    const lo = [Infinity, Infinity, Infinity], hi = [-Infinity, -Infinity, -Infinity];
    obj.traverse(o => {
        const g = o.geometry;
        if (!g) return;
        if (!g.boundingBox) g.computeBoundingBox();
        const b = g.boundingBox, e = o.matrixWorld.elements;
        for (const x of [b.min.x, b.max.x]) for (const y of [b.min.y, b.max.y]) for (const z of [b.min.z, b.max.z]) {
            const w = [0, 1, 2].map(r => e[r] * x + e[4 + r] * y + e[8 + r] * z + e[12 + r]);
            for (let i = 0; i < 3; i++) { lo[i] = Math.min(lo[i], w[i]); hi[i] = Math.max(hi[i], w[i]); }
        }
    });
    if (!(lo[0] <= hi[0])) return null;
    const p = [0, 1, 2].map(i => (lo[i] + hi[i]) / 2).concat([1]);
    const cam = m.camera;
    cam.updateMatrixWorld();
    const mul = (e, v) => [0, 1, 2, 3].map(r => e[r] * v[0] + e[4 + r] * v[1] + e[8 + r] * v[2] + e[12 + r] * v[3]);
    const c = mul(cam.projectionMatrix.elements, mul(cam.matrixWorldInverse.elements, p));
    if (!(c[3] > 0)) return null;
    const rect = m.canvas.getBoundingClientRect();
    const x = rect.x + (c[0] / c[3] + 1) / 2 * rect.width, y = rect.y + (1 - c[1] / c[3]) / 2 * rect.height;
    const under = document.elementFromPoint(x, y);
    return {x, y, under: under ? under.tagName + (under.className ? "." + String(under.className) : "") : ""};
}"""
FRAME_OFFSET_JS = """() => {
    const frame = document.getElementById("mine");
    if (!frame) return null;
    const r = frame.getBoundingClientRect();
    return {x: r.x + frame.clientLeft, y: r.y + frame.clientTop};
}"""


def link_on_screen(page: Any, link: str) -> dict[str, Any] | None:
    """Where the lab's page draws `link` (page px, `LINK_ON_SCREEN_JS`), and what lies there; None until it can
    tell."""
    element = page.query_selector("#mine")
    frame = element.content_frame() if element is not None else None
    offset = page.evaluate(FRAME_OFFSET_JS)
    if frame is None or offset is None:
        return None
    at = frame.evaluate(LINK_ON_SCREEN_JS, f"/robot/{link}/mesh")
    return None if at is None else {**at, "x": at["x"] + offset["x"], "y": at["y"] + offset["y"]}


def press_and_pull(student: Student, lobby: Lobby, link: str) -> None:
    """Press on `link` where the page draws it (`link_on_screen`) and pull up and to the left, button held,
    until the seat holds the arm with the drag spring (a press that takes no hold is made again, up to
    PRESSES times in all)."""
    page = student.page
    seat = lobby.pool.by_number(student.seat)
    assert seat is not None
    box = poll(page, lambda: page.evaluate(CANVAS_BOX_JS, SCENE_CANVAS), 60, "the lab's 3D view")
    pressed: list[tuple[int, int, str]] = []
    for _attempt in range(PRESSES):
        at = poll(page, lambda: link_on_screen(page, link), 30, f"{link} drawn in the lab's page")
        x, y = at["x"], at["y"]
        assert box["x"] < x < box["x"] + box["width"] and box["y"] < y < box["y"] + box["height"], (x, y, box)
        pressed.append((round(x), round(y), at["under"]))
        page.mouse.move(x, y)
        page.mouse.down()
        for k in range(1, 4):  # past the drag threshold
            page.mouse.move(x, y - 4 * k)
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline and not seat.status.get("drag"):
            page.wait_for_timeout(100)
        if seat.status.get("drag"):
            print(f"pressed {link} at {pressed} (page px, what lies there in the lab's frame)")
            for k in range(1, 7):
                page.mouse.move(x - 15 * k, y - 12 - 20 * k)
            return
        page.mouse.up()
        page.wait_for_timeout(500)
    pytest.fail(
        f"no drag of {link} in seat {student.seat}'s page after {PRESSES} presses at {pressed} (page px, what lies"
        f" there in the lab's frame; the 3D view {box}); the seat's status: {seat.status}",
        pytrace=False,
    )


def test_two_pages_get_two_seats_whose_arms_move_independently(lobby, students):
    a, b = students
    assert {a.seat, b.seat} == {1, 2}
    seat_a, seat_b = lobby.pool.by_number(a.seat), lobby.pool.by_number(b.seat)
    assert seat_a.proc.pid != seat_b.proc.pid and seat_a.port != seat_b.port
    tcp_a0, tcp_b0, frames_b0 = tcp(a.lab), tcp(b.lab), b.lab.frames
    counted_b0 = b.page.evaluate(LAB_COUNTS_JS)
    press_and_pull(a, lobby, PRESS_LINK)
    try:
        moved_a = poll(
            a.page,
            lambda: d if (d := float(np.linalg.norm(tcp(a.lab) - tcp_a0))) >= MOVED_M else 0.0,
            60,
            f"seat {a.seat}'s TCP to follow the drag by {MOVED_M * 100:g} cm",
        )
        moved_b = float(np.linalg.norm(tcp(b.lab) - tcp_b0))
        frames_b = b.lab.frames - frames_b0
        counted_b = b.page.evaluate(LAB_COUNTS_JS)
        print(
            f"dragged seat's TCP moved {moved_a * 100:.1f} cm, the other seat's {moved_b * 1000:.3f} mm "
            f"(its page received {frames_b} frames meanwhile)"
        )
        assert moved_a >= MOVED_M
        assert moved_b < AT_REST_M, moved_b  # the other student's arm, as their page shows it, stays at rest
        assert frames_b > 10  # while that page was live
        # the page's own count (bench --classroom --chromium-pages reads it) against the frames on its socket
        received_b = counted_b["received"] - counted_b0["received"]
        assert abs(received_b - frames_b) <= max(3, 0.05 * frames_b), (received_b, frames_b)
        assert counted_b["drawn"] > counted_b0["drawn"]  # and it drew its 3D view meanwhile
        assert seat_a.status["drag"] and not seat_b.status["drag"]  # held in one seat only, as each seat says
    finally:
        a.page.mouse.up()
    poll(a.page, lambda: not seat_a.status.get("drag"), 20, "mouse-up to release the drag")


def test_a_reload_returns_to_the_same_seat(lobby, students):
    a, _b = students
    seat = lobby.pool.by_number(a.seat)
    pid, port, opened = seat.proc.pid, seat.port, a.lab.opened
    a.lab.positions.clear()
    a.lab.wxyz.clear()
    a.lab.camera = None
    a.page.reload(wait_until="commit")
    poll(a.page, lambda: a.lab.opened > opened and arm_shown(a, lobby), 60, "the reloaded page's lab")
    assert seat_of(a.page) == a.seat
    assert f"seat {a.seat}" in a.page.locator(".bar").inner_text()
    assert (seat.proc.pid, seat.port) == (pid, port)  # the same process: the same arm, parameters, lessons
    poll(a.page, lambda: seat.pages == 1, 20, "the old page's socket to close")  # one page open on it, the new one


def test_a_lab_whose_connection_drops_opens_it_again_without_focus_and_receives_frames(lobby, students):
    """viser's client opens a dropped websocket again only while its document has focus, which the lab's
    frame has only after a click into it: such a lab (every page of bench --classroom --chromium-pages)
    received no frame after a drop."""
    _a, b = students
    frame_focused = "() => document.activeElement === document.getElementById('mine')"
    b.page.evaluate("() => { document.getElementById('mine').blur(); window.focus(); }")
    assert not b.page.evaluate(frame_focused)
    opened = b.lab.opened

    async def drop() -> None:
        for conn in list(lobby.pages.get(b.seat, ())):
            await conn.close(1011, "dropped by the test")

    lobby.call(drop)
    poll(b.page, lambda: b.lab.opened > opened, 20, "the lab's websocket to open again")
    frames0, counted0 = b.lab.frames, b.page.evaluate(LAB_COUNTS_JS)["received"]
    handed = poll(
        b.page,
        lambda: n if (n := b.page.evaluate(LAB_COUNTS_JS)["received"] - counted0) > 10 else 0,
        30,
        "more than 10 frames handed to the page on its reopened websocket",
    )
    print(f"reopened after the drop: {b.lab.frames - frames0} frames on its socket, {handed} handed to the page")
    assert handed > 10 and not b.page.evaluate(frame_focused)  # and still without focus


def test_a_page_without_the_teacher_token_is_refused_the_teacher_view(lobby, students, browser):
    a, _b = students
    base = f"http://127.0.0.1:{lobby.bound_port}"
    token = lobby.teacher_token
    wrong = token[:-1] + ("y" if token.endswith("x") else "x")
    stranger = browser.new_context(viewport=VIEWPORT)
    teacher = browser.new_context(viewport=VIEWPORT)
    try:
        for page in (a.page, stranger.new_page()):  # a student's page, a page with no cookie at all
            for path in ("/teacher/", f"/teacher?token={wrong}", "/teacher/seat/1/view/"):
                response = page.goto(base + path)
                assert response is not None and response.status == 403, (path, response and response.status)
                assert "403 Forbidden" in page.locator("body").inner_text()
            socket = page.evaluate(
                """url => new Promise(done => { const ws = new WebSocket(url);
                    ws.onopen = () => { ws.close(); done('open'); }; ws.onclose = () => done('refused'); })""",
                f"ws://127.0.0.1:{lobby.bound_port}/teacher/ws",
            )
            assert socket == "refused"
            assert not any(c["name"] == TEACHER_COOKIE for c in page.context.cookies())
        view = teacher.new_page()  # the teacher's link opens it
        response = view.goto(f"{base}/teacher?token={token}")
        assert response is not None and response.status == 200 and view.url == f"{base}/teacher/"
        poll(view, lambda: view.locator("body").inner_text().count("healthy") >= 2, 20, "both seats in the view")
    finally:
        stranger.close()
        teacher.close()
        a.page.goto(base + "/", wait_until="commit")  # back to the lab
        poll(a.page, lambda: arm_shown(a, lobby), 60, "the student's lab again")


def wait_ended(page: Any, seat_log: Any, proc: Any) -> None:
    poll(page, lambda: proc.returncode is not None and seat_log.ended, 20, "the seat's process to end")


def test_a_seat_stopped_with_its_page_connected_exits_cleanly_without_a_traceback(lobby, students):
    a, b = students
    seat_a, seat_b = lobby.pool.by_number(a.seat), lobby.pool.by_number(b.seat)
    poll(a.page, lambda: arm_shown(a, lobby) and arm_shown(b, lobby), 60, "both pages connected")
    # the lobby frees a seat (closes its pages' sockets, its command pipe, then SIGTERM) with its page open
    proc, log = seat_b.proc, seat_b.log
    lobby.call(lambda: lobby.pool.free(seat_b))
    wait_ended(b.page, log, proc)
    b.context.close()  # (the page would take the free seat again)
    print(f"freed seat: exit {proc.returncode}, stderr {list(log.lines)}")
    assert proc.returncode == 0, list(log.lines)
    assert not [line for line in log.lines if "Traceback" in line or "Exception ignored" in line]
    # SIGTERM again and again while it stops (a second stop signal once cut the shutdown short)
    proc, log = seat_a.proc, seat_a.log
    for _ in range(30):
        try:
            os.kill(proc.pid, signal.SIGTERM)
        except ProcessLookupError:
            break
        a.page.wait_for_timeout(10)
    wait_ended(a.page, log, proc)
    print(f"seat given SIGTERM repeatedly: exit {proc.returncode}, stderr {list(log.lines)}")
    assert proc.returncode == 0, list(log.lines)
    assert not [line for line in log.lines if "Traceback" in line or "Exception ignored" in line]
    assert seat_a.health() == "stopped: exit code 0"
