"""Bad input at the command line: one clear line on stderr, non-zero exit, no traceback."""

from __future__ import annotations

import re
import subprocess
import sys

import pytest

import robots


def run_cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "app.cli", *args], capture_output=True, text=True, timeout=120)


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
def test_bad_robot_gives_one_line_error(args, needle):
    res = run_cli(*args)
    assert res.returncode != 0
    assert "Traceback" not in res.stderr
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and needle in lines[0]


def test_six_dof_urdf_is_refused(tmp_path):
    res = run_cli("check", "--urdf", str(six_dof_urdf(tmp_path)))
    assert res.returncode != 0
    assert "Traceback" not in res.stderr
    assert "7-DOF" in res.stderr and len(res.stderr.strip().splitlines()) == 1


def test_check_passes_for_shipped_robots():
    res = run_cli("check", "--samples", "20", "--json")
    assert res.returncode == 0, res.stderr
    assert res.stdout.count('"ok": true') == 2
