"""The [C] experiments' reports (limit-drop, mass-drop, compliance) say which command and code made them."""

from __future__ import annotations

import argparse
import subprocess

import pytest

from app.core import provenance
from app.core.provenance import code_text, code_version
from app.headless.experiments.c_common import command_line, write_report


def test_the_command_line_spells_out_every_option_as_parsed():
    args = argparse.Namespace(
        experiment="compliance", command="experiment", func=print, out="out/c", jobs=2, json=False, quick=True,
        mu=[0.25, 1.0], robot=None, package_path=[],
    )  # fmt: skip
    assert command_line(args) == "torquelab experiment compliance --out out/c --jobs 2 --quick --mu 0.25,1.0"


def test_a_report_carries_the_command_and_the_code_version(tmp_path):
    args = argparse.Namespace(experiment="mass-drop", out=str(tmp_path), jobs=1, json=False)
    text = write_report(tmp_path, "Mass drop", [("Setup", "<p>x</p>")], args).read_text()
    assert (
        f"torquelab experiment mass-drop --out {tmp_path} --jobs 1" in text
        and code_text() in text
        and code_version() in text
    )
    assert text.index("code version") < text.index("<h2>Setup</h2>")  # at the top, under the title


def _git(repo, *words):
    subprocess.run(
        ["git", "-C", str(repo), "-c", "user.name=t", "-c", "user.email=t@t", *words], check=True, capture_output=True
    )


def test_the_code_version_is_the_commit_with_dirty_when_the_tree_differs_and_the_source_hash_beside_it(
    tmp_path, monkeypatch
):
    (tmp_path / "a.py").write_text("x = 1\n")
    _git(tmp_path, "init", "-q")
    _git(tmp_path, "add", "a.py")
    _git(tmp_path, "commit", "-q", "-m", "a")
    head = subprocess.run(["git", "-C", str(tmp_path), "rev-parse", "HEAD"], capture_output=True, text=True).stdout
    monkeypatch.setattr(provenance, "_root", lambda: tmp_path)
    provenance.git_commit.cache_clear()
    assert provenance.git_commit() == head.strip()[:12]
    (tmp_path / "a.py").write_text("x = 2\n")
    provenance.git_commit.cache_clear()
    assert provenance.git_commit() == head.strip()[:12] + "+dirty"
    text = provenance.code_text()
    assert text == f"commit {head.strip()[:12]}+dirty, source hash {provenance.code_version()}"
    monkeypatch.setattr(provenance, "_root", lambda: tmp_path / "nowhere")
    provenance.git_commit.cache_clear()
    assert provenance.git_commit() is None and provenance.code_text().startswith("no git checkout, source hash ")
    provenance.git_commit.cache_clear()


def test_set_options_become_typed_session_parameters_and_a_malformed_one_is_one_line():
    from app.headless.experiments.run_config import parse_settings

    got = parse_settings(["sensor.cutoff_hz=15", "sensor.noise=off", "world.armature_scale=1.5", "damper.form=classic"])
    assert got == [("sensor", "cutoff_hz", 15), ("sensor", "noise", False), ("world", "armature_scale", 1.5),
                   ("damper", "form", "classic")]  # fmt: skip
    for bad in ("cutoff_hz=15", "sensor.cutoff_hz", "sensor.=1", "a.b.c=1", "sensor.cutoff_hz="):
        with pytest.raises(ValueError, match=r"expected GROUP\.FIELD=VALUE") as err:
            parse_settings([bad])
        assert "\n" not in str(err.value)
