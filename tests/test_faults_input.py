"""Bad input is one line and loses nothing: huge integers, zero counts, absurd grids, missing meshes."""

from __future__ import annotations

import time
from types import SimpleNamespace

import numpy as np
import pytest
import viser

from app.cli import main
from app.core.commands import SetParam
from app.core.params import load_settings, settings_commands
from app.core.session import Session
from app.headless.sweep.grid import MAX_CELLS, Axis, SweepError, cells, parse_grid
from app.live.lab import Lab
from app.live.ui.scene import SceneView
from control.gains import DamperGains
from control.params import ParamError, replaced
from tests import urdf_fixtures as fx
from tests.conftest import wait_until

HUGE = 10**400


def test_an_integer_beyond_any_float_is_a_one_line_refusal_not_an_overflow():
    with pytest.raises(ParamError, match=r"lambda_ must be a number .* too large"):
        replaced(DamperGains(), "lambda_", HUGE)
    with pytest.raises(ParamError):
        replaced(DamperGains(), "lambda_", -HUGE)


def test_setparam_with_a_huge_integer_is_refused_to_its_client_and_changes_nothing():
    lab = Lab("free")
    group = next(iter(lab.settings.values))
    field = next(k for k, v in lab.settings.values[group].items() if isinstance(v, float))
    before = lab.settings.values[group][field]
    lab.apply(SetParam(group, field, HUGE, client_id=7))
    notices = list(lab.notice_log)
    assert [n.title for n in notices] == ["Value refused"]
    assert notices[0].client_id == 7 and "\n" not in notices[0].body
    assert lab.settings.values[group][field] == before


def test_a_settings_file_with_one_huge_entry_applies_the_valid_ones_and_says_which_was_refused():
    text = f"[joint_hold]\nstiffness = {HUGE}\n[drag]\nmax_force_n = 120.0\n"
    s = Session("free")
    refused = load_settings(s, text)
    assert len(refused) == 1 and "stiffness" in refused[0] and "\n" not in refused[0]
    assert s.params()["drag"].max_force_n == 120.0
    commands, refused = settings_commands(s.params(), text)
    assert [(c.group, c.field) for c in commands] == [("drag", "max_force_n")] and len(refused) == 1


def test_a_failing_command_keeps_its_client_for_the_notice(monkeypatch):
    lab = Lab("free")

    def boom(*args, **kwargs):
        raise RuntimeError("set_param broke")

    monkeypatch.setattr(lab.session, "set_param", boom)
    lab.apply(SetParam("drag", "max_force_n", 100.0, client_id=3))
    (notice,) = [n for n in lab.notice_log if n.title == "Command failed"]
    assert notice.client_id == 3


@pytest.mark.parametrize(
    "argv, says",
    [
        (["check", "--samples", "0"], "--samples must be at least 1, got"),
        (["check", "--samples", "-3"], "--samples must be at least 1, got"),
        (["bench", "--repeats", "0"], "--repeats must be at least 1, got 0"),
        (["bench", "--serve", "--seconds", "0"], "--seconds must be a positive number"),
        (["sweep", "polish", "--out", "/tmp/x", "--grid", "mu=0.5", "--seeds", "0"], "--seeds must be"),
        (["sweep", "polish", "--out", "/tmp/x", "--grid", "mu=0.5", "--jobs", "0"], "--jobs must be"),
        (["experiment", "polish", "--seeds", "0"], "--seeds must be"),
        (["experiment", "polish", "--jobs", "-1"], "--jobs must be"),
        (["check", "--samples", str(10**30)], "--samples must be at most 10,000,000"),
        (["bench", "--soak", "0"], "--soak must be a positive number of minutes"),
    ],
)
def test_a_zero_negative_or_absurd_count_is_one_line_and_exit_2(argv, says, capsys):
    assert main(argv) == 2
    out = capsys.readouterr()
    lines = out.err.strip().splitlines()
    assert len(lines) == 1 and says in lines[0], out.err
    assert out.out == ""


def test_an_absurd_grid_is_refused_before_it_is_allocated():
    t0 = time.perf_counter()
    with pytest.raises(SweepError, match="more than a sweep's"):
        parse_grid(["mu=0:1:1000000000"])
    axes = [Axis("a", tuple(range(1000))), Axis("b", tuple(range(1000)))]
    with pytest.raises(SweepError, match=rf"1,000,000 cells .* at most {MAX_CELLS:,}"):
        cells(axes, 1)
    assert time.perf_counter() - t0 < 1.0
    assert len(cells([Axis("a", (1, 2, 3))], 2)) == 6


def _arm_with_one_missing_mesh(tmp_path):
    """A URDF whose link 3 is drawn from a mesh file that does not exist and link 5 from one that does."""
    fx.box_mesh(tmp_path / "meshes" / "link.stl")
    return fx.write(
        tmp_path / "arm.urdf", fx.gripper_arm_meshes({"a_link3": "meshes/missing.stl", "a_link5": "meshes/link.stl"})
    )


def test_a_missing_mesh_is_drawn_as_nothing_the_robot_loads_and_one_notice_names_it(tmp_path, monkeypatch):
    import robots
    from robots import meshes

    monkeypatch.setenv("TORQUELAB_CACHE", str(tmp_path / "cache"))
    urdf = _arm_with_one_missing_mesh(tmp_path)
    robot = robots.load(str(urdf))  # the model does not need the visuals
    assert robot.model.nq == 7
    shapes = meshes.link_meshes(robot.urdf_path)
    assert "a_link3" not in shapes and {"a_link2", "a_link5"} <= set(shapes)
    np.testing.assert_allclose(shapes["a_link5"].extents, [0.05, 0.05, 0.1], atol=1e-6)  # the file that exists
    problems = meshes.mesh_problems(robot.urdf_path)
    assert list(problems) == ["meshes/missing.stl"] and "not found" in problems["meshes/missing.stl"]
    meshes._MEMORY.clear()  # a new process: the disk cache keeps the problem too
    assert meshes.mesh_problems(robot.urdf_path) == problems
    session = Session("free", robot=str(urdf))
    t0 = session.world.time
    records = [session.step() for _ in range(100)]
    dt = float(session.world.model.opt.timestep)
    assert session.world.time - t0 == pytest.approx(100 * dt, rel=1e-6)  # it runs
    assert all(np.isfinite(r.tau).all() for r in records)

    server = viser.ViserServer(port=0, verbose=False)
    try:
        scene = SceneView(server, robot, lambda cmd: None)
        assert "a_link3" in scene.frames and "a_link3" not in scene.meshes and "a_link5" in scene.meshes
        assert list(scene.missing_meshes) == ["meshes/missing.stl"]
    finally:
        server.stop()


def test_serve_with_a_missing_mesh_starts_and_says_so_in_one_line(tmp_path, monkeypatch, capsys):
    from app.live import server

    monkeypatch.setenv("TORQUELAB_CACHE", str(tmp_path / "cache"))
    urdf = _arm_with_one_missing_mesh(tmp_path)
    started: list[str | None] = []

    def start_app(**kwargs):
        started.append(kwargs["robot"])
        return SimpleNamespace(
            loop=SimpleNamespace(alive=False, failure=""),
            publisher=SimpleNamespace(supervise=lambda: ""),
            port=8080,
            url="http://127.0.0.1:8080",
            stop=lambda: None,
        )

    monkeypatch.setattr(server, "start_app", start_app)
    assert main(["serve", "--urdf", str(urdf), "--port", "0", "--no-warmup"]) == 0
    out = capsys.readouterr()
    assert started == [str(urdf)] and out.err == ""
    said = [ln for ln in out.out.splitlines() if "missing.stl" in ln]
    assert len(said) == 1 and "1 mesh file drawn as nothing" in said[0] and "not found" in said[0]


def _shipped_arm_with_a_missing_mesh(tmp_path):
    """A copy of the Gen3's URDF and sidecar whose base visual is drawn from a mesh file that does not exist."""
    import robots

    text = (robots.ROBOTS_DIR / "gen3.urdf").read_text()
    sphere = '<geometry><sphere radius="0.05"/></geometry></visual>'
    assert sphere in text
    text = text.replace(sphere, '<geometry><mesh filename="meshes/missing.stl"/></geometry></visual>', 1)
    (tmp_path / "arm.toml").write_text((robots.ROBOTS_DIR / "gen3.toml").read_text())
    return fx.write(tmp_path / "arm.urdf", text)


@pytest.mark.parametrize(
    "argv",
    [
        ("check", "--samples", "5"),
        ("experiment", "limit-drop", "--quick", "--duration", "0.3", "--jobs", "1", "--out", "OUT"),
    ],
)
def test_a_headless_command_on_a_urdf_with_a_missing_mesh_says_so_in_one_line_and_runs(
    tmp_path, monkeypatch, capfd, argv
):
    import robots

    monkeypatch.setenv("TORQUELAB_CACHE", str(tmp_path / "cache"))
    monkeypatch.setenv(robots.ROBOT_ENV, "")  # restored after the command set it
    urdf = _shipped_arm_with_a_missing_mesh(tmp_path)
    args = [str(tmp_path / "out") if a == "OUT" else a for a in argv]
    assert main([*args, "--urdf", str(urdf)]) == 0
    err = capfd.readouterr().err
    said = [ln for ln in err.splitlines() if "missing.stl" in ln]
    assert len(said) == 1 and said[0].startswith("torquelab: arm: 1 mesh file drawn as nothing: "), err
    assert "not found" in said[0] and str(tmp_path / "meshes" / "missing.stl") in said[0]


def test_a_robot_switch_in_the_running_app_to_an_arm_with_a_missing_mesh_gives_one_notice(app, tmp_path, monkeypatch):
    """The running loop and publisher (no browser): a switch to the arm draws it without link 3, one
    notice names the file, frames keep coming, and a preset switch on the same arm says nothing again."""
    from app.core.commands import StepOnce, SwitchSession
    from tests.conftest import wait_until

    monkeypatch.setenv("TORQUELAB_CACHE", str(tmp_path / "cache"))
    urdf = _arm_with_one_missing_mesh(tmp_path)
    pub, loop = app.publisher, app.loop

    def said() -> list:
        return [n for n in loop.notice_log if n.title == "Missing meshes"]

    def scene_of(path) -> bool:
        return pub.scene is not None and pub.scene.robot.urdf_path == path

    def frames_grow() -> bool:
        before = pub.frames_shown
        loop.submit(StepOnce(1))
        return wait_until(lambda: pub.frames_shown > before)

    before = len(said())
    try:
        loop.submit(SwitchSession(robot=str(urdf)))
        assert wait_until(lambda: scene_of(urdf.resolve()) or (frames_grow() and scene_of(urdf.resolve())), 30.0)
        assert "a_link3" in pub.scene.frames and "a_link3" not in pub.scene.meshes and "a_link5" in pub.scene.meshes
        t0 = loop.sync().t
        for _ in range(10):
            assert frames_grow()
        assert loop.sync().t > t0 and loop.alive  # the arm runs
        assert wait_until(lambda: len(said()) - before == 1)
        (notice,) = said()[before:]
        assert "meshes/missing.stl" in notice.body and "\n" not in notice.body
        session_id = pub.scene_session_id
        loop.submit(SwitchSession("compliance"))  # a new session on the same arm
        assert wait_until(lambda: frames_grow() and pub.scene_session_id != session_id, 30.0)
        for _ in range(10):
            assert frames_grow()
        assert len(said()) - before == 1  # once per robot, not per frame or per preset
    finally:
        loop.submit(SwitchSession("free", robot=""))
        assert wait_until(lambda: frames_grow() and pub.scene is not None and pub.scene.robot.name == "rizon4s", 30.0)


def _notifications(ws, seconds: float) -> list[tuple[str, str]]:
    """(title, body) of every notification a raw viser websocket received within `seconds`."""
    import msgspec
    import zstandard

    out: list[tuple[str, str]] = []
    deadline = time.monotonic() + seconds
    while (left := deadline - time.monotonic()) > 0:
        try:
            data = ws.recv(timeout=left)
        except TimeoutError:
            break
        size, packed = int.from_bytes(data[:8], "little"), int.from_bytes(data[8:16], "little")
        inner = zstandard.ZstdDecompressor().decompress(data[16 : 16 + packed], max_output_size=size)
        for msg in msgspec.msgpack.decode(inner)["messages"]:
            if msg.get("type") == "NotificationShowMessage":
                out.append((msg["props"]["title"], msg["props"]["body"]))
    return out


def test_a_page_opened_after_start_gets_the_missing_mesh_notice_once(tmp_path, monkeypatch):
    """The app starts on an arm with a missing mesh file (no page open): each page that opens later
    gets one "Missing meshes" notice naming the file, sent to it alone, and no second one."""
    from websockets.sync.client import connect

    from app.core.commands import StepOnce
    from app.live.server import start_app
    from tests.conftest import camera_message, wait_until

    monkeypatch.setenv("TORQUELAB_CACHE", str(tmp_path / "cache"))
    urdf = _arm_with_one_missing_mesh(tmp_path)
    app = start_app(port=0, scenario="free", robot=str(urdf), running=False)
    pages = []
    try:
        app.loop.submit(StepOnce(1))

        def said() -> list:
            return [n for n in app.loop.notice_log if n.title == "Missing meshes"]

        assert wait_until(lambda: said() and not app.loop.lab.notices, 30.0)  # said at start, and sent
        assert [n.client_id for n in said()] == [None]  # at start: to every page (there was none)
        for _ in range(2):  # two pages, one after the other
            before = set(app.server.get_clients())
            ws = connect(f"ws://127.0.0.1:{app.port}", subprotocols=[f"viser-v{viser.__version__}"], open_timeout=10)
            pages.append(ws)
            ws.send(camera_message())
            assert wait_until(lambda b=before: len(set(app.server.get_clients()) - b) == 1)
            (client_id,) = set(app.server.get_clients()) - before
            shown = [body for title, body in _notifications(ws, 3.0) if title == "Missing meshes"]
            assert len(shown) == 1 and "meshes/missing.stl" in shown[0] and "\n" not in shown[0], shown
            assert len([n for n in said() if n.client_id == client_id]) == 1  # to that page alone
        assert not [body for title, body in _notifications(pages[0], 1.0) if title == "Missing meshes"]
    finally:
        for ws in pages:
            ws.close()
        app.stop()


def _raw_page(app):
    """A raw websocket to the app that has sent its camera (a page, as viser counts them)."""
    from websockets.sync.client import connect

    from tests.conftest import camera_message

    ws = connect(f"ws://127.0.0.1:{app.port}", subprotocols=[f"viser-v{viser.__version__}"], open_timeout=10)
    ws.send(camera_message())
    return ws


JUNK = (
    "a text frame",  # text, not binary
    b"\xc1\xc1 not msgpack",  # bytes that are no MessagePack
    __import__("msgspec").msgpack.encode({"type": "NoSuchMessage", "x": 1}),  # no such message type
    __import__("msgspec").msgpack.encode({"type": "ViewerCameraMessage", "wxyz": "junk"}),  # wrong fields
)


def test_junk_frames_are_skipped_in_one_log_line_per_client_and_kind_and_a_flood_drops_the_connection(app, capfd):
    """One raw client sends each of four kinds of junk frame 4 times (16, under the drop rate): the connection
    stays and is served on; the log has one line per kind with no traceback. Then it floods: each
    connection is dropped at the stated rate (DROP_AFTER within DROP_WINDOW_S), with
    one line more: a flood over 15 connections, 25 frames each, all dropped, adds that one line within
    the minute. (viser logged a traceback per frame and dropped the connection at the first.)"""
    from websockets.exceptions import ConnectionClosed
    from websockets.protocol import State

    capfd.readouterr()
    before = set(app.server.get_clients())
    ws = _raw_page(app)
    try:
        assert wait_until(lambda: set(app.server.get_clients()) - before)
        (page,) = set(app.server.get_clients()) - before
        for _ in range(4):
            for frame in JUNK:
                ws.send(frame)
        ws.send(__import__("msgspec").msgpack.encode({"type": "GuiUpdateMessage", "uuid": "none", "updates": {}}))
        guard = getattr(app, "junk_guard", None)
        # until the junk is counted, or the page is let go
        wait_until(lambda: page not in app.server.get_clients() or (guard is not None and guard.log.received >= 16))
        assert page in app.server.get_clients() and ws.protocol.state is State.OPEN, "the page's junk ended it"
        assert ws.ping().wait(10.0) and ws.protocol.state is State.OPEN  # and it is served on
    finally:
        ws.close()
    err = capfd.readouterr().err
    lines = [ln for ln in err.splitlines() if "junk from" in ln]
    assert len(lines) == 4, err[-3000:]
    assert "Traceback" not in err and app.junk_guard.dropped == 0
    from app.live.ui.junk import DROP_AFTER

    assert DROP_AFTER > 16
    dropped = app.junk_guard.dropped
    for k in range(15):  # a flood over reconnects: each connection dropped at the rate
        before = set(app.server.get_clients())
        ws = _raw_page(app)
        try:
            assert wait_until(lambda b=before: set(app.server.get_clients()) - b)
            (page,) = set(app.server.get_clients()) - before
            try:
                for _ in range(DROP_AFTER + 5):
                    ws.send(JUNK[1])
            except ConnectionClosed:  # a send after the drop
                pass
            assert wait_until(lambda k=k: app.junk_guard.dropped - dropped == k + 1), k
            assert wait_until(lambda p=page: p not in app.server.get_clients()), k  # the server let it go
        finally:
            ws.close()
    assert app.junk_guard.dropped - dropped == 15
    err = capfd.readouterr().err
    assert "Traceback" not in err
    assert len([ln for ln in err.splitlines() if "junk from" in ln]) == 1, err[-3000:]  # the drops' one line


def test_the_junk_log_writes_one_line_per_client_and_kind_per_minute_with_the_count_since():
    from app.live.ui.junk import JunkLog

    now = [0.0]
    lines: list[str] = []
    log = JunkLog(lines.append, clock=lambda: now[0], capacity=8)
    for _ in range(500):  # 500 of one kind within 50 s from one client
        log.record("10.0.0.1", "text frames")
        now[0] += 0.1
    assert len(lines) == 1 and "text frames, 1 since" in lines[0]
    log.record("10.0.0.2", "text frames")  # another client: its own line
    assert len(lines) == 2
    now[0] += 60.0
    log.record("10.0.0.1", "text frames")  # a minute later: the count of the silent ones with it
    assert len(lines) == 3 and "text frames, 500 since" in lines[2]
    for i in range(100):  # kinds that vary: memory stays bounded
        log.record(f"10.0.1.{i}", "frames that are not MessagePack")
    assert len(log._pairs) <= 8 and log.received == 602


def test_a_value_sent_to_the_load_settings_button_is_refused_with_a_clear_notice(app):
    """A GuiUpdateMessage carrying a value (not a file) for the Load settings upload button: refused on
    arrival with a notice to its sender saying a file is uploaded with the button, nothing raised (it
    passed the guard and viser raised TypeError)."""
    import msgspec

    scenario = app.panels[0]
    button = scenario.settings.load_button
    guard = app.input_guard
    refused, notified = guard.refused, dict(guard.notified)
    before = button.value
    ws = _raw_page(app)
    try:
        for value in ("junk.toml", 7, {"name": "x.toml"}, None):
            msg = {"type": "GuiUpdateMessage", "uuid": button._impl.uuid, "updates": {"value": value}}
            ws.send(msgspec.msgpack.encode(msg))
        assert wait_until(lambda: guard.refused - refused == 4)
        assert sum(guard.notified.values()) - sum(notified.values()) == 1  # counted while the page is open
    finally:
        ws.close()
    assert button.value == before
    from app.live.ui.inputs import check_value

    assert "uploaded with the button" in check_value(before, None, "junk.toml")
