"""Bad input is one line and loses nothing: huge integers, zero counts, absurd grids, missing meshes."""

from __future__ import annotations

import shutil
import time

import pytest

from app.cli import main
from app.core.commands import SetParam
from app.core.params import load_settings, settings_commands
from app.core.session import Session
from app.headless.sweep.grid import MAX_CELLS, Axis, SweepError, cells, parse_grid
from app.live.lab import Lab
from control.gains import DamperGains
from control.params import ParamError, replaced

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


def test_a_missing_mesh_is_one_line_before_anything_starts(tmp_path, capsys):
    import robots

    src = robots.load("rizon4s").urdf_path
    text = src.read_text()
    first = text.index("<visual>")
    start, end = text.index("<geometry>", first), text.index("</geometry>", first)
    urdf = tmp_path / "arm.urdf"
    urdf.write_text(text[:start] + '<geometry><mesh filename="meshes/missing.stl"/>' + text[end:])
    sidecar = src.with_suffix(".toml")
    if sidecar.exists():
        shutil.copy(sidecar, tmp_path / "arm.toml")
    assert main(["serve", "--urdf", str(urdf), "--port", "0"]) == 2
    out = capsys.readouterr()
    lines = out.err.strip().splitlines()
    assert len(lines) == 1 and "meshes/missing.stl not found" in lines[0], out.err
