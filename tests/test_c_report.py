"""The [C] experiments' reports (limit-drop, mass-drop, compliance) say which command and code made them."""

from __future__ import annotations

import argparse

from app.core.provenance import code_version
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
    assert f"torquelab experiment mass-drop --out {tmp_path} --jobs 1" in text and code_version() in text
    assert text.index("code version") < text.index("<h2>Setup</h2>")  # at the top, under the title
