"""The real page in headless Chromium against a server this module starts in-process.

Chromium: $TORQUELAB_CHROMIUM, else /usr/bin/chromium (scripts/test.sh installs it); a missing
browser fails the tests with the reason instead of skipping them. Software WebGL on two cores is
slow (a mouse move waits ~0.3 s for a frame), so every check polls for its condition with a
generous timeout instead of sleeping a fixed time.

Projection for clicks (DESIGN §6): the test sets the page's camera from the server, reads back
position, orientation (OpenCV-style: +z forward, +y down), vertical fov and image size, and
maps a world point to CSS pixels of the canvas.
"""

from __future__ import annotations

import functools
import itertools
import os
import re
import shutil
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import pytest
import viser.transforms as vtf

from app.tools.bench_serve import CHROMIUM_ARGS
from tests.conftest import free_port

pytestmark = [pytest.mark.browser, pytest.mark.usefixtures("warm_kernels")]

ROOT = Path(__file__).resolve().parents[1]
ARTIFACTS = ROOT / "test-artifacts"
README_SCREENSHOT = ROOT / "static" / "screenshot.png"
VIEWPORT = {"width": 1600, "height": 1000}  # the plots dock left, the controls right: the 3D view is between
SCREENSHOT_VIEWPORT = {"width": 1600, "height": 1000}
PANEL_WIDTH_PX = 420  # the control panel covers the right of the page
CAMERA_POSITION = np.array([0.55, -1.45, 0.75])  # side view of the polishing arm, elbow left of centre
CAMERA_LOOK_AT = np.array([0.35, 0.0, 0.45])
SCENE_CANVAS = "canvas[data-engine^=three]"  # the 3D view (the plots and a 0×0 helper draw on other canvases)
DRAG_LINK = "link4"  # the elbow link: free in the nullspace while the tool presses the table


def chromium_path() -> str:
    """The Chromium binary for Playwright; fails (not skips) with the fix when there is none."""
    for candidate in (os.environ.get("TORQUELAB_CHROMIUM"), "/usr/bin/chromium", "/usr/bin/chromium-browser"):
        if candidate and os.path.isfile(candidate) and os.access(candidate, os.X_OK):
            return candidate
    pytest.fail(
        "no Chromium for the browser tests: run scripts/test.sh (installs Debian's chromium) or set "
        "TORQUELAB_CHROMIUM to a Chromium binary",
        pytrace=False,
    )


def wait_for(condition: Callable[[], Any], timeout: float, what: str, period: float = 0.1) -> Any:
    """Poll `condition` until it returns something truthy; fail naming `what` after `timeout` s."""
    deadline = time.monotonic() + timeout
    while True:
        value = condition()
        if value:
            return value
        if time.monotonic() > deadline:
            pytest.fail(f"timed out after {timeout:.0f} s waiting for {what}", pytrace=False)
        time.sleep(period)


# ---- fixtures -----------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def app() -> Iterator[Any]:
    from app.live.server import start_app

    running = start_app("127.0.0.1", free_port(), "polish", "rizon4s", "projection")
    try:
        yield running
    finally:
        running.stop()


@pytest.fixture(scope="module")
def browser() -> Iterator[Any]:
    from playwright.sync_api import sync_playwright

    path = chromium_path()
    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=path, headless=True, args=CHROMIUM_ARGS)
        try:
            yield b
        finally:
            b.close()


def open_page(app: Any, browser: Any) -> tuple[Any, Any]:
    """A new page on the app and the server's handle of its client."""
    before = set(app.server.get_clients())
    page = browser.new_page(viewport=VIEWPORT)
    page.goto(app.url)
    # the 3D view (a 0×0 helper canvas may come first); a software-rendered page on a loaded machine
    # has taken over 100 s to show it
    page.wait_for_selector(SCENE_CANVAS, timeout=180_000)
    new = wait_for(lambda: set(app.server.get_clients()) - before, 60, "the page to connect")
    client = app.server.get_clients()[min(new)]
    wait_for(lambda: client.camera.image_width > 0, 30, "the page to report its camera")
    wait_for(lambda: client.client_id in app.publisher.framed_clients, 30, "the app to frame the robot")
    time.sleep(0.5)  # the framing's camera message reaches the page before a test moves the camera
    return page, client


@pytest.fixture(scope="module")
def page(app: Any, browser: Any) -> Iterator[tuple[Any, Any]]:
    """One page for the module (the disconnect test, last, closes it)."""
    page, client = open_page(app, browser)
    # The page's first few pointer moves stall for seconds once (software WebGL sets up picking):
    # take that hit here, over empty floor, instead of inside a drag.
    for k in range(6):
        page.mouse.move(120 + 10 * k, VIEWPORT["height"] - 80)
    try:
        yield page, client
    finally:
        if not page.is_closed():
            page.close()


@pytest.fixture
def paused(app: Any) -> Iterator[None]:
    """The simulation paused for a test that only clicks and reads (a running simulation keeps a
    software-rendered page busy, so each click waits seconds); it plays again afterwards."""
    from app.core.commands import Pause, Play

    app.loop.submit(Pause())
    app.loop.sync()
    try:
        yield
    finally:
        app.loop.submit(Play())


@pytest.fixture
def unpaced(app: Any) -> Iterator[None]:
    """The simulation as fast as the machine allows (`SetSpeed(UNPACED_SPEED)`) for a test that reads what
    a lesson's run shows at its end: a step's numbers depend on its steps, not on the wall clock, and the
    page draws a paused step's end as it draws it paced. Speed 1 again afterwards."""
    from app.core.commands import SetSpeed
    from app.live.run_flags import UNPACED_SPEED

    app.loop.submit(SetSpeed(UNPACED_SPEED))
    try:
        yield
    finally:
        app.loop.submit(SetSpeed(1.0))


# ---- camera and projection ------------------------------------------------------------------------
class CameraReports:
    """The camera poses the page itself reports (viser replaces `client.camera`'s state with each one,
    so right after a setter the state says where the page is told to go, not where it is)."""

    def __init__(self, client: Any):
        self.poses: list[tuple[np.ndarray, np.ndarray]] = []
        client.camera.on_update(self._record)

    def _record(self, camera: Any) -> None:
        self.poses.append((np.array(camera.position), np.array(camera.look_at)))


# per client handle, the handle kept beside its reports: client ids restart at 0 with every server,
# so an id alone would hand a later module's client the reports of an earlier server's one
_CAMERA_REPORTS: dict[int, tuple[Any, CameraReports]] = {}


def set_camera(client: Any, position: np.ndarray, look_at: np.ndarray, app: Any = None) -> None:
    """Put the page's camera at a known pose (position first, then look_at) and wait until the page
    reports that pose back. With `app`, first wait until the app has framed a newly chosen preset,
    so that framing cannot move the camera after this."""
    if app is not None:
        wait_for(lambda: not app.publisher.framing_pending, 30, "the app to frame the new preset")
    held = _CAMERA_REPORTS.get(client.client_id)
    if held is None or held[0] is not client:
        held = _CAMERA_REPORTS[client.client_id] = (client, CameraReports(client))
    reports = held[1]

    def at_pose(p: np.ndarray, a: np.ndarray) -> bool:
        return bool(np.allclose(p, position, atol=1e-3) and np.allclose(a, look_at, atol=1e-3))

    seen = len(reports.poses)
    if at_pose(client.camera.position, client.camera.look_at):
        # viser sends nothing for a pose its state already holds: move away first, so the page reports
        client.camera.position = np.asarray(position) + np.array([0.0, 0.0, 0.01])
    client.camera.position = position
    client.camera.look_at = look_at
    client.camera.up_direction = (0.0, 0.0, 1.0)
    wait_for(
        lambda: (
            any(at_pose(p, a) for p, a in reports.poses[seen:])
            and at_pose(client.camera.position, client.camera.look_at)
        ),
        20,
        "the page to report the camera at the new pose",
    )


def project(client: Any, canvas_box: dict[str, float], point_world: np.ndarray) -> tuple[float, float]:
    """CSS pixel (page coordinates) of a world point for the page's camera (DESIGN §6)."""
    cam = client.camera
    R_world_cam = vtf.SO3(np.asarray(cam.wxyz)).as_matrix()
    p_cam = R_world_cam.T @ (np.asarray(point_world, dtype=float) - np.asarray(cam.position))
    assert p_cam[2] > 0, "the point is behind the camera"
    H, W = float(cam.image_height), float(cam.image_width)
    f = 0.5 * H / np.tan(0.5 * float(cam.fov))
    u = f * p_cam[0] / p_cam[2] + 0.5 * W
    v = f * p_cam[1] / p_cam[2] + 0.5 * H
    return canvas_box["x"] + u * canvas_box["width"] / W, canvas_box["y"] + v * canvas_box["height"] / H


def link_point_world(app: Any, link: str) -> np.ndarray:
    """World position of the centroid of a link's drawn mesh (a point on the link, inside its shape)."""

    def read(session: Any) -> tuple[np.ndarray, np.ndarray]:
        body = session.world.model.body(link).id
        return session.world.data.xpos[body].copy(), session.world.data.xmat[body].reshape(3, 3).copy()

    position, rotation = app.loop.call(read)
    centroid = _link_centroids(str(app.loop.call(lambda s: s.robot.urdf_path)))[link]
    return position + rotation @ centroid


@functools.cache
def _link_centroids(urdf_path: str) -> dict[str, np.ndarray]:
    from app.live.ui.scene import link_meshes

    return {name: np.array(mesh.centroid) for name, mesh in link_meshes(urdf_path).items()}


class DragView(NamedTuple):
    """The drag spring as the loop thread sees it."""

    body: str | None  # grabbed link, None when released
    force_n: float  # |spring force| applied in the last step
    point: np.ndarray | None  # grabbed point, world
    target: np.ndarray | None  # where the spring pulls it, world


def drag_state(app: Any) -> DragView:
    """The drag spring, read between two steps of the loop thread."""

    def read(session: Any) -> DragView:
        drag = session.drag
        if not drag.active:
            return DragView(None, 0.0, None, None)
        name = session.world.model.body(drag.body_id).name
        force = 0.0 if drag.state is None else float(np.linalg.norm(drag.state.force_world))
        return DragView(name, force, drag.point_world(session.world).copy(), drag.target_world.copy())

    return app.loop.call(read)


def start_drag(page: Any, client: Any, app: Any, link: str, attempts: int = 2) -> tuple[float, float]:
    """Press on the link and move until the server holds a drag of that link; returns the pointer.
    A press the page does not turn into a drag within 10 s (a software-rendered page on a loaded
    machine) is let go and made again where the link is then, up to `attempts` presses; each retry
    is printed with the body the server holds then."""
    box = page.locator(SCENE_CANVAS).first.bounding_box()
    for attempt in range(1, attempts + 1):
        set_camera(client, CAMERA_POSITION, CAMERA_LOOK_AT, app)
        x, y = project(client, box, link_point_world(app, link))
        inside = box["x"] + 40 < x < box["x"] + box["width"] - 40 and 160 < y < box["height"] - 40
        assert inside, f"{link} projects off the 3D view: {x, y} in {box}"
        page.mouse.move(x, y)
        page.mouse.down()
        for k in range(1, 4):  # past the ~3 px drag threshold
            page.mouse.move(x, y - 4 * k)
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline:
            if drag_state(app).body == link:
                return x, y - 12
            time.sleep(0.1)
        print(
            f"press {attempt} on {link} at {x:.0f}, {y:.0f} gave no drag (server holds {drag_state(app).body!r}; "
            f"camera at {np.round(client.camera.position, 3)} looking at {np.round(client.camera.look_at, 3)})"
        )
        page.mouse.up()
    pytest.fail(f"no drag of {link} after {attempts} presses", pytrace=False)


def drag_along_the_spring(page: Any, client: Any, app: Any, link: str, what: str) -> tuple[float, float]:
    """Press on `link`, move the pointer five times up and to the left (~25 px each) and wait until the
    grabbed point has followed the spring's pull by more than 1 cm (`what` names it in a timeout); returns
    (m moved along the pull, peak spring force in N). The button stays down: the caller releases it."""
    x, y = start_drag(page, client, app, link)
    start = drag_state(app).point
    assert start is not None
    peak = 0.0
    for k in range(1, 6):
        page.mouse.move(x - 15 * k, y - 20 * k)
        peak = max(peak, drag_state(app).force_n)

    def pulled_along_the_spring() -> float:
        """Displacement (m) of the grabbed point along the spring's pull direction since the grab."""
        view = drag_state(app)
        if view.point is None or view.target is None or np.linalg.norm(view.target - start) < 0.02:
            return 0.0
        pull = (view.target - start) / np.linalg.norm(view.target - start)
        along = float((view.point - start) @ pull)
        return along if along > 0.01 else 0.0

    moved = wait_for(pulled_along_the_spring, 30, what)
    return moved, max(peak, drag_state(app).force_n)


# ---- GUI controls -----------------------------------------------------------------------------------
_CONTROL_JS = """([pattern, role]) => {
    const re = new RegExp(pattern);
    for (const label of document.querySelectorAll('label')) {
        if (!re.test(label.textContent.trim())) continue;
        const el = document.getElementById(label.htmlFor);
        if (el && (el.getAttribute('role') === role || el.querySelector(`[role=${role}]`))) return true;
    }
    return false;
}"""


def has_control(pg: Any, label_pattern: str, role: str) -> bool:
    """True if the page shows a control of `role` ("slider", "combobox") whose label matches."""
    return bool(pg.evaluate(_CONTROL_JS, [label_pattern, role]))


def open_tab(pg: Any, name: str, timeout_ms: float | None = None) -> None:
    """Show the control panel's tab `name` (Run, Tune, Visuals, Record); waits up to `timeout_ms` (the
    page's default timeout when None)."""
    pg.get_by_role("tab", name=name).click(timeout=timeout_ms)


def show_tab(pg: Any, name: str) -> None:
    """Show the control panel's tab `name`, clicking it only when another is shown (a click waits for a
    busy page to settle)."""
    tab = pg.get_by_role("tab", name=name)
    if tab.get_attribute("aria-selected") != "true":
        tab.click()


def choose(pg: Any, label: str, option: str) -> list[str]:
    """Open the dropdown labelled `label`, pick `option`; returns all the options it offered."""
    box = pg.get_by_label(label, exact=True)
    box.scroll_into_view_if_needed()
    box.click()
    options = pg.get_by_role("option")
    options.first.wait_for(timeout=20_000)
    offered = [t.strip() for t in options.all_inner_texts()]
    pg.get_by_role("option", name=option, exact=True).click()
    return offered


# ---- tests ------------------------------------------------------------------------------------------
def test_page_loads_and_draws_the_robot_where_the_camera_projects_it(app, page):
    from app.core.commands import Pause, Play

    pg, client = page
    app.loop.submit(Pause())  # a still arm: the projected points stay on it however slow the page is
    app.loop.sync()
    try:
        _robot_is_drawn_where_projected(app, pg, client)
    finally:
        app.loop.submit(Play())


def _robot_is_drawn_where_projected(app: Any, pg: Any, client: Any) -> None:
    set_camera(client, CAMERA_POSITION, CAMERA_LOOK_AT, app)
    box = pg.locator(SCENE_CANVAS).first.bounding_box()
    links = [project(client, box, link_point_world(app, name)) for name in ("link2", "link4", "link6")]
    floor = project(client, box, np.array([0.3, 0.9, 0.0]))  # bare floor beside the table
    pts = np.array([*links, floor])
    lo = np.maximum(pts.min(axis=0) - 20, [box["x"], box["y"]])
    hi = np.minimum(pts.max(axis=0) + 20, [box["x"] + box["width"], box["y"] + box["height"]])
    clip = {"x": float(lo[0]), "y": float(lo[1]), "width": float(hi[0] - lo[0]), "height": float(hi[1] - lo[1])}

    def is_green(image: np.ndarray, xy: tuple[float, float]) -> bool:
        x, y = int(xy[0] - lo[0]), int(xy[1] - lo[1])
        r, g, b = image[y - 3 : y + 4, x - 3 : x + 4].reshape(-1, 3).mean(axis=0)
        return bool(g > r + 25 and g > b + 25)  # link colour while far from joint limits

    def robot_drawn() -> bool:
        from io import BytesIO

        from PIL import Image

        image = np.asarray(Image.open(BytesIO(pg.screenshot(clip=clip))).convert("RGB")).astype(int)
        last["image"] = image
        return all(is_green(image, xy) for xy in links) and not is_green(image, floor) and image.std() > 10

    last: dict[str, np.ndarray] = {}
    try:
        wait_for(robot_drawn, 60, "the green links at their projected pixels (and no green on the floor)", period=0.5)
    finally:
        if "image" in last:
            from PIL import Image

            ARTIFACTS.mkdir(exist_ok=True)
            Image.fromarray(last["image"].astype(np.uint8)).save(ARTIFACTS / "browser-robot-clip.png")
    ARTIFACTS.mkdir(exist_ok=True)
    pg.screenshot(path=str(ARTIFACTS / "browser-robot.png"))


def test_objective_dropdown_in_the_page_sets_the_controllers_objective(app, page, paused):
    pg, _ = page
    open_tab(pg, "Tune")
    wait_for(lambda: has_control(pg, r"^Objective$", "combobox"), 30, "the Objective dropdown")
    wait_for(lambda: has_control(pg, r"^k0\b", "slider"), 30, "the k0 slider")
    offered = choose(pg, "Objective", "W_d")
    assert {"W_j", "W_f", "W_a", "W_d"} <= set(offered)
    objective = lambda: app.loop.call(lambda s: s.executor.nullspace.objective)  # noqa: E731
    wait_for(lambda: objective() == "d", 20, "the server's objective to become d")
    from app.core.commands import SetParam

    app.loop.submit(SetParam("nullspace", "objective", "a"))  # back to the polish default for the screenshot
    wait_for(lambda: objective() == "a", 20, "the objective to return to a")
    wait_for(lambda: pg.get_by_label("Objective", exact=True).input_value() == "W_a", 20, "the page to show W_a")


def test_self_motion_preview_checkbox_in_the_page_draws_the_ghost_arm(app, page, paused):
    from app.live.ui.panels.nullspace import NullspacePanel

    pg, _ = page
    preview = next(p for p in app.panels if isinstance(p, NullspacePanel)).preview
    open_tab(pg, "Tune")
    scans = preview.scans
    box = pg.get_by_label("Self-motion preview", exact=True)
    box.wait_for(timeout=20_000)
    box.check()  # opening the preview starts the scans at once
    wait_for(lambda: preview.scans > scans and preview.ghost_visible, 30, "a scan and the ghost arm")
    assert "flow settles" in preview.text.content
    wait_for(lambda: pg.get_by_text("the flow settles", exact=False).first.is_visible(), 20, "the scan text")
    box.uncheck()
    wait_for(lambda: not preview.ghost_visible, 30, "the ghost arm to hide")


def test_self_motion_preview_in_the_page_colours_the_loop_by_the_stability_map(app, page, paused, tmp_path):
    """With a stability map, the preview's W curve is drawn in the map's colour of each swivel at the
    session's μ: the page's legend names the levels, the line under the plot names the μ, and along the
    loop the colour changes where the map's tolerated latency changes (−60°…−40°: 1 period, else 3)."""
    import json

    from app.live.ui import latency_map as L
    from app.live.ui.panels.nullspace import NullspacePanel

    pg, _ = page
    preview = next(p for p in app.panels if isinstance(p, NullspacePanel)).preview
    swivels = [-170.0 + 10.0 * k for k in range(35)]
    doc = {
        "format": L.FORMAT,
        "robot": app.loop.call(lambda s: s.robot.name),
        "tolerated": [
            {"mu": mu, "swivel_deg": swivels, "tolerated_periods": [1 if -60 <= s <= -40 else 3 for s in swivels]}
            for mu in (0.25, 1.5)
        ],
    }
    (tmp_path / "map.json").write_text(json.dumps(doc))
    kept = preview.latency_map
    preview.latency_map = L.load(tmp_path / "map.json")
    open_tab(pg, "Tune")
    box = pg.get_by_label("Self-motion preview", exact=True)
    box.wait_for(timeout=20_000)
    try:
        scans = preview.scans
        box.check()
        wait_for(lambda: preview.scans > scans + 1, 30, "two scans with the map")
        wait_for(lambda: pg.get_by_text("Coloured by the latency", exact=False).first.is_visible(), 20, "the map line")
        for level in (1, 3):
            label = L.level_label(level)
            wait_for(lambda label=label: pg.get_by_text(label, exact=True).count() > 0, 20, f"the legend's {label!r}")
        x = np.asarray(preview.plot.data[0])
        levels = preview.plot.data[7:]
        colour = np.array([next((k for k, s in enumerate(levels) if np.isfinite(s[i])), -1) for i in range(len(x))])
        coloured = np.flatnonzero(colour >= 0)
        switches = [0.5 * (x[a] + x[b]) for a, b in itertools.pairwise(coloured) if colour[a] != colour[b]]
        assert len(switches) == 2
        assert switches[0] == pytest.approx(-65.0, abs=3.0) and switches[1] == pytest.approx(-35.0, abs=3.0)
        inside = colour[(x > -60.0) & (x < -40.0) & (colour >= 0)]
        assert inside.size > 0 and set(inside.tolist()) == {L.LEVELS.index(1)}
    finally:
        box.uncheck()
        preview.latency_map = kept


def test_twin_arm_dropdown_in_the_page_runs_a_second_arm_and_draws_it(app, page, paused):
    from app.core.commands import SetTwin

    pg, _ = page
    open_tab(pg, "Tune")
    offered = choose(pg, "Twin arm", "W_j")
    assert {"off", "W_j", "W_f", "W_a", "W_d"} <= set(offered)
    try:
        wait_for(lambda: app.loop.status.twin == "j", 20, "the server's twin to run W_j")
        scene = app.publisher.scene
        wait_for(lambda: scene.twin_meshes and all(h.visible for h in scene.twin_meshes.values()), 20, "the twin")
    finally:
        app.loop.submit(SetTwin(None))
        wait_for(lambda: app.loop.status.twin == "", 20, "the twin to stop")


@pytest.mark.skipif(
    os.environ.get("TORQUELAB_UPDATE_SCREENSHOT") != "1" and README_SCREENSHOT.exists(),
    reason="writes the README's screenshot: run with TORQUELAB_UPDATE_SCREENSHOT=1 (the drawn arm is "
    "checked at its projected pixels by test_page_loads_and_draws_the_robot_where_the_camera_projects_it)",
)
def test_the_readme_screenshot_is_written_on_request(app, page):
    """test-artifacts/app.png at the README's viewport, copied to static/screenshot.png (the README's)
    when that is missing or TORQUELAB_UPDATE_SCREENSHOT=1."""
    from app.live.ui.panels.nullspace import NullspacePanel
    from app.live.ui.selfmotion import GHOST_CHOICES

    pg, client = page
    preview = next(p for p in app.panels if isinstance(p, NullspacePanel)).preview
    pg.set_viewport_size(SCREENSHOT_VIEWPORT)
    try:
        close = pg.locator(".mantine-Notification-closeButton")  # the software-WebGL notice
        for _ in range(close.count()):
            close.first.click()
        preview.set_enabled(True, ghost_at=GHOST_CHOICES[1])  # ghost at the best W_a inside the limits
        wait_for(lambda: preview.ghost_visible and "flow settles" in preview.text.content, 30, "the ghost arm")
        scan_text = pg.get_by_text("the flow settles", exact=False).first
        scan_text.wait_for(timeout=20_000)
        scan_text.scroll_into_view_if_needed()
        set_camera(client, np.array([1.25, -1.0, 0.8]), np.array([0.42, 0.0, 0.3]))
        canvas = pg.locator(SCENE_CANVAS).first

        def resized() -> bool:  # the page draws at an adaptive pixel ratio: compare shapes, not pixels
            box = canvas.bounding_box()
            cam = client.camera
            return (
                cam.image_height > 0 and abs(cam.image_width / cam.image_height - box["width"] / box["height"]) < 0.01
            )

        wait_for(resized, 20, "the page to report its view at the canvas's shape")
        time.sleep(2.0)  # a few software-rendered frames at the new pose
        ARTIFACTS.mkdir(exist_ok=True)
        shot = ARTIFACTS / "app.png"
        pg.screenshot(path=str(shot))
    finally:
        preview.set_enabled(False, ghost_at=GHOST_CHOICES[0])
        pg.set_viewport_size(VIEWPORT)
    from PIL import Image

    image = np.asarray(Image.open(shot).convert("RGB")).astype(int)
    assert image.shape[:2] == (SCREENSHOT_VIEWPORT["height"], SCREENSHOT_VIEWPORT["width"])
    shutil.copyfile(shot, README_SCREENSHOT)


def test_compliance_and_damper_sliders_appear_with_the_qp_executor(app, page, paused):
    """Γ (task compliance), λ and M belong to the [C] QP executor: with it running they are in the page,
    and the Nullspace folder of the [T] executor (its Twin arm input, its live W line) is not."""
    from app.core.commands import SwitchSession

    pg, _ = page
    wait_for(lambda: app.loop.call(lambda s: s.executor_name) == "projection", 30, "the projection executor")
    open_tab(pg, "Tune")
    # the projection executor has no task compliance: its slider is hidden, not greyed out
    wait_for(lambda: not has_control(pg, r"^Γ task", "slider"), 30, "the Γ task slider to be hidden")
    wait_for(lambda: pg.get_by_text("Twin arm", exact=True).count() > 0, 30, "the Nullspace folder")
    app.loop.submit(SwitchSession(executor="compliance-qp"))
    try:
        wait_for(lambda: app.loop.call(lambda s: s.executor_name) == "compliance-qp", 30, "the executor switch")
        for pattern in (r"^Γ task", r"^λ", r"^M\b"):
            wait_for(lambda p=pattern: has_control(pg, p, "slider"), 30, f"a slider labelled {pattern}")
        # the whole Nullspace folder (its prose, live W line, twin arm, preview) belongs to the [T] executor
        wait_for(lambda: not pg.get_by_text("Twin arm", exact=True).count(), 30, "the Nullspace folder to hide")
        assert not pg.get_by_text("Live:", exact=False).count()
    finally:
        app.loop.submit(SwitchSession(executor="projection"))
        wait_for(lambda: app.loop.call(lambda s: s.executor_name) == "projection", 30, "the switch back")


_FORCE_PLOT_JS = """() => {
    for (const v of Object.values((window.__viserTestpoints || {}).uplots || {})) {
        const c = v.chart, title = c.root.querySelector('.u-title')?.textContent || '';
        if (!title.startsWith('Force error') && !title.startsWith('F̂_z')) continue;
        const r = c.root.getBoundingClientRect();
        return {ymin: c.scales.y.min, ymax: c.scales.y.max, n: c.data[0].length,
                box: {x: r.x, y: r.y, width: r.width, height: r.height}};
    }
    return null;
}"""


def save_tour_shot(pg: Any, name: str) -> None:
    """A screenshot for the docs' tour (docs/getting-started.md): test-artifacts/NAME, copied to static/ with
    TORQUELAB_UPDATE_SCREENSHOT=1."""
    ARTIFACTS.mkdir(exist_ok=True)
    close_notices(pg)
    pg.screenshot(path=str(ARTIFACTS / name))
    if os.environ.get("TORQUELAB_UPDATE_SCREENSHOT") == "1":
        shutil.copyfile(ARTIFACTS / name, README_SCREENSHOT.parent / name)


def close_notices(pg: Any) -> None:
    """Close the page's pop-up notices (they would cover the 3D view in a screenshot)."""
    close = pg.locator(".mantine-Notification-closeButton")
    for _ in range(close.count()):
        try:
            close.first.click(timeout=5_000)
        except Exception:  # closed on its own meanwhile
            pass


def force_plot(pg: Any) -> dict[str, Any] | None:
    """The force-error chart's y range, sample count and box in the page (None if not drawn)."""
    return pg.evaluate(_FORCE_PLOT_JS)


def red_pixels(pg: Any, box: dict[str, float]) -> int:
    """Pixels of the main arm's force-error colour (#d62728) inside a page box."""
    from io import BytesIO

    from PIL import Image

    image = np.asarray(Image.open(BytesIO(pg.screenshot(clip=box, timeout=90_000))).convert("RGB")).astype(int)
    r, g, b = image[..., 0], image[..., 1], image[..., 2]
    return int(np.count_nonzero((r > 150) & (g < 90) & (b < 90)))


_CHARTS_JS = """() => {
    const out = [];
    for (const v of Object.values((window.__viserTestpoints || {}).uplots || {})) {
        const c = v.chart;
        if (!c.root.isConnected) continue;
        const r = c.root.getBoundingClientRect();
        if (!(r.width > 0 && r.height > 0 && c.root.offsetParent !== null)) continue;
        const y = c.axes[1] || {};
        const finite = (c.data[1] || []).filter(x => x !== null && Number.isFinite(x)).length;
        const over = c.over.getBoundingClientRect();  // the plotting area: the y axis is left of it
        const sp = typeof y.splits === 'function' ? y.splits(c, 1, c.scales.y.min, c.scales.y.max) : [];
        const fmt = new Intl.NumberFormat();
        out.push({title: c.root.querySelector('.u-title')?.textContent || '', top: r.y, label: y.label || '',
                  values: (sp || []).map(v => fmt.format(v)), size: y._size || 0, show: y.show !== false,
                  finite: finite, ymin: c.scales.y ? c.scales.y.min : null, ymax: c.scales.y ? c.scales.y.max : null,
                  strip: {x: over.x - (y._size || 0) + 2, y: over.y, width: Math.max(1, (y._size || 0) - 4),
                          height: Math.max(1, over.height)}});
    }
    return out.sort((a, b) => a.top - b.top);
}"""

PRESET_TOP_CHART = {  # the chart each preset's lesson is about, on top of the Plots panel
    "polish": "Force error",
    "free": "",  # the coupling plots have no title: their folder's heading says it
    "limit-drop": "Joint 4 phase",
    "mass-drop": "Deflection",
    "compliance": "Deflection",
}


def dark_pixels(image: np.ndarray, box: dict[str, float]) -> int:
    """Pixels of text colour (dark grey or black) inside a page box of a viewport screenshot (RGB)."""
    x0, y0 = round(box["x"]), round(box["y"])
    part = image[y0 : y0 + round(box["height"]), x0 : x0 + round(box["width"])]
    return int(np.count_nonzero(np.all(part < 150, axis=-1)))


# the strip left of each shown chart's plotting area where its y axis writes its ticks, in page px, and
# whether it lies inside the viewport; with a chart's (title, label) given, that chart is scrolled into view
_STRIPS_JS = """(scroll) => {
    const out = [];
    for (const v of Object.values((window.__viserTestpoints || {}).uplots || {})) {
        const c = v.chart;
        if (!c.root.isConnected || c.root.offsetParent === null) continue;
        const name = c.root.querySelector('.u-title')?.textContent || '', label = c.axes[1].label || '';
        if (scroll && name === scroll[0] && label === scroll[1]) c.root.scrollIntoView({block: 'center'});
        out.push([name, label, c]);
    }
    return out.map(([name, label, c]) => {
        const over = c.over.getBoundingClientRect(), size = c.axes[1]._size || 0;
        const box = {x: over.x - size + 2, y: over.y, width: Math.max(1, size - 4), height: Math.max(1, over.height)};
        const inside = box.x >= 0 && box.y >= 0 && box.x + box.width <= innerWidth && box.y + box.height <= innerHeight;
        return {title: name, label: label, box: box, inside: inside};
    });
}"""


def ticks_missing(pg: Any) -> list[str]:
    """The shown charts whose y axis drew no tick text left of its plotting area (empty: every one did).
    One viewport screenshot serves every chart inside the viewport; a chart outside it is scrolled into
    view for the next (a screenshot of a software-rendered page costs about a second)."""
    from io import BytesIO

    from PIL import Image

    checked: set[tuple[str, str]] = set()
    missing: list[str] = []
    scroll: list[str] | None = None
    for _ in range(40):
        todo = [s for s in pg.evaluate(_STRIPS_JS, scroll) if (s["title"], s["label"]) not in checked]
        if not todo:
            return missing
        seen = [s for s in todo if s["inside"]]
        if not seen:
            first = [todo[0]["title"], todo[0]["label"]]
            if scroll == first:  # scrolled into view and still not inside it
                checked.add((first[0], first[1]))
                missing.append(f"{first[0] or first[1]} (not in the viewport)")
            scroll = first
            continue
        image = np.asarray(Image.open(BytesIO(pg.screenshot(timeout=90_000))).convert("RGB")).astype(int)
        for strip in seen:
            checked.add((strip["title"], strip["label"]))
            if dark_pixels(image, strip["box"]) <= 10:
                missing.append(strip["title"] or strip["label"])
        scroll = None
    return [*missing, "(charts left unchecked)"]


def charts(pg: Any) -> list[dict[str, Any]]:
    """The uPlot charts the page shows, top to bottom: title, y-axis label, tick texts and width, finite samples."""
    return pg.evaluate(_CHARTS_JS)


def test_every_plot_has_its_y_axis_with_units_in_every_preset_and_the_lessons_plot_on_top(app, page):
    """In each preset's default state every chart shown draws a y axis whose label has a unit and whose
    ticks fit (none is clipped: the axis is at least 7 px per character of its longest tick), from the
    first frames on; the preset's own chart is on top and has drawn samples."""
    from app.core.commands import Play, SwitchSession
    from app.scenarios import SCENARIOS

    pg, _ = page
    try:
        for name in SCENARIOS:
            app.loop.submit(SwitchSession(scenario=name, robot=""))
            app.loop.submit(Play())
            wait_for(lambda n=name: app.loop.status.scenario == n and app.loop.status.t > 0.5, 60, f"{name} to run")

            def laid_out(n: str = name) -> list[dict[str, Any]] | None:
                shown = charts(pg)
                top = PRESET_TOP_CHART[n]
                if not shown or not shown[0]["title"].startswith(top) or (top and shown[0]["finite"] < 5):
                    return None
                return shown

            shown = wait_for(laid_out, 60, f"{name}'s own chart on top with data", period=0.5)
            # a chart built before its panel had its size gets its axes again within seconds
            # (each look takes a screenshot or two: the ticks are checked here, not again below)
            wait_for(lambda: not ticks_missing(pg), 60, f"{name}'s ticks in every chart", 3.0)
            shown = charts(pg)
            for chart in shown:
                where = f"{name}: {chart['title'] or chart['label']}"
                assert chart["show"] and re.search(r"\(.+\)|×", chart["label"]), where  # a unit in the label
                assert chart["values"], where  # ticks asked for
                longest = max(len(str(v)) for v in chart["values"])
                assert chart["size"] >= 7 * longest, where  # wide enough for the longest, as the page writes it
                assert np.isfinite(chart["ymin"]) and np.isfinite(chart["ymax"]) and chart["ymax"] > chart["ymin"]
            if name == "limit-drop":
                wait_for(lambda: pg.get_by_text("peak |τ|", exact=False).first.is_visible(), 30, "the peak readout")
                assert app.publisher.plots.readouts["peak_torque_nm"] > 0.0
    finally:
        app.loop.submit(SwitchSession(scenario="polish", robot="rizon4s", executor="projection"))
        app.loop.submit(Play())
        wait_for(lambda: app.loop.status.scenario == "polish", 60, "polish again")


def test_a_paused_reset_clears_the_plots_and_readouts_of_the_old_run(app, page):
    """The limit drop runs into its peak-torque readout; paused, Reset: no chart of the page has a sample of
    the old run left, the readouts are gone and the readout line says a new run starts."""
    from app.core.commands import Pause, Play, Reset, SetSpeed, SwitchSession

    pg, _ = page
    app.loop.submit(SwitchSession(scenario="limit-drop", robot=""))
    app.loop.submit(Play())
    try:
        wait_for(lambda: app.publisher.plots.readouts.get("peak_torque_nm", 0) > 0, 60, "the old run's readout")
        wait_for(lambda: charts(pg) and charts(pg)[0]["finite"] > 5, 30, "the old run's samples in the page")
        app.loop.submit(Pause())
        app.loop.submit(Reset())
        app.loop.sync()
        wait_for(lambda: all(c["finite"] == 0 for c in charts(pg)), 30, "every chart of the page to be empty")
        assert app.publisher.plots.readouts == {}
        wait_for(lambda: pg.get_by_text("A new run", exact=False).count() > 0, 20, "the new-run line")
        assert not pg.get_by_text("peak |τ|", exact=False).count()
    finally:
        app.loop.submit(SetSpeed(1.0))
        app.loop.submit(SwitchSession(scenario="polish", robot="rizon4s", executor="projection"))
        app.loop.submit(Play())
        wait_for(lambda: app.loop.status.scenario == "polish", 60, "polish again")


def test_a_case_switch_in_the_page_keeps_the_users_friction_and_says_what_it_reset(app, page, paused):
    """Polish, μ = 1 and W_d typed into the page, then Case → mirror start: μ stays 1 (in force and in the
    Tune tab's box) and W_d stays the objective; one notice (repeated in the status line, at the top of the
    plots) says it kept both (the case owns neither; tests/test_lessons.py checks that a value the case
    owns is named as reset)."""
    from app.core.commands import SwitchSession

    pg, _ = page
    app.loop.submit(SwitchSession(scenario="polish", robot="rizon4s", executor="projection", variant="flow"))
    app.loop.sync(timeout=60)
    try:
        open_tab(pg, "Tune")
        type_number(pg, r"^Friction μ", "1")
        wait_for(lambda: param(app, "contact", "mu") == pytest.approx(1.0), 20, "μ = 1 in force")
        choose(pg, "Objective", "W_d")
        wait_for(lambda: param(app, "nullspace", "objective") == "d", 20, "W_d in force")
        open_tab(pg, "Run")
        choose(pg, "Case", "mirror start")
        wait_for(lambda: app.loop.status.variant == "mirror start", 60, "the mirror start")
        assert param(app, "contact", "mu") == pytest.approx(1.0) and param(app, "nullspace", "objective") == "d"
        notices = [n for n in app.loop.lab.notice_log if n.title == "Case mirror start"]
        assert len(notices) == 1 and "kept 2 value(s) you set" in notices[0].body  # μ and the objective
        open_tab(pg, "Tune")  # the status line is at the top of the plots: in view from Tune too
        wait_for(lambda: re.fullmatch(r"1(\.0*)?", number_text(pg, r"^Friction μ")), 20, "the μ box to show 1")
        wait_for(lambda: pg.get_by_text("Latest notice: Case mirror start", exact=False).count() > 0, 20, "status")
        assert pg.get_by_text("Latest notice: Case mirror start", exact=False).first.is_visible()
    finally:
        app.loop.submit(SwitchSession(scenario="polish", robot="rizon4s", executor="projection", variant="flow"))
        app.loop.sync(timeout=60)


def _knob(app: Any, label: str) -> tuple[Any, Any]:
    """The panel and the knob whose input is labelled `label`."""
    for panel in app.panels:
        for k in getattr(panel, "knobs", ()):
            if k.label == label:
                return panel, k
    raise AssertionError(f"no knob labelled {label!r}")


def test_typed_text_a_number_box_cannot_take_gets_a_notice_naming_the_value_in_force(app, page, paused):
    """Polish, Tune, the Force setpoint's box (a slider's): "1e9" typed key by key is clamped to the
    slider's top (the browser alone would have sent 19) and "abc" typed, "NaN" filled in, change
    nothing; each gets one notice in the page naming the text and the value in force, the box then
    shows that value, and the setpoint in force is it."""
    from app.core.commands import SetParam

    pg, client = page
    label = "Force setpoint F̂ (N)"
    _, k = _knob(app, label)
    hi = k.bounds[1]
    before = param(app, k.group, k.field)
    mark = f"box{time.monotonic_ns()}"
    open_tab(pg, "Tune", timeout_ms=120_000)  # the first click of a fresh page waits for its first frames
    wait_for(lambda: pg.evaluate(_NUMBER_BOX_JS, ["^" + re.escape(label) + "$", mark]), 30, f"the box of {label}")
    box = pg.locator(f"[data-tour-box={mark}]")
    box.scroll_into_view_if_needed()
    cases = [  # (text, how it goes in, the notice's words, the value in force after)
        ("1e9", "type", f"'1e9' is above the largest value {hi:g}; {hi:g} is in force", hi),
        ("abc", "type", f"'abc' is not a number; {hi:g} stays", hi),
        ("NaN", "fill", f"'NaN' is not a finite number; {hi:g} stays", hi),
    ]
    pg.set_default_timeout(120_000)  # a software-rendered page on a loaded machine takes seconds per input
    try:
        for text, how, words, expected in cases:
            seen = len(app.loop.lab.notice_log)
            box.focus()
            if how == "type":
                pg.keyboard.press("Control+A")
                pg.keyboard.type(text, delay=30)
            else:
                box.fill(text)
            box.press("Enter")

            def new_notices(seen: int = seen, words: str = words) -> list[Any]:
                return [n for n in list(app.loop.lab.notice_log)[seen:] if words in n.body]

            notices = wait_for(new_notices, 30, f"the notice {words!r}")
            assert len(notices) == 1 and notices[0].client_id == client.client_id  # one notice, to the typist
            assert notices[0].body.startswith(label)
            in_page = pg.get_by_text(words, exact=False)
            wait_for(lambda in_page=in_page: in_page.count() > 0, 20, f"{words!r} shown in the page")
            assert float(param(app, k.group, k.field)) == pytest.approx(expected)
            shown = f"{expected:g}"
            wait_for(lambda shown=shown: box.input_value() == shown, 20, f"the box to show {shown}")
    finally:
        pg.set_default_timeout(30_000)
        app.loop.submit(SetParam(k.group, k.field, before))
        app.loop.sync()


_PHASE_LAST_JS = """() => {
    for (const v of Object.values((window.__viserTestpoints || {}).uplots || {})) {
        const c = v.chart, title = c.root.querySelector('.u-title')?.textContent || '';
        if (!title.startsWith('Joint ') || !c.root.isConnected) continue;
        let last = null;
        for (let i = 0; i < c.data[1].length; i++) {
            const y = c.data[1][i];
            if (y !== null && Number.isFinite(y)) last = [c.data[0][i], y];
        }
        return last;
    }
    return null;
}"""


_PHASE_LINES_JS = """() => {
    for (const v of Object.values((window.__viserTestpoints || {}).uplots || {})) {
        const c = v.chart, title = c.root.querySelector('.u-title')?.textContent || '';
        if (!title.startsWith('Joint ') || !c.root.isConnected || c.root.offsetParent === null) continue;
        const lines = [4, 5, 6].map(k => {
            const xs = new Set();
            for (let i = 0; i < c.data[0].length; i++) {
                const y = c.data[k][i];
                if (y !== null && Number.isFinite(y)) xs.add(c.data[0][i]);
            }
            return [...xs];
        });
        return {min: c.scales.x.min, max: c.scales.x.max, lines: lines};
    }
    return null;
}"""


def test_replay_moves_the_arm_and_the_plots_to_the_same_instant(app, page):
    """The limit drop runs 3 s; Replay (Plots panel) pauses it; At t = 0.2 s (joint 4 still falling): every
    link of the 3D arm stands where the logged joint positions of t ≈ 0.2 s put it (MuJoCo kinematics,
    ≤ 1 mm), and the phase plot in the page ends at the plots' last sample at or before that instant
    (< 30 ms before it, joint 4 within 0.05 rad of the arm's); turning Replay off shows the live view again."""
    import mujoco

    from app.core.commands import Play, SwitchSession

    pg, _ = page
    replay = app.publisher.replay
    app.loop.submit(SwitchSession(scenario="limit-drop", robot=""))
    app.loop.submit(Play())
    try:
        wait_for(lambda: app.loop.status.scenario == "limit-drop" and app.loop.status.t > 3.0, 90, "3 s of the drop")
        box = pg.get_by_label("Replay", exact=True)
        box.scroll_into_view_if_needed()
        box.check()
        wait_for(lambda: replay.t is not None and not app.loop.status.running, 30, "the replay to start, paused")
        type_number(pg, r"^At t \(s\)", "0.2")
        wait_for(lambda: replay.t is not None and abs(replay.t - 0.2) < 0.003, 20, "the replay instant t = 0.2 s")
        cols = replay.columns
        i = int(np.clip(np.searchsorted(cols["t"], replay.t), 0, len(cols["t"]) - 1))  # the sample it shows
        q = np.array([cols[f"q_{j + 1}"][i] for j in range(7)])
        session = app.loop.session
        data = mujoco.MjData(session.world.model)
        data.qpos[:] = session.world.data.qpos
        data.qpos[session.world.qpos_adr] = q
        mujoco.mj_kinematics(session.world.model, data)
        names = tuple(session.robot.link_names)
        expected = data.xpos[session.world.body_ids(names)]

        def arm_at_instant() -> bool:
            scene = app.publisher.scene
            if scene is None:  # rebuilding
                return False
            frames = scene.frames
            shown = np.array([np.asarray(frames[n].position) for n in names if n in frames])
            return shown.shape == expected.shape and float(np.max(np.abs(shown - expected))) < 1e-3

        wait_for(arm_at_instant, 20, "the arm at the logged posture of t = 0.2 s")
        live_q4 = app.loop.call(lambda s: float(s.world.q[3]))
        assert abs(live_q4 - q[3]) > 0.02  # the instant differs from the live posture (joint 4 fell since)

        hist = app.publisher.plots.history  # the plots' samples (≈ 50 a second): the last one at or before t
        k = int(np.searchsorted(hist.t, replay.t, side="right")) - 1
        assert k >= 0 and replay.t - hist.t[k] < 0.03
        q4, dq4 = float(hist.columns["q_4"][k]), float(hist.columns["dq_4"][k])
        assert abs(q4 - q[3]) < 0.05  # the same instant as the arm's, within one plot sample

        def phase_at_instant() -> bool:
            last = pg.evaluate(_PHASE_LAST_JS)
            return last is not None and abs(last[0] - q4) < 1e-6 and abs(last[1] - dq4) < 1e-6

        wait_for(phase_at_instant, 20, "the page's phase plot to end at joint 4's (q, q̇) of t = 0.2 s")
        box.uncheck()
        wait_for(lambda: replay.t is None, 20, "the live view")
    finally:
        if replay.t is not None:
            replay.set_active(False)
        app.loop.submit(SwitchSession(scenario="polish", robot="rizon4s", executor="projection"))
        app.loop.submit(Play())
        wait_for(lambda: app.loop.status.scenario == "polish", 60, "polish again")


def run_lesson_in_the_page(
    app: Any, pg: Any, lesson: str, steps: int | None = None, after_step: Callable[[int, str], None] | None = None
) -> dict[str, str]:
    """Open the Lessons tab, pick `lesson`, click "Set up this step" for each step (the first `steps`
    of them when given) and wait for its result line, then call `after_step(index, key)` if given; returns
    the claims the page showed, by step key. Each step's charts are checked in the viewport while it runs
    and at its end, as `test_every_lesson_steps_plot_and_the_margins_warning_lie_in_the_viewport` asks
    (`step_in_view`), so that test runs again only the steps no lesson test ran."""
    from app.live.curriculum import LESSONS
    from app.live.ui.panels.lessons import LessonsPanel

    panel = next(p for p in app.panels if isinstance(p, LessonsPanel))
    spec = next(x for x in LESSONS if x.key == lesson)
    show_tab(pg, "Lessons")
    choose(pg, "Lesson", spec.title)
    wait_for(lambda: panel.lesson.key == lesson, 20, f"the lesson {spec.title}")
    shown: dict[str, str] = {}
    for i, step in enumerate(spec.steps[:steps]):
        wait_for(lambda i=i: panel.index == i, 20, f"step {i + 1}")
        pg.get_by_text(f"Step {i + 1} of {len(spec.steps)}", exact=False).first.wait_for(timeout=20_000)
        # force: a software-rendered page on a loaded machine redraws without pause, and the check that the
        # button stands still before the click then waits for minutes
        pg.get_by_role("button", name="Set up this step").click(force=True)
        key = (lesson, step.key)
        step_in_view(pg, panel, step, "while it runs")
        wait_for(lambda k=key: k in panel.claims, 600, f"the result of {step.title}", period=0.5)
        claim = panel.claims[key]
        wait_for(lambda c=claim: pg.get_by_text(c[:60], exact=False).count() > 0, 30, "the claim in the page")
        assert not app.loop.sync().running  # the run froze at the end of the step
        assert not claim.startswith("Cancelled"), claim
        step_in_view(pg, panel, step, "at its end")
        VIEW_CHECKED.add(key)
        shown[step.key] = claim
        if after_step is not None:
            after_step(i, step.key)
        if i + 1 < len(spec.steps):
            pg.get_by_role("button", name="Next ▶").click(force=True)
    return shown


def test_the_dampers_lesson_in_the_page_tells_the_delay_step_as_it_happens(app, page, unpaced):
    """Lessons → Dampers at the joint limit, each step as a student takes it. The claims carry this run's
    numbers (checked against the step log read here) and say what happened: λ = 500 brakes harder than
    λ = 100 (peak |τ₄| ≥ 1.5×, both without a velocity reversal in 3 s); with 5 ms of torque delay the
    other joints move too (one of joints 1–3 swings > 1 rad, more than 1 s of thrashing), then q̇₄
    chatters (≥ 10 reversals in the last 2 s); λ = 100 with the delay stops with ≤ 2 reversals. When each
    step ends, the page's phase chart of joint 4 has the limit, d_s and d_i lines each inside its x range
    (zoomed on the limit the joint falls to) and d_s more than 5 % of the width from the limit (screenshots
    lesson-dampers-step1…4.png)."""
    from app.live.ui.panels.lessons import LessonsPanel

    pg, _ = page
    panel = next(p for p in app.panels if isinstance(p, LessonsPanel))

    try:
        claims = run_lesson_in_the_page(app, pg, "dampers", after_step=functools.partial(lines_in_view, pg))
        memo = panel.results["dampers"]
        low, high, thrash, low_delay = memo["l100"], memo["l500"], memo["l500d"], memo["l100d"]
        assert f"{low['peak_tau_4']:.1f} N m" in claims["l100"] and f"{high['peak_tau_4']:.1f} N m" in claims["l500"]
        assert high["peak_tau_4"] >= 1.5 * low["peak_tau_4"]
        assert low["reversals_first_3s"] == 0 and high["reversals_first_3s"] == 0
        for j in (1, 2, 3, 5, 6, 7):
            assert f"joint {j} {thrash[f'swing_{j}']:.2f} rad" in claims["l500d"]
        assert max(thrash[f"swing_{j}"] for j in (1, 2, 3)) > 1.0 and thrash["thrash_end_s"] > 1.0
        assert thrash["reversals_late"] >= 10
        assert low_delay["reversals_first_3s"] <= 2
        # the claim's numbers are the log's: joint 2's swing over the run, read again on the loop thread
        assert app.loop.status.scenario == "limit-drop"
        swing_2 = app.loop.call(lambda s: float(np.ptp(app.loop.log.window(60.0, app.loop.dt)["q_2"])))
        assert f"{memo['l100d']['swing_2']:.2f}" == f"{swing_2:.2f}"
        save_tour_shot(pg, "lesson-dampers.png")
    finally:
        from app.core.commands import Play, SwitchSession

        app.loop.submit(SwitchSession(scenario="polish", robot="rizon4s", executor="projection"))
        app.loop.submit(Play())
        wait_for(lambda: app.loop.status.scenario == "polish", 60, "polish again")


def lines_in_view(pg: Any, i: int, key: str) -> None:
    """The page's phase chart: the limit, d_s and d_i each drawn inside its x range, d_s > 5 % of the
    width from the limit (the zoom on the limit); then a screenshot lesson-dampers-step{i + 1}.png."""

    def drawn() -> bool:
        got = pg.evaluate(_PHASE_LINES_JS)
        if not got:
            return False
        lo, hi, lines = got["min"], got["max"], got["lines"]
        inside = [[x for x in xs if lo <= x <= hi] for xs in lines]
        if any(len(xs) != 1 for xs in inside):
            return False
        return abs(inside[0][0] - inside[1][0]) > 0.05 * (hi - lo)

    wait_for(drawn, 30, f"the limit, d_s and d_i in view in step {key}")
    ARTIFACTS.mkdir(exist_ok=True)
    pg.screenshot(path=str(ARTIFACTS / f"lesson-dampers-step{i + 1}.png"), timeout=180_000)  # a loaded machine


_STD3 = r"([\d.]+)/([\d.]+)/([\d.]+) N"
_STROKES = re.compile(rf"S2/S4/S6 had a force-error STD of {_STD3} against {_STD3}")


def stroke_means(text: str) -> tuple[float, float]:
    """(mean STD of S2/S4/S6, mean STD of S1/S3/S5) in N, read from a polish lesson's result text."""
    m = _STROKES.search(text)
    assert m is not None, f"no per-stroke STDs in the result: {text!r}"
    v = [float(x) for x in m.groups()]
    return float(np.mean(v[:3])), float(np.mean(v[3:]))


def margin_said(text: str) -> tuple[dict[int, str], dict[int, str]]:
    """What a polish lesson's result says the force-loop margin predicted for each stroke, and what it says
    happened after the strokes, each by stroke ("S2, S4, S6: predicted to …; …. After the strokes: …")."""
    m = re.search(r"The force-loop margin \(.*?\): (.*?)\. After the strokes: (.*?)\.(?: |$)", text)
    assert m is not None, f"no margin prediction and outcome in the result: {text!r}"

    def by_stroke(part: str) -> dict[int, str]:
        out: dict[int, str] = {}
        for names, words in re.findall(r"((?:S\d, )*S\d): (.*?)(?=; S\d|$)", part):
            out.update({int(k): words for k in re.findall(r"S(\d)", names)})
        return out

    return by_stroke(m.group(1)), by_stroke(m.group(2))


def shown_result(pg: Any, claim: str) -> str:
    """The text of the page's element that shows a lesson step's result."""
    return str(pg.get_by_text(claim[:60], exact=False).first.inner_text())


def test_the_posture_and_latency_lessons_in_the_page_show_the_shaking_and_its_cause(app, page, unpaced):
    """Lessons → Posture and friction (W_j, then W_a, then both at once: W_j here, W_a on the twin arm, at
    μ = 1), then Latency's first step (W_j with the
    F/T reading 0 periods late; its second step, the default delay, is the posture lesson's W_j run and
    is not run again). Read from the results the page shows: W_j's stretching strokes S2/S4/S6 have ≥ 3×
    the force-error STD of S1/S3/S5, W_a's < 1.5×; with no sensing delay W_j's stretching strokes are
    < 2× its others and < 0.4× the delayed run's (the oscillation all but gone; on the Lab: 5.3×, 1.1×,
    1.5× and 0.24×, tests/test_lessons.py); the margin says in words that W_j's stretching strokes lose
    contact and every W_a stroke keeps it, and after the strokes, for each, whether that came true and
    whether contact was kept. The numbers shown are the run's (the panel's measurements, to the 0.1 N the
    page prints). W_a's force chart draws W_j's run faint behind it (RMS > 2× W_a's over the last 10 s); the
    side-by-side step draws the twin arm and its force error, and W_j's stretching strokes have > 3× the twin
    W_a's STD (W_j's within 10 % of its own step's)."""
    from app.live.ui.panels.lessons import LessonsPanel

    pg, _ = page
    panel = next(p for p in app.panels if isinstance(p, LessonsPanel))
    pg.set_default_timeout(120_000)  # a software-rendered page on a loaded machine takes seconds per click
    seen: dict[str, Any] = {}

    def look(i: int, key: str) -> None:
        if key in ("wa", "side"):  # the force chart as the page draws it at the step's end
            seen[key] = wait_for(lambda: pg.evaluate(_CHART_DATA_JS, "Force error"), 30, "the force chart")
        if key == "side":
            scene = app.publisher.scene
            seen["twin drawn"] = bool(scene.twin_label is not None and scene.twin_label.visible)

    try:
        posture = run_lesson_in_the_page(app, pg, "posture", after_step=look)  # each claim was seen in the page
        memo = panel.results["posture"]
        for key in ("wj", "wa"):  # the numbers shown are the run's, to the 0.1 N printed
            fw, bk = stroke_means(posture[key])
            o = memo[key]
            assert fw == pytest.approx(np.mean([o["std_S2"], o["std_S4"], o["std_S6"]]), abs=0.05)
            assert bk == pytest.approx(np.mean([o["std_S1"], o["std_S3"], o["std_S5"]]), abs=0.05)
        wj_fw, wj_bk = stroke_means(posture["wj"])
        wa_fw, wa_bk = stroke_means(posture["wa"])  # as the page showed it (later steps replace it)
        assert wj_fw >= 3.0 * wj_bk, (wj_fw, wj_bk)
        assert wa_fw < 1.5 * wa_bk, (wa_fw, wa_bk)
        # the margin as the page states it, in words (its sign with a band, no headroom figure): W_j's stretching
        # strokes predicted to lose contact, every W_a stroke to keep it; and after the strokes, for every stroke,
        # whether that came true and whether contact was kept (tests/test_lessons.py checks each against the verdict)
        wj_said, wj_after = margin_said(posture["wj"])
        wa_said, wa_after = margin_said(posture["wa"])
        assert all(wj_said[k].startswith("predicted to shake off the table") for k in (2, 4, 6)), wj_said
        assert all(wa_said[k].startswith("predicted to keep contact") for k in range(1, 7)), wa_said
        for after in (wj_after, wa_after):
            assert sorted(after) == [1, 2, 3, 4, 5, 6] and all("the stroke was" in w for w in after.values()), after
        # W_a's step draws W_j's run faint behind it (the previous run, aligned on the first stroke): over the
        # last 10 s (W_a's S3…S6) W_j's shaking stretching strokes against W_a's calm ones
        _, own, _, _, previous = (np.array(v, dtype=float) for v in seen["wa"])
        assert np.count_nonzero(np.isfinite(previous)) >= 50, "no previous-run trace in W_a's force chart"
        rms_own, rms_previous = (float(np.sqrt(np.nanmean(v**2))) for v in (own, previous))
        assert rms_previous > 2.0 * rms_own, (rms_previous, rms_own)
        # the side-by-side step: W_j on this arm and W_a on the twin in one run; the twin is drawn, its force
        # error charted, and the claim's numbers are this run's (the two arms' stroke STDs, to the 0.1 N shown)
        side = memo["side"]
        assert seen["twin drawn"]
        twin_error = np.array(seen["side"][2], dtype=float)
        assert np.count_nonzero(np.isfinite(twin_error)) >= 50, "no twin trace in the force chart"
        own_fw = float(np.mean([side[f"std_S{k}"] for k in (2, 4, 6)]))
        twin_fw = float(np.mean([side[f"twin_std_S{k}"] for k in (2, 4, 6)]))
        assert "/".join(f"{side[f'twin_std_S{k}']:.1f}" for k in (2, 4, 6)) + " N with W_a" in posture["side"]
        assert own_fw > 3.0 * twin_fw, (own_fw, twin_fw)
        assert own_fw == pytest.approx(np.mean([memo["wj"][f"std_S{k}"] for k in (2, 4, 6)]), rel=0.1)
        latency = run_lesson_in_the_page(app, pg, "latency", steps=1)
        # the claim as the page showed it (run_lesson_in_the_page saw it there before its "Next ▶" moved the
        # panel on to the next step, whose result is blank: reading the page now races that click)
        ideal_fw, ideal_bk = stroke_means(latency["delay0"])
        assert panel.results["latency"]["delay0"]["reading_delay"] == 0
        _, ideal_after = margin_said(latency["delay0"])  # no prediction left without its outcome
        assert sorted(ideal_after) == [1, 2, 3, 4, 5, 6], ideal_after
        assert all(("contact kept" in w) or w.endswith("lost contact") for w in ideal_after.values()), ideal_after
        assert ideal_fw < 2.0 * ideal_bk and ideal_fw < 0.4 * wj_fw, (ideal_fw, ideal_bk, wj_fw)
        print(
            f"posture lesson in the page: W_j S2/S4/S6 {wj_fw:.2f} N vs S1/S3/S5 {wj_bk:.2f} N "
            f"({wj_fw / wj_bk:.2f}×); W_a {wa_fw:.2f} vs {wa_bk:.2f} N ({wa_fw / wa_bk:.2f}×); "
            f"no sensing delay: {ideal_fw:.2f} vs {ideal_bk:.2f} N ({ideal_fw / ideal_bk:.2f}×); "
            f"margin W_j {wj_said}, W_a {wa_said}; side by side W_j {own_fw:.2f} N vs the twin's W_a {twin_fw:.2f} N; "
            f"W_a's force chart: W_j's faint trace RMS {rms_previous:.2f} N vs W_a's {rms_own:.2f} N"
        )
    finally:
        from app.core.commands import Play, SwitchSession

        pg.set_default_timeout(30_000)
        app.loop.submit(SwitchSession(scenario="polish", robot="rizon4s", executor="projection"))
        app.loop.submit(Play())
        wait_for(lambda: app.loop.status.scenario == "polish", 60, "polish again")


def test_the_compliance_lesson_in_the_page_compares_the_gamma_modes(app, page, unpaced):
    """Lessons → Compliance under a push: stiff, nullspace-compliant, fully compliant. The elbow yields
    under the elbow push with Γ₀ = I (> 3× the stiff arm's) while the TCP holds (< 1 mm under its push);
    with Γ = I the TCP moves > 10× as far; each claim quotes its numbers."""
    from app.live.ui.panels.lessons import LessonsPanel

    pg, _ = page
    panel = next(p for p in app.panels if isinstance(p, LessonsPanel))
    try:
        claims = run_lesson_in_the_page(app, pg, "compliance")
        memo = panel.results["compliance"]
        stiff, null, full = memo["gamma-stiff"], memo["gamma-nullspace"], memo["gamma-full"]
        for key, o in memo.items():
            assert f"elbow {o['elbow_push_elbow_mm']:.1f} mm" in claims[key]
        assert null["elbow_push_elbow_mm"] > 3.0 * stiff["elbow_push_elbow_mm"] and null["tcp_push_tcp_mm"] < 1.0
        assert full["tcp_push_tcp_mm"] > 10.0 * null["tcp_push_tcp_mm"]
        save_tour_shot(pg, "lesson-compliance.png")
    finally:
        from app.core.commands import Play, SwitchSession

        app.loop.submit(SwitchSession(scenario="polish", robot="rizon4s", executor="projection"))
        app.loop.submit(Play())
        wait_for(lambda: app.loop.status.scenario == "polish", 60, "polish again")


def test_a_steps_result_comes_back_in_a_page_opened_after_it(app, browser, page, unpaced):
    """Compliance's first step taken from the Lessons panel to its end; a page opened afterwards (what a
    reload opens) shows the Lessons tab at that lesson and step with its *What you saw* line, this run's
    elbow deflection in it."""
    from app.core.commands import Play, SwitchSession
    from app.live.ui.panels.lessons import LessonsPanel

    panel = next(p for p in app.panels if isinstance(p, LessonsPanel))
    key = ("compliance", "gamma-stiff")
    other = None
    try:
        panel.select("compliance", 0)
        panel.start_step()
        claim = wait_for(lambda: panel.claims.get(key), 300, "the stiff step's result", period=0.5)
        assert not claim.startswith("Cancelled"), claim
        o = panel.results["compliance"]["gamma-stiff"]
        other, _ = open_page(app, browser)
        other.set_default_timeout(120_000)  # a second software-rendered page on a loaded machine
        show_tab(other, "Lessons")  # a new page opens on the first tab, Lessons
        other.get_by_text("Step 1 of 3: Γ = 0, stiff", exact=False).first.wait_for(timeout=60_000)
        shown = other.get_by_text(claim[:40], exact=False).first
        shown.wait_for(timeout=60_000)
        text = shown.inner_text()
        assert text.startswith("What you saw.") and f"elbow {o['elbow_push_elbow_mm']:.1f} mm" in text, text
    finally:
        if other is not None:
            other.close()
        app.loop.submit(SwitchSession(scenario="polish", robot="rizon4s", executor="projection"))
        app.loop.submit(Play())
        wait_for(lambda: app.loop.status.scenario == "polish", 60, "polish again")


_CHART_DATA_JS = """(title) => {
    for (const v of Object.values((window.__viserTestpoints || {}).uplots || {})) {
        const c = v.chart;
        if (!c.root.isConnected || !(c.root.querySelector('.u-title')?.textContent || '').startsWith(title)) continue;
        return c.data.map(a => Array.from(a || [], y => (y === null || !Number.isFinite(y)) ? null : y));
    }
    return null;
}"""
_ELBOW_PUSH = re.compile(
    r"Push at the elbow \(peak over the push and the ([\d.]+) s after it\): TCP moved ([\d.]+) mm, elbow ([\d.]+) mm"
)


def test_the_compliance_readout_its_plot_and_its_report_agree_on_the_elbow_push_in_the_page(app, page):
    """Compliance, Γ₀ = I, both pushes run, paused: the elbow's deflection under the elbow push as the page's
    readout prints it, as the page's deflection chart draws it (its samples in the push and the 0.5 s after
    it) and as `torquelab experiment compliance` measures it agree to 0.1 mm; the chart marks both pushes."""
    from app.core.commands import Pause, Play, SwitchSession
    from app.headless.experiments.compliance import run_mode
    from app.scenarios.compliance import PUSHES

    pg, _ = page
    try:
        app.loop.submit(SwitchSession(scenario="compliance", robot="", variant="nullspace"))
        app.loop.submit(Play())
        wait_for(lambda: app.loop.status.scenario == "compliance" and app.loop.status.t >= 4.0, 120, "both pushes")
        app.loop.submit(Pause())
        text = wait_for(
            lambda: (m := _ELBOW_PUSH.search(pg.locator("body").inner_text())) and m, 60, "the elbow push's readout"
        )
        after_s, readout = float(text.group(1)), float(text.group(3))
        (_, t0, t1) = next(p for p in PUSHES if p[0] == "elbow")
        report = run_mode("nullspace")["phases"]["elbow"]["peak_elbow_deflection_mm"]

        def drawn() -> tuple[float, list[float]] | None:
            data = pg.evaluate(_CHART_DATA_JS, "Deflection")
            now = float(app.publisher.plots.history.t[-1])
            if not data or len(data) < 4:
                return None
            x, elbow, marker = data[0], data[2], data[3]
            inside = [e for xi, e in zip(x, elbow, strict=True) if e is not None and t0 <= xi + now < t1 + after_s]
            marks = sorted({round(xi + now, 2) for xi, m in zip(x, marker, strict=True) if m is not None})
            # the picture of the paused instant: each push marked where it starts (a picture drawn before
            # the pause, still shown by a lagging page, has its times shifted by the lag)
            current = all(any(abs(m - start) <= 0.025 for m in marks) for _, start, _ in PUSHES)
            return (max(inside), marks) if inside and current else None

        peak, marks = wait_for(drawn, 60, "the deflection chart's samples of the elbow push, each push marked")
        print(f"elbow in the page: readout {readout} mm, chart {peak:.3f} mm (marks {marks}), report {report:.3f}")
        assert after_s == 0.5 and readout > 5.0
        assert peak == pytest.approx(readout, abs=0.1) and report == pytest.approx(readout, abs=0.1)
    finally:
        app.loop.submit(SwitchSession(scenario="polish", robot="rizon4s", executor="projection"))
        app.loop.submit(Play())
        wait_for(lambda: app.loop.status.scenario == "polish", 60, "polish again")


_SIGNALS_FOLD_JS = """(title) => {
    for (const v of Object.values((window.__viserTestpoints || {}).uplots || {})) {
        const c = v.chart;
        if (!c.root.isConnected || !(c.root.querySelector('.u-title')?.textContent || '').startsWith(title)) continue;
        for (let el = c.root.parentElement; el; el = el.parentElement) {
            const labels = [...el.querySelectorAll('.mantine-Paper-root')].filter(
                p => p.firstChild && p.firstChild.nodeType === 3 && p.firstChild.textContent.trim() === 'Signals');
            if (labels.length > 1) return false;
            if (labels.length === 1) {
                labels[0].scrollIntoView({block: 'center'});
                labels[0].click();
                return true;
            }
        }
    }
    return false;
}"""

_SERIES_JS = """(title) => {
    for (const v of Object.values((window.__viserTestpoints || {}).uplots || {})) {
        const c = v.chart;
        if (!c.root.isConnected || !(c.root.querySelector('.u-title')?.textContent || '').startsWith(title)) continue;
        return c.series.slice(1).map((s, i) => ({label: s.label, show: s.show !== false,
            finite: (c.data[i + 1] || []).filter(y => y !== null && Number.isFinite(y)).length}));
    }
    return null;
}"""

TORQUE_TITLE = "Torques"


def drawn_joints(pg: Any) -> tuple[int, ...] | None:
    """The joints (1-based) whose torque series the page's torque chart shows with samples; None if a series
    is shown without samples or hidden with some (a choice half applied), or there is no torque chart."""
    series = pg.evaluate(_SERIES_JS, TORQUE_TITLE)
    if not series:
        return None
    joints = [(int(s["label"][1:]), s["show"], s["finite"]) for s in series if re.fullmatch(r"τ\d+", s["label"])]
    if any(show != (finite > 0) for _, show, finite in joints):
        return None
    return tuple(j for j, show, _ in joints if show)


def torque_chart_state(pg: Any, plots: Any) -> str:
    """What the page's torque chart and the server's plots hold, for a failure's message."""
    page_series = pg.evaluate(_SERIES_JS, TORQUE_TITLE)
    boxes = {k: box.value for (c, k), box in plots.signal_boxes.items() if c == "torque"}
    server_show = [s.get("show", True) for s in tuple(plots.handles["torque"].series)]
    return (
        f"page series {page_series}; server choice {plots.signals.shown_keys('torque')}; boxes {boxes}; "
        f"server series show {server_show}; frozen {plots.freeze.value}; history {len(plots.history.t)} samples "
        f"to t = {plots.history.t[-1] if len(plots.history.t) else None}, keys {sorted(plots.history.columns)[:6]}…; "
        f"replay {plots.replay_t}"
    )


def test_the_signals_ticked_in_a_plots_fold_are_the_series_its_chart_draws(app, page):
    """Polish, paused: in the torque chart's Signals fold a person unticks τ1, τ2 and τ3: the page's chart
    hides those series and holds no sample of them while τ4…τ7 keep drawing; after a switch to the limit
    drop its torque chart draws the same joints; ticking τ2 again draws it."""
    from app.core.commands import Pause, Play, SwitchSession

    pg, _ = page
    plots = app.publisher.plots
    n = plots.n
    try:
        # the polish run has torques in the plots' history (the chart may still show the run before a switch
        # that an earlier test made: paused before the new run's first frame, a redraw has nothing to draw)
        wait_for(
            lambda: app.loop.status.scenario == "polish" and app.loop.status.t > 0.5 and len(plots.history.t) >= 2,
            60,
            "the polish run's torques in the plots' history",
        )
        wait_for(lambda: drawn_joints(pg) == tuple(range(1, n + 1)), 60, "every joint's torque drawn")
        app.loop.submit(Pause())  # a still page answers clicks sooner; the chart redraws from its history
        wait_for(lambda: pg.evaluate(_SIGNALS_FOLD_JS, TORQUE_TITLE), 30, "the torque chart's Signals fold to open")
        for k in (1, 2, 3):
            box = pg.get_by_label(f"τ{k}", exact=True)
            box.scroll_into_view_if_needed()
            box.uncheck()
        try:
            wait_for(lambda: drawn_joints(pg) == tuple(range(4, n + 1)), 30, "τ1…τ3 hidden in the page's chart")
        except pytest.fail.Exception:
            state = torque_chart_state(pg, plots)
            pytest.fail(f"τ1…τ3 not hidden in the page's chart after 30 s: {state}", pytrace=False)
        assert plots.signals.shown_keys("torque") == (*(f"tau_{k}" for k in range(4, n + 1)), "limits")
        app.loop.submit(SwitchSession(scenario="limit-drop", robot=""))
        app.loop.submit(Play())
        wait_for(lambda: app.loop.status.scenario == "limit-drop" and app.loop.status.t > 0.5, 60, "the limit drop")
        wait_for(lambda: drawn_joints(pg) == tuple(range(4, n + 1)), 60, "the same joints drawn after the switch")
        box = pg.get_by_label("τ2", exact=True)
        box.scroll_into_view_if_needed()
        box.check()
        wait_for(lambda: drawn_joints(pg) == (2, *range(4, n + 1)), 30, "τ2 drawn again")
    finally:
        plots.choose_signals("torque", [k for k, _ in plots.signals.specs["torque"]])
        app.loop.submit(SwitchSession(scenario="polish", robot="rizon4s", executor="projection"))
        app.loop.submit(Play())
        wait_for(lambda: app.loop.status.scenario == "polish", 60, "polish again")


_DRAWN_POINTS_JS = """(points) => {
    // world points (the server's frame, z up) where the page draws them: the scene root's transform, then
    // the page's own camera; CSS pixels of the page
    const m = window.__viserMutable, root = m && m.nodeRefFromName[''];
    if (!m || !m.camera || !m.canvas || !root) return null;
    const cam = m.camera, rect = m.canvas.getBoundingClientRect();
    cam.updateMatrixWorld();
    root.updateWorldMatrix(true, false);
    const mul = (e, p) => [0, 1, 2, 3].map(r => e[r] * p[0] + e[4 + r] * p[1] + e[8 + r] * p[2] + e[12 + r] * p[3]);
    const out = points.map(p => {
        const c = mul(cam.projectionMatrix.elements, mul(cam.matrixWorldInverse.elements,
                                                         mul(root.matrixWorld.elements, [p[0], p[1], p[2], 1])));
        return c[3] > 0 ? [rect.x + (c[0] / c[3] + 1) / 2 * rect.width, rect.y + (1 - c[1] / c[3]) / 2 * rect.height]
                        : null;
    });
    return {points: out, canvas: {x: rect.x, y: rect.y, width: rect.width, height: rect.height}};
}"""
IN_VIEW_MARGIN_PX = 40  # about a link's radius at the framed distance: the link around its origin is in view too


def arm_in_view(app: Any, pg: Any) -> str:
    """ "" if every link origin, the tool and the coupling ellipse's centre are drawn inside the page's 3D
    view (the canvas between the panels) at least IN_VIEW_MARGIN_PX from its edges, else what is not."""
    snap = app.publisher.last_frame.scene
    names = [*snap.link_names, "tool"]
    points = [*np.asarray(snap.link_positions).tolist(), np.asarray(snap.tcp_position).tolist()]
    center = app.publisher.scene.overlays.coupling_center if app.publisher.scene is not None else None
    if center is not None and app.publisher.scene.overlays.coupling_disc.visible:
        names.append("coupling ellipse")
        points.append(np.asarray(center).tolist())
    got = pg.evaluate(_DRAWN_POINTS_JS, points)
    if got is None:
        return "no camera in the page"
    box, m = got["canvas"], IN_VIEW_MARGIN_PX
    out = [
        f"{name} at {None if xy is None else (round(xy[0]), round(xy[1]))}"
        for name, xy in zip(names, got["points"], strict=True)
        if xy is None
        or not (
            box["x"] + m < xy[0] < box["x"] + box["width"] - m and box["y"] + m < xy[1] < box["y"] + box["height"] - m
        )
    ]
    return "; ".join(out) + (f" outside the view {box}" if out else "")


def assert_in_view(app: Any, pg: Any, what: str, timeout: float = 10.0) -> None:
    """`arm_in_view` within `timeout` s (the page takes a frame or two to draw a new camera), else fail with
    what is out of view."""
    deadline = time.monotonic() + timeout
    while (problem := arm_in_view(app, pg)) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not problem, f"{what}: {problem}"


def test_the_arm_its_tool_and_the_ellipse_stay_in_view_after_a_robot_switch_a_load_and_a_preset_switch(
    app, page, browser
):
    """Polish → robot gen3: after 8 s (the settle swings gen3's elbow far from its start) every link origin,
    the tool and the coupling ellipse are drawn inside the 3D view between the panels; so they are in a page
    that loads then, and after a switch to the mass drop (gen3)."""
    from app.core.commands import Play, SwitchSession

    pg, _ = page
    try:
        app.loop.submit(SwitchSession(scenario="polish", robot="gen3"))
        app.loop.submit(Play())
        wait_for(lambda: app.loop.status.scenario == "polish" and app.loop.status.t > 8.0, 90, "8 s of gen3's polish")
        assert_in_view(app, pg, "gen3's polish after the robot switch")
        other, _ = open_page(app, browser)
        try:
            assert_in_view(app, other, "gen3's polish in a page that loads now", 20.0)
        finally:
            other.close()
        app.loop.submit(SwitchSession(scenario="mass-drop", robot=""))
        app.loop.submit(Play())
        wait_for(lambda: app.loop.status.scenario == "mass-drop" and app.loop.status.t > 3.0, 90, "the mass drop")
        assert_in_view(app, pg, "the mass drop after the preset switch")
    finally:
        app.loop.submit(SwitchSession(scenario="polish", robot="rizon4s", executor="projection"))
        app.loop.submit(Play())
        wait_for(lambda: app.loop.status.scenario == "polish", 60, "polish again")


def test_space_pauses_and_plays_arrow_steps_and_r_resets(app, page):
    from app.core.commands import Play
    from app.live.ui.panels.scenario import ScenarioPanel

    pg, _ = page
    open_tab(pg, "Run")
    pg.evaluate("() => document.activeElement && document.activeElement.blur()")
    wait_for(lambda: app.loop.status.running and app.loop.status.t > 0.3, 30, "the simulation to run")
    try:
        pg.keyboard.press("Space")
        wait_for(lambda: not app.loop.sync().running, 20, "Space to pause")
        panel = next(p for p in app.panels if isinstance(p, ScenarioPanel))
        wait_for(lambda: panel.run.label == "Play", 20, "the run button to offer Play")
        wait_for(lambda: pg.locator("button:has-text('Play')").count() > 0, 20, "the page to show Play")
        t = app.loop.sync().t
        pg.keyboard.press("ArrowRight")
        wait_for(lambda: abs(app.loop.sync().t - (t + 0.001)) < 1e-9, 20, "→ to step 1 ms")
        pg.keyboard.press("Space")
        wait_for(lambda: app.loop.sync().running, 20, "Space to play")
        wait_for(lambda: app.loop.status.t > t + 0.3, 30, "time to advance")
        before = app.loop.status.t
        pg.keyboard.press("r")
        wait_for(lambda: app.loop.sync().t < before - 0.2, 20, "R to reset (time starts again)")
    finally:
        app.loop.submit(Play())


def test_restore_defaults_button_in_the_page_returns_the_parameters_to_the_presets_defaults(app, page, paused):
    from app.core.commands import SetParam
    from app.core.session import Session

    pg, _ = page
    open_tab(pg, "Run")
    default = Session("polish", robot="rizon4s", executor="projection").params()["drag"].max_force_n
    app.loop.submit(SetParam("drag", "max_force_n", 0.5 * default))
    app.loop.sync()
    assert app.loop.session.drag.max_force_n == pytest.approx(0.5 * default) and app.loop.lab.overrides
    button = pg.get_by_role("button", name="Restore defaults")
    button.scroll_into_view_if_needed()
    button.click()
    wait_for(lambda: app.loop.sync() and not app.loop.lab.overrides, 20, "Restore defaults to forget the overrides")
    assert app.loop.session.drag.max_force_n == pytest.approx(default)
    assert pg.get_by_role("button", name="Save settings").count() == 1


_NUMBER_BOX_JS = """([pattern, mark]) => {
    const re = new RegExp(pattern);
    for (const label of document.querySelectorAll('label')) {
        if (!re.test(label.textContent.trim())) continue;
        let el = document.getElementById(label.htmlFor);
        for (let up = 0; el && up < 5; up++, el = el.parentElement) {
            const box = el.querySelector('input:not([type=hidden])');
            if (box) { box.setAttribute('data-tour-box', mark); return true; }
        }
    }
    return false;
}"""


def type_number(pg: Any, label_pattern: str, text: str) -> None:
    """Type `text` into the number box of the input labelled `label_pattern` (a slider's box too)."""
    mark = f"box{time.monotonic_ns()}"
    wait_for(lambda: pg.evaluate(_NUMBER_BOX_JS, [label_pattern, mark]), 30, f"the number box of {label_pattern}")
    box = pg.locator(f"[data-tour-box={mark}]")
    box.scroll_into_view_if_needed()
    box.fill(text)
    box.press("Enter")


def number_text(pg: Any, label_pattern: str) -> str:
    """The text the number box of the input labelled `label_pattern` shows in the page."""
    mark = f"box{time.monotonic_ns()}"
    wait_for(lambda: pg.evaluate(_NUMBER_BOX_JS, [label_pattern, mark]), 30, f"the number box of {label_pattern}")
    return str(pg.locator(f"[data-tour-box={mark}]").input_value())


def param(app: Any, group: str, field: str) -> Any:
    """A parameter in force, read on the loop thread."""
    return app.loop.call(lambda s: getattr(s.params()[group], field))


def press(pg: Any, key: str) -> None:
    """A key for the page's hotkeys (Space, r, …), with no input focused."""
    pg.evaluate("() => document.activeElement && document.activeElement.blur()")
    pg.keyboard.press(key)


def set_running(app: Any, pg: Any, running: bool) -> None:
    """Play or pause with Space (the tour's key) until the loop is in that state."""
    if app.loop.sync().running != running:
        press(pg, "Space")
    wait_for(lambda: app.loop.sync().running == running, 30, "Space to " + ("play" if running else "pause"))


def choose_preset(app: Any, pg: Any, name: str) -> None:
    """Pick a preset in the Run tab's dropdown (again if a busy page lost the first pick)."""
    open_tab(pg, "Run")
    for _ in range(3):
        choose(pg, "Preset", name)
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline:
            if app.loop.status.scenario == name and app.publisher.scene_session_id == app.loop.lab.session_id:
                return
            time.sleep(0.1)
    pytest.fail(f"the preset {name} did not start", pytrace=False)


def test_the_first_look_drag_in_free_moves_the_elbow_along_the_spring(app, page):
    """docs/getting-started.md "A first look", as a person takes it in the page (the lessons have their own
    tests below):
    free: a drag on the elbow moves the grabbed point ≥ 1 cm along the spring's pull with > 5 N; mouse-up
    releases it. Executor → projection, the same drag: the elbow follows ≥ 1 cm (the TCP's shift is
    printed: that page says a hard pull moves it as well)."""
    from app.core.commands import Play, SetSpeed, SwitchSession

    pg, client = page
    t0 = time.monotonic()

    def lap(what: str) -> None:
        print(f"tour: {what} at {time.monotonic() - t0:.1f} s wall")

    try:
        # ---- 1. free: drag the elbow --------------------------------------------------------------
        set_running(app, pg, False)
        choose_preset(app, pg, "free")
        set_running(app, pg, True)
        assert drag_state(app).body is None
        moved, peak = drag_along_the_spring(
            pg, client, app, DRAG_LINK, "the grabbed point to follow the spring by 1 cm"
        )
        assert moved > 0.01 and peak > 5.0, f"moved {moved * 1e3:.1f} mm with at most {peak:.1f} N"
        save_tour_shot(pg, "tour-1-drag.png")
        pg.mouse.up()
        wait_for(lambda: drag_state(app).body is None, 20, "mouse-up to release the drag")
        # Executor → projection: only the TCP pose is held, so the dragged elbow moves in the nullspace
        set_running(app, pg, False)
        open_tab(pg, "Run")
        choose(pg, "Executor", "projection")
        wait_for(lambda: app.loop.sync().executor == "projection", 30, "the projection executor")
        set_running(app, pg, True)
        tcp_before = app.loop.call(lambda s: s.dyn.tcp_position_world.copy())
        moved, _ = drag_along_the_spring(
            pg, client, app, DRAG_LINK, "the elbow to follow the spring by 1 cm (projection)"
        )
        tcp_now = app.loop.call(lambda s: s.dyn.tcp_position_world.copy())
        tcp_shift = float(np.linalg.norm((tcp_now - tcp_before)[:2]))  # x, y: motion axes (z: the force axis)
        print(
            f"tour step 1: projection: elbow {moved * 1e3:.1f} mm along the pull, TCP {tcp_shift * 1e3:.1f} mm in x, y "
            f"and {(tcp_now - tcp_before)[2] * 1e3:+.1f} mm in z"
        )
        assert moved > 0.01 and app.loop.status.executor == "projection"
        pg.mouse.up()
        wait_for(lambda: drag_state(app).body is None, 20, "mouse-up to release the drag")
        set_running(app, pg, False)
        lap("step 1 done")

    finally:
        pg.mouse.up()
        app.loop.submit(SetSpeed(1.0))
        app.loop.submit(SwitchSession(scenario="polish", robot="rizon4s", executor="projection"))
        app.loop.submit(Play())
        wait_for(lambda: app.loop.status.scenario == "polish", 60, "polish again")


def test_bench_serve_runs_the_app_with_a_plain_headless_chromium_and_reports_what_it_measured(monkeypatch):
    """`bench --serve` opens the page in a Chromium process of its own (no automation driver in the
    server's process), runs the polish preset with every overlay, and reports a run it measured: one
    browser connected, simulated time advancing near real time, frames published, nothing halted,
    the plots' redraw probed; the browser is gone afterwards."""
    import subprocess

    from app.tools import bench_serve

    monkeypatch.setattr(bench_serve, "CHROMIUM", chromium_path())
    report = bench_serve.run_serve_bench(seconds=3.0, warmup=0.5)
    assert report["browser_clients"] == 1
    assert report["halted"] == ""
    assert report["sim_s"] > 1.0
    assert 0.5 < report["real_time_factor"] < 1.1
    assert report["frames_per_s"] > 5.0
    assert report["scene_updates_per_s"] > 5.0
    assert report["step_cpu_per_sim_s"] > 0.0
    assert len(report["overlays_on"]) >= 5
    wait, choice = report["plots_redraw_wait_ms"], report["plots_signal_choice_ms"]  # probed 10 and 1 times a second
    assert 20 <= wait["n"] <= 40 and 2 <= choice["n"] <= 4
    assert 0.0 <= wait["median"] <= wait["p99"] <= wait["max"] < 1000.0
    assert 0.0 < choice["median"] <= choice["max"] < 1000.0
    stalls = report["machine_stalls"]  # the probe process beside the app reported
    assert "error" not in stalls, stalls
    assert stalls["seconds"] == 3.0 and stalls["wakeups"] > 100
    left = subprocess.run(["pgrep", "-f", "torquelab-chromium-"], capture_output=True, text=True).stdout.split()
    assert left == []


def test_contact_loss_is_marked_in_the_3d_view_live_and_in_replay_and_a_reset_clears_the_replay(app, page):
    """Polish with μ = 1 and W_j loses contact on S2 (about 6 s). Live: the red cross where the tool lifted
    is drawn in the page (red pixels where the camera projects it). Replay at the first loss + 10 ms: the
    status line says it is a replay at that instant, *Jump to event* names that loss, the ring is red and
    the target stands where it was logged. Reset: the replay ends and its controls hold no range nor event."""
    from app.core.commands import Play, Reset, RestoreDefaults, SetParam, SetSpeed, SwitchSession
    from app.scenarios.metrics import contact_loss_onsets

    pg, client = page
    replay = app.publisher.replay
    loop = app.loop
    for cmd in (
        RestoreDefaults(),
        SwitchSession(scenario="polish", robot="rizon4s", executor="projection"),
        SetParam("contact", "mu", 1.0),
        SetParam("nullspace", "objective", "j"),
        SetSpeed(1000.0),
        Play(),
    ):
        loop.submit(cmd)
    try:

        def overlays() -> Any:
            """The scene's overlays, once the publisher has built the polish scene (it is None while it rebuilds)."""
            return wait_for(lambda: app.publisher.scene, 30, "the polish scene").overlays

        wait_for(lambda: loop.status.scenario == "polish" and loop.status.t > 6.4, 180, "polish past S2's first loss")
        loop.submit(SetSpeed(1.0))
        wait_for(lambda: overlays().lift_marks.visible, 30, "the live lift mark")
        box = pg.get_by_label("Replay", exact=True)
        box.scroll_into_view_if_needed()
        box.check()
        wait_for(lambda: replay.t is not None and not loop.status.running, 30, "the replay to start, paused")
        cols = replay.columns
        onsets = contact_loss_onsets(cols["contact_force_n"], cols["segment"])
        assert len(onsets) >= 1
        lift_t = float(cols["t"][onsets[0]])
        mark = overlays().lift_marks
        cross = np.asarray(mark.points, dtype=float)[:2].reshape(-1, 3).mean(axis=0)
        set_camera(client, cross + np.array([0.35, -0.55, 0.35]), cross)
        canvas = pg.locator(SCENE_CANVAS).bounding_box()
        u, v = project(client, canvas, cross)
        around = {"x": u - 40, "y": v - 40, "width": 80, "height": 80}
        ARTIFACTS.mkdir(exist_ok=True)
        pg.screenshot(path=str(ARTIFACTS / "scene-contact-lost.png"))
        assert red_pixels(pg, around) > 30  # the red cross (and the red ring beside it) in the page

        type_number(pg, r"^At t \(s\)", f"{lift_t + 0.01:.3f}")
        wait_for(lambda: replay.t is not None and abs(replay.t - (lift_t + 0.01)) < 0.003, 20, "the replay instant")
        wait_for(lambda: overlays().lost_ring.visible, 20, "the red ring at the replayed loss")
        label = f"contact lost at {cols['t'][onsets[0]]:.2f} s"
        assert replay.jump.value == label
        pg.get_by_text(re.compile(r"Replay at t = " + re.escape(f"{replay.t:.3f}"))).first.wait_for(timeout=20_000)
        i = int(np.searchsorted(cols["t"], replay.t))
        logged_target = np.array([cols[f"target_{a}_m"][i] for a in "xyz"])
        wait_for(
            lambda: np.allclose(np.asarray(overlays().target.position), logged_target, atol=1e-6),
            20,
            "the target at its logged place",
        )
        pg.screenshot(path=str(ARTIFACTS / "scene-contact-replay.png"))

        loop.submit(Reset())
        wait_for(lambda: replay.t is None and tuple(replay.jump.options) == ("–",), 30, "the replay's controls reset")
        assert replay.slider.disabled and not replay.active.value
    finally:
        if replay.t is not None:
            replay.set_active(False)
        loop.submit(RestoreDefaults())
        loop.submit(SwitchSession(scenario="polish", robot="rizon4s", executor="projection"))
        loop.submit(SetSpeed(1.0))
        loop.submit(Play())
        wait_for(lambda: loop.status.scenario == "polish", 60, "polish again")


_HINT_SHOWN_JS = """(text) => {
    for (const tip of document.querySelectorAll('[role="tooltip"]')) {
        if (!tip.textContent.startsWith(text)) continue;
        const style = getComputedStyle(tip);
        if (style.display !== 'none' && Number(style.opacity) > 0.05) return tip.id || 'shown';
    }
    return null;
}"""
_UNDER_POINTER_JS = """([x, y]) => {
    const el = document.elementFromPoint(x, y);
    return el ? (el.closest('button') || el).textContent.trim() : '';
}"""


def test_a_hint_is_gone_when_the_pointer_moves_on_to_the_button_below_or_its_control_moves_away(app, page, paused):
    """Run tab: the pointer rests on the *Single step* buttons until their hint shows, then moves on to
    *Reset* below: within 0.5 s the hint is hidden, and the hint never takes the pointer (what lies under
    it is *Reset*). Again with the pointer still and the buttons moved 300 px away under it (as a panel's
    controls move when a line above them grows): the hint is hidden within 1 s."""
    pg, _ = page
    hint = "→: 1 ms"
    show_tab(pg, "Run")

    def centre(name: str) -> tuple[float, float]:
        box = wait_for(lambda: pg.get_by_role("button", name=name).bounding_box(), 30, f"the {name} button")
        return box["x"] + box["width"] / 2, box["y"] + box["height"] / 2

    def rest_on(x: float, y: float) -> str:
        pg.mouse.move(x - 200, y)  # from off the panel: the pointer enters the control
        pg.mouse.move(x, y, steps=3)
        return wait_for(lambda: pg.evaluate(_HINT_SHOWN_JS, hint), 30, "the Single step hint")

    step_x, step_y = centre("100 ms")
    reset = centre("Reset")
    moved = False
    try:
        rest_on(step_x, step_y)
        pg.mouse.move(*reset, steps=2)
        left = time.monotonic()
        assert pg.evaluate(_UNDER_POINTER_JS, list(reset)) == "Reset", "the hint took the pointer over Reset"
        wait_for(lambda: not pg.evaluate(_HINT_SHOWN_JS, hint), 10, "the hint to close over Reset", period=0.02)
        assert time.monotonic() - left < 0.5, f"the hint stayed {time.monotonic() - left:.2f} s over Reset"
        tip = rest_on(step_x, step_y)
        moved = pg.evaluate(
            '(id) => { const c = document.querySelector(`[aria-describedby~="${id}"]`);'
            " if (!c) return false; c.style.transform = 'translateY(300px)'; return true; }",
            tip,
        )
        assert moved, "no control names the hint"
        still = time.monotonic()
        wait_for(lambda: not pg.evaluate(_HINT_SHOWN_JS, hint), 10, "the hint to close under the still pointer")
        assert time.monotonic() - still < 1.0, f"the hint stayed {time.monotonic() - still:.2f} s"
    finally:
        if moved:
            pg.evaluate("() => document.querySelectorAll('[aria-describedby]').forEach(c => c.style.transform = '')")
        pg.mouse.move(120, VIEWPORT["height"] - 80)


def test_the_lambda_box_refuses_minus_5_in_its_own_words_and_takes_250_5_as_typed(app, page, paused):
    """Limit-drop, Tune, the damper's λ box (a slider's, step 1): "-5" is refused with a notice in the
    page that names λ, not the parameter's internal name, and λ stays; "250.5" is taken as typed (the
    page dropped the "." of a step-1 box and sent 250) and the box shows 250.5."""
    from app.core.commands import SetParam, SwitchSession

    pg, _ = page
    app.loop.submit(SwitchSession(scenario="limit-drop", robot=""))
    wait_for(lambda: app.loop.status.scenario == "limit-drop", 60, "the limit drop")
    label = "λ (1/s)"
    _, k = _knob(app, label)
    before = float(param(app, k.group, k.field))
    open_tab(pg, "Tune", timeout_ms=120_000)
    pg.set_default_timeout(120_000)
    try:
        seen = len(app.loop.lab.notice_log)
        type_number(pg, "^" + re.escape(label) + "$", "-5")
        words = "λ must be between 1 and 1000 1/s, got -5"
        notices = wait_for(
            lambda: [n for n in list(app.loop.lab.notice_log)[seen:] if n.title == "Value refused"], 30, "the refusal"
        )
        assert notices[0].body == words and "lambda_" not in notices[0].body
        wait_for(lambda: pg.get_by_text(words, exact=False).count() > 0, 20, "the refusal shown in the page")
        assert float(param(app, k.group, k.field)) == pytest.approx(before)
        type_number(pg, "^" + re.escape(label) + "$", "250.5")
        wait_for(lambda: float(param(app, k.group, k.field)) == pytest.approx(250.5), 30, "λ = 250.5 in force")
        assert number_text(pg, "^" + re.escape(label) + "$") == "250.5"
    finally:
        pg.set_default_timeout(30_000)
        app.loop.submit(SetParam(k.group, k.field, before))
        app.loop.submit(SwitchSession(scenario="polish", robot="rizon4s", executor="projection"))
        wait_for(lambda: app.loop.status.scenario == "polish", 60, "polish again")


_CHART_BOXES_JS = """() => {
    const out = [];
    for (const v of Object.values((window.__viserTestpoints || {}).uplots || {})) {
        const c = v.chart;
        if (!c.root.isConnected || c.root.offsetParent === null) continue;
        const r = c.root.getBoundingClientRect();
        if (!(r.width > 0 && r.height > 0)) continue;
        const finite = (c.data[1] || []).filter(x => x !== null && Number.isFinite(x)).length;
        out.push({title: c.root.querySelector('.u-title')?.textContent || '', x: r.x, y: r.y,
                  right: r.right, bottom: r.bottom, finite: finite});
    }
    return out;
}"""
STEP_CHART_TITLES = {  # a lesson step's chart (`Step.plots`) by the start of its title in the page
    "force": ("Force error", "F̂_z"),
    "phase": ("Joint 4 phase",),
    "torque": ("Torques",),
    "deflection": ("Deflection",),
}
WARNING_TITLE = "Stroke headroom"  # the margin's chart, under the force error in a polish step


def chart_box(pg: Any, prefixes: tuple[str, ...]) -> dict[str, Any] | None:
    """The page box (x, y, right, bottom, CSS px) and finite samples of the shown chart whose title starts
    with one of `prefixes`."""
    return next((b for b in pg.evaluate(_CHART_BOXES_JS) if b["title"].startswith(prefixes)), None)


def outside_viewport(box: dict[str, Any] | None) -> str:
    """How a chart's box leaves the 1600×1000 viewport ("" when it lies inside it)."""
    if box is None:
        return "not shown"
    w, h = VIEWPORT["width"], VIEWPORT["height"]
    inside = box["x"] >= 0 and box["y"] >= 0 and box["right"] <= w and box["bottom"] <= h
    return (
        ""
        if inside
        else f"{box['title']!r} at x {box['x']:.0f}…{box['right']:.0f}, y {box['y']:.0f}…{box['bottom']:.0f}"
    )


def step_charts_in_view(pg: Any, step: Any, polish: bool, when: str) -> None:
    """The chart a lesson step names first and, in a polish step, the margin's headroom chart under it lie
    inside the viewport (waits up to 60 s for the page to arrange them)."""
    wanted = [STEP_CHART_TITLES[step.plots[0]]] + ([(WARNING_TITLE,)] if polish else [])

    def misplaced() -> list[str]:
        return [m for m in (outside_viewport(chart_box(pg, t)) for t in wanted) if m]

    try:
        wait_for(lambda: not misplaced(), 60, f"{step.title}: its charts in view {when}", period=1.0)
    except pytest.fail.Exception:
        ARTIFACTS.mkdir(exist_ok=True)
        pg.screenshot(path=str(ARTIFACTS / f"lesson-view-{step.key}.png"))
        raise AssertionError(f"{step.title} {when}: outside the 1600×1000 viewport: {misplaced()}") from None


LESSON_SPEED = 4.0  # the lesson viewport test's requested speed (× real time)


def step_scenario(step: Any) -> str:
    """The preset a lesson step's set-up switches to."""
    from app.core.commands import SwitchSession

    return next(c.scenario for c in step.setup(None) if isinstance(c, SwitchSession))


VIEW_CHECKED: set[tuple[str, str]] = set()  # (lesson, step) whose charts a lesson test saw in view (`step_in_view`)


def step_in_view(pg: Any, panel: Any, step: Any, when: str) -> None:
    """A lesson step just set up from the Lessons panel (`when` "while it runs") or ended ("at its end"):
    its first chart has drawn samples, it and (in a polish step) the margin's headroom chart lie in the
    viewport (`step_charts_in_view`), and the Replay fold sits under the step's charts."""
    polish = step_scenario(step) == "polish"
    first = STEP_CHART_TITLES[step.plots[0]]
    wait_for(lambda: (chart_box(pg, first) or {}).get("finite", 0) > 5, 120, f"{step.title}'s samples")
    step_charts_in_view(pg, step, polish, when)
    # under the step's first chart (order 1), from the first frame of the step's run on
    wait_for(lambda: panel.view.replay_folder.order > 1.0, 30, f"{step.title}: the Replay fold under its charts {when}")


def test_every_lesson_steps_plot_and_the_margins_warning_lie_in_the_viewport(app, page):
    """Every step of every lesson, set up from the Lessons panel, in a 1600×1000 page: once its run has
    drawn samples and again at its end (paused, the result shown), the chart the step names first
    (`Step.plots`) and, in a polish step, the margin's headroom chart under the force error lie inside the
    viewport, the status line above them; the Replay fold sits under the step's charts while the step's run is
    on and returns to the top after a Reset. The lesson tests above check the steps they run as they run them
    (`run_lesson_in_the_page`); this test runs the others (all of them when run alone). With
    TORQUELAB_UPDATE_SCREENSHOT=1 it runs every step and writes each one's end to
    static/lessons/after/LESSON-stepN.png (docs/lessons/*.md)."""
    from app.core.commands import Play, Reset, SetSpeed, SwitchSession
    from app.live.curriculum import LESSONS
    from app.live.ui.panels.lessons import LessonsPanel

    pg, _ = page
    panel = next(p for p in app.panels if isinstance(p, LessonsPanel))
    replay_order = panel.view.replay_order
    pg.set_default_timeout(120_000)
    try:
        show_tab(pg, "Lessons")
        # the steps' runs (over 3 simulated minutes) as fast as the loop goes, up to LESSON_SPEED× real time:
        # the layout and the claims do not depend on the pace (a claim is measured on the step log); the
        # screenshots are taken at the page's own pace
        if os.environ.get("TORQUELAB_UPDATE_SCREENSHOT") != "1":
            app.loop.submit(SetSpeed(LESSON_SPEED))
        shots = os.environ.get("TORQUELAB_UPDATE_SCREENSHOT") == "1"
        ran = 0
        for lesson in LESSONS:
            for i, step in enumerate(lesson.steps):
                key = (lesson.key, step.key)
                if key in VIEW_CHECKED and not shots:
                    continue
                ran += 1
                panel.select(lesson.key, i)
                panel.start_step()
                # the step's own preset: the loop's status may still be the step before's for a while after
                # the set-up on a loaded machine (it read "polish" in the first dampers step, which then
                # waited for a headroom chart the limit drop does not have)
                step_in_view(pg, panel, step, "while it runs")
                wait_for(lambda k=key: k in panel.claims, 900, f"the result of {step.title}", period=0.5)
                claim = panel.claims[key]
                assert not claim.startswith("Cancelled"), claim
                step_in_view(pg, panel, step, "at its end")
                VIEW_CHECKED.add(key)
                if shots:  # the docs' picture of the step
                    pg.get_by_text(claim[:40], exact=False).first.wait_for()
                    save_step_shot(pg, f"{lesson.key}-step{i + 1}.png", claim[:40])
        # the Replay fold is still under the charts of the last step run here, until the Reset
        assert ran > 0 and panel.view.replay_folder.order != replay_order, (ran, panel.view.replay_folder.order)
        every = {(lesson.key, step.key) for lesson in LESSONS for step in lesson.steps}
        assert VIEW_CHECKED >= every, sorted(every - VIEW_CHECKED)
        print(f"lesson steps in view: {len(every)}, {ran} of them run here")
        app.loop.submit(Reset())
        wait_for(lambda: panel.view.replay_folder.order == replay_order, 30, "the Replay fold back on top")
    finally:
        pg.set_default_timeout(30_000)
        app.loop.submit(SetSpeed(1.0))
        app.loop.submit(SwitchSession(scenario="polish", robot="rizon4s", executor="projection"))
        app.loop.submit(Play())
        wait_for(lambda: app.loop.status.scenario == "polish", 60, "polish again")


LESSON_SHOTS = README_SCREENSHOT.parent / "lessons"
LESSON_SHOT_BYTES = 300_000  # a docs page's picture: larger ones are cut to a 256-colour palette
STEP_SHOT_SIZE = (1200, 750)  # each lesson step's picture: the 1600×1000 page scaled by 3/4
STEP_SHOT_COLOURS = 128  # in a palette without dithering: about 130 kB a picture
STEP_SHOTS = LESSON_SHOTS / "after"  # the page at the end of every lesson step (docs/lessons/*.md)


def save_lesson_shot(pg: Any, name: str, text: str) -> None:
    """The page with `text` (a step's result line) scrolled into view: test-artifacts/lessons/NAME, copied to
    static/lessons/ (docs/lessons/*.md show it), as a 256-colour PNG when the full-colour one is too large."""
    from PIL import Image

    pg.get_by_text(text, exact=False).first.scroll_into_view_if_needed()
    (ARTIFACTS / "lessons").mkdir(parents=True, exist_ok=True)
    save_tour_shot(pg, f"lessons/{name}")
    shot = ARTIFACTS / "lessons" / name
    if shot.stat().st_size > LESSON_SHOT_BYTES:
        Image.open(shot).convert("RGB").quantize(256).save(shot, optimize=True)
    assert Image.open(shot).size == (VIEWPORT["width"], VIEWPORT["height"])
    LESSON_SHOTS.mkdir(exist_ok=True)
    shutil.copyfile(shot, LESSON_SHOTS / name)


def save_step_shot(pg: Any, name: str, text: str) -> None:
    """The page at 1600×1000 with `text` (a step's result line) scrolled into view, scaled to STEP_SHOT_SIZE
    in STEP_SHOT_COLOURS: test-artifacts/lessons/steps/NAME, copied to STEP_SHOTS."""
    from PIL import Image

    pg.get_by_text(text, exact=False).first.scroll_into_view_if_needed()
    shot = ARTIFACTS / "lessons" / "steps" / name
    shot.parent.mkdir(parents=True, exist_ok=True)
    close_notices(pg)
    pg.screenshot(path=str(shot))
    image = Image.open(shot).convert("RGB")
    assert image.size == (VIEWPORT["width"], VIEWPORT["height"])
    small = image.resize(STEP_SHOT_SIZE, Image.Resampling.LANCZOS)
    small.quantize(STEP_SHOT_COLOURS, dither=Image.Dither.NONE).save(shot, optimize=True)
    STEP_SHOTS.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(shot, STEP_SHOTS / name)


@pytest.mark.skipif(
    os.environ.get("TORQUELAB_UPDATE_SCREENSHOT") != "1",
    reason="writes the lesson pages' screenshots (static/lessons/): run with TORQUELAB_UPDATE_SCREENSHOT=1 "
    "(the lessons' claims are checked by the lesson tests above)",
)
def test_the_lesson_screenshots_are_written_on_request(app, page):
    """Dampers step 1 with λ changed after *Set up this step*: its "Step cancelled" line in view,
    static/lessons/dampers-step1-cancelled.png (every step's end: the viewport test above)."""
    from app.core.commands import Pause, Play, SetParam, SwitchSession
    from app.live.curriculum import LESSONS
    from app.live.ui.panels.lessons import LessonsPanel

    pg, _ = page
    panel = next(p for p in app.panels if isinstance(p, LessonsPanel))
    pg.set_default_timeout(120_000)  # a software-rendered page on a loaded machine takes seconds per click
    label = "λ (1/s)"
    _, k = _knob(app, label)
    before: float | None = None
    try:
        spec = next(x for x in LESSONS if x.key == "dampers")
        open_tab(pg, "Lessons")
        choose(pg, "Lesson", spec.title)
        wait_for(lambda: panel.lesson.key == "dampers" and panel.index == 0, 20, "the dampers lesson")
        pg.get_by_role("button", name="Set up this step").click()
        wait_for(lambda: panel.armed is not None and app.loop.status.scenario == "limit-drop", 180, "the step set up")
        app.loop.submit(Pause())  # the step's 3 s would end before a slow page has typed λ
        before = float(param(app, k.group, k.field))
        open_tab(pg, "Tune")
        type_number(pg, "^" + re.escape(label) + "$", "1000")
        wait_for(lambda: float(param(app, k.group, k.field)) == pytest.approx(1000.0), 30, "λ = 1000 in force")
        app.loop.submit(Play())
        key = ("dampers", spec.steps[0].key)
        claim = wait_for(lambda: panel.claims.get(key), 120, "the step to be cancelled", period=0.5)
        assert claim.startswith("Cancelled: ") and "λ" in claim, claim
        open_tab(pg, "Lessons")
        save_lesson_shot(pg, "dampers-step1-cancelled.png", "Step cancelled")
        app.loop.submit(SetParam(k.group, k.field, before))
    finally:
        pg.set_default_timeout(30_000)
        if before is not None:
            app.loop.submit(SetParam(k.group, k.field, before))
        app.loop.submit(SwitchSession(scenario="polish", robot="rizon4s", executor="projection"))
        app.loop.submit(Play())
        wait_for(lambda: app.loop.status.scenario == "polish", 60, "polish again")


# ---- last: it closes the module's page ------------------------------------------------------------
def test_disconnect_during_a_drag_releases_the_force_within_a_second(app, page):
    """Closing the tab mid-drag (no mouse-up) releases the spring within 1 s, even behind ten seconds
    of queued single steps; runs last: it closes the page."""
    from app.core.commands import StepOnce

    pg, client = page
    start_drag(pg, client, app, DRAG_LINK)
    view = drag_state(app)
    assert view.body == DRAG_LINK and view.force_n > 0.0
    for _ in range(5):
        app.loop.submit(StepOnce(2000))
    pg.close()
    closed = time.monotonic()
    # read what the loop published (a call() would wait behind the queued steps)
    wait_for(lambda: app.loop.status.drag_client is None, 20, "the disconnect to release the drag", period=0.01)
    released_s = time.monotonic() - closed
    print(f"page closed mid-drag: released after {released_s:.3f} s")
    assert released_s < 1.0, f"the release took {released_s:.2f} s"
    assert not app.loop.session.drag.active
    wait_for(lambda: client.client_id not in app.server.get_clients(), 20, "the server to drop the client")
