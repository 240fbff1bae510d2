"""The web app: a viser server, the real-time loop, the panels, the plots and the 3D scene.

`start_app(...)` starts everything without blocking and returns an `App` (tests use it
in-process); `serve(args)` is the `torquelab serve` command: it starts the app, prints the URL
and runs until Ctrl-C (exit 0), or until the simulation loop dies or the publisher thread dies and
cannot be restarted (exit 1, with the reason). The
server binds 127.0.0.1 unless `--host` says otherwise; if the port is taken, the next free one is
used, and `--port 0` picks any free port; the URL printed says which.
"""

from __future__ import annotations

import argparse
import atexit
import contextlib
import io
import logging
import os
import signal
import socket
import sys
import time
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import viser

import robots
import robots.meshes
from app.core.commands import DragCommand
from app.core.params import parse_settings
from app.live import closed_kernels
from app.live.classroom.seat import SECRET_ENV, SeatChannel
from app.live.loop import SimLoop
from app.live.memory import (
    CollectAfterClose,
    cap_arenas,
    fill_array_cache,
    fix_mmap_threshold,
    freeze_start_up_objects,
)
from app.live.priority import SERVER_NICENESS, raise_autogroup_priority, set_autogroup_niceness
from app.live.settings_io import check_settings_text, load_settings_text
from app.live.ui.inputs import GuiUpdateGuard, guard_gui_updates
from app.live.ui.junk import JunkGuard, guard_junk
from app.live.ui.keys import add_hotkeys
from app.live.ui.lesson_view import LessonView
from app.live.ui.panels import ALL_FIELDS
from app.live.ui.panels.compliance import CompliancePanel
from app.live.ui.panels.latency import LatencyPanel
from app.live.ui.panels.lessons import LessonsPanel
from app.live.ui.panels.more_gains import MoreGainsPanel, claimed_fields
from app.live.ui.panels.motion_force import MotionForcePanel
from app.live.ui.panels.nullspace import NullspacePanel
from app.live.ui.panels.record import RecordPanel
from app.live.ui.panels.safety import SafetyPanel
from app.live.ui.panels.scenario import ScenarioPanel
from app.live.ui.panels.tune import TuneOrder
from app.live.ui.phase import starts_paused
from app.live.ui.plots import STATUS_ORDER, Plots
from app.live.ui.publisher import Publisher
from app.live.ui.replay import ReplayPanel
from app.live.ui.scene import SceneView
from app.live.ui.snapshot import capture
from app.live.ui.typed import typed_numbers
from app.live.ui.viser_seam import on_connection_close
from app.live.ui.visuals import VisualSettings, VisualsPanel
from app.live.ui.warmup_page import WarmupPage
from app.live.warm_workers import WarmProgress, first_start, progress_text
from app.live.watch import WatchGate, install_watch_gate
from app.scenarios import APP_PRESET, SCENARIOS


@dataclass
class App:
    """A running web app."""

    server: viser.ViserServer
    loop: SimLoop
    publisher: Publisher
    url: str
    port: int
    requested_port: int
    panels: list[Any] = field(default_factory=list)
    visual_settings: Any = None  # the Visuals panel's settings
    stopped: bool = False
    autogroup_niceness_before: int | None = None  # given back on stop when start_app raised it
    input_guard: GuiUpdateGuard | None = None  # checks every GUI update a page sends
    junk_guard: JunkGuard | None = None  # skips and counts the malformed frames a page sends
    watch_gate: WatchGate | None = None  # which pages only watch; refuses their steering
    collector: CollectAfterClose | None = None  # a full pass of the collector after a connection closes

    def stop(self) -> None:
        """Stop the publisher, the loop and the web server (again: nothing happens)."""
        if self.stopped:
            return
        self.stopped = True
        self.publisher.stop()
        if self.collector is not None:
            self.collector.stop()
        for panel in self.panels:
            stop = getattr(panel, "stop", None)
            if callable(stop):
                stop()
        self.loop.stop()
        with contextlib.redirect_stdout(io.StringIO()):
            self.server.stop()
        if self.autogroup_niceness_before is not None:
            set_autogroup_niceness(self.autogroup_niceness_before)


def port_is_free(host: str, port: int) -> bool:
    """True if a TCP server could bind (host, port) now. The probe binds as the server does, with
    SO_REUSEADDR: a port whose last connections wait in TIME_WAIT (a restart right after a stop) is free
    to it, as it is to the server."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    with socket.socket(family, socket.SOCK_STREAM) as sock:
        if sys.platform != "win32":  # on Windows the option lets two servers share a port
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            sock.bind((host, port))
        except (OSError, OverflowError):
            return False
    return True


HANDSHAKE_FAILED = "opening handshake failed"  # the websocket server's record for a failed opening


def not_a_failed_handshake(record: logging.LogRecord) -> bool:
    """Logging filter: drop the websocket server's "opening handshake failed" record. Browsers open
    spare connections to the page's origin and close them unused; viser drops these records itself,
    but only once it has served its first request, so a fresh server printed a traceback for the
    first one. Installed from the start, this does the same from the first connection on."""
    return record.getMessage() != HANDSHAKE_FAILED


def quiet_failed_handshakes() -> None:
    """Install `not_a_failed_handshake` on the websocket server's logger (once)."""
    logger = logging.getLogger("websockets.server")
    if not_a_failed_handshake not in logger.filters:
        logger.addFilter(not_a_failed_handshake)


class OpenServer(NamedTuple):
    """A web server that serves, with the guards that must be there before any page connects."""

    server: viser.ViserServer
    watch_gate: WatchGate  # which pages only watch (and, for a seat, which connections are served)
    junk_guard: JunkGuard  # skips and counts the malformed frames a page sends


def open_server(
    host: str,
    port: int,
    verbose: bool = False,
    watch_only: bool = False,
    steer_local: bool = False,
    seat_secret: str = "",
) -> OpenServer:
    """The web server, serving at once (on the next free port if `port` is taken; any with 0), with
    the watch gate and the junk guard in front of every page's messages (see `start_app`)."""
    quiet_failed_handshakes()
    with contextlib.redirect_stdout(io.StringIO()) if not verbose else contextlib.nullcontext():
        server = viser.ViserServer(host=host, port=port, label="torquelab", verbose=verbose)
    # before any page
    watch_gate = install_watch_gate(server, watch_only=watch_only, steer_local=steer_local, seat_secret=seat_secret)
    junk_guard = guard_junk(server)  # malformed frames skipped and counted in bounded log lines
    return OpenServer(server, watch_gate, junk_guard)


def start_app(
    host: str = "127.0.0.1",
    port: int = 8080,
    scenario: str = APP_PRESET,
    robot: str | None = None,
    executor: str | None = None,
    running: bool = True,
    verbose: bool = False,
    watch_only: bool = False,
    steer_local: bool = False,
    seat_secret: str = "",
    opened: OpenServer | None = None,
) -> App:
    """Start loop, server, panels and scene; returns at once. `port=0` picks any free port. With
    `watch_only` every page watches and steers nothing (with `steer_local` too, pages from this machine
    steer); a page the classroom lobby opens as a watcher watches either way; with `seat_secret` (a
    classroom seat) only connections that carry it are served (app/live/watch.py). With `opened`
    (`open_server`'s, as `serve` starts it to show the warm-up) the lab is built on that server, whose
    gate was set up with these three."""
    fix_mmap_threshold()  # large blocks freed go back to the system (app.live.memory)
    cap_arenas()  # threads that come and go share glibc's arenas instead of each leaving one behind
    fill_array_cache()  # numpy's cache of small freed blocks at its bound now, not over the first minutes
    loop = SimLoop(scenario, robot=robot, executor=executor, capture=capture)
    if opened is None:
        opened = open_server(host, port, verbose, watch_only, steer_local, seat_secret)
    server, watch_gate, junk_guard = opened
    input_guard = guard_gui_updates(server)  # every GUI update checked on arrival
    typed_numbers(server)  # text typed into a number box reaches the server (at the root, hidden)
    server.gui.configure_theme(control_width="large")
    server.gui.main_panel.dock_right()  # the 3D view is the canvas between the panels
    actual = server.get_port()

    extra = (robot,) if robot and robot not in robots.available() else ()
    # The control panel as tabs: Lessons · Run (preset, play, settings) · Tune (the controllers' knobs)
    # · Visuals · Record.
    # The plots docked left; at their top, under the replay controls, the status line (time, real-time
    # factor, phase, the latest notice): in view whichever tab of the control panel is open.
    plots = Plots(server, n_joints=loop.session.robot.nq, order=6)
    with plots.panel_tab:
        status_box = server.gui.add_folder(None, order=STATUS_ORDER)
    tabs = server.gui.add_tab_group(order=0)
    with tabs.add_tab("Lessons", viser.Icon.SCHOOL):  # the first thing a newcomer sees
        lessons = LessonsPanel(server, loop, order=0)
    with tabs.add_tab("Run", viser.Icon.PLAYER_PLAY):
        panels: list[Any] = [ScenarioPanel(server, loop, extra_robots=extra, order=0, status_box=status_box)]
    with tabs.add_tab("Tune", viser.Icon.ADJUSTMENTS):
        tune = [
            MotionForcePanel(server, loop, order=1),
            NullspacePanel(server, loop, order=2),
            CompliancePanel(server, loop, order=3),
            SafetyPanel(server, loop, order=4),
            LatencyPanel(server, loop, order=4.2),
        ]
        panels += [*tune, MoreGainsPanel(server, loop, claimed=claimed_fields(ALL_FIELDS), order=4.5)]
        panels.append(TuneOrder(tune, base_order=1.0))  # the running preset's folders first
    visual_settings = VisualSettings()
    with tabs.add_tab("Visuals", viser.Icon.EYE):
        VisualsPanel(server.gui, visual_settings, order=5)
    with tabs.add_tab("Record", viser.Icon.DOWNLOAD):
        RecordPanel(server, loop, order=7)
    panels.append(lessons)

    def make_scene(robot_desc: Any) -> Any:
        return SceneView(server, robot_desc, loop.submit, settings=visual_settings)

    collector = CollectAfterClose()  # what a closed connection held, freed soon (app.live.memory)
    on_connection_close(server, collector.request)

    @server.on_client_disconnect
    def _release_drag(client: viser.ClientHandle) -> None:
        loop.submit(DragCommand("release", client_id=client.client_id))

    replay = ReplayPanel(server, loop, plots, order=0.4)
    panels.append(replay)
    lessons.view = LessonView(plots, replay.folder)  # a lesson step's charts on top, Replay under them
    publisher = Publisher(server, loop, panels, plots, make_scene)
    publisher.replay = replay
    replay.publisher = publisher
    scenario_panel = panels[0]
    scenario_panel.on_frame = publisher.frame_view
    replay.status_hook = scenario_panel.show_replay
    add_hotkeys(server, loop, scenario_panel.toggle_run, scenario_panel.reset_preset, publisher.frame_view)
    # Everything built so far lives as long as the app: keep it out of the garbage collector's
    # full passes, which otherwise stop every thread for ~50 ms now and then.
    freeze_start_up_objects()
    loop.start(running=running and not starts_paused(scenario))  # a drop over in seconds waits for Play
    publisher.start()
    shown_host = "127.0.0.1" if host in ("0.0.0.0", "") else host
    app = App(server, loop, publisher, f"http://{shown_host}:{actual}", actual, port, panels, visual_settings)
    app.input_guard = input_guard
    app.junk_guard = junk_guard
    app.watch_gate = watch_gate
    app.collector = collector
    # the server's session before the browser's in the CPU's division between sessions (app/live/priority.py)
    app.autogroup_niceness_before = raise_autogroup_priority(SERVER_NICENESS)
    atexit.register(app.stop)  # threads that step MuJoCo must end before the interpreter does
    return app


def _print_url(args: argparse.Namespace, busy: bool, port: int, watch_only: bool, steer_local: bool) -> None:
    """The lines that say where the page is (and why on another port than asked) and who steers."""
    if args.port == 0:
        print(f"torquelab: --port 0: using free port {port}", flush=True)
    elif busy or port != args.port:
        print(f"torquelab: port {args.port} is busy; using port {port} instead", flush=True)
    shown_host = "127.0.0.1" if args.host in ("0.0.0.0", "") else args.host
    print(f"torquelab: open http://{shown_host}:{port} in a browser (Ctrl-C to stop)", flush=True)
    if watch_only:
        who = "pages from other machines" if steer_local else "every page"
        print(f"torquelab: watch-only: {who} sees the arm and steers nothing", flush=True)
    if args.host not in ("127.0.0.1", "localhost", "::1"):
        print(f"torquelab: listening on {args.host}: reachable from other machines", flush=True)


def _warm_up_on_page(server: viser.ViserServer, robot: str | None) -> None:
    """The warm-up (`app.live.warm_workers.first_start`) with its progress on the page and the
    terminal, then every kernel closed to new argument types."""
    page = WarmupPage(server)

    def show(progress: WarmProgress) -> None:
        page.show(progress)
        if sys.stdout.isatty():  # one line, overwritten (the page shows the same)
            print(f"\rtorquelab: {progress_text(progress)}\033[K", end="", flush=True)

    print("torquelab: compiling or loading the kernels (the page shows how far) …", flush=True)
    took, compiled, failures, compiled_here = first_start(robot, show)
    if sys.stdout.isatty():
        print("\r\033[K", end="")
    for failure in failures:  # compiled by the last pass instead
        print(f"torquelab: a warm-up worker failed: {failure}", flush=True)
    closed = closed_kernels.close()  # from here on a kernel refuses a new type instead of compiling
    how = "compiled in worker processes and loaded" if compiled else "loaded from the cache"
    if compiled_here:  # a type the workers' jobs did not meet (or a failed job's kernels)
        how += f", {compiled_here} compiled here"
    print(f"torquelab: kernels ready in {took:.1f} s ({how}; {closed} closed to new argument types)", flush=True)
    page.remove()


def _say_when_running(app: App, scenario: str, timeout: float = 120.0) -> None:
    """Print that the arm moves once the loop has stepped (a preset that waits for Play says so, and
    so does a loop that has not stepped within `timeout` s: a machine busy with other work)."""
    if starts_paused(scenario):
        print("torquelab: ready (this preset waits for Play)", flush=True)
        return
    deadline = time.monotonic() + timeout
    while app.loop.alive and time.monotonic() < deadline:
        if app.loop.status.steps > 0:
            print("torquelab: the arm is running", flush=True)
            return
        time.sleep(0.02)
    if app.loop.alive:
        print(f"torquelab: the arm has not stepped within {timeout:.0f} s (a busy machine?)", flush=True)


STOP_SIGNALS = tuple(s for s in (signal.SIGTERM, getattr(signal, "SIGHUP", None)) if s is not None)


def _interrupt(signum: int, frame: Any) -> None:
    """Signal handler: stop `serve` as Ctrl-C does, once. A second stop signal is ignored: raised again
    inside the shutdown, it would cut `App.stop` short (a classroom seat gets two, its command pipe
    closed and a SIGTERM, and logged the web server's half-done stop as tracebacks)."""
    for signum_ in STOP_SIGNALS:
        signal.signal(signum_, signal.SIG_IGN)
    raise KeyboardInterrupt


def _read_settings_file(path: str, scenario: str, robot: str | None) -> str:
    """The text of a settings file, checked as TOML and against the preset's default parameters on
    `robot`; ValueError (one line) when it cannot be read or none of its entries applies."""
    try:
        with open(path, encoding="utf-8") as fh:
            text = fh.read()
    except OSError as exc:
        raise ValueError(f"cannot read settings file {path}: {exc.strerror}") from None
    except UnicodeDecodeError as exc:  # a binary file: the reason names the file, as every other does
        raise ValueError(f"{path}: not a TOML settings file: not UTF-8 text (byte {exc.start})") from None
    _, problems = parse_settings(text)
    if problems and problems[0].startswith("not a TOML"):
        raise ValueError(f"{path}: {problems[0]}")
    applied, refused = check_settings_text(scenario, robot, text)
    if refused and not applied:  # nothing of what was asked for applies: no start on other settings
        raise ValueError(f"{path}: no entry applies: {'; '.join(refused)}")
    return text


def serve(args: argparse.Namespace) -> int:
    """`torquelab serve`: start the app, print the URL, run until Ctrl-C."""
    if getattr(args, "seat", False) and hasattr(signal, "SIGPIPE"):
        signal.signal(signal.SIGPIPE, signal.SIG_DFL)  # a seat whose lobby is gone ends at its next line, quietly
    scenario = args.scenario
    if scenario not in SCENARIOS:
        raise ValueError(f"unknown scenario {scenario!r}; choose one of {', '.join(SCENARIOS)}")
    robot = robots.spec_from_args(args)
    if not 0 <= args.port <= 65535:
        raise ValueError(f"port must be 0…65535, got {args.port}")
    if not port_is_free(args.host, 0):
        raise ValueError(f"cannot listen on host {args.host!r} (not an address of this machine)")
    # a wrong name or URDF path, or a settings file of which nothing applies, is a one-line error
    # before anything starts (no compile, thread, child process or URL)
    described = robots.load(robot) if robot else None
    settings_file = getattr(args, "settings", None)
    settings_text = _read_settings_file(settings_file, scenario, robot) if settings_file else None
    if described is not None:
        # the visual meshes read (or taken from the cache) now; a missing or unreadable one is drawn
        # as nothing, said in one line here (and once in the page)
        missing = robots.meshes.missing_meshes_line(described)
        if missing:
            print(f"torquelab: {missing}", flush=True)
    # the other robots of the page's selector converted in a niced child: a switch reads the cache
    robots.meshes.warm_in_background(tuple(n for n in robots.available() if n != robot))
    busy = args.port != 0 and not port_is_free(args.host, args.port)
    watch_only = bool(getattr(args, "watch_only", False))
    steer_local = bool(getattr(args, "steer_local", False))
    if steer_local and not watch_only:
        raise ValueError("--steer-local goes with --watch-only (pages from this machine steer, the others watch)")
    seat = bool(getattr(args, "seat", False))  # a classroom seat: started by the lobby, reached through it
    seat_secret = os.environ.get(SECRET_ENV, "") if seat else ""
    if seat and not seat_secret:
        raise ValueError(f"--seat needs the lobby's secret in {SECRET_ENV}")
    fix_mmap_threshold()  # before the warm-up's step logs: large blocks freed go back to the system
    cap_arenas()  # and threads that come and go share glibc's arenas (app.live.memory)
    # the page is there at once (its guards before any page connects); the warm-up shows on it
    opened = open_server(args.host, args.port, False, watch_only, steer_local, seat_secret)
    _print_url(args, busy, opened.server.get_port(), watch_only, steer_local)
    # a `kill` or a closed terminal stops the app as Ctrl-C does (the session's CPU share given back),
    # during the warm-up too (its worker processes end with it)
    for signum in STOP_SIGNALS:
        signal.signal(signum, _interrupt)
    try:
        if getattr(args, "warm", False):  # the CLI's default (--no-warmup skips it); tests warm elsewhere
            _warm_up_on_page(opened.server, robot)
        print(f"torquelab: starting scenario {scenario!r} …", flush=True)
        app = start_app(
            host=args.host, port=args.port, scenario=scenario, robot=robot, watch_only=watch_only,
            steer_local=steer_local, seat_secret=seat_secret, opened=opened,
        )  # fmt: skip
    except BaseException as exc:
        with contextlib.redirect_stdout(io.StringIO()):
            opened.server.stop()
        if isinstance(exc, KeyboardInterrupt):
            return 0
        raise
    if seat:
        SeatChannel(app).start()
    display_failure = ""
    try:
        if settings_text is not None:
            refused = load_settings_text(app.loop, settings_text)  # checked before the start
            for line in refused:
                print(f"torquelab: {settings_file}: refused: {line}", flush=True)
            print(f"torquelab: settings from {settings_file} applied ({len(refused)} refused)", flush=True)
        _say_when_running(app, scenario)
        while app.loop.alive and not display_failure:
            display_failure = app.publisher.supervise()  # a dead publisher thread is restarted
            time.sleep(0.5)
    except KeyboardInterrupt:
        pass
    finally:
        app.stop()
    if display_failure:
        print(f"torquelab: error: the page stopped updating: {display_failure}", file=sys.stderr, flush=True)
        return 1
    if app.loop.failure:
        print(f"torquelab: error: the simulation loop stopped: {app.loop.failure}", file=sys.stderr, flush=True)
        return 1
    return 0
