"""The web app without a browser: start/stop, panels refuse nonsense, a closed client drops its drag."""

from __future__ import annotations

import os
import socket
import threading
import time
import urllib.request

import msgspec
import numpy as np
import pytest
import viser
from websockets.sync.client import connect

from app.core.commands import DragCommand, StepOnce
from app.live.server import port_is_free, start_app
from app.live.ui.panels.base import KnobPanel
from app.live.ui.viser_seam import input_uuid
from tests.conftest import browser_update, camera_message, wait_until

# the loop thread is timed here: the kernels are compiled (or loaded) before, not inside it
pytestmark = pytest.mark.usefixtures("warm_kernels")


def _knob_handle(app, key: str):
    for panel in app.panels:
        if isinstance(panel, KnobPanel):
            for i, knob in enumerate(panel.knobs):
                if knob.field == key:
                    return panel, knob, panel.handles[i]
    raise KeyError(key)


def test_page_is_served_on_localhost_and_frames_are_published(app):
    assert app.url.startswith("http://127.0.0.1:")
    with urllib.request.urlopen(app.url, timeout=10) as resp:
        assert resp.status == 200
        assert b"<html" in resp.read().lower()
    shown = app.publisher.frames_shown
    app.loop.submit(StepOnce(1))  # the paused loop publishes when something changed
    assert wait_until(lambda: app.publisher.frames_shown > shown)


def test_the_publisher_sends_each_frame_as_one_message_batch(app, monkeypatch):
    """Every message the publisher queues for a frame (scene poses, overlays, panels, plots) is
    inside one atomic block, so the server's event loop is woken once per frame, not per property."""

    buffer = app.server._websock_server.get_message_buffer()
    pushes: list[bool] = []  # for each message the publisher thread queued: inside an atomic block?
    push = buffer.push

    def recording_push(message):
        if threading.current_thread().name == "torquelab-publisher":
            pushes.append(buffer.atomic_counter > 0)
        return push(message)

    monkeypatch.setattr(buffer, "push", recording_push)
    for _ in range(5):
        shown = app.publisher.frames_shown
        app.loop.submit(StepOnce(10))  # the paused loop publishes a frame with the arm moved
        assert wait_until(lambda shown=shown: app.publisher.frames_shown > shown)
    assert len(pushes) >= 5 and all(pushes), (len(pushes), pushes.count(False))


@pytest.mark.skipif(not hasattr(os, "setpriority") or os.uname().sysname != "Linux", reason="per-thread niceness")
def test_the_publisher_and_the_server_event_loop_run_between_the_browser_and_the_loop_in_priority(app):
    """The publisher thread and the server's event loop ask for niceness −9 (just below the loop's −10,
    above Chromium's display threads at −8): granted where permitted, else they keep the process's."""
    import resource

    from app.live.loop import LOOP_NICENESS
    from app.live.ui.publisher import PUBLISHER_NICENESS

    assert LOOP_NICENESS < PUBLISHER_NICENESS == -9
    process = os.getpriority(os.PRIO_PROCESS, 0)
    permitted = os.geteuid() == 0 or 20 - resource.getrlimit(resource.RLIMIT_NICE)[0] <= PUBLISHER_NICENESS
    expected = min(PUBLISHER_NICENESS, process) if permitted else process
    assert wait_until(lambda: app.publisher.niceness is not None and app.publisher.server_niceness is not None)
    assert app.publisher.niceness == os.getpriority(os.PRIO_PROCESS, app.publisher._thread.native_id) == expected
    assert app.publisher.server_niceness == expected
    tids: list[int] = []  # the event loop thread's id, asked from that thread
    app.server.get_event_loop().call_soon_threadsafe(lambda: tids.append(threading.get_native_id()))
    assert wait_until(lambda: bool(tids))
    assert os.getpriority(os.PRIO_PROCESS, tids[0]) == expected
    assert os.getpriority(os.PRIO_PROCESS, 0) == process  # the other threads keep theirs


def test_panel_refuses_nonsense_values_and_applies_valid_ones(app):
    _panel, _knob, handle = _knob_handle(app, "max_force_n")
    before = app.loop.settings.values["drag"]["max_force_n"]
    for nonsense in ("abc", float("nan"), float("inf"), -10.0, 1e9, None, [1, 2]):
        browser_update(handle, nonsense, client_id=12345)
    app.loop.sync()
    assert app.loop.alive
    assert app.loop.settings.values["drag"]["max_force_n"] == before
    browser_update(handle, 55.0, client_id=12345)
    app.loop.sync()
    assert app.loop.session.drag.max_force_n == 55.0
    assert wait_until(lambda: app.loop.settings.values["drag"]["max_force_n"] == 55.0)


def test_closing_a_tab_releases_its_drag(app):
    port = app.port
    before = set(app.server.get_clients())
    ws = connect(f"ws://127.0.0.1:{port}", subprotocols=[f"viser-v{viser.__version__}"], open_timeout=10)
    try:
        ws.send(camera_message())
        assert wait_until(lambda: len(set(app.server.get_clients()) - before) == 1)
        (client_id,) = set(app.server.get_clients()) - before
        s = app.loop.session
        body = s.world.model.body(s.world.wrist_body).name
        p0 = tuple(s.world.site_pose(s.world.tcp_site)[0])
        app.loop.submit(DragCommand("grab", client_id=client_id, body_name=body, point_world=p0))
        app.loop.submit(DragCommand("move", client_id=client_id, target_world=tuple(np.add(p0, (0, 0.1, 0)))))
        status = app.loop.sync()
        assert status.drag_client == client_id and s.drag.active
    finally:
        ws.close()
    assert wait_until(lambda: app.loop.sync().drag_client is None)
    assert not app.loop.session.drag.active


def test_a_busy_port_moves_to_the_next_free_one():
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind(("127.0.0.1", 0))
        sock.listen()
        busy = sock.getsockname()[1]
        assert not port_is_free("127.0.0.1", busy)
        other = start_app(port=busy, scenario="free", running=False)
        try:
            assert other.port != busy and other.requested_port == busy
            assert other.url.endswith(f":{other.port}")
        finally:
            other.stop()


def test_serve_says_when_the_port_is_busy_serves_the_url_and_stops_on_ctrl_c(monkeypatch, capsys):
    """`serve` on a busy port says so and takes the next free one, serves the page at the URL it printed,
    and a Ctrl-C while it waits (KeyboardInterrupt) stops it with exit code 0."""
    import argparse
    import re

    from app.live.server import serve
    from app.live.ui.publisher import Publisher

    printed: list[str] = []
    status: list[int] = []

    def ctrl_c(self) -> str:  # the page is fetched while serve waits, then Ctrl-C
        printed.append(capsys.readouterr().out)
        url = re.search(r"open (http://\S+)", printed[-1]).group(1)  # type: ignore[union-attr]
        with urllib.request.urlopen(url, timeout=10) as resp:
            status.append(resp.status)
        raise KeyboardInterrupt

    monkeypatch.setattr(Publisher, "supervise", ctrl_c)
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind(("127.0.0.1", 0))
        sock.listen()
        busy = sock.getsockname()[1]
        args = argparse.Namespace(scenario="free", host="127.0.0.1", port=busy, robot=None, urdf=None)
        assert serve(args) == 0
    text = "".join(printed)
    port = int(re.search(rf"port {busy} is busy; using port (\d+) instead", text).group(1))  # type: ignore[union-attr]
    assert port != busy and f"open http://127.0.0.1:{port} " in text and status == [200]


def test_nonsense_sent_over_the_websocket_is_refused_and_the_server_keeps_running(app):
    _panel, _knob, handle = _knob_handle(app, "max_force_n")
    before = app.loop.settings.values["drag"]["max_force_n"]
    shown = app.publisher.frames_shown
    ws = connect(f"ws://127.0.0.1:{app.port}", subprotocols=[f"viser-v{viser.__version__}"], open_timeout=10)
    try:
        ws.send(camera_message())
        for value in ("abc", float("nan"), -1e300, None, [1, 2], {"x": 1}, 1e308):
            ws.send(
                msgspec.msgpack.encode(
                    {"type": "GuiUpdateMessage", "uuid": input_uuid(handle), "updates": {"value": value}}
                )
            )
        ws.send(b"\x00not msgpack at all")
        time.sleep(0.5)
    finally:
        ws.close()
    status = app.loop.sync()
    assert app.loop.alive and status.halted == ""
    assert app.loop.settings.values["drag"]["max_force_n"] == before
    app.loop.submit(StepOnce(1))
    assert wait_until(lambda: app.publisher.frames_shown > shown)  # the publisher still shows frames
    with urllib.request.urlopen(app.url, timeout=10) as resp:
        assert resp.status == 200


def test_status_shows_the_fallback_badge_the_halt_message_and_a_slow_machine(app):
    import dataclasses

    from app.live.ui.panels.scenario import ScenarioPanel

    panel = next(p for p in app.panels if isinstance(p, ScenarioPanel))
    app.loop.sync()
    time.sleep(0.3)  # the paused app publishes nothing new: the publisher leaves the panel alone
    frame = app.loop.wait_frame(0, timeout=5.0)
    assert frame is not None
    base = frame.status
    # the status line's real-time factor is simulated over wall time across the last seconds of frames
    wall = time.monotonic()
    ok = dataclasses.replace(base, running=True, t=10.0, speed=1.0, fallback=False, halted="")
    panel.live(dataclasses.replace(frame, status=ok))
    time.sleep(1.2)
    ok = dataclasses.replace(ok, t=10.0 + (time.monotonic() - wall))  # kept up with the wall clock
    panel.live(dataclasses.replace(frame, status=ok))
    assert not panel.fallback_md.visible and not panel.halted_md.visible
    assert "slower than requested" not in panel.status_md.content.lower()
    assert "t = " in panel.status_md.content and "running" in panel.status_md.content
    kept_up, wall = ok.t, time.monotonic()
    time.sleep(1.2)
    half = kept_up + 0.5 * (time.monotonic() - wall)  # from now on only half as fast as the wall clock
    bad = dataclasses.replace(
        base, running=True, t=half, speed=1.0, fallback=True, fallback_steps=base.fallback_steps + 3, halted="x"
    )
    panel.live(dataclasses.replace(frame, status=bad))
    assert panel.fallback_md.visible and panel.halted_md.visible and "Reset" in panel.halted_md.content
    assert "slower than requested" in panel.status_md.content.lower()


def test_status_line_names_the_qp_backend_and_the_fallback_reason_from_the_step_view(app):
    import dataclasses

    from app.live.ui.panels.scenario import ScenarioPanel
    from control.executor import StepView

    panel = next(p for p in app.panels if isinstance(p, ScenarioPanel))
    frame = app.loop.wait_frame(0, timeout=5.0)
    assert frame is not None and frame.scene is not None
    failed = StepView("compliance-qp", qp_status="infeasible", qp_backend="dense", qp_fallback=True, qp_solve_us=6.0)
    status = dataclasses.replace(frame.status, fallback=True, fallback_steps=frame.status.fallback_steps + 1)
    panel.live(dataclasses.replace(frame, status=status, scene=dataclasses.replace(frame.scene, step=failed)))
    assert "QP dense 6 µs" in panel.status_md.content
    assert panel.fallback_md.visible and "(infeasible)" in panel.fallback_md.content


def test_averaged_rate_does_not_read_a_catch_up_burst_as_faster_than_real_time():
    from app.live.ui.panels.scenario import AveragedRate

    rate = AveragedRate(window_s=2.0)
    sim, values = 0.0, []
    for k in range(100):  # 10 s of wall time in 0.1 s frames; a 0.1 s stall every 2 s, caught up in one burst
        wall = 0.1 * k
        sim = wall - (0.1 if k % 20 == 5 else 0.0)
        value = rate.update(wall, sim, running=True)
        if value is not None:
            values.append(value)
    # the burst itself runs at 2× (0.2 s simulated in 0.1 s); over the ≥ 1 s window it reads at most 1.1
    assert values and max(values) <= 1.0 + 0.1 / 1.0 + 1e-9 and min(values) >= 1.0 - 0.1 / 1.0 - 1e-9
    assert rate.update(11.0, sim, running=False) is None  # paused: no factor


def test_a_preset_about_one_joint_points_the_phase_plot_at_it(app):
    from app.core.commands import SwitchSession

    plots = app.publisher.plots
    plots.joint.value = "2"
    app.loop.submit(SwitchSession(scenario="limit-drop"))
    app.loop.sync()
    assert wait_until(lambda: plots.joint.value == "4")  # joint 4 falls into its limit
    plots.joint.value = "6"
    app.loop.submit(SwitchSession(scenario="free"))
    app.loop.sync()

    def shown_free() -> bool:
        last = app.publisher.last_frame
        return last is not None and last.status.scenario == "free" and app.publisher.scene_session_id == last.session_id

    assert wait_until(shown_free)
    assert plots.joint.value == "6"  # a preset without a focus joint leaves the choice alone


def test_serve_exits_non_zero_with_the_reason_when_the_loop_thread_dies(monkeypatch, capsys):
    import argparse

    from app.live.loop import SimLoop
    from app.live.server import serve

    def boom(self):
        raise RuntimeError("the loop broke")

    monkeypatch.setattr(SimLoop, "_loop", boom)
    args = argparse.Namespace(scenario="free", host="127.0.0.1", port=0, robot=None, urdf=None)
    assert serve(args) == 1
    assert "the simulation loop stopped: RuntimeError: the loop broke" in capsys.readouterr().err


def test_page_settings_load_applies_good_entries_lists_bad_ones_and_restore_defaults_undoes_them(app):
    from viser._gui_handles import UploadedFile

    from app.core.session import Session

    buttons = app.panels[0].settings
    defaults = Session("free", executor=app.loop.status.executor).params()  # the preset's own defaults
    default_force = defaults["drag"].max_force_n
    good = 0.5 * default_force
    text = f"[drag]\nmax_force_n = {good}\n[world]\ntorque_delay_ms = 1e9\n"
    browser_update(buttons.load_button, UploadedFile("s.toml", text.encode()), client_id=12345)
    assert app.loop.sync().t >= 0.0
    assert app.loop.session.drag.max_force_n == pytest.approx(good)
    assert app.loop.session.params()["world"].torque_delay_ms == defaults["world"].torque_delay_ms
    refused = buttons.load(None, text.encode())  # the same file again: the bad entry is reported, one line
    assert len(refused) == 1 and "torque_delay_ms" in refused[0] and "\n" not in refused[0]
    assert buttons.load(None, b"\xff\xfe") and app.loop.session.drag.max_force_n == pytest.approx(good)
    saved = buttons.save(None)
    assert "max_force_n" in saved and "torque_delay_ms" not in saved
    buttons.restore(None)
    app.loop.sync()
    assert app.loop.call(lambda s: s.params()) == defaults
    assert app.loop.session.drag.max_force_n == pytest.approx(default_force)
    assert "max_force_n" not in buttons.save(None)


def test_a_refused_or_adjusted_number_is_replaced_in_the_input_by_the_value_in_force_at_once(app, monkeypatch):
    import app.live.ui.panels.base as base

    panel, knob, handle = _knob_handle(app, "max_force_n")
    browser_update(handle, 60.0, client_id=12345)
    assert handle.value == pytest.approx(60.0) and app.loop.session.drag.max_force_n == pytest.approx(60.0)
    notices: list[tuple[str, str]] = []
    monkeypatch.setattr(base, "notify", lambda server, cid, title, body, error=True: notices.append((title, body)))
    log = app.loop.lab.notice_log
    refused_before = sum(n.title == "Value refused" for n in log)
    browser_update(handle, 1e9, client_id=12345)  # out of range: refused by the group
    assert handle.value == pytest.approx(60.0)  # back in the input when the callback returns
    assert sum(n.title == "Value refused" for n in log) == refused_before + 1
    assert notices == []  # the refusal's own notice says why; no second one
    browser_update(handle, 19.0, client_id=12345)  # e.g. "1e9" parsed by the browser: applied as is
    assert handle.value == pytest.approx(19.0) and app.loop.session.drag.max_force_n == pytest.approx(19.0)
    assert notices == []

    class FakeHandle:
        value = 0.0

    fake = FakeHandle()
    assert panel.echo(knob, fake, 25.0, 12345, before=log[-1] if log else None) == pytest.approx(19.0)
    assert fake.value == pytest.approx(19.0)  # differs from what arrived: the value in force is shown
    assert len(notices) == 1 and notices[0][0] == "Value adjusted" and "19" in notices[0][1]


def test_tune_tab_puts_the_presets_folders_first_and_hides_what_the_executor_lacks(app):
    """polish: Motion–force and Nullspace on top; limit-drop: Safety on top. With the [C] QP executor
    the Nullspace folder (prose, live lines, twin, preview) is hidden and Motion–force's [T] prose
    gives way to one line; with the [T] executor Compliance shows only its Γ_x line."""
    from app.core.commands import SwitchSession
    from app.live.ui.panels.compliance import CompliancePanel
    from app.live.ui.panels.motion_force import MotionForcePanel
    from app.live.ui.panels.nullspace import NullspacePanel
    from app.live.ui.panels.tune import TuneOrder

    tune = next(p for p in app.panels if isinstance(p, TuneOrder))
    mf = next(p for p in app.panels if isinstance(p, MotionForcePanel))
    ns = next(p for p in app.panels if isinstance(p, NullspacePanel))
    co = next(p for p in app.panels if isinstance(p, CompliancePanel))

    def orders() -> list[str]:
        return sorted(tune.panels, key=lambda t: tune.panels[t].folder.order)

    try:
        app.loop.submit(SwitchSession(scenario="polish", executor="projection"))
        assert wait_until(lambda: orders()[:2] == ["Motion–force", "Nullspace"], 20), orders()
        # The publisher refreshes the panels one after another: wait for the last of them too.
        assert wait_until(
            lambda: (
                ns.folder.visible
                and mf.intro.visible
                and not mf.other.visible
                and co.folder.visible
                and not co.intro.visible
                and co.gamma_x.visible
            ),
            20,
        ), (
            ns.folder.visible,
            mf.intro.visible,
            mf.other.visible,
            co.folder.visible,
            co.intro.visible,
            co.gamma_x.visible,
        )
        app.loop.submit(SwitchSession(executor="compliance-qp"))
        assert wait_until(
            lambda: (
                not ns.folder.visible
                and not mf.intro.visible
                and mf.other.visible
                and not mf.help.visible
                and co.intro.visible
                and not co.gamma_x.visible
            ),
            20,
        ), (
            ns.folder.visible,
            mf.intro.visible,
            mf.other.visible,
            mf.help.visible,
            co.intro.visible,
            co.gamma_x.visible,
        )
        app.loop.submit(SwitchSession(scenario="limit-drop"))
        assert wait_until(lambda: orders()[0] == "Safety", 20), orders()
    finally:
        app.loop.submit(SwitchSession(scenario="free", robot=""))
        app.loop.sync()
        assert wait_until(lambda: orders()[0] == "Nullspace", 20)


def test_tune_order_and_the_live_w_line_near_a_singularity():
    from app.live.ui.panels.nullspace import w_text
    from app.live.ui.panels.tune import tune_order

    titles = ["Motion–force", "Nullspace", "Compliance", "Safety"]
    assert tune_order("limit-drop", titles) == ["Safety", "Compliance", "Motion–force", "Nullspace"]
    assert tune_order("unknown", titles) == titles
    assert w_text("W_a", 1.3e11, singular=True) == "W_a: singular"
    assert w_text("W_j", 0.25, singular=True) == "W_j = 0.25"
    assert w_text("W_d", 0.713, singular=False) == "W_d = 0.713"
    assert w_text("W_f", None, singular=False) == "W_f = –"


def test_settle_now_button_shows_in_polishs_settle_phase_and_runs_it(app):
    """The button is shown while polish settles; a click runs the settle phase on the loop until the
    trajectory starts, then hides it."""
    from app.core.commands import Pause, SetParam, SwitchSession
    from app.live.ui.panels.scenario import ScenarioPanel

    panel = next(p for p in app.panels if isinstance(p, ScenarioPanel))
    try:
        app.loop.submit(SwitchSession(scenario="polish", executor="projection"))
        app.loop.submit(SetParam("nullspace", "objective", "j"))
        assert wait_until(lambda: app.loop.sync().scenario == "polish" and panel.settle.visible, 60), app.loop.status
        browser_update(panel.settle, True, client_id=1)
        assert wait_until(lambda: not app.loop.sync().can_settle, 120), app.loop.status
        status = app.loop.sync()
        assert status.running and not status.settling and status.t > 1.0, status
        assert wait_until(lambda: not panel.settle.visible, 60)
    finally:
        app.loop.submit(Pause())
        app.loop.submit(SwitchSession(scenario="free", robot=""))
        app.loop.sync()


def test_a_paused_page_shows_the_value_in_force_once_the_touched_inputs_hold_has_passed(app):
    """Paused, no frames come; a value set on the server right after a person touched the input (within
    its 0.6 s hold) still reaches the input within a few seconds."""
    from app.core.commands import Pause, SetParam

    app.loop.submit(Pause())
    _, _, handle = _knob_handle(app, "max_force_n")
    browser_update(handle, 100.0, client_id=1)
    app.loop.submit(SetParam("drag", "max_force_n", 120.0))
    app.loop.sync()
    assert app.loop.session.drag.max_force_n == 120.0 and not app.loop.status.running
    assert wait_until(lambda: handle.value == 120.0, 5.0), handle.value


def test_a_connection_closed_before_its_request_is_not_logged_as_an_error():
    """Browsers open spare connections to the page's origin and close them unused. The first one, to a
    server that has not yet answered a request, logged "opening handshake failed" with a traceback
    (viser filters that record only after its first request): a fresh server now logs nothing for it."""
    import logging

    records: list[logging.LogRecord] = []

    class Keep(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            records.append(record)

    handler = Keep(level=logging.ERROR)
    logging.getLogger().addHandler(handler)
    fresh = start_app(port=0, scenario="free", running=False)
    try:
        with socket.create_connection(("127.0.0.1", fresh.port)):
            pass  # closed before sending a byte
        time.sleep(0.5)
        urllib.request.urlopen(f"http://127.0.0.1:{fresh.port}/", timeout=10).read()  # the server still answers
    finally:
        fresh.stop()
        logging.getLogger().removeHandler(handler)
    assert [r.getMessage() for r in records if r.name.startswith("websockets")] == []


def test_priority_reads_and_raises_an_autogroup_niceness_and_says_what_to_give_back(tmp_path):
    from app.live.priority import autogroup_niceness, raise_autogroup_priority, set_autogroup_niceness

    fake = tmp_path / "autogroup"
    fake.write_text("/autogroup-255 nice 0\n")
    assert autogroup_niceness(str(fake)) == 0
    assert raise_autogroup_priority(-10, str(fake)) == 0  # changed: 0 is what to give back
    assert autogroup_niceness(str(fake)) == -10
    assert raise_autogroup_priority(-5, str(fake)) is None  # already higher: nothing to give back
    assert set_autogroup_niceness(0, str(fake)) == 0
    assert autogroup_niceness(str(tmp_path / "missing")) is None
    assert raise_autogroup_priority(-10, str(tmp_path / "missing")) is None
    empty = tmp_path / "empty"  # what a process outside any autogroup reads (e.g. in a container's cgroup)
    empty.write_text("")
    assert autogroup_niceness(str(empty)) is None
    assert raise_autogroup_priority(-10, str(empty)) is None


def _in_an_autogroup() -> bool:
    """Whether this process is in an autogroup: /proc/self/autogroup can exist and read empty, as in
    a container whose processes sit in a cgroup of their own (no autogroup scheduling for them)."""
    from app.live.priority import autogroup_niceness

    return autogroup_niceness() is not None


@pytest.mark.skipif(not _in_an_autogroup(), reason="this process is in no autogroup here")
def test_the_app_raises_its_sessions_share_of_the_cpu_while_it_runs_and_gives_it_back(app):
    """With autogroup scheduling the CPU is divided between sessions first: the app asks for its
    session's niceness SERVER_NICENESS where permitted and restores the one it found on stop."""
    from app.live.priority import SERVER_NICENESS, autogroup_niceness, set_autogroup_niceness

    found = autogroup_niceness()
    assert found is not None
    try:
        # whether this session may take SERVER_NICENESS, asked of the system itself (root in a
        # container can lack the capability a negative niceness needs)
        permitted = set_autogroup_niceness(SERVER_NICENESS) == SERVER_NICENESS
        base = set_autogroup_niceness(0)  # 0, or `found` where that is above 0 and lowering it is refused
        assert base is not None and base >= 0
        second = start_app(port=0, scenario="free", running=False)
        try:
            assert autogroup_niceness() == (SERVER_NICENESS if permitted else base)
        finally:
            second.stop()
        assert autogroup_niceness() == base
    finally:
        set_autogroup_niceness(found)


def test_an_app_stopped_right_after_it_started_sends_nothing_to_its_closed_server():
    """The plots' delayed axis resends (timers) fired after the server stopped: viser warned of a
    message queued on a closed connection at every quick stop (a Ctrl-C soon after start)."""
    import warnings

    from app.live.ui.plots import RESEND_AFTER_SHOW_S

    app = start_app(port=0, scenario="polish", running=True)  # no page: only the resends after a show
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        app.stop()
        time.sleep(max(RESEND_AFTER_SHOW_S) + 0.5)
    closed = [w for w in caught if "closed connection" in str(w.message)]
    assert closed == [], [str(w.message) for w in closed]
