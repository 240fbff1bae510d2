"""Every report prints only what its run computed: rendered under --robot gen3, as the experiments
run by default and with changed sensor and armature settings (--set), no sentence names another
robot and every number in the text is a value of the run's JSON (at the precision printed, in the
report's units: ×10³, ×10⁻³, ×100, 1/x for a rate from a period, √x for a σ from a variance).

The runs are the smallest each experiment offers that still print each of its sections (one polish
row at one μ and one seed, with the v_ε check and Table III at the other latencies, and with --quick's
latency table; the whole limit-drop
and --quick; mass-drop with two repetitions per case; the three compliance modes; sweeps of a few
cells, the stability map's of two); they are made once for the module (about a minute and a half on one core)."""

from __future__ import annotations

import html
import json
import math
import re
from pathlib import Path

import numpy as np
import pytest

import robots

ROBOT = "gen3"
OTHER_ROBOTS = ("rizon", "panda", "franka", "flexiv")  # names of the other arms, as a report would spell them
POLISH_CHANGED = ("sensor.cutoff_hz=15", "sensor.force_noise_var=3", "scenario.armature_scale=1.5")
C_CHANGED = ("sensor.force_noise_var=0.0529", "world.armature_scale=1.5")  # the [C] presets' F/T and arm
# limit-drop's preset has no F/T group of its own (the payload's reading is the observer's): its arm only
LIMIT_DROP_CHANGED = ("world.armature_scale=1.5",)


def _sets(settings: tuple[str, ...]) -> list[str]:
    return [w for s in settings for w in ("--set", s)]


RUNS = {  # name: (command words, the JSON files of the run)
    "polish": (
        ["experiment", "polish", "--rows", "a", "--mu", "1", "--seeds", "1", "--no-armature", "--no-latency"],
        ["polish.json"],
    ),
    "polish-changed": (
        ["experiment", "polish", "--quick", "--rows", "a", "--mu", "1", *_sets(POLISH_CHANGED)],  # + latency table
        ["polish.json"],
    ),
    "limit-drop": (["experiment", "limit-drop"], ["limit_drop.json", "limit_drop_traces.json"]),  # every item
    "limit-drop-changed": (
        ["experiment", "limit-drop", "--quick", *_sets(LIMIT_DROP_CHANGED)],
        ["limit_drop.json", "limit_drop_traces.json"],
    ),
    "mass-drop": (["experiment", "mass-drop", "--repetitions", "2", "--held-repetitions", "2"], ["mass_drop.json"]),
    "mass-drop-changed": (
        ["experiment", "mass-drop", "--repetitions", "2", "--held-repetitions", "2", *_sets(C_CHANGED)],
        ["mass_drop.json"],
    ),
    "compliance": (["experiment", "compliance"], ["compliance.json"]),
    "compliance-changed": (["experiment", "compliance", *_sets(C_CHANGED)], ["compliance.json"]),
    "sweep-limit-drop": (
        ["sweep", "limit-drop", "--grid", "lambda=70,300", "M=2,3", "--no-progress"],
        ["cells.jsonl", "sweep.json"],
    ),
    "sweep-polish-changed": (
        [
            "sweep",
            "polish",
            "--grid",
            "sensor.cutoff_hz=15",
            "mu=1",
            "world.armature_scale=1.5",
            "strokes=1",
            "--no-progress",
        ],
        ["cells.jsonl", "sweep.json"],
    ),
    "sweep-polish-map": (  # one settled swivel, two cells: the map's section, its figure and JSON
        ["sweep", "polish-map", "--grid", "hold_swivel=0", "mu=1", "latency=1+0,2+1", "--no-progress"],
        ["cells.jsonl", "sweep.json", "stability_map.json"],
    ),
}


@pytest.fixture(scope="module")
def reports(tmp_path_factory) -> dict[str, tuple[str, list]]:
    """name -> (the report's text, the run's JSON documents), every run of `RUNS` made once."""
    from app.cli import main

    base = tmp_path_factory.mktemp("reports")
    out: dict[str, tuple[str, list]] = {}
    with pytest.MonkeyPatch.context() as mp:  # the command sets the robot for its sessions: restored after
        mp.setenv(robots.ROBOT_ENV, "")
        for name, (words, files) in RUNS.items():
            d = base / name
            assert main([*words, "--out", str(d), "--robot", ROBOT]) == 0, name
            docs = [_load(d / f) for f in files]
            out[name] = ((d / "report.html").read_text(), docs)
    return out


def _load(path: Path):
    if path.suffix == ".jsonl":
        return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    return json.loads(path.read_text())


# ---- the text a reader sees, and its numbers --------------------------------------------------------
CITATIONS = re.compile(
    r"\[[TC][^\]]*\]"  # [T], [C23], [T12]
    r"|§[IVX]+(?:-[A-E])?(?:[–-][A-E])?"  # §IV-B–C
    r"|Figs?\.\s*\d+[a-z]?(?:\s*[–-]\s*\d+)?"  # Fig. 6a, Figs. 2–3
    r"|Table [IVX]+\b"
)
NUMBER = re.compile(r"(?<![\w.])(\d{1,3}(?:,\d{3})+|\d+(?:\.\d+)?(?:e[-+]?\d+)?)(?!\w)")


def visible_text(page: str) -> tuple[str, list[str]]:
    """(the page's text without markup, styles, code spans and paper citations; the code spans)."""
    page = re.sub(r"<style.*?</style>", " ", page, flags=re.S)
    codes = [html.unescape(c) for c in re.findall(r"<code>(.*?)</code>", page, flags=re.S)]
    page = re.sub(r"<code>.*?</code>", " ", page, flags=re.S)
    page = re.sub(r"<img [^>]*>|<[^>]+>", " ", page)
    text = CITATIONS.sub(" ", html.unescape(page))
    return " ".join(text.split()), codes


def _tolerance(token: str) -> float:
    """Half a unit in the last place printed."""
    if "e" in token:
        mantissa, exp = token.split("e")
        decimals = len(mantissa.split(".")[1]) if "." in mantissa else 0
        return 0.5 * 10.0 ** (int(exp) - decimals)
    if "." in token:
        return 0.5 * 10.0 ** -len(token.split(".")[1])
    return 0.5


def _field_totals(items: list) -> list[float]:
    """The sum of each numeric field over a list of records (the cells' CPU seconds, their wall time)."""
    totals: dict[str, float] = {}
    for item in items:
        if isinstance(item, dict):
            for key, v in item.items():
                if isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v):
                    totals[key] = totals.get(key, 0.0) + float(v)
    return list(totals.values())


def json_values(docs: list) -> tuple[np.ndarray, set[str]]:
    """Every number of the documents (every list's length and its records' totals too) in each of the
    report's units, sorted by magnitude, and the numeric tokens of their strings (a command's options, a date)."""
    values: list[float] = []
    tokens: set[str] = set()

    def walk(x) -> None:
        if isinstance(x, dict):
            for v in x.values():
                walk(v)
        elif isinstance(x, list):
            values.append(float(len(x)))
            values.extend(_field_totals(x))  # a report's total over its cells or invocations (CPU, wall time)
            for v in x:
                walk(v)
        elif isinstance(x, bool) or x is None:
            return
        elif isinstance(x, int | float) and math.isfinite(x):
            values.append(float(x))
        elif isinstance(x, str):
            tokens.update(NUMBER.findall(x))

    walk(docs)
    v = np.abs(np.array(values))
    with np.errstate(divide="ignore"):
        units = [v, v * 1e3, v * 1e-3, v * 100.0, np.where(v > 0, 1.0 / np.where(v > 0, v, 1.0), 0.0), np.sqrt(v)]
    return np.sort(np.concatenate(units)), tokens


def numbers_absent(text: str, docs: list) -> list[str]:
    """The numbers of `text` that no value of `docs` gives at the printed precision, each with its context."""
    values, tokens = json_values(docs)
    missing = []
    for m in NUMBER.finditer(text):
        token = m.group(1)
        if token in tokens:
            continue
        x = float(token.replace(",", ""))
        tol = _tolerance(token.replace(",", "")) * 1.001 + 1e-12
        i = int(np.searchsorted(values, x - tol))
        if i < len(values) and values[i] <= x + tol:
            continue
        missing.append(f"{token!r} in …{text[max(0, m.start() - 60) : m.end() + 30]}…")
    return missing


# ---- the tests --------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", list(RUNS))
def test_a_report_names_no_other_robot(reports, name):
    text, _ = visible_text(reports[name][0])
    named = [r for r in OTHER_ROBOTS if r in text.lower()]
    assert not named, f"{name}: the report names {named} under --robot {ROBOT}"


@pytest.mark.parametrize("name", list(RUNS))
def test_every_number_of_a_report_is_a_value_of_its_runs_json(reports, name):
    page, docs = reports[name]
    text, codes = visible_text(page)
    assert len(NUMBER.findall(text)) >= 20, f"{name}: too few numbers to say anything"  # the check has material
    missing = numbers_absent(text, docs)
    assert not missing, f"{name}: {len(missing)} number(s) not in the run's JSON:\n" + "\n".join(missing[:25])
    strings = json.dumps(docs, ensure_ascii=False)
    # the command and code version printed are the ones the run recorded (the [C] and polish reports)
    if name.startswith("sweep"):
        return
    assert codes, f"{name}: no command printed"
    for code in codes:
        if code.startswith("torquelab "):
            assert all(w in strings for w in code.split()), f"{name}: the command {code!r} is not the recorded one"


def test_the_changed_settings_are_the_ones_the_reports_print(reports):
    """--set reaches the runs and their reports say so: the polish report's low-pass and armature, the
    [C] reports' F/T noise (σ = √0.0529 N), each from the run's record, not the presets' defaults."""
    polish, _ = visible_text(reports["polish-changed"][0])
    assert "15 Hz low-pass" in polish and "25 Hz" not in polish
    (doc,) = reports["polish-changed"][1]
    (run,) = doc["runs"]
    assert run["armature_scale"] == 1.5 and run["sensor"]["cutoff_hz"] == 15.0
    model = run["config"]["armature_model_kg_m2"]
    nominal = robots.load(ROBOT).armature
    assert np.allclose(model, 1.5 * nominal, rtol=1e-12)
    assert "scenario armature scale ×1.5" in polish and ", ".join(f"{a:g}" for a in model) in polish
    for name in ("compliance-changed", "mass-drop-changed"):
        text, _ = visible_text(reports[name][0])
        assert "σ = 0.23 N" in text, name
    default, _ = visible_text(reports["compliance"][0])
    assert "σ = 0.1 N" in default
    (ld,) = reports["limit-drop-changed"][1][:1]
    assert ld["config"]["params"]["world"]["armature_scale"] == 1.5


def test_the_number_check_finds_a_number_the_json_does_not_hold():
    """The checker itself: a value printed at its precision passes, in mm from m too; one the JSON does
    not hold, or printed more finely than it rounds, is reported."""
    docs = [{"x": 0.012345, "y": [3.0, 4.0], "cmd": "torquelab experiment polish --mu 0.25"}]
    assert numbers_absent("x is 0.0123 and 12.35 mm; two values; μ 0.25", docs) == []
    assert numbers_absent("y has 2 items, 3 and 4", docs) == []
    missing = numbers_absent("x is 0.0124, z is 7.5", docs)
    assert [m.split()[0] for m in missing] == ["'0.0124'", "'7.5'"]
    text, codes = visible_text("<p>Run: <code>torquelab x</code> [C23] Figs. 2–3 Table III §IV-B–C ok 5</p>")
    assert text == "Run: ok 5" and codes == ["torquelab x"]


def test_limit_drop_names_the_joint_that_moved_most_from_the_runs_not_a_fixed_one():
    from app.headless.experiments.limit_drop import other_joints_item

    def run(feedback: bool, drift: list[float]) -> dict:
        return {"feedback": feedback, "falling_joint": 4, "other_joints_drift": max(drift), "stop": "until",
                "other_joints_drift_per_joint": drift, "limit": "position", "form": "proposed", "lambda": 100.0,
                "M": 2.0, "oscillations": 0}  # fmt: skip

    derived: dict = {}
    text = other_joints_item([run(True, [0.0] * 7), run(False, [0.1, 0.2, 0.0, 0.0, 0.9, 0.3, 0.0])], derived)
    assert "most at joint 5 (0.90 rad)" in text and "joint 2" not in text and "sags" not in text
    assert derived["most_moved_joint_without_feedback"] == 5
    assert "every one of these runs had stopped before the cap" in text


def test_the_start_pose_margin_is_described_with_what_it_omits_and_names_the_runs_it_gets_wrong():
    from app.headless.experiments.polish_report import findings_in_words, start_margin_text

    loop = {"stiffness_n_per_m": 30000.0, "force_kp": 0.5, "force_ki": 0.0, "sensor_cutoff_hz": 25.0,
            "sensing_delay_steps": 1, "actuation_delay_steps": 0, "shaping": True, "speed_m_s": 0.157}  # fmt: skip

    def run(row: str, margin: float | None, stable: bool) -> dict:
        return {"row": row, "mu": 1.0, "seed": 0, "margin": margin, "stable": stable, "converged": True,
                "convergence_time_s": 3.0, "margin_detail": {"loop": loop}}  # fmt: skip

    doc = {"runs": [run("W_a", -3.0, True), run("W_d", -1.0, True), run("W_j", 20.0, False), run("W_f", 5.0, True)]}
    text = start_margin_text(doc)
    assert "K_f^i = 0" in text and "the reading 1 and the torque 0 control period(s) late" in text
    assert "leaves out how the posture moves along the strokes" in text
    assert "agree in 1 of 4 runs" in text and "W_a μ = 1 seed 0 (margin -3, stable)" in text
    assert "W_d μ = 1 seed 0 (margin -1, stable)" in text and "W_j μ = 1 seed 0 (margin +20" in text
    assert "predict" not in text.replace("no prediction", "")
    doc.update(summary=[], settings={"settle": {"cap_s": 120.0}})
    assert not any("margin" in f for f in findings_in_words(doc))  # the margin is no finding of the run
