"""The page at the end of every lesson step, for a checkout of any age: static/lessons/before/ was made with it.

Usage (the checkout's `app` first on the path, in an environment with the packages it imports):

    git worktree add --detach /tmp/before 5092a13
    cd /tmp/before && PYTHONPATH=$PWD python /path/to/scripts/lesson_step_shots.py OUT_DIR [LESSON-stepN ...]

It warms the kernels as `serve` does (`app.live.warmup.warm_up`), starts the app on polish / rizon4s /
projection (the browser tests' start), opens it in headless Chromium at 1600×1000 and, for every step of
every lesson (or the named ones), sets the step up from the Lessons panel, waits for its result line and
writes the page with that line in view as OUT_DIR/LESSON-stepN.png, scaled to 1200×750 in 128 colours: the
size and palette of static/lessons/after/ (written by tests/test_browser.py's lesson viewport test with
TORQUELAB_UPDATE_SCREENSHOT=1). It reads the lessons from `app.live.curriculum` or, in older checkouts,
`app.live.lessons`.
"""

from __future__ import annotations

import os
import socket
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

VIEWPORT = {"width": 1600, "height": 1000}
SHOT_SIZE = (1200, 750)
SHOT_COLOURS = 128
STEP_TIMEOUT_S = 900.0  # the longest step (a polish run with its settle) on a loaded machine


def wait_for(condition: Callable[[], Any], timeout: float, what: str, period: float = 0.2) -> Any:
    """Poll `condition` until it is truthy; TimeoutError naming `what` after `timeout` s."""
    deadline = time.monotonic() + timeout
    while not (value := condition()):
        if time.monotonic() > deadline:
            raise TimeoutError(f"timed out after {timeout:.0f} s waiting for {what}")
        time.sleep(period)
    return value


def lessons() -> tuple[Any, ...]:
    """The checkout's lessons (their module moved once)."""
    try:
        from app.live.curriculum import LESSONS
    except ImportError:
        from app.live.lessons import LESSONS
    return tuple(LESSONS)


def close_notices(pg: Any) -> None:
    """Close the page's pop-up notices (they would cover the 3D view) and wait until they are gone
    (a notice fades out after its close: a picture taken at once caught one half-faded)."""
    close = pg.locator(".mantine-Notification-closeButton")
    for _ in range(close.count()):
        try:
            close.first.click(timeout=5_000)
        except Exception:  # closed on its own meanwhile
            pass
    wait_for(lambda: pg.locator(".mantine-Notification-root").count() == 0, 10, "the notices to fade out")


def shoot(pg: Any, claim: str, path: Path) -> None:
    """The page with the start of `claim` in view, scaled and reduced to the 'after' set's size and palette."""
    from PIL import Image

    line = pg.get_by_text(claim[:40], exact=False).first
    line.wait_for()
    time.sleep(2.0)  # the frame after the pause drawn
    close_notices(pg)
    line.scroll_into_view_if_needed()
    pg.screenshot(path=str(path))
    image = Image.open(path).convert("RGB")
    if image.size != (VIEWPORT["width"], VIEWPORT["height"]):
        raise RuntimeError(f"{path.name}: the page is {image.size}, not 1600×1000")
    small = image.resize(SHOT_SIZE, Image.Resampling.LANCZOS)
    small.quantize(SHOT_COLOURS, dither=Image.Dither.NONE).save(path, optimize=True)


def main(argv: list[str]) -> int:
    if not argv:
        print(__doc__, file=sys.stderr)
        return 2
    out, only = Path(argv[0]), set(argv[1:])
    from playwright.sync_api import sync_playwright

    import app
    from app.live.server import start_app
    from app.live.ui.panels.lessons import LessonsPanel
    from app.live.warmup import warm_up
    from app.tools.bench_serve import CHROMIUM_ARGS

    print(f"lesson_step_shots: the app from {Path(app.__file__).parent}", flush=True)
    warm_up(None, lambda line: None)
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    lab = start_app("127.0.0.1", port, "polish", "rizon4s", "projection")
    panel = next(p for p in lab.panels if isinstance(p, LessonsPanel))
    out.mkdir(parents=True, exist_ok=True)
    chromium = os.environ.get("TORQUELAB_CHROMIUM", "/usr/bin/chromium")
    try:
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=chromium, headless=True, args=CHROMIUM_ARGS)
            pg = browser.new_page(viewport=VIEWPORT)
            pg.set_default_timeout(120_000)  # a software-rendered page on a loaded machine
            pg.goto(lab.url)
            pg.wait_for_selector("canvas[data-engine^=three]", timeout=180_000)
            pg.get_by_role("tab", name="Lessons").click()
            for lesson in lessons():
                for i, step in enumerate(lesson.steps):
                    name = f"{lesson.key}-step{i + 1}"
                    if only and name not in only:
                        continue
                    panel.select(lesson.key, i)
                    panel.start_step()
                    key = (lesson.key, step.key)
                    claim = wait_for(lambda k=key: panel.claims.get(k), STEP_TIMEOUT_S, step.title, 0.5)
                    shoot(pg, claim, out / f"{name}.png")
                    print(f"{name}.png: {claim[:100]}", flush=True)
            browser.close()
    finally:
        lab.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
