"""The small faults: divergence time, a silent client's drag, a panel callback that must not wait on the loop."""

from __future__ import annotations

import time

import pytest

from app.core.commands import DragCommand
from app.core.session import Session
from app.live import loop as loop_module
from app.live.loop import SimLoop


def test_a_divergence_is_reported_at_its_time_not_at_the_zero_mujocos_reset_leaves():
    s = Session("free")
    assert s.run(steps=1500).stop == "done"
    s.world.data.qvel[:] = 1e11  # MuJoCo resets such a state (time back to 0) and counts a warning
    result = s.run(steps=10)
    assert result.stop == "diverged"
    assert "t = 1.501 s" in result.reason and abs(result.t - 1.501) < 1e-9


@pytest.mark.usefixtures("warm_kernels")
def test_a_silent_clients_drag_is_released_after_the_timeout_with_a_notice_to_it(monkeypatch):
    monkeypatch.setattr(loop_module, "DRAG_TIMEOUT_S", 0.5)
    lp = SimLoop("free", capture=lambda s: None)
    lp.start(running=True)
    try:
        link = lp.call(lambda s: s.robot.link_names[-1])
        lp.submit(DragCommand("grab", 5, body_name=link, point_world=(0.4, 0.0, 0.6)))
        lp.submit(DragCommand("move", 5, body_name=link, target_world=(0.5, 0.0, 0.5)))
        assert lp.sync().drag_client == 5
        t0 = time.monotonic()
        while lp.sync().drag_client is not None and time.monotonic() - t0 < 30.0:
            time.sleep(0.05)
        held = time.monotonic() - t0
    finally:
        lp.stop()
    assert lp.status.drag_client is None and held < 10.0
    notices = [n for n in lp.notice_log if n.title == "Drag released"]
    assert len(notices) == 1 and notices[0].client_id == 5


def test_a_moving_drag_is_kept(monkeypatch):
    monkeypatch.setattr(loop_module, "DRAG_TIMEOUT_S", 0.5)
    lp = SimLoop("free", capture=lambda s: None)
    lp.start(running=False)
    try:
        link = lp.call(lambda s: s.robot.link_names[-1])
        lp.submit(DragCommand("grab", 5, body_name=link, point_world=(0.4, 0.0, 0.6)))
        for i in range(15):  # a move every 0.1 s for 1.5 s: three timeouts long
            lp.submit(DragCommand("move", 5, body_name=link, target_world=(0.5, 0.0, 0.5 + 0.001 * i)))
            time.sleep(0.1)
        assert lp.sync().drag_client == 5
    finally:
        lp.stop()


def test_a_panel_echo_does_not_wait_on_a_loop_busy_with_a_presets_work():
    from types import SimpleNamespace

    from app.live.ui.panels.base import KnobPanel

    calls = []
    loop = SimpleNamespace(planner=SimpleNamespace(busy=True), sync=lambda timeout=10.0: calls.append(timeout))
    panel = KnobPanel.__new__(KnobPanel)
    panel.loop = loop
    t0 = time.perf_counter()
    assert panel.echo(None, None, 1.0, 3) is None
    assert time.perf_counter() - t0 < 0.1 and calls == []

    def slow(timeout=10.0):
        calls.append(timeout)
        raise TimeoutError

    loop.planner.busy = False
    loop.sync = slow
    assert panel.echo(None, None, 1.0, 3) is None and calls == [2.0]  # bounded wait, then no echo


def test_the_soak_slope_is_the_least_squares_line_in_mb_per_minute():
    import numpy as np

    from app.tools.soak import slope_mb_per_min

    t = np.arange(0.0, 600.0, 5.0)
    assert abs(slope_mb_per_min(t, 300.0 + 0.5 * t / 60.0) - 0.5) < 1e-9
    assert np.isnan(slope_mb_per_min(t[:2], t[:2]))


def test_the_soaks_second_half_slope_tells_growth_that_levels_off():
    import numpy as np

    from app.tools.soak import late_slope_mb_per_min, slope_mb_per_min

    t = np.arange(0.0, 600.0, 5.0)
    filling = 300.0 + 2.0 * (1.0 - np.exp(-t / 60.0))  # a cache that fills within the first minutes
    assert slope_mb_per_min(t, filling) > 0.1
    assert abs(late_slope_mb_per_min(t, filling)) < 0.02
    assert abs(late_slope_mb_per_min(t, 300.0 + 0.5 * t / 60.0) - 0.5) < 1e-9  # steady growth stays
    assert np.isnan(late_slope_mb_per_min(t[:3], t[:3]))


def test_a_joint_in_its_stop_for_one_step_between_two_looks_is_reported():
    import numpy as np

    import robots
    from app.sim.world import HARD_STOP_BEYOND_RAD, World

    robot = robots.load("rizon4s")
    world = World(robot)
    j = next(i for i in range(7) if not robot.endless[i])
    q = np.array(robot.home, dtype=float)
    world.reset(q)
    world.step(np.zeros(7))
    assert world.overpowered(None) == ""
    inside = q.copy()
    inside[j] = robot.q_upper[j] + HARD_STOP_BEYOND_RAD + 0.005  # 5 mrad into the stop for one step
    world.data.qpos[world.qpos_adr] = inside
    world.step(np.zeros(7))
    world.data.qpos[world.qpos_adr] = q  # back well inside before anybody looks
    world.data.qvel[:] = 0.0
    for _ in range(20):
        world.step(np.zeros(7))
    said = world.overpowered(None)
    assert f"joint {j + 1} is pressed against its hard stop" in said
    assert float(world.stop_depth[j]) > 0.004
    assert world.overpowered(None) == ""  # the next look covers only the steps since


HEADROOM = 1.2  # the hard-stop promise stands at least this far above the deepest drag measured


def _promised_stop_depth_rad() -> float:
    """The hard-stop depth the documentation promises ("sinks no joint more than X rad"), read from the
    README or, where the text has moved, the documentation pages under docs/."""
    import re
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    pages = [root / "README.md", *sorted((root / "docs").rglob("*.md"))]
    for page in pages:
        if page.is_file():
            promise = re.search(r"sinks no joint more than\s+([0-9.]+)\s+rad", page.read_text(encoding="utf-8"))
            if promise:
                return float(promise.group(1))
    raise AssertionError("neither the README nor docs/ states a hard-stop depth")


@pytest.mark.usefixtures("warm_kernels")
def test_the_hard_stop_promise_has_headroom_over_a_coarse_grid_of_the_hardest_drags():
    """A coarse `stop_depth` grid (every preset × executor, the tip pulled 2 m up and down at the page's
    maximum drag, 300 N, for 1 s; the full grid's worst, free / projection pulled up, is among them): no
    run halts, and the deepest any joint went into its stop, times HEADROOM, stays within the depth the
    documentation promises. A promise that sits on the measured worst fails here."""
    from app.core.executors import EXECUTORS
    from app.scenarios import SCENARIOS
    from app.tools.stop_depth import probe

    promise = _promised_stop_depth_rad()
    rows = []
    for scenario in SCENARIOS:
        for executor in EXECUTORS:
            for name, direction in (("+z", (0, 0, 1)), ("-z", (0, 0, -1))):
                depth, _, _, halted = probe(scenario, executor, direction, 1000)
                assert not halted, (scenario, executor, name)
                rows.append((depth, scenario, executor, name))
    worst = max(rows)
    print(f"deepest into a stop {1e3 * worst[0]:.1f} mrad ({worst[1:]}); promised {1e3 * promise:.1f} mrad")
    assert 0.0 < worst[0] and worst[0] * HEADROOM <= promise, (worst, promise)


def test_the_port_probe_finds_a_port_free_whose_last_connection_waits_in_time_wait():
    """A restart right after a stop: the old server's accepted connection, closed by the server first,
    waits in TIME_WAIT on its port. The server binds with SO_REUSEADDR and gets the port; the probe must
    say it is free (it said busy, and `serve` printed "port N is busy; using port N instead")."""
    import socket

    from app.live.server import port_is_free

    listener = socket.socket()
    listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    listener.bind(("127.0.0.1", 0))
    listener.listen()
    port = listener.getsockname()[1]
    client = socket.create_connection(("127.0.0.1", port))
    accepted, _ = listener.accept()
    accepted.close()  # the server side closes first: its end of the connection goes to TIME_WAIT
    client.recv(1)
    client.close()
    listener.close()
    assert port_is_free("127.0.0.1", port)
    with socket.socket() as server_again:  # as the restarted server binds
        server_again.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        server_again.bind(("127.0.0.1", port))
        server_again.listen()
        assert not port_is_free("127.0.0.1", port)  # a port in use is still busy


def test_a_twin_that_raises_on_a_change_is_switched_off_and_the_panels_show_what_the_main_arm_runs():
    """The twin's set_param raises something other than a refusal: the main arm keeps the new μ, the
    settings the panels show say the same, and the twin is switched off with a notice."""
    from app.core.commands import SetParam, SetTwin
    from app.live.lab import Lab

    lab = Lab("polish")
    lab.apply(SetTwin("j"))
    assert lab.twin is not None
    before = lab.settings.groups["contact"].mu

    def broken(*args, **kwargs):
        raise RuntimeError("twin broke")

    lab.twin.set_param = broken  # type: ignore[method-assign]
    lab.apply(SetParam("contact", "mu", 0.7))
    assert lab.session.params()["contact"].mu == pytest.approx(0.7, abs=1e-12)
    shown = lab.settings.groups["contact"].mu
    assert shown == pytest.approx(0.7, abs=1e-12), f"the panels show mu = {shown} (before: {before})"
    assert lab.twin is None
    off = [n for n in lab.notice_log if n.title == "Twin arm off"]
    assert len(off) == 1 and "contact.mu" in off[0].body and "twin broke" in off[0].body


def test_a_binary_settings_file_is_one_error_line_that_names_the_file(tmp_path, capsys):
    from app.cli import main

    path = tmp_path / "settings.toml"
    path.write_bytes(bytes(range(256)) * 4)
    code = main(["serve", "--scenario", "free", "--port", "0", "--no-warmup", "--settings", str(path)])
    lines = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert code == 2 and len(lines) == 1, lines
    assert str(path) in lines[0] and "not UTF-8" in lines[0]
