"""Framing the arm (app.live.ui.camera): a switch frames every page, a moving arm that leaves the framed
box frames again the pages whose camera the app placed, and a camera a person moved is left alone."""

from __future__ import annotations

import contextlib
import math
from types import SimpleNamespace

import numpy as np
import pytest

from app.live.ui.camera import (
    DEFAULT_FOV_RAD,
    FOLLOW_PERIOD_S,
    FOLLOW_TOLERANCE_M,
    Framer,
    frame_points,
    view_basis,
)


class FakeCamera:
    def __init__(self) -> None:
        self.position = np.array([2.0, 2.0, 2.0])
        self.look_at = np.zeros(3)
        self.up_direction = (0.0, 0.0, 1.0)
        self.fov = DEFAULT_FOV_RAD
        self.image_width, self.image_height = 800, 1000


class FakeClient:
    def __init__(self, client_id: int) -> None:
        self.client_id = client_id
        self.camera = FakeCamera()

    def atomic(self) -> contextlib.AbstractContextManager[None]:
        return contextlib.nullcontext()


class FakeServer:
    def __init__(self, n: int) -> None:
        self.clients = {i: FakeClient(i) for i in range(n)}
        self.initial_camera = SimpleNamespace(position=None, look_at=None, up=None)

    def get_clients(self) -> dict[int, FakeClient]:
        return self.clients


def in_view(camera: FakeCamera, points: np.ndarray) -> np.ndarray:
    """Each point's image coordinates in [−1, 1]² (x across, y up) for a camera at its position looking at
    its look-at with +z up and the camera's fov and aspect."""
    position = np.asarray(camera.position, dtype=float)
    forward = np.asarray(camera.look_at, dtype=float) - position
    forward = forward / np.linalg.norm(forward)
    across = np.cross(forward, [0.0, 0.0, 1.0])
    across /= np.linalg.norm(across)
    up = np.cross(across, forward)
    rel = points - position
    depth = rel @ forward
    assert np.all(depth > 0)
    tan_half = math.tan(0.5 * camera.fov)
    aspect = camera.image_width / camera.image_height
    return np.stack([(rel @ across) / depth / (tan_half * aspect), (rel @ up) / depth / tan_half], axis=1)


ARM = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.3], [0.2, -0.1, 0.6], [0.45, -0.2, 0.5], [0.6, -0.2, 0.2]])


def test_a_switch_frames_every_page_on_the_arm_inside_the_view():
    server = FakeServer(2)
    framer = Framer(server)  # type: ignore[arg-type]
    framer.frame(ARM)
    for client in server.clients.values():
        xy = in_view(client.camera, ARM)
        assert np.all(np.abs(xy) < 0.95), xy  # every point inside the image, none on its edge
        assert np.allclose(client.camera.position, framer.placed[client.client_id][0])
    assert server.initial_camera.position is not None


def test_an_arm_leaving_the_framed_box_is_framed_again_except_on_a_camera_a_person_moved():
    now = [0.0]
    server = FakeServer(2)
    framer = Framer(server, clock=lambda: now[0])  # type: ignore[arg-type]
    framer.frame(ARM)
    across, up, _ = view_basis()
    assert not framer.follow(ARM + 0.5 * FOLLOW_TOLERANCE_M * across)  # inside the tolerance: no new framing
    moved = server.clients[1].camera
    moved.position = np.asarray(moved.position) + np.array([0.3, 0.0, 0.0])  # a person orbits page 1
    person = moved.position.copy()
    swung = ARM.copy()
    swung[2] += 0.4 * across + 0.2 * up  # the elbow swings far out
    assert framer.follow(swung)
    assert framer.reframes == 1
    page0 = server.clients[0].camera
    xy = in_view(page0, np.vstack([ARM, swung]))
    assert np.all(np.abs(xy) < 0.95), xy  # both postures in page 0's view
    assert np.allclose(moved.position, person)  # page 1 kept the person's camera
    swung[3] -= 0.8 * across  # the forearm the other way, beyond the widened box
    assert not framer.follow(swung)  # within FOLLOW_PERIOD_S of the last framing
    now[0] += FOLLOW_PERIOD_S + 0.01
    assert framer.follow(swung) and framer.reframes == 2
    assert np.all(np.abs(in_view(page0, swung)) < 0.95)
    framer.frame(ARM)  # a switch: every page again, the count starts anew
    assert framer.reframes == 0 and np.allclose(moved.position, framer.placed[1][0])


def test_frame_points_looks_from_the_front_right_above():
    position, look_at = frame_points(ARM)
    direction = (position - look_at) / np.linalg.norm(position - look_at)
    assert direction[0] > 0 and direction[1] < 0 and direction[2] > 0


def test_a_new_run_frames_the_arm_at_rest_again_after_a_thrash_widened_the_view():
    """A thrash swings the arm far out and the pages zoom out; the next run (a Reset) frames the arm at
    rest again on the pages still placed by the app (the view shrinks back), not on a page a person moved."""
    now = [0.0]
    server = FakeServer(2)
    framer = Framer(server, clock=lambda: now[0])  # type: ignore[arg-type]
    framer.frame(ARM)
    page0, moved = server.clients[0].camera, server.clients[1].camera
    near = float(np.linalg.norm(np.asarray(page0.position) - np.asarray(page0.look_at)))
    across, up, _ = view_basis()
    thrash = ARM.copy()
    thrash[2:] += 0.8 * across + 0.5 * up
    now[0] += FOLLOW_PERIOD_S + 0.01
    assert framer.follow(thrash)
    far = float(np.linalg.norm(np.asarray(page0.position) - np.asarray(page0.look_at)))
    assert far > 1.2 * near  # zoomed out for the thrash
    moved.position = np.asarray(moved.position) + np.array([0.3, 0.0, 0.0])
    person = moved.position.copy()
    framer.new_run(ARM)
    again = float(np.linalg.norm(np.asarray(page0.position) - np.asarray(page0.look_at)))
    assert again == pytest.approx(near, rel=1e-6)  # the arm at rest framed as at the start
    assert np.allclose(moved.position, person)
