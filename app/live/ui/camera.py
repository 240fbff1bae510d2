"""Framing the robot: a camera pose that shows the arm in the 3D view's free area.

The arm (its link origins, the tool and the coupling ellipse beside the tool) is
seen from the front right, a little from above, so the coupling ellipse beside the tool shows its face
rather than its edge. The distance is chosen so the arm spans `HEIGHT_SHARE` of the view's height (and
at most `WIDTH_SHARE` of its width). The 3D view is the canvas between the docked panels, so centring
in the canvas centres in the free area.

`Framer` frames every page on a new preset or robot and then keeps the arm in view as it moves (a
settle phase can swing the elbow far from the start posture): when a point leaves the framed box by
more than `FOLLOW_TOLERANCE_M`, the pages whose camera is still where the app put it are framed again
on everything seen since the switch (widened by `FOLLOW_PAD` about its middle, not compounding), at
most once per `FOLLOW_PERIOD_S`, and not while a link is dragged. A page whose camera a person moved
is left alone until the next switch or *Frame the robot*. A new run of the same preset (a Reset, a lesson
step) frames the pages still placed by the app on its arm anew (`new_run`).

The cameras are written on the server's event loop thread (`on_server_loop`), where viser's asyncio
objects live: written from the publisher thread, a page connecting or leaving meanwhile made asyncio
raise "deque mutated during iteration" (its event's waiters changed while the write woke them).
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import math
import threading
import time
from collections.abc import Callable, Iterable
from typing import Any

import numpy as np
import viser

HEIGHT_SHARE = 0.8  # of the origins-plus-radius box: the drawn arm comes out smaller (perspective, link shapes)
WIDTH_SHARE = 0.85
AZIMUTH_DEG = -45.0  # from +x toward −y: the front right of an arm reaching along +x
ELEVATION_DEG = 28.0  # above the horizon: the ellipse's face is seen, not its edge
LINK_RADIUS_M = 0.07
DEFAULT_FOV_RAD = math.radians(75.0)  # viser's default vertical field of view
DEFAULT_ASPECT = 1.0  # the view between the two docked panels is about square
FOLLOW_TOLERANCE_M = 0.03  # a point this far outside the framed box (across the view) frames again
FOLLOW_PAD = 1.1  # a new framing takes what was seen, widened about its middle by this factor
FOLLOW_PERIOD_S = 0.5  # at most one new framing per this many seconds
PLACED_TOLERANCE_M = 0.01  # a camera within this of where the app put it is still the app's
LOOP_WAIT_S = 5.0  # the longest a framing waits for the server's event loop to write the cameras


def view_direction() -> np.ndarray:
    """Unit vector from the target toward the camera."""
    az, el = math.radians(AZIMUTH_DEG), math.radians(ELEVATION_DEG)
    return np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])


def frame_points(
    points: np.ndarray, fov_rad: float = DEFAULT_FOV_RAD, aspect: float = DEFAULT_ASPECT
) -> tuple[np.ndarray, np.ndarray]:
    """(camera position, look-at) that frame `points` (k, 3) as the module docstring says."""
    pts = np.asarray(points, dtype=float).reshape(-1, 3)
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    if len(pts) == 0:
        raise ValueError("no finite points to frame")
    back = view_direction()
    right = np.cross(back, np.array([0.0, 0.0, 1.0]))
    right /= np.linalg.norm(right)
    up = np.cross(right, back)
    u, v = pts @ right, pts @ up
    # link origins lie inside the links: widen by a link's radius
    du = 0.5 * float(u.max() - u.min()) + LINK_RADIUS_M
    dv = 0.5 * float(v.max() - v.min()) + LINK_RADIUS_M
    centre_depth = float(np.mean(pts @ back))
    look_at = right * 0.5 * (u.max() + u.min()) + up * 0.5 * (v.max() + v.min()) + back * centre_depth
    tan_half = math.tan(0.5 * fov_rad)
    distance = max(dv / (HEIGHT_SHARE * tan_half), du / (WIDTH_SHARE * tan_half * aspect), 0.3)
    # the nearest points sit closer to the camera than the centre: back off by their depth
    distance += max(0.0, float(np.max(pts @ back)) - centre_depth)
    return look_at + distance * back, look_at


def view_basis() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(across, up, back): unit vectors of the framing's view (across the image, up in it, toward the camera)."""
    back = view_direction()
    across = np.cross(back, np.array([0.0, 0.0, 1.0]))
    across /= np.linalg.norm(across)
    return across, np.cross(across, back), back


def robot_points(scene: Any, extra: np.ndarray | None = None) -> np.ndarray | None:
    """The link origins and the tool of a scene snapshot, and `extra` points (the coupling disc beside the
    tool), or None without a snapshot."""
    if scene is None:
        return None
    parts = [np.asarray(scene.link_positions, dtype=float), np.asarray(scene.tcp_position, dtype=float)[None, :]]
    if extra is not None:
        parts.append(np.asarray(extra, dtype=float).reshape(-1, 3))
    return np.vstack(parts)


def on_server_loop(server: Any, fn: Callable[[], Any], timeout: float = LOOP_WAIT_S) -> Any:
    """`fn()` run on the server's event loop thread, waited for (TimeoutError after `timeout`); run here
    when called on that thread, or for a server without an event loop (a stand-in in tests). A stopped
    server's closed loop runs nothing: None."""
    get_loop = getattr(server, "get_event_loop", None)
    if get_loop is None:
        return fn()
    loop = get_loop()
    try:
        running = asyncio.get_running_loop()
    except RuntimeError:
        running = None
    if running is loop:
        return fn()
    done: concurrent.futures.Future = concurrent.futures.Future()

    def run() -> None:
        try:
            done.set_result(fn())
        except BaseException as exc:
            done.set_exception(exc)

    try:
        loop.call_soon_threadsafe(run)
    except RuntimeError:  # the loop is closed: no page to write to
        return None
    return done.result(timeout)


def frame_cameras(
    server: viser.ViserServer, points: np.ndarray, clients: Iterable[viser.ClientHandle] | None = None
) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """`write_cameras` on the server's event loop thread (see the module docstring); {} for a stopped server."""
    chosen = None if clients is None else list(clients)
    return on_server_loop(server, lambda: write_cameras(server, points, chosen)) or {}


def write_cameras(
    server: viser.ViserServer, points: np.ndarray, clients: Iterable[viser.ClientHandle] | None = None
) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Frame `points` for the initial camera and the given clients (every connected client when None);
    returns the (position, look-at) each client was given, by client id."""
    position, look_at = frame_points(points)
    server.initial_camera.position = tuple(position)
    server.initial_camera.look_at = tuple(look_at)
    server.initial_camera.up = (0.0, 0.0, 1.0)
    placed: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    for client in server.get_clients().values() if clients is None else clients:
        cam = client.camera
        aspect = cam.image_width / cam.image_height if cam.image_width > 0 and cam.image_height > 0 else DEFAULT_ASPECT
        fov = float(cam.fov) if 0.1 < float(cam.fov) < 3.0 else DEFAULT_FOV_RAD
        position, look_at = frame_points(points, fov, aspect)
        with client.atomic():
            cam.up_direction = (0.0, 0.0, 1.0)
            cam.position = tuple(position)
            cam.look_at = tuple(look_at)
        placed[client.client_id] = (position, look_at)
    return placed


def extremes(points: np.ndarray) -> np.ndarray:
    """The rows of `points` that bound it across, up and along the view (at most six): what framing them
    gives is what framing all of them gives, but for the mean depth."""
    basis = np.stack(view_basis(), axis=1)
    coords = points @ basis
    rows = {int(i) for k in range(3) for i in (np.argmin(coords[:, k]), np.argmax(coords[:, k]))}
    return points[sorted(rows)]


class Framer:
    """Frames the pages' cameras on the arm and keeps it in view (see the module docstring)."""

    def __init__(self, server: viser.ViserServer, clock: Callable[[], float] = time.monotonic):
        self.server = server
        self._clock = clock
        self._lock = threading.Lock()  # the publisher thread and a connecting page's callback both frame
        self.seen: np.ndarray | None = None  # the extremes of every point seen since the last switch
        self.framed: np.ndarray | None = None  # the points framed last (`seen`, widened after a follow)
        self.placed: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # client id → the pose the app gave it
        self.reframes = 0  # framings after the first since the last switch (the arm left the view)
        self._next = 0.0

    def frame(self, points: np.ndarray, clients: Iterable[viser.ClientHandle] | None = None) -> None:
        """Frame `points` anew (a switch, *Frame the robot*): every client when None."""
        with self._lock:
            pts = extremes(np.asarray(points, dtype=float))
            if clients is None:
                self.seen = self.framed = pts
                self.reframes = 0
                self.placed = {}
            else:
                self.seen = pts if self.seen is None else extremes(np.vstack([self.seen, pts]))
                self.framed = pts = self.seen if self.framed is None else extremes(np.vstack([self.framed, pts]))
            self.placed.update(frame_cameras(self.server, pts, clients))

    def new_run(self, points: np.ndarray) -> None:
        """A new run of the same preset (a Reset, a lesson step): forget what the last run swept and frame
        `points` anew on the pages whose camera is still where the app put it (after a thrash had widened
        the framed box, those pages stayed zoomed out on an arm at rest)."""
        with self._lock:
            self.seen = self.framed = framed = extremes(np.asarray(points, dtype=float))
            self.reframes = 0

            def still_placed() -> dict[int, tuple[np.ndarray, np.ndarray]]:
                clients = [c for cid, c in self.server.get_clients().items() if self._still_placed(cid, c)]
                return write_cameras(self.server, framed, clients)

            self.placed.update(on_server_loop(self.server, still_placed) or {})

    def frame_new_client(self, points: np.ndarray | None, client: viser.ClientHandle) -> bool:
        """A page that just connected: frame it on what is framed for the others (else `points`)."""
        with self._lock:
            pts = self.framed if self.framed is not None else points
            if pts is None:
                return False
            self.placed.update(frame_cameras(self.server, pts, [client]))
            return True

    def follow(self, points: np.ndarray) -> bool:
        """Frame again if `points` left the framed box (see the module docstring); True if it did."""
        with self._lock:
            if self.framed is None or self.seen is None or self._clock() < self._next:
                return False
            pts = np.asarray(points, dtype=float)
            pts = pts[np.all(np.isfinite(pts), axis=1)]
            if len(pts) == 0:
                return False
            across, up, _ = view_basis()
            plane = np.stack([across, up], axis=1)
            box, now = self.framed @ plane, pts @ plane
            lo, hi = box.min(axis=0) - FOLLOW_TOLERANCE_M, box.max(axis=0) + FOLLOW_TOLERANCE_M
            if np.all((now >= lo) & (now <= hi)):
                return False
            self.seen = seen = extremes(np.vstack([self.seen, pts]))
            middle = 0.5 * (seen.min(axis=0) + seen.max(axis=0))
            self.framed = middle + FOLLOW_PAD * (seen - middle)
            self._next = self._clock() + FOLLOW_PERIOD_S
            framed = self.framed

            def still_placed() -> dict[int, tuple[np.ndarray, np.ndarray]]:  # the clients read on the loop too
                clients = [c for cid, c in self.server.get_clients().items() if self._still_placed(cid, c)]
                return write_cameras(self.server, framed, clients)

            self.placed.update(on_server_loop(self.server, still_placed) or {})
            self.reframes += 1
            return True

    def _still_placed(self, client_id: int, client: viser.ClientHandle) -> bool:
        pose = self.placed.get(client_id)
        if pose is None:
            return False
        cam = client.camera
        return bool(
            np.allclose(np.asarray(cam.position), pose[0], atol=PLACED_TOLERANCE_M)
            and np.allclose(np.asarray(cam.look_at), pose[1], atol=PLACED_TOLERANCE_M)
        )


def frame_on_connect(framer: Framer, points_of: Callable[[], np.ndarray | None]) -> set[int]:
    """Frame each page's camera once, as soon as it reports its view size (`points_of()` gives the newest
    scene's points); returns the set of the open pages' client ids framed so far (a page leaves it as it
    disconnects)."""
    framed: set[int] = set()
    framer.server.on_client_disconnect(lambda client: framed.discard(client.client_id))

    @framer.server.on_client_connect
    def _(client: viser.ClientHandle) -> None:
        @client.camera.on_update
        def _(camera: Any) -> None:
            if client.client_id in framed or camera.image_width <= 0:
                return
            if framer.frame_new_client(points_of(), client):
                framed.add(client.client_id)

    return framed
