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
import math
import os
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
    page.wait_for_selector("canvas", timeout=60_000)
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


# ---- camera and projection ------------------------------------------------------------------------
class CameraReports:
    """The camera poses the page itself reports (viser replaces `client.camera`'s state with each one,
    so right after a setter the state says where the page is told to go, not where it is)."""

    def __init__(self, client: Any):
        self.poses: list[tuple[np.ndarray, np.ndarray]] = []
        client.camera.on_update(self._record)

    def _record(self, camera: Any) -> None:
        self.poses.append((np.array(camera.position), np.array(camera.look_at)))


_CAMERA_REPORTS: dict[int, CameraReports] = {}


def set_camera(client: Any, position: np.ndarray, look_at: np.ndarray, app: Any = None) -> None:
    """Put the page's camera at a known pose (position first, then look_at) and wait until the page
    reports that pose back. With `app`, first wait until the app has framed a newly chosen preset,
    so that framing cannot move the camera after this."""
    if app is not None:
        wait_for(lambda: not app.publisher.framing_pending, 30, "the app to frame the new preset")
    if client.client_id not in _CAMERA_REPORTS:
        _CAMERA_REPORTS[client.client_id] = CameraReports(client)
    reports = _CAMERA_REPORTS[client.client_id]

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


def open_tab(pg: Any, name: str) -> None:
    """Show the control panel's tab `name` (Run, Tune, Visuals, Record)."""
    pg.get_by_role("tab", name=name).click()


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
    """A screenshot for the README's tour: test-artifacts/NAME, copied to static/ with
    TORQUELAB_UPDATE_SCREENSHOT=1."""
    ARTIFACTS.mkdir(exist_ok=True)
    close = pg.locator(".mantine-Notification-closeButton")  # notices would cover the 3D view
    for _ in range(close.count()):
        try:
            close.first.click(timeout=5_000)
        except Exception:  # closed on its own meanwhile
            pass
    pg.screenshot(path=str(ARTIFACTS / name))
    if os.environ.get("TORQUELAB_UPDATE_SCREENSHOT") == "1":
        shutil.copyfile(ARTIFACTS / name, README_SCREENSHOT.parent / name)


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


def test_force_plot_has_a_finite_range_and_a_drawn_trace_in_every_preset(app, page):
    """With the twin off (its series all NaN) the force error is drawn in each preset's default state;
    the limit drop shows its peak-torque readout."""
    from app.core.commands import Play, SwitchSession
    from app.scenarios import SCENARIOS

    pg, _ = page
    try:
        for name in SCENARIOS:
            app.loop.submit(SwitchSession(scenario=name, robot=""))
            app.loop.submit(Play())
            wait_for(lambda n=name: app.loop.status.scenario == n and app.loop.status.t > 0.5, 60, f"{name} to run")

            def drawn() -> dict[str, Any] | None:
                plot = force_plot(pg)
                if not plot or plot["n"] < 5 or not red_pixels(pg, plot["box"]) > 30:
                    return None
                return plot

            plot = wait_for(drawn, 60, f"a drawn force-error trace in {name}", period=0.5)
            assert np.isfinite(plot["ymin"]) and np.isfinite(plot["ymax"]) and plot["ymax"] > plot["ymin"], name
            if name == "limit-drop":
                wait_for(lambda: pg.get_by_text("peak |τ|", exact=False).first.is_visible(), 30, "the peak readout")
                assert app.publisher.plots.readouts["peak_torque_nm"] > 0.0
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


def param(app: Any, group: str, field: str) -> Any:
    """A parameter in force, read on the loop thread."""
    return app.loop.call(lambda s: getattr(s.params()[group], field))


TOUR_WJ_MARGIN = -30.0  # tour step 2: W_j at μ = 1, force-loop margin at rest (one period of sensing delay), N s/m
TOUR_MARGIN_TOLERANCE = 5.0
TOUR_WJ_STD = {2: 1.84, 4: 3.58, 6: 2.42}  # W_j at μ = 1: force-error STD (N) of the forward strokes, ± 0.15
TOUR_WA_SWIVEL, TOUR_WA_SETTLE_S = 75.0, 54.7  # W_a flows to about +75° in close to a minute
TOUR_SWIVEL_TOLERANCE, TOUR_SETTLE_TOLERANCE_S = 3.0, 3.0
TOUR_STD_RATIO = 1.58  # README tour step 2: twin W_j over main W_d, force-error STD over S2 and S4, μ = 1
TOUR_STD_TOLERANCE = 0.15
TOUR_PEAK_NM = {100.0: 14.5, 500.0: 36.9}  # README tour step 3: peak |τ₄| of the limit drop per λ
TOUR_PEAK_TOLERANCE_NM = 1.0
TOUR_TORQUE_LIMIT_NM = 39.0  # Gen3 joint 4: "chatters against the limit at the torque limit"
TOUR_CHATTER_REVERSALS = 20  # λ = 500 with 5 ms of delay: 74 velocity reversals in the first 3 s
TOUR_MIRROR_SWIVEL = -82.0  # README tour step 2: the mirror start's W_a flow reaches the −82° minimum
TOUR_PLANNED_SWIVEL = -84.0  # README tour step 2: the planned W_a path holds −84° (polish experiment's planned row)
TOUR_LATE_BRAKE_MRAD = 2.0  # M = 0.5, λ = 100, no delay: run_drop measures 8.1 mrad into d_s, 3 reversals


def first_seconds_reversals(columns: dict[str, np.ndarray], seconds: float) -> int:
    """Velocity reversals of joint 4 in the first `seconds` of the logged run."""
    return velocity_reversals(columns["dq_4"][columns["t"] <= seconds])


def velocity_reversals(dq: np.ndarray, floor: float = 1e-3) -> int:
    """Sign changes of a joint velocity, ignoring |q̇| ≤ `floor` rad/s (at rest)."""
    signs = np.sign(dq[np.abs(dq) > floor])
    return int(np.count_nonzero(np.diff(signs) != 0))


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


def settle_now(app: Any, pg: Any, pause: bool = True) -> dict[str, float]:
    """Click Run → Settle now and wait until the settle phase has ended; returns the polish signals
    of the step that ended it (swivel, margin, settle seconds), as the loop logged them, then pauses
    with Space unless `pause` is False. The signals are read from the step log, not from the status
    when the wait sees the end: on a loaded machine that can come a simulated second or more later,
    when the strokes have moved the arm and the margin has been computed again."""
    open_tab(pg, "Run")
    button = pg.get_by_role("button", name="Settle now", exact=True)
    button.wait_for(timeout=30_000)
    button.click()
    wait_for(lambda: app.loop.status.settling or not app.loop.status.can_settle, 30, "Settle now to start")

    def ended() -> bool:
        status = app.loop.sync()
        return not (status.can_settle or status.settling)

    wait_for(ended, 240, "the settle phase to end")
    assert app.loop.status.running
    if pause:
        set_running(app, pg, False)
    return app.loop.call(lambda s: signals_at_settle_end(app.loop.log.window(60.0, app.loop.dt)))


def signals_at_settle_end(window: dict[str, np.ndarray]) -> dict[str, float]:
    """Swivel (and planned swivel), margin and settle seconds of the logged step at which the newest settle phase ended
    (the first step whose "settle_converged" is no longer NaN)."""
    ended = ~np.isnan(window["settle_converged"])
    starts = np.flatnonzero(ended & ~np.concatenate(([False], ended[:-1])))
    assert starts.size and starts[-1] > 0, "the settle end is not in the last 60 s of the log"
    row = int(starts[-1])
    keys = ("swivel_deg", "swivel_plan_deg", "margin_kd", "settle_s")
    return {k: float(window[k][row]) for k in keys if k in window}


def test_the_readme_tour_step_by_step(app, page):
    """README "A five-minute tour", each step as a person takes it in the page (paused with Space while
    choosing settings: a running simulation makes a software-rendered page slow to answer).
    1. free: a drag on the elbow moves the grabbed point ≥ 1 cm along the spring's pull with > 5 N;
       mouse-up releases it. Executor → projection, the same drag: the elbow follows ≥ 1 cm (the TCP's
       shift is printed: the README says a hard pull moves it as well).
    2. polish, Friction μ 1, Objective W_j, Settle now: the force-loop margin at rest is +5 ± 5 N s/m;
       W_a, Reset, Settle now: the elbow converges at +75 ± 3° after 54.7 ± 3 s. Then Speed as fast as
       possible, Objective W_d, μ 1, Twin arm W_j, Settle now,
       on through S1…S4: the readout's force-error STD over S2 and S4 (each arm over its own
       segments, every step), twin over main, is 1.58 ± 0.15; the W_j twin's forward strokes S2/S4/S6
       read 1.84/3.58/2.42 ± 0.15 N.
    3. limit-drop waits paused ("Press Play"); Play (Space): the peak |τ₄| readout reads 14.5 ± 1 N m;
       λ = 500, Reset (R), Play: 36.9 ± 1 N m; Torque delay 5 ms: λ = 500 chatters (≥ 20 reversals of
       q̇₄ in 3 s) at the torque limit (peak ≥ 38.5 N m), λ = 100 stops without a bounce (0 reversals);
       no delay and M = 0.5: at the torque limit, more than 2 mrad into d_s, at least 2 reversals.
    (Step 2 also: Case → mirror start, Settle now: the W_a flow ends at −82 ± 3°; Case → planned W_a,
    Settle now: the posture is at the plan's −84 ± 3° and within 3° of the planned swivel the page shows.)"""
    from app.core.commands import Play, SetSpeed, SwitchSession

    pg, client = page
    plots = app.publisher.plots
    t0 = time.monotonic()

    def lap(what: str) -> None:
        print(f"tour: {what} at {time.monotonic() - t0:.1f} s wall")

    def drop_again() -> tuple[int, float]:
        """R, Play for three seconds of the limit drop, Pause: (reversals of q̇₄ in its first 3 s, peak |τ₄|)."""
        press(pg, "r")
        wait_for(lambda: app.loop.sync().t == 0.0 and not app.loop.status.running, 20, "R: reset, paused")
        set_running(app, pg, True)
        wait_for(lambda: app.loop.status.t > 3.0, 120, "three seconds of the drop")
        set_running(app, pg, False)
        reversals = app.loop.call(lambda s: first_seconds_reversals(app.loop.log.window(60.0, app.loop.dt), 3.0))
        return reversals, wait_for(lambda: plots.readouts.get("peak_torque_nm"), 30, "the peak torque")

    try:
        # ---- 1. free: drag the elbow --------------------------------------------------------------
        set_running(app, pg, False)
        choose_preset(app, pg, "free")
        set_running(app, pg, True)
        assert drag_state(app).body is None
        x, y = start_drag(pg, client, app, DRAG_LINK)
        start = drag_state(app).point
        assert start is not None
        peak = 0.0
        for k in range(1, 6):  # 5 moves up and to the left, ~25 px each
            pg.mouse.move(x - 15 * k, y - 20 * k)
            peak = max(peak, drag_state(app).force_n)

        def pulled_along_the_spring() -> float:
            """Displacement (m) of the grabbed point along the spring's pull direction since the grab."""
            view = drag_state(app)
            if view.point is None or view.target is None or np.linalg.norm(view.target - start) < 0.02:
                return 0.0
            pull = (view.target - start) / np.linalg.norm(view.target - start)
            along = float((view.point - start) @ pull)
            return along if along > 0.01 else 0.0

        moved = wait_for(pulled_along_the_spring, 30, "the grabbed point to follow the spring by 1 cm")
        peak = max(peak, drag_state(app).force_n)
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
        x, y = start_drag(pg, client, app, DRAG_LINK)
        start = drag_state(app).point
        assert start is not None
        for k in range(1, 6):
            pg.mouse.move(x - 15 * k, y - 20 * k)
        moved = wait_for(pulled_along_the_spring, 30, "the elbow to follow the spring by 1 cm (projection)")
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

        # ---- 2. polish at μ = 1: W_j's margin at rest, where W_a flows ----------------------------------
        choose_preset(app, pg, "polish")
        open_tab(pg, "Tune")
        type_number(pg, r"^Friction μ", "1")
        wait_for(lambda: param(app, "contact", "mu") == 1.0, 20, "μ = 1")
        choose(pg, "Objective", "W_j")
        wait_for(lambda: param(app, "nullspace", "objective") == "j", 20, "the objective W_j")
        at_rest = settle_now(app, pg, pause=False)  # at 1×: the margin at rest, before the strokes move the arm
        print(f"tour step 2: W_j settled: {at_rest}")
        assert abs(at_rest["margin_kd"] - TOUR_WJ_MARGIN) <= TOUR_MARGIN_TOLERANCE
        set_running(app, pg, False)
        open_tab(pg, "Tune")
        choose(pg, "Objective", "W_a")
        wait_for(lambda: param(app, "nullspace", "objective") == "a", 20, "the objective W_a")
        press(pg, "r")  # (at 1×: once settled, the arm goes on slowly, so the swivel read is the settled one)
        wait_for(lambda: app.loop.sync().t == 0.0, 20, "R: reset")
        flowed = settle_now(app, pg)
        print(f"tour step 2: W_a settled: {flowed}")
        assert abs(flowed["swivel_deg"] - TOUR_WA_SWIVEL) <= TOUR_SWIVEL_TOLERANCE
        assert abs(flowed["settle_s"] - TOUR_WA_SETTLE_S) <= TOUR_SETTLE_TOLERANCE_S
        # Scenario → Case → mirror start: from −30°, across the W_a ridge, the flow reaches the −82° minimum
        open_tab(pg, "Run")
        choose(pg, "Case", "mirror start")
        wait_for(lambda: app.loop.sync().variant == "mirror start" and app.loop.status.t < 0.1, 30, "the mirror start")
        mirrored = settle_now(app, pg)
        print(f"tour step 2: mirror start settled: {mirrored}")
        assert abs(mirrored["swivel_deg"] - TOUR_MIRROR_SWIVEL) <= TOUR_SWIVEL_TOLERANCE
        # Case → planned W_a: the nullspace tracks the planned swivel path, the transfer across the ridge first
        open_tab(pg, "Run")
        choose(pg, "Case", "planned W_a")
        # (the first switch plans the path in a worker process, ~5 s on a quiet 2-core machine; a sync
        # queued behind the switch is answered once it applied)
        wait_for(
            lambda: app.loop.sync(timeout=60.0).variant == "planned W_a" and app.loop.status.t < 0.1,
            60,
            "the planned case",
        )
        planned = settle_now(app, pg)
        print(f"tour step 2: planned W_a settled: {planned}")
        assert abs(planned["swivel_deg"] - TOUR_PLANNED_SWIVEL) <= TOUR_SWIVEL_TOLERANCE
        assert abs(planned["swivel_deg"] - planned["swivel_plan_deg"]) <= TOUR_SWIVEL_TOLERANCE
        open_tab(pg, "Run")
        choose(pg, "Case", "flow")
        wait_for(lambda: app.loop.sync().variant == "flow", 30, "the flow case again")
        lap("W_j, W_a and the mirror start checked")

        # ---- 2. (cont.) W_d arm against a W_j twin at μ = 1, Settle now --------------------------------
        choose(pg, "Speed", "as fast as possible")
        open_tab(pg, "Tune")
        choose(pg, "Objective", "W_d")
        wait_for(lambda: param(app, "nullspace", "objective") == "d", 20, "the objective W_d")
        type_number(pg, r"^Friction μ", "1")
        wait_for(lambda: param(app, "contact", "mu") == 1.0, 20, "μ = 1")
        choose(pg, "Twin arm", "W_j")
        wait_for(lambda: app.loop.status.twin == "j", 30, "the W_j twin (switching it on restarts both arms)")
        assert app.loop.sync().t == 0.0 and app.loop.status.speed > 100
        lap("settings of step 2 made")
        settled = settle_now(app, pg, pause=False)
        lap(f"settled: {settled}")
        wait_for(lambda: app.loop.status.signals.get("segment", 0.0) > 4, 240, "S4 to end")
        set_running(app, pg, False)
        keys = ("force_error_std_S2", "force_error_std_S4", "twin_force_error_std_S2", "twin_force_error_std_S4")
        try:
            wait_for(lambda: all(k in plots.readouts for k in keys), 30, "the S2/S4 readouts of both arms")
        finally:
            print("tour: readouts", {k: round(v, 3) for k, v in plots.readouts.items()})
        r = plots.readouts
        ratio = (r["twin_force_error_std_S2"] + r["twin_force_error_std_S4"]) / (
            r["force_error_std_S2"] + r["force_error_std_S4"]
        )
        main = f"{r['force_error_std_S2']:.2f}/{r['force_error_std_S4']:.2f}"
        twin = f"{r['twin_force_error_std_S2']:.2f}/{r['twin_force_error_std_S4']:.2f}"
        print(f"tour step 2: S2/S4 force-error STD main {main} N, twin {twin} N, ratio {ratio:.3f}")
        assert abs(ratio - TOUR_STD_RATIO) <= TOUR_STD_TOLERANCE, f"ratio {ratio:.3f}"
        # the W_j twin's own zig-zag (over before the W_d arm's starts) is W_j at μ = 1: its forward strokes
        wj = {k: r.get(f"twin_force_error_std_S{k}", math.nan) for k in TOUR_WJ_STD}
        assert all(abs(wj[k] - v) <= 0.15 for k, v in TOUR_WJ_STD.items()), wj
        wait_for(lambda: pg.get_by_text("Force-error STD", exact=False).first.is_visible(), 30, "the STD readout")
        save_tour_shot(pg, "tour-2-polish.png")
        lap("step 2 done")

        # ---- 3. limit-drop: Play, then λ = 500, Reset, Play --------------------------------------------
        choose_preset(app, pg, "limit-drop")
        assert not app.loop.status.running
        wait_for(lambda: pg.get_by_text("Press Play", exact=False).first.is_visible(), 30, "Press Play")
        for lam in (100.0, 500.0):
            if lam != 100.0:
                open_tab(pg, "Tune")
                type_number(pg, r"^λ", f"{lam:g}")
                wait_for(lambda l=lam: param(app, "damper", "lambda_") == l, 20, f"λ = {lam:g}")
                press(pg, "r")
                wait_for(lambda: app.loop.sync().t == 0.0 and not app.loop.status.running, 20, "R: reset, paused")
            assert param(app, "damper", "lambda_") == lam
            set_running(app, pg, True)
            wait_for(lambda: app.loop.status.t > 3.0, 120, "three seconds of the drop")
            set_running(app, pg, False)
            wait_for(lambda: pg.get_by_text("peak |τ|", exact=False).first.is_visible(), 30, "the peak readout")
            peak_nm = wait_for(lambda: plots.readouts.get("peak_torque_nm"), 30, "the peak torque")
            print(f"tour step 3: λ = {lam:g}: peak |τ4| {peak_nm:.2f} N m")
            assert abs(peak_nm - TOUR_PEAK_NM[lam]) <= TOUR_PEAK_TOLERANCE_NM, f"λ = {lam:g}: {peak_nm:.2f} N m"
            if lam == 100.0:
                open_tab(pg, "Run")
                save_tour_shot(pg, "tour-3-limit-drop.png")
        # 5 ms of torque delay: λ = 500 chatters at the torque limit, λ = 100 still stops without a bounce
        for lam in (500.0, 100.0):
            open_tab(pg, "Tune")
            if lam == 500.0:
                type_number(pg, r"^Torque delay", "5")
                wait_for(lambda: param(app, "world", "torque_delay_ms") == 5.0, 20, "a torque delay of 5 ms")
            else:
                type_number(pg, r"^λ", "100")
                wait_for(lambda: param(app, "damper", "lambda_") == 100.0, 20, "λ = 100")
            reversals, peak_nm = drop_again()
            print(f"tour step 3: 5 ms delay, λ = {lam:g}: {reversals} reversals of q̇4, peak |τ4| {peak_nm:.2f} N m")
            if lam == 500.0:
                assert reversals >= TOUR_CHATTER_REVERSALS and peak_nm >= TOUR_TORQUE_LIMIT_NM - 0.5
            else:
                assert reversals == 0 and peak_nm < TOUR_TORQUE_LIMIT_NM - 10.0
        # no delay, M = 0.5: the damper brakes too late, saturates the motor, enters d_s and rings
        open_tab(pg, "Tune")
        type_number(pg, r"^Torque delay", "0")
        wait_for(lambda: param(app, "world", "torque_delay_ms") == 0.0, 20, "no torque delay")
        type_number(pg, r"^M\b", "0.5")
        wait_for(lambda: param(app, "damper", "M") == 0.5, 20, "M = 0.5")
        reversals, peak_nm = drop_again()
        beyond = plots.readouts.get("overshoot_beyond_ds_rad", math.nan)
        print(
            f"tour step 3: M = 0.5: {reversals} reversals, peak |τ4| {peak_nm:.2f} N m, {beyond * 1e3:.1f} mrad in d_s"
        )
        assert peak_nm >= TOUR_TORQUE_LIMIT_NM - 0.5 and beyond > TOUR_LATE_BRAKE_MRAD * 1e-3 and reversals >= 2
        lap("step 3 done")
    finally:
        pg.mouse.up()
        app.loop.submit(SetSpeed(1.0))
        app.loop.submit(SwitchSession(scenario="polish", robot="rizon4s", executor="projection"))
        app.loop.submit(Play())
        wait_for(lambda: app.loop.status.scenario == "polish", 60, "polish again")


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


def test_bench_serve_runs_the_app_with_a_plain_headless_chromium_and_reports_what_it_measured(monkeypatch):
    """`bench --serve` opens the page in a Chromium process of its own (no automation driver in the
    server's process), runs the polish preset with every overlay, and reports a run it measured: one
    browser connected, simulated time advancing near real time, frames published, nothing halted;
    the browser is gone afterwards."""
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
    stalls = report["machine_stalls"]  # the probe process beside the app reported
    assert "error" not in stalls, stalls
    assert stalls["seconds"] == 3.0 and stalls["wakeups"] > 100
    left = subprocess.run(["pgrep", "-f", "torquelab-chromium-"], capture_output=True, text=True).stdout.split()
    assert left == []
