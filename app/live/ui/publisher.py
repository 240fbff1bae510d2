"""The publisher thread: shows the loop's frames in the browser.

It waits for the newest `Frame` (30 Hz), updates the 3D scene inside `server.atomic()`, refreshes
the panels' values and live numbers (~6 Hz), the plots (10 Hz), and turns the loop's notices into
notifications. It rebuilds the scene view when the session's robot changes. It never touches the
session: everything it shows is a copy the loop made between two steps.

Each stage of showing a frame (notify, scene, each panel, plots) is an error boundary (`app.live.supervise`):
a failing one is skipped for that frame, reported once per distinct error per minute (again at once
after a preset switch) and tried again with the next frame, so the page keeps updating through it. If
the thread dies anyway, `supervise()` (called by `serve` twice a second) restarts it, up to
MAX_RESTARTS times a minute; beyond that it returns the reason, and `serve` exits non-zero with it.
"""

from __future__ import annotations

import sys
import threading
import time
import traceback
from collections import deque
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import viser

from app.live.loop import Frame, SimLoop, raise_thread_priority
from app.live.supervise import Stages, error_text
from app.live.ui.camera import Framer, frame_on_connect, robot_points
from app.live.ui.mesh_notice import MeshNotice
from app.live.ui.page_lag import PageClock
from app.live.ui.panel_guard import PanelGuard
from app.live.ui.panels.base import notify
from app.live.ui.plots import Plots

LIVE_PERIOD_S = 0.15
# Niceness of the publisher thread and of the server's event loop (Linux, where permitted): just below
# the loop thread's (−10). At the default 0 they got a tenth of its weight in the server's share of
# the CPU, and lost frames; it is also above Chromium's display threads (−8) where the browser runs
# in the server's session.
PUBLISHER_NICENESS = -9
MAX_RESTARTS = 5  # restarts of a dead publisher thread within RESTART_WINDOW_S before giving up
RESTART_WINDOW_S = 60.0
STAGE_TEXT = {  # what each publisher stage does, for the notice
    "notify": "showing the loop's notices",
    "scene": "drawing the 3D scene",
    "panels": "refreshing the panels",
    "plots": "drawing the plots",
    "page clock": "stamping the pages' clock",
}


class Publisher:
    """Consumes frames from a SimLoop (see the module docstring)."""

    def __init__(
        self,
        server: viser.ViserServer,
        loop: SimLoop,
        panels: Sequence[Any],
        plots: Plots | None,
        make_scene: Callable[[Any], Any] | None,
    ):
        self.server = server
        self.loop = loop
        self.panels = list(panels)
        self.plots = plots
        self.make_scene = make_scene
        self.scene: Any = None
        self.replay: Any = None  # the Replay fold (app.live.ui.replay): it may show a logged instant instead
        self.scene_session_id = -1
        self.frames_shown = 0
        self.scene_updates = 0
        self.last_frame: Frame | None = None
        self._stop = threading.Event()
        self._thread = self._new_thread()
        self.stages = Stages(self._report)  # notify, scene, each panel, plots: one error boundary each
        self.panel_guards = [PanelGuard(panel, self.stages, server.gui) for panel in self.panels]
        self.failure = ""  # why the thread died last ("" while it runs)
        self.restarts: deque[float] = deque(maxlen=MAX_RESTARTS)  # when the thread was restarted
        self.plot_updates = 0  # plot data shown
        self._scene_wanted = False  # a new session's scene view is still to be built
        self.mesh_notice = MeshNotice(server, loop)  # the shown robot's files drawn as nothing, to each page once
        self._settings_version = -1
        self._plot_seq = -1
        self._next_live = 0.0
        self._live_state: tuple[bool, str, float, int, int] | None = None
        self._frame_pending = True  # frame the robot once a new scene has a snapshot
        self._run_restarts: int | None = None  # the run (restart count) the framing belongs to
        self._new_run = False  # a new run of the same preset: frame its arm anew (`Framer.new_run`)
        self.framer = Framer(server)  # frames the pages on the arm and keeps it in view
        self.page_clock = PageClock(server)  # a page that falls behind says so (app.live.ui.page_lag)
        # pages whose camera was framed on connect (client ids)
        self.framed_clients = frame_on_connect(
            self.framer, lambda: self._points(self.last_frame.scene if self.last_frame is not None else None)
        )
        self.niceness: int | None = None  # the publisher thread's, once it runs (None: not on Linux)
        self.server_niceness: int | None = None  # the server event loop thread's, likewise

    def _new_thread(self) -> threading.Thread:
        return threading.Thread(target=self._run_guarded, name="torquelab-publisher", daemon=True)

    def start(self) -> None:
        """Start the thread, and raise it and the server's event loop to PUBLISHER_NICENESS."""
        self._thread.start()

        def raise_server_priority() -> None:
            self.server_niceness = raise_thread_priority(PUBLISHER_NICENESS)

        self.server.get_event_loop().call_soon_threadsafe(raise_server_priority)

    def stop(self, timeout: float = 5.0) -> None:
        """Stop the thread and remove the scene view; the plots send nothing more."""
        self._stop.set()
        self._thread.join(timeout)
        if self.plots is not None:
            self.plots.stop()

    @property
    def alive(self) -> bool:
        """True while the publisher thread runs."""
        return self._thread.is_alive()

    def supervise(self, now: float | None = None) -> str:
        """Restart the thread if it died (not after `stop`); "" when it runs, else why it cannot be
        restarted (it died MAX_RESTARTS times within RESTART_WINDOW_S, or would not start)."""
        if self._stop.is_set() or self._thread.is_alive() or not self._thread.ident:
            return ""
        now = time.monotonic() if now is None else now
        if len(self.restarts) == MAX_RESTARTS and now - self.restarts[0] < RESTART_WINDOW_S:
            return f"the publisher thread died {MAX_RESTARTS + 1} times within {RESTART_WINDOW_S:g} s: {self.failure}"
        try:
            thread = self._new_thread()
            thread.start()
        except Exception as exc:
            return f"the publisher thread died ({self.failure}) and cannot be restarted: {error_text(exc)}"
        self._thread = thread
        self.restarts.append(now)
        print(f"torquelab: the publisher thread died ({self.failure}); restarted", file=sys.stderr, flush=True)
        return ""

    def _run_guarded(self) -> None:
        try:
            self._run()
        except BaseException as exc:  # `supervise` restarts the thread and says why it died
            traceback.print_exc()
            self.failure = error_text(exc)

    def _report(self, stage: str, text: str) -> None:
        """A notice to every page for a failing stage (the budget lets through one per distinct error per minute)."""
        what = STAGE_TEXT.get(stage) or (f"updating the {stage[6:]} panel" if stage.startswith("panel ") else stage)
        notify(
            self.server,
            None,
            "Display problem",
            f"{what} failed ({text}); it is skipped until it works again, the simulation keeps running",
            error=False,
        )

    def _notify(self) -> None:
        for notice in self.loop.take_notices():
            notify(self.server, notice.client_id, notice.title, notice.body, error=notice.level == "error")
        self.mesh_notice.notices_sent()  # a page opened since gets the shown robot's

    def _run(self) -> None:
        self.niceness = raise_thread_priority(PUBLISHER_NICENESS)
        seq = self.last_frame.seq if self.last_frame is not None else 0
        while not self._stop.is_set():
            self.stages.run("notify", self._notify)
            frame = self.loop.wait_frame(seq, timeout=0.2)
            if frame is None:
                self._refresh_idle()
                continue
            seq = frame.seq
            self.show(frame)

    def _refresh_idle(self) -> None:
        """While no frames come (a paused loop publishes only when something changes), refresh the panels
        from the last frame now and then, so an input a person touched shows the value in force once
        its hold has passed."""
        frame = self.last_frame
        now = time.monotonic()
        if frame is None or now < self._next_live:
            return
        self._next_live = now + LIVE_PERIOD_S
        with self.server.atomic():
            self.stages.run("panels", self._refresh_panels, frame)
            self.stages.run("page clock", self.page_clock.tick, frame.status.t)

    def _refresh_panels(self, frame: Frame) -> None:
        for guard in self.panel_guards:  # each panel in its own boundary: one that raises stops no other
            guard.refresh(frame.settings)

    @property
    def framing_pending(self) -> bool:
        """True from a new scene until its first snapshot has framed every page's camera on the arm."""
        return self._frame_pending

    def frame_view(self, client: viser.ClientHandle | None = None) -> bool:
        """Point one client's camera (every client's when None) at the arm of the newest frame."""
        frame = self.last_frame
        points = self._points(frame.scene if frame is not None else None)
        if points is None:
            return False
        self.framer.frame(points, None if client is None else [client])
        return True

    def _points(self, snap: Any) -> np.ndarray | None:
        """What framing keeps in view: the arm, its tool and, while drawn, the coupling ellipse's room."""
        overlays = getattr(self.scene, "overlays", None)
        return robot_points(snap, overlays.coupling_extent() if overlays is not None else None)

    def show(self, frame: Frame) -> None:
        """Show one frame: its scene, panels and plots go out as one message batch (one wake-up of
        the server's event loop per frame instead of one per changed property)."""
        self.last_frame = frame
        with self.server.atomic():
            self._show(frame)
        self.frames_shown += 1

    def _show(self, frame: Frame) -> None:
        """Each part in its own error boundary: a failing one is skipped for this frame only."""
        if frame.session_id != self.scene_session_id:
            self.stages.rearm()  # a preset switch: the next failure of every stage is reported at once
        self.stages.run("scene", self._show_scene, frame)
        self.stages.run("panels", self._show_panels, frame)
        self.stages.run("plots", self._show_plots, frame)
        self.stages.run("page clock", self.page_clock.tick, frame.status.t)

    def _show_scene(self, frame: Frame) -> None:
        if frame.session_id != self.scene_session_id:
            if self.scene is not None:
                scene, self.scene = self.scene, None
                scene.remove()
            self.scene_session_id = frame.session_id
            self._frame_pending = True
            self._scene_wanted = self.make_scene is not None
            if self.plots is not None:
                self.plots.focus(frame.status.focus_joint, frame.status.scenario)
        if frame.restarts != self._run_restarts:
            self._new_run = self._run_restarts is not None and not self._frame_pending
            self._run_restarts = frame.restarts
        if self._scene_wanted and self.make_scene is not None:  # tried again each frame until it builds
            self.scene = self.make_scene(frame.robot)
            self._scene_wanted = False
            self.mesh_notice.robot_shown(frame.robot, getattr(self.scene, "missing_meshes", None) or {})
        if self.scene is not None and frame.scene is not None:
            snap = frame.scene if self.replay is None else self.replay.scene_for(frame.scene, frame.session_id)
            self.scene.update(snap)
            self.scene_updates += 1
            points = self._points(frame.scene)
            if points is None:
                pass
            elif self._frame_pending:
                self.framer.frame(points)
                self._frame_pending = False
                self._new_run = False
            elif self._new_run and frame.scene.drag_point is None:
                self.framer.new_run(points)
                self._new_run = False
            elif frame.scene.drag_point is None:  # never under a person's drag (the pointer would slip)
                self.framer.follow(points)

    def _show_panels(self, frame: Frame) -> None:
        now = time.monotonic()
        settings_changed = frame.settings.version != self._settings_version
        if settings_changed or now >= self._next_live:
            self._refresh_panels(frame)
            self._settings_version = frame.settings.version
        # a paused loop publishes one last frame: show it at once, or the page keeps saying "running"
        # (or shows the preset before a switch made while paused)
        state = (frame.status.running, frame.status.halted, frame.status.t, frame.session_id, frame.settings.version)
        if now >= self._next_live or (not frame.status.running and state != self._live_state):
            self._next_live = now + LIVE_PERIOD_S
            self._live_state = state
            for guard in self.panel_guards:
                guard.live(frame)

    def _show_plots(self, frame: Frame) -> None:
        if frame.plot is not None and self.plots is not None and frame.plot_seq != self._plot_seq:
            self._plot_seq = frame.plot_seq  # a frame skipped while busy does not lose a plot update
            self.plots.update(frame.plot, (frame.session_id, frame.restarts), frame.settings)
            self.plot_updates += 1
