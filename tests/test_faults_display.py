"""Faults injected into the display path: each stage fails alone, is reported rarely and comes back."""

from __future__ import annotations

import argparse
import time
from types import SimpleNamespace

import msgspec
import numpy as np
import pytest
import viser
from websockets.sync.client import connect

from app.core.commands import StepOnce, SwitchSession
from app.live.frames import FrameBuilder
from app.live.lab import Lab
from app.live.supervise import ErrorBudget, Stages
from app.live.ui.inputs import check_value
from tests.conftest import camera_message, wait_until

# the loop thread is timed here: the kernels are compiled (or loaded) before, not inside it
pytestmark = pytest.mark.usefixtures("warm_kernels")


class Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def test_a_failing_stage_is_reported_once_per_distinct_error_per_minute_with_bounded_memory():
    clock = Clock()
    reports: list[str] = []
    stages = Stages(lambda stage, text: reports.append(text), ErrorBudget(60.0, 32, clock))

    def fail(text: str) -> None:
        raise RuntimeError(text)

    for _ in range(1000):  # the same error every frame for 33 s
        stages.run("notify", fail, "the same")
        clock.t += 1 / 30
    assert len(reports) == 1 and stages.failures["notify"] == 1000
    for i in range(3000):  # an error whose text varies every frame
        stages.run("build", fail, f"frame {i}")
    assert len(stages.budget) <= 32 and len(reports) <= 1 + 32
    clock.t += 61.0  # a minute later the same error is reported again
    n = len(reports)
    stages.run("notify", fail, "the same")
    assert len(reports) == n + 1
    assert stages.run("notify", lambda: 7) == 7 and "notify" not in stages.failing  # back by itself
    n = len(reports)
    stages.run("notify", fail, "the same")
    assert len(reports) == n  # within the minute: silent
    stages.rearm()  # a preset switch
    stages.run("notify", fail, "the same")
    assert len(reports) == n + 1


def test_a_capture_that_fails_for_a_while_comes_back_and_a_failing_twin_leaves_the_arm_drawn():
    calls = {"n": 0}

    def capture(session):
        calls["n"] += 1
        if calls["n"] <= 10:
            raise RuntimeError("capture broke")
        return SimpleNamespace(link_names=("a",), step=None)

    lab = Lab("free")
    frames = FrameBuilder(1 / 30, 0.1, capture)
    built = [frames.publish(lab, now=0.1 * i) for i in range(15)]
    assert all(f is not None for f in built)  # every frame went out
    assert [f.scene is not None for f in built] == [False] * 10 + [True] * 5  # the scene came back
    problems = [n for n in lab.notice_log if n.title == "Display problem"]
    assert len(problems) == 1  # ten failures, one notice

    class BrokenTwin:
        objective = "j"
        W = 0.0

        def link_poses(self, names):
            raise ValueError("twin poses broke")

    stub = SimpleNamespace(session=lab.session, twin=BrokenTwin())
    scene = frames._scene(stub)
    assert scene is not None and scene.link_names == ("a",)  # the arm without its twin
    assert frames.stages.failures["twin poses"] == 1


def _shown_grows(app, attr: str = "frames_shown", timeout: float = 10.0) -> bool:
    before = getattr(app.publisher, attr)
    app.loop.submit(StepOnce(1))
    return wait_until(lambda: getattr(app.publisher, attr) > before, timeout)


def test_the_page_keeps_updating_through_a_failing_notify_scene_panel_or_plot_stage(app, monkeypatch):
    pub = app.publisher
    assert wait_until(lambda: _shown_grows(app) and pub.scene is not None)
    for stage, target, name in (
        ("notify", app.loop, "take_notices"),
        ("scene", pub.scene, "update"),
        (pub.panel_guards[0].stage, pub.panels[0], "live"),
        ("plots", pub.plots, "update"),
    ):
        calls = {"n": 0}
        original = getattr(target, name)

        def broken(*args, _orig=original, _calls=calls, _stage=stage, **kwargs):
            _calls["n"] += 1
            if _calls["n"] <= 5:
                raise RuntimeError(f"{_stage} broke")
            return _orig(*args, **kwargs)

        monkeypatch.setattr(target, name, broken)
        failures = pub.stages.failures[stage]
        for _ in range(8):  # the stage fails five times, then works again
            assert _shown_grows(app), stage
        assert pub.alive, stage
        assert pub.stages.failures[stage] - failures == 5, stage
        assert stage not in pub.stages.failing, stage
        monkeypatch.setattr(target, name, original)
    assert _shown_grows(app, "scene_updates") and _shown_grows(app, "plot_updates")


def test_a_failing_panel_shows_it_stopped_updating_and_every_panel_after_it_updates_on(app, monkeypatch):
    """The Nullspace panel's `live` raises: the panels after it (Lessons and Replay among them) still get
    their calls, the page gets one notice for it, its folder says it stopped updating, and once it works
    again it is updated and the line goes."""
    import app.live.ui.publisher as publisher_module
    from app.live.ui.panels.nullspace import NullspacePanel

    pub = app.publisher
    assert wait_until(lambda: _shown_grows(app) and pub.scene is not None)
    broken_at = next(i for i, p in enumerate(pub.panels) if isinstance(p, NullspacePanel))
    later = pub.panels[broken_at + 1 :]
    names = {type(p).__name__ for p in later}
    assert {"LessonsPanel", "ReplayPanel"} <= names and len(later) >= 5
    sent: list[str] = []
    real_notify = publisher_module.notify

    def notify(server, client_id, title, body, **kwargs):
        sent.append(body)
        return real_notify(server, client_id, title, body, **kwargs)

    monkeypatch.setattr(publisher_module, "notify", notify)
    calls = [0] * len(later)
    for i, p in enumerate(later):

        def counted(frame, _orig=p.live, _i=i):
            calls[_i] += 1
            return _orig(frame)

        monkeypatch.setattr(p, "live", counted)
    broken = pub.panels[broken_at]
    flag = {"on": True, "calls": 0}
    monkeypatch.setattr(broken, "live", _failing_while(flag, broken.live, "nullspace readout broke"))
    pub.stages.rearm()
    for _ in range(12):  # the live numbers go out a few times a second: about 2 s of frames
        assert _shown_grows(app)
        time.sleep(0.15)
    silent = [type(p).__name__ for p, n in zip(later, calls, strict=True) if n < 3]
    assert not silent, f"panels after the failing one got fewer than 3 calls: {silent}"
    guard = pub.panel_guards[broken_at]
    assert flag["calls"] >= 3 and guard.failing  # tried again with later frames, failing each time
    assert sum("updating the Nullspace panel failed" in body for body in sent) == 1  # one notice
    assert guard.stale is not None and guard.stale.visible
    assert "stopped updating" in guard.stale.content and "nullspace readout broke" in guard.stale.content
    flag["on"] = False
    assert wait_until(lambda: _shown_grows(app) and not guard.failing)  # retried, and back
    assert not guard.stale.visible


def test_a_dead_publisher_thread_is_restarted(app, monkeypatch):
    pub = app.publisher

    def die(frame):
        raise SystemExit("the publisher broke")  # not an Exception: past every stage's boundary

    monkeypatch.setattr(pub, "show", die)
    app.loop.submit(StepOnce(1))
    assert wait_until(lambda: not pub.alive)
    assert "the publisher broke" in pub.failure
    monkeypatch.undo()
    assert pub.supervise() == "" and pub.alive
    assert _shown_grows(app)


def test_serve_exits_non_zero_with_the_reason_when_the_publisher_cannot_be_restarted(monkeypatch, capsys):
    from app.live.server import serve
    from app.live.ui.publisher import Publisher

    def always_dies(self):
        raise SystemExit("the publisher always breaks")

    monkeypatch.setattr(Publisher, "_run", always_dies)
    args = argparse.Namespace(scenario="free", host="127.0.0.1", port=0, robot=None, urdf=None)
    t0 = time.monotonic()
    assert serve(args) == 1
    assert time.monotonic() - t0 < 60.0
    err = capsys.readouterr().err
    assert "the page stopped updating: the publisher thread died 6 times" in err
    assert "the publisher always breaks" in err


def _junk_from_one_client(app, uuid: str, junk: tuple, count: int, then: tuple = ()) -> dict[int, int]:
    """From a raw websocket (beside a bystander that sends nothing) `count` GUI updates for the input `uuid`
    cycling through `junk`, waiting until the guard has refused them all, then the values `then`; returns
    the notices sent meanwhile, by client id."""
    guard = app.input_guard
    refused, notified = guard.refused, dict(guard.notified)
    sub = [f"viser-v{viser.__version__}"]
    bystander = connect(f"ws://127.0.0.1:{app.port}", subprotocols=sub, open_timeout=10)
    ws = connect(f"ws://127.0.0.1:{app.port}", subprotocols=sub, open_timeout=10)
    try:
        bystander.send(camera_message())
        ws.send(camera_message())
        for i in range(count):
            msg = {"type": "GuiUpdateMessage", "uuid": uuid, "updates": {"value": junk[i % len(junk)]}}
            ws.send(msgspec.msgpack.encode(msg))
        assert wait_until(lambda: guard.refused - refused == count)
        new = {k: v - notified.get(k, 0) for k, v in guard.notified.items() if v - notified.get(k, 0)}
        for value in then:
            ws.send(msgspec.msgpack.encode({"type": "GuiUpdateMessage", "uuid": uuid, "updates": {"value": value}}))
        return new
    finally:
        ws.close()
        bystander.close()


def test_junk_for_the_phase_joint_selector_is_one_notice_to_its_sender_and_the_plots_run_on(app):
    joint = app.publisher.plots.joint
    before = joint.value
    new = _junk_from_one_client(app, joint._impl.uuid, ("abc", "0", "99", 4, None, [1], "4.5", ""), 1000)
    assert joint.value == before  # the value every page sees is unchanged
    assert list(new.values()) == [1]  # one notice, to one client (the sender: the bystander sent no junk)
    assert _shown_grows(app, "plot_updates")
    assert "plots" not in app.publisher.stages.failing


def test_junk_for_a_plots_signal_checkbox_is_one_notice_to_its_sender_and_the_choice_stands(app):
    """A raw websocket sends 200 values a checkbox cannot take for the torque plot's τ3 box: all refused,
    one notice to that client only, τ3 still drawn, and a real update after them still applies."""
    plots = app.publisher.plots
    box = plots.signal_boxes[("torque", "tau_3")]
    try:
        new = _junk_from_one_client(app, box._impl.uuid, ("false", 0, 1, None, [False], 0.5, ""), 200)
        assert list(new.values()) == [1]  # one notice, to the sender alone
        assert box.value is True and plots.signals.shown("torque", "tau_3")
        _junk_from_one_client(app, box._impl.uuid, (), 0, then=(False,))
        assert wait_until(lambda: not plots.signals.shown("torque", "tau_3"))  # the real update applied
        assert wait_until(lambda: plots.handles["torque"].series[3].get("show") is False)
    finally:
        plots.choose_signals("torque", (*plots.signals.shown_keys("torque"), "tau_3"))


def test_the_check_accepts_what_a_page_sends_and_refuses_the_rest():
    dropdown = SimpleNamespace(options=("1", "2"))
    assert check_value("1", dropdown, "2") == ""
    assert "one of 1, 2" in check_value("1", dropdown, "3")
    assert check_value(1.0, None, 3) == "" and check_value(1.0, None, 10**400) != ""
    assert check_value(1.0, None, float("nan")) != "" and check_value(1.0, None, "5") != ""
    assert check_value(True, None, 1) != "" and check_value(True, None, False) == ""
    assert check_value((0.0, 0.0, 0.0), None, [1, 2, 3]) == "" and check_value((0.0, 0.0, 0.0), None, [1, 2]) != ""


def test_a_preset_switch_re_arms_the_display_reports(app):
    frames = app.loop.frames
    frames.stages.budget.should_report("capture: RuntimeError: old")
    n = len(frames.stages.budget)
    assert n >= 1
    app.loop.submit(SwitchSession("compliance"))
    assert wait_until(lambda: app.loop.status.scenario == "compliance" or app.loop.sync().scenario == "compliance")
    app.loop.submit(StepOnce(1))
    assert wait_until(lambda: len(frames.stages.budget) == 0)


def _failing_while(flag: dict, original, text: str):
    """`original`, but raising RuntimeError(text) while flag["on"]; counts its calls in flag["calls"]."""

    def broken(*args, **kwargs):
        flag["calls"] += 1
        if flag["on"]:
            raise RuntimeError(text)
        return original(*args, **kwargs)

    return broken


@pytest.mark.parametrize("stage", ["capture", "build"])
def test_a_failing_frame_build_stage_in_the_running_loop_is_reported_once_and_comes_back(app, monkeypatch, stage):
    """The loop thread's capture (part of a frame) or the whole frame build fails for ten steps: the
    loop steps on, the publisher's other stages run on (frames without a scene go out while capture
    fails), the page gets one notice, and frames with a scene come back by themselves after."""
    import app.live.ui.publisher as publisher_module

    pub, loop, frames = app.publisher, app.loop, app.loop.frames
    assert wait_until(lambda: _shown_grows(app) and pub.scene is not None)
    sent: list[str] = []
    real_notify = publisher_module.notify

    def notify(server, client_id, title, body, **kwargs):
        sent.append(title)
        return real_notify(server, client_id, title, body, **kwargs)

    monkeypatch.setattr(publisher_module, "notify", notify)
    flag = {"on": True, "calls": 0}
    monkeypatch.setattr(frames, stage, _failing_while(flag, getattr(frames, stage), f"{stage} broke"))
    frames.stages.rearm()  # an earlier test's report of the same text does not hide this one
    failures, shown, updates = frames.stages.failures[stage], pub.frames_shown, pub.scene_updates
    notify_runs = pub.stages.runs["notify"]
    t0 = loop.sync().t
    for _ in range(10):
        calls = flag["calls"]
        loop.submit(StepOnce(1))
        assert wait_until(lambda c=calls: flag["calls"] > c), stage
    assert loop.sync().t - t0 == pytest.approx(10 * loop.dt, rel=1e-6)  # ten steps ran
    assert frames.stages.failures[stage] - failures == flag["calls"] >= 10
    assert wait_until(lambda: sent.count("Display problem") == 1)  # delivered while the stage still fails
    assert pub.alive and loop.alive and pub.stages.runs["notify"] - notify_runs >= 1
    if stage == "capture":  # frames still go out, without a scene
        assert wait_until(lambda: pub.frames_shown - shown >= 10)
        assert pub.scene_updates - updates <= 1  # at most the frame captured before the patch
        updates = pub.scene_updates
        for _ in range(5):  # every frame captured while capture fails goes out without a scene
            assert _shown_grows(app), stage
        assert pub.scene_updates == updates
    else:  # no frame to show: the publisher waits on
        assert pub.frames_shown - shown <= 1  # at most the frame built before the patch
        shown = pub.frames_shown
        for _ in range(5):
            calls = flag["calls"]
            loop.submit(StepOnce(1))
            assert wait_until(lambda c=calls: flag["calls"] > c), stage
        assert pub.frames_shown == shown
    flag["on"] = False
    for _ in range(5):
        assert _shown_grows(app, "scene_updates"), stage  # back by itself
    assert stage not in frames.stages.failing
    assert sent.count("Display problem") == 1  # ten failures, one notice


def _logged_plots(app):
    """The app's plots with a second of logged history (the loop stepped, the plots updated)."""
    plots = app.publisher.plots
    before = app.publisher.plot_updates
    app.loop.submit(StepOnce(1000))
    app.loop.sync(timeout=60.0)
    assert wait_until(lambda: app.publisher.plot_updates > before and len(plots.history.t) > 20)
    return plots


def test_a_redraw_reads_the_replay_instant_once_so_replay_clearing_it_meanwhile_cannot_break_it(app, monkeypatch):
    """Replay clears `replay_t` from another thread; here it is cleared right after each read, the worst
    moment. The redraw reads it once and draws that instant (it read it twice, and the second read's
    None raised in the middle of a frame)."""
    import threading

    plots = _logged_plots(app)
    reads = [0]
    here = threading.get_ident()

    class ClearedAfterEachRead(type(plots)):  # type: ignore[misc]
        @property  # type: ignore[override]
        def replay_t(self):
            reads[0] += threading.get_ident() == here  # this thread's redraws (the publisher may redraw too)
            value = self.__dict__.get("_replay_t_value")
            self.__dict__["_replay_t_value"] = None  # Replay switched off right after this read
            return value

        @replay_t.setter
        def replay_t(self, value):
            self.__dict__["_replay_t_value"] = value

    monkeypatch.setattr(plots, "__class__", ClearedAfterEachRead)
    t = plots.history.t
    for instant in np.linspace(float(t[len(t) // 4]), float(t[-1]), 20):
        plots.replay_t = float(instant)
        reads[0] = 0
        plots.redraw()  # raised TypeError when the second read met None
        assert reads[0] == 1


def test_replay_toggled_from_another_thread_during_redraws_breaks_no_redraw(app):
    """A thread switches the replay instant on and off as fast as it can while 300 redraws run."""
    import threading

    plots = _logged_plots(app)
    t = plots.history.t
    instant = float(t[len(t) // 2])
    stop = threading.Event()
    toggles = [0]

    def toggle() -> None:
        while not stop.is_set():
            plots.replay_t = instant if toggles[0] % 2 == 0 else None
            toggles[0] += 1

    thread = threading.Thread(target=toggle, daemon=True)
    thread.start()
    try:
        for _ in range(300):
            plots.redraw()
    finally:
        stop.set()
        thread.join(5.0)
        plots.replay_t = None
    assert toggles[0] > 300


def test_the_framer_writes_cameras_on_the_servers_event_loop_while_pages_connect_and_leave(app):
    """The publisher frames the pages while 40 raw websocket clients connect (sending their camera, so
    they are framed too) and leave: every camera write runs on the server's event loop thread, and none
    of the framings from the publisher's side raises (asyncio's "deque mutated during iteration" did)."""
    import threading

    import app.live.ui.camera as camera_module

    pub = app.publisher
    assert wait_until(lambda: _shown_grows(app) and pub.last_frame is not None and pub.last_frame.scene is not None)
    loop_thread: list[int] = []
    app.server.get_event_loop().call_soon_threadsafe(lambda: loop_thread.append(threading.get_ident()))
    assert wait_until(lambda: bool(loop_thread))
    writers: list[int] = []
    # the function that writes the cameras (`frame_cameras` wrote them on its caller's thread)
    name = "write_cameras" if hasattr(camera_module, "write_cameras") else "frame_cameras"
    real_write = getattr(camera_module, name)

    def recorded(*args, **kwargs):
        writers.append(threading.get_ident())
        return real_write(*args, **kwargs)

    setattr(camera_module, name, recorded)
    errors: list[BaseException] = []
    stop = threading.Event()
    framings = [0]

    def frame_again() -> None:
        while not stop.is_set():
            try:
                assert pub.frame_view()
                framings[0] += 1
            except BaseException as exc:
                errors.append(exc)
                return

    thread = threading.Thread(target=frame_again, daemon=True)
    thread.start()
    sub = [f"viser-v{viser.__version__}"]
    try:
        for _ in range(40):
            ws = connect(f"ws://127.0.0.1:{app.port}", subprotocols=sub, open_timeout=10)
            ws.send(camera_message())
            time.sleep(0.02)
            ws.close()
    finally:
        stop.set()
        thread.join(10.0)
        setattr(camera_module, name, real_write)
    assert not errors, errors[0]
    assert framings[0] >= 40 and writers
    elsewhere = sum(1 for w in writers if w != loop_thread[0])
    assert elsewhere == 0, f"{elsewhere} of {len(writers)} camera writes ran outside the server's event loop"


@pytest.mark.parametrize("urdf", sorted(p.name for p in __import__("robots").ROBOTS_DIR.glob("*.urdf")))
def test_every_shipped_urdf_loaded_by_path_without_its_sidecar_gives_every_presets_first_scene(tmp_path, urdf):
    """A shipped URDF copied alone to a folder (no sidecar: the arm starts at its zero posture, Gen3
    stretched straight up, a singular posture) and loaded by path: the first frame of every preset has
    its scene, with the coupling shapes hidden where the posture is singular (the coupling kernel
    divided by the zero force-axis entry of Λx⁻¹ and raised ZeroDivisionError in free and compliance)."""
    import shutil

    import robots
    from app.live.ui.snapshot import capture
    from app.scenarios import SCENARIOS

    path = tmp_path / urdf
    shutil.copy(robots.ROBOTS_DIR / urdf, path)
    assert not list(tmp_path.glob("*.toml"))
    for scenario in SCENARIOS:
        lab = Lab(scenario, robot=str(path))
        frames = FrameBuilder(1 / 30, 0.1, capture)
        frame = frames.publish(lab, now=0.0)
        failing = {stage: frames.stages.last_error.get(stage) for stage in frames.stages.failing}
        assert frame is not None and frame.scene is not None and not failing, (scenario, failing)
        snap = frame.scene
        if not snap.near_singular:
            assert all(np.isfinite(snap.W[k]) for k in ("W_f", "W_a", "W_d")), (scenario, snap.W)
