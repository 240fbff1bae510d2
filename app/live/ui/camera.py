"""Framing the robot: a camera pose that shows the arm in the 3D view's free area.

The arm (its link origins and the tool) is seen from the front right, a little from above, so the
coupling ellipse above the tool shows its face rather than its edge. The distance is chosen so
the arm spans `HEIGHT_SHARE` of the view's height (and at most `WIDTH_SHARE` of its width). The 3D
view is the canvas between the docked panels, so centring in the canvas centres in the free area.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import Any

import numpy as np
import viser

HEIGHT_SHARE = 0.7  # of the origins-plus-radius box: the drawn arm comes out at ≈ 60 % (perspective, link shapes)
WIDTH_SHARE = 0.8
AZIMUTH_DEG = -45.0  # from +x toward −y: the front right of an arm reaching along +x
ELEVATION_DEG = 28.0  # above the horizon: the ellipse's face is seen, not its edge
LINK_RADIUS_M = 0.07
DEFAULT_FOV_RAD = math.radians(75.0)  # viser's default vertical field of view
DEFAULT_ASPECT = 1.0  # the view between the two docked panels is about square


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


def robot_points(scene: Any) -> np.ndarray | None:
    """The link origins and the tool of a scene snapshot, or None without one."""
    if scene is None:
        return None
    return np.vstack([np.asarray(scene.link_positions, dtype=float), np.asarray(scene.tcp_position)[None, :]])


def frame_robot(server: viser.ViserServer, scene: Any, clients: Iterable[viser.ClientHandle] | None = None) -> bool:
    """Point the initial camera (for pages that connect later) and the given clients' cameras (every
    connected client when None) at the arm; False when there is no scene to frame."""
    points = robot_points(scene)
    if points is None:
        return False
    position, look_at = frame_points(points)
    server.initial_camera.position = tuple(position)
    server.initial_camera.look_at = tuple(look_at)
    server.initial_camera.up = (0.0, 0.0, 1.0)
    for client in server.get_clients().values() if clients is None else clients:
        cam = client.camera
        aspect = cam.image_width / cam.image_height if cam.image_width > 0 and cam.image_height > 0 else DEFAULT_ASPECT
        fov = float(cam.fov) if 0.1 < float(cam.fov) < 3.0 else DEFAULT_FOV_RAD
        position, look_at = frame_points(points, fov, aspect)
        with client.atomic():
            cam.up_direction = (0.0, 0.0, 1.0)
            cam.position = tuple(position)
            cam.look_at = tuple(look_at)
    return True


def frame_on_connect(server: viser.ViserServer, scene_of: Any) -> set[int]:
    """Frame each page's camera once, as soon as it reports its view size (`scene_of()` gives the
    newest scene snapshot); returns the set of client ids framed so far (it fills as pages connect)."""
    framed: set[int] = set()

    @server.on_client_connect
    def _(client: viser.ClientHandle) -> None:
        @client.camera.on_update
        def _(camera: Any) -> None:
            if client.client_id not in framed and camera.image_width > 0 and frame_robot(server, scene_of(), [client]):
                framed.add(client.client_id)

    return framed
