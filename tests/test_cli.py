"""Bad input at the command line: one clear line on stderr, non-zero exit, no traceback.

The commands run in this process (`main(argv)`, stderr captured at the file descriptor, so a C
library's or parser's own noise would show); one smoke test starts the real `python -m app.cli`."""

from __future__ import annotations

import re
import subprocess
import sys

import pytest

import robots


@pytest.fixture
def run_cli(capfd):
    """`torquelab ARGS` in this process: (exit code, stdout, stderr); an argparse exit counts as its code."""
    from app.cli import main

    def run(*args: str) -> subprocess.CompletedProcess:
        capfd.readouterr()
        try:
            code = main(list(args))
        except SystemExit as exc:
            code = exc.code if isinstance(exc.code, int) else 2
        out, err = capfd.readouterr()
        return subprocess.CompletedProcess(list(args), code, out, err)

    return run


def six_dof_urdf(tmp_path):
    text = (robots.ROBOTS_DIR / "rizon4s.urdf").read_text()
    # make joint7 fixed: a 6-DOF arm
    text = re.sub(r'<joint name="joint7" type="revolute">', '<joint name="joint7" type="fixed">', text)
    path = tmp_path / "six.urdf"
    path.write_text(text)
    return path


@pytest.mark.parametrize(
    "args, needle",
    [
        (["check", "--robot", "ur5"], "unknown robot"),
        (["check", "--urdf", "/no/such/arm.urdf"], "not found"),
        (["serve", "--robot", "ur5", "--port", "0"], "unknown robot"),
        (["bench", "--only", "no_such_bench"], "unknown benchmark"),
        (["bench", "--only", "mj_step", "--repeats", "5", "--vs-placo", "/no/such/python"], "could not run placo"),
    ],
)
def test_bad_robot_gives_one_line_error(run_cli, args, needle):
    res = run_cli(*args)
    assert res.returncode != 0
    assert "Traceback" not in res.stderr
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and needle in lines[0]


def test_six_dof_urdf_is_refused(run_cli, tmp_path):
    res = run_cli("check", "--urdf", str(six_dof_urdf(tmp_path)))
    assert res.returncode != 0
    assert "Traceback" not in res.stderr
    assert "7-DOF" in res.stderr and len(res.stderr.strip().splitlines()) == 1


def test_check_passes_for_shipped_robots(run_cli):
    res = run_cli("check", "--samples", "20", "--json")
    assert res.returncode == 0, res.stderr
    assert res.stdout.count('"ok": true') == len(robots.available())  # the Panda too with the robots extra


@pytest.mark.parametrize("jobs", ["0", "-2"])
def test_jobs_below_one_is_refused_in_one_line(run_cli, jobs, tmp_path):
    res = run_cli("experiment", "compliance", "--jobs", jobs, "--out", str(tmp_path / "out"))
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert res.returncode == 2 and lines == [f"torquelab: error: --jobs must be at least 1, got {jobs}"]
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(
    "text, needle",
    [
        ('<robot name="x"><link name="a"></robot>', "XML_ERROR_MISMATCHED_ELEMENT"),
        (
            '<robot name="x"><link name="a"/><link name="b"/><joint name="j" type="revolute">'
            '<parent link="a"/><child link="b"/></joint></robot>',
            "does not specify limits",
        ),
        ("not xml at all", "XML_ERROR_PARSING_TEXT"),
    ],
)
def test_a_urdf_that_does_not_parse_gives_one_line_with_its_path_and_no_parser_noise(run_cli, tmp_path, text, needle):
    path = tmp_path / "broken.urdf"
    path.write_text(text)
    res = run_cli("check", "--urdf", str(path))
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert res.returncode == 2 and len(lines) == 1, res.stderr
    assert lines[0].startswith(f"torquelab: error: cannot parse URDF {path.resolve()}") and needle in lines[0]


def test_serve_prints_the_url_first_warms_up_then_runs_the_arm_and_stops_cleanly_on_sigterm():
    """The smoke test of the real command (`python -m app.cli serve`), the one test that starts it in a
    process of its own: the URL comes first (`--port 0` says which port it took) and the page is
    served there while the kernels are made ready (compiled in worker processes or loaded); then the
    kernels are ready, then the arm runs; `kill` (SIGTERM) stops it as Ctrl-C does (the Ctrl-C path is
    tested in process, tests/test_server.py): exit code 0 and, where it raised its session's autogroup
    niceness (app/live/priority.py), the value it found is back."""
    import signal
    import urllib.request

    from app.live.priority import autogroup_niceness, set_autogroup_niceness

    found = autogroup_niceness()
    if found is not None:
        set_autogroup_niceness(0)  # (raising a niceness is always permitted)
    proc = subprocess.Popen(
        [sys.executable, "-m", "app.cli", "serve", "--scenario", "free", "--port", "0"],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:
        assert proc.stdout is not None
        lines: list[str] = []
        served_before_ready = None
        for line in proc.stdout:
            lines.append(line)
            if "open http://" in line:
                port = int(re.search(r"using free port (\d+)", "".join(lines)).group(1))  # type: ignore[union-attr]
                assert f"open http://127.0.0.1:{port} " in line
                with urllib.request.urlopen(f"http://127.0.0.1:{port}", timeout=10) as resp:
                    served_before_ready = resp.status
            if "the arm is running" in line or "error" in line:
                break
        text = "".join(lines)
        at = {key: next((i for i, ln in enumerate(lines) if key in ln), None)
              for key in ("open http://", "kernels ready in", "the arm is running")}  # fmt: skip
        assert None not in at.values(), text
        assert at["open http://"] < at["kernels ready in"] < at["the arm is running"], text
        assert served_before_ready == 200 and "closed to new argument types" in text, text
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=60) == 0  # a clean exit; a loaded machine may take a while
        if found is not None:
            assert autogroup_niceness() == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=30)
        if found is not None:
            set_autogroup_niceness(found)


@pytest.mark.parametrize(
    "exc, needle",
    [
        (TimeoutError(), "timed out waiting for the simulation loop"),
        (OSError(), "OSError"),
        (FileNotFoundError(), "FileNotFoundError"),
        (ValueError(""), "ValueError"),
        (ValueError("bad\nvalue"), "bad value"),
        (robots.RobotLoadError("unknown robot 'x'"), "unknown robot 'x'"),
    ],
)
def test_every_caught_error_prints_one_non_empty_line(exc, needle, monkeypatch, capsys):
    from app import cli

    def fail(args):
        raise exc

    monkeypatch.setattr(cli, "cmd_check", fail)
    assert cli.main(["check"]) == 2
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 1
    assert lines[0] == f"torquelab: error: {needle}"


@pytest.fixture
def serve_once(monkeypatch):
    """`serve` in this process that stops (as Ctrl-C does) right after printing its URL; the apps it
    started are kept (stopped) for a look at their sessions."""
    from app.live import server

    started: list = []
    real = server.start_app

    def start_app(**kwargs):
        app = real(**kwargs)

        def interrupt() -> str:
            raise KeyboardInterrupt

        app.publisher.supervise = interrupt
        started.append(app)
        return app

    monkeypatch.setattr(server, "start_app", start_app)
    return started


@pytest.mark.parametrize("huge", ["1e400", str(10**400), "-1e400", "nan"])
def test_serve_settings_of_which_nothing_applies_is_one_line_and_exit_2_before_anything_starts(
    run_cli, serve_once, monkeypatch, tmp_path, huge
):
    """Checked against the preset's defaults before the warm-up, the mesh child, the app or its threads."""
    import threading

    from app.live import server

    begun: list[str] = []
    monkeypatch.setattr(server, "first_start", lambda *a: begun.append("warm-up") or (0.0, False, []))
    monkeypatch.setattr(server, "open_server", lambda *a: begun.append("server"))
    monkeypatch.setattr(server.robots.meshes, "warm_in_background", lambda names: begun.append("mesh child"))
    threads = set(threading.enumerate())
    path = tmp_path / "huge.toml"
    path.write_text(f"[joint_hold]\nstiffness = {huge}\n[nothing_like_this]\nx = 1\n")
    res = run_cli("serve", "--scenario", "free", "--port", "0", "--settings", str(path))
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert res.returncode == 2 and len(lines) == 1, res.stderr
    assert "no entry applies" in lines[0] and "joint_hold.stiffness" in lines[0] and str(path) in lines[0]
    assert "nothing_like_this" in lines[0]
    assert begun == [] and serve_once == [] and res.stdout == ""
    assert set(threading.enumerate()) <= threads


def test_serve_settings_with_one_bad_entry_applies_the_valid_ones_and_names_the_bad_one_once(
    run_cli, serve_once, tmp_path
):
    from app.core.session import Session

    defaults = Session("free").params()
    force, damping = defaults["drag"].max_force_n + 7.0, defaults["joint_hold"].damping + 1.0
    path = tmp_path / "mixed.toml"
    path.write_text(f"[joint_hold]\nstiffness = {10**400}\ndamping = {damping}\n[drag]\nmax_force_n = {force}\n")
    res = run_cli("serve", "--scenario", "free", "--port", "0", "--no-warmup", "--settings", str(path))
    assert res.returncode == 0 and res.stderr == "", res.stderr
    said = [ln for ln in res.stdout.splitlines() if "stiffness" in ln]
    assert len(said) == 1 and "refused" in said[0] and "too large" in said[0]
    assert f"settings from {path} applied (1 refused)" in res.stdout and "open http" in res.stdout
    params = serve_once[0].loop.lab.session.params()
    assert params["drag"].max_force_n == pytest.approx(force, abs=1e-12)
    assert params["joint_hold"].damping == pytest.approx(damping, abs=1e-12)
    assert params["joint_hold"].stiffness == pytest.approx(defaults["joint_hold"].stiffness, abs=1e-12)
