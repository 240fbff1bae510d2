"""A preset owns its facts and the runner reads them through `Scenario`'s declared hooks.

`app.scenarios.Scenario` declares every hook a preset may have; the session, the live lab, its
frames, plots, phase line and lessons read them as attributes of that contract, never by a name
looked up at run time (a `getattr(scenario, "hook", None)` finds a hook no contract declares, and a
preset that spells it differently is silently skipped). The first test runs each preset through
the live lab and fails if code of the app outside `app/scenarios` reads an attribute of a preset
that `Scenario` does not declare. The second holds the polish plan lead to the nullspace gain in
force after a reset (1/k0_j), which the preset read once from its own executor before. The last
ones grep the live app and the core for a preset's name, module or copied constant.
"""

from __future__ import annotations

import re
import sys
from collections import deque
from pathlib import Path

import numpy as np
import pytest

from app.core.session import Session
from app.live.frames import FrameBuilder, plot_data
from app.live.lab import Lab
from app.live.lessons import measure
from app.live.ui.phase import PhaseReader
from app.live.ui.snapshot import capture
from app.scenarios import SCENARIOS, Scenario, get_scenario
from app.scenarios import polish_plan as PP
from app.scenarios.polish import PolishScenario


class Reads:
    """Attribute names of presets read from code of the app outside `app/scenarios`."""

    def __init__(self) -> None:
        self.names: dict[str, set[str]] = {}

    def install(self, monkeypatch: pytest.MonkeyPatch, cls: type) -> None:
        original = cls.__getattribute__
        names = self.names

        def recording(obj, name):
            caller = sys._getframe(1).f_globals.get("__name__", "")
            if caller.startswith(("app.", "tests.test_scenario_contract")) and not caller.startswith("app.scenarios"):
                names.setdefault(name, set()).add(caller)
            return original(obj, name)

        monkeypatch.setattr(cls, "__getattribute__", recording)

    def undeclared(self) -> dict[str, set[str]]:
        """The names read that `Scenario` does not declare (a hook or attribute of the contract)."""
        return {n: callers for n, callers in self.names.items() if not hasattr(Scenario, n) and not n.startswith("__")}


def _run_through_the_lab(name: str) -> None:
    lab = Lab(name)
    builder = FrameBuilder(1 / 30, 0.25, capture=capture)
    phase = PhaseReader()
    for _ in range(3):
        lab.advance(40)
        frame = builder.build(lab, now=lab.session.world.time)
        phase.text(frame.status, frame.scene)
    plot_data(lab, deque())
    measure(lab)
    lab.reset()
    lab.advance(5)
    lab.session.restore_defaults()


def test_the_recorder_sees_a_hook_looked_up_by_name(monkeypatch):
    reads = Reads()
    reads.install(monkeypatch, PolishScenario)
    scenario = PolishScenario()
    getattr(scenario, "undeclared_hook", None)  # what the runner did with prepare_robot, fall, configure_executor
    _ = scenario.segments  # a declared one
    assert set(reads.undeclared()) == {"undeclared_hook"}


@pytest.mark.parametrize("name", list(SCENARIOS))
def test_the_live_lab_reads_no_hook_a_scenario_does_not_declare(monkeypatch, name):
    reads = Reads()
    reads.install(monkeypatch, type(get_scenario(name)))
    _run_through_the_lab(name)
    assert reads.names, "the recorder saw no read at all"
    assert reads.undeclared() == {}


def test_the_polish_plan_lead_is_one_over_k0_j_in_force_after_a_reset(monkeypatch):
    """After set_param("nullspace", "k0_j", 4) and a reset the target leads the plan by 0.25 s (and its
    posture is the plan's at that lead); before, by 1/k0_j of the default gain."""
    monkeypatch.setattr(PP, "PLAN_SAMPLE_S", 1.25)  # a coarse plan: the lead, not the plan, is tested
    monkeypatch.setattr(PP, "PLAN_GRID_DEG", 8.0)
    session = Session(PolishScenario(plan_cost="a"), seed=0)
    k0_default = float(session.params()["nullspace"].k0_j)
    assert session.params()["nullspace"].objective == "j"  # the planned case runs W_j (executor_changes)
    assert session.target_fn.plan_lead_s == pytest.approx(1.0 / k0_default, rel=1e-12)
    session.set_param("nullspace", "k0_j", 4.0)
    session.reset()
    target = session.target_fn
    assert target.plan_lead_s == pytest.approx(0.25, rel=1e-12)
    plan = target.plan
    t = 1.0 + plan.transfer_s / 2  # during the transfer, before the trajectory starts
    s = min(max(target.plan_time(t) + 0.25, plan.t[0]), min(0.0, plan.t[-1]))
    expected = np.array([np.interp(s, plan.t, plan.q[:, j]) for j in range(plan.q.shape[1])])
    np.testing.assert_allclose(target.planned_posture(t), expected, rtol=0, atol=1e-12)
    assert session.params()["nullspace"].objective == "j" and session.params()["nullspace"].k0_j == 4.0


ROOT = Path(__file__).resolve().parents[1]
# the one module of the live app that names presets: the lessons' scripts, which switch to a preset by
# name as a person picks it from the menu (everything they measure and claim reads the contract)
CURRICULUM = ROOT / "app" / "live" / "curriculum.py"


COMMON_WORDS = ("free",)  # preset names that are also ordinary words (a classroom seat is "free" too)


def _preset_words() -> list[re.Pattern[str]]:
    """What naming a preset looks like in code: its name as a string, its module, a constant of its own."""
    words = [re.compile(rf"""["']{re.escape(name)}["']""") for name in SCENARIOS if name not in COMMON_WORDS]
    # a preset named by an ordinary word counts where the line speaks of a scenario or preset
    words += [
        re.compile(rf"""(scenario|preset|SCENARIO).*["']{name}["']|["']{name}["'].*(scenario|preset|SCENARIO)""")
        for name in COMMON_WORDS
    ]
    words += [re.compile(rf"app\.scenarios\.{module}\b") for module in SCENARIOS.values()]
    words += [re.compile(r"\bapp\.scenarios\.(polish_\w+|payload|drop_postures)\b")]
    # a copied constant: the stroke count, the contact time, a constant named after a preset
    words += [re.compile(r"^\s*((N_)?SEGMENTS|\w*CONTACT_TIME\w*|(POLISH|LIMIT_DROP|MASS_DROP)_\w+)\s*=")]
    return words


def preset_mentions(text: str) -> list[str]:
    """The lines of `text` that name a preset (comments included: they go stale the same way)."""
    return [line.strip() for line in text.splitlines() if any(w.search(line) for w in _preset_words())]


def test_the_grep_finds_a_preset_named_in_code():
    assert preset_mentions('if name == "polish":\n    pass') == ['if name == "polish":']
    assert preset_mentions("SEGMENTS = 6\nPOLISH_CONTACT_S = 1.0\nCONTACT_RING_SEGMENTS = 32\n") == [
        "SEGMENTS = 6",
        "POLISH_CONTACT_S = 1.0",
    ]
    assert preset_mentions("from app.scenarios.polish_stroke import N_SEGMENTS\n")
    assert preset_mentions('group.compliance\nx = "compliance_qp"\nscenario.segments\n') == []
    assert preset_mentions('state: str = "free"\nLab(scenario="free")\n') == ['Lab(scenario="free")']


@pytest.mark.parametrize("package", ["live", "core"])
def test_the_live_app_and_the_core_name_no_preset(package):
    files = [p for p in sorted((ROOT / "app" / package).rglob("*.py")) if p != CURRICULUM]
    assert len(files) >= 10
    found = {str(p.relative_to(ROOT)): preset_mentions(p.read_text()) for p in files}
    assert {k: v for k, v in found.items() if v} == {}
