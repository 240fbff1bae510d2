"""The Franka Panda in the real page (headless Chromium, the harness of tests/test_browser.py): the app
serves `--robot panda`, the page draws the Panda's meshes, and a drag on its hand moves the arm."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest

from app.tools.bench_serve import CHROMIUM_ARGS
from robots import external
from tests.conftest import free_port
from tests.test_browser import chromium_path, drag_along_the_spring, drag_state, open_page, wait_for

pytestmark = [
    pytest.mark.browser,
    pytest.mark.usefixtures("warm_kernels"),
    pytest.mark.skipif(not external.installed("panda"), reason="needs the robots extra (example-robot-data)"),
]

PANDA_VISUAL_LINKS = {f"panda_link{i}" for i in range(8)} | {"panda_hand", "panda_leftfinger", "panda_rightfinger"}
DRAG_LINK = "panda_hand"  # the TCP's link


@pytest.fixture(scope="module")
def panda_app() -> Iterator[Any]:
    from app.live.server import start_app

    running = start_app("127.0.0.1", free_port(), "free", "panda")
    try:
        yield running
    finally:
        running.stop()


@pytest.fixture(scope="module")
def chromium() -> Iterator[Any]:
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=chromium_path(), headless=True, args=CHROMIUM_ARGS)
        try:
            yield b
        finally:
            b.close()


def test_the_page_draws_the_pandas_meshes_and_a_drag_on_its_hand_moves_the_arm(panda_app, chromium):
    """The scene holds one mesh node per Panda link with a visual, each the real DAE (> 500 faces); a
    press on the hand's drawn mesh in the page grabs panda_hand (the page picked that node), and
    moving the pointer pulls the TCP more than 1 cm along the spring with more than 5 N; mouse-up
    releases it."""
    app = panda_app
    page, client = open_page(app, chromium)
    try:
        scene = wait_for(lambda: app.publisher.scene, 30, "the scene of the Panda")
        assert set(scene.meshes) == PANDA_VISUAL_LINKS
        assert all(len(scene._link_shapes[name].faces) > 500 for name in PANDA_VISUAL_LINKS)
        assert all(scene.meshes[name].visible for name in PANDA_VISUAL_LINKS)
        tcp0, q0 = app.loop.call(lambda s: (s.dyn.tcp_position_world.copy(), s.world.q.copy()))
        moved, peak = drag_along_the_spring(page, client, app, DRAG_LINK, "the hand to follow the spring by 1 cm")
        tcp, q = app.loop.call(lambda s: (s.dyn.tcp_position_world.copy(), s.world.q.copy()))
        shift = float(np.linalg.norm(tcp - tcp0))
        print(
            f"Panda drag: hand {moved * 1e3:.1f} mm along the pull, TCP moved {shift * 1e3:.1f} mm,"
            f" joints up to {np.max(np.abs(q - q0)):.3f} rad, peak spring force {peak:.1f} N"
        )
        assert moved > 0.01 and peak > 5.0
        assert shift > 0.01
        page.mouse.up()
        wait_for(lambda: drag_state(app).body is None, 20, "mouse-up to release the drag")
    finally:
        page.mouse.up()
        page.close()
