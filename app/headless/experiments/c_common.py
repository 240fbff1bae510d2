"""Helpers shared by the [C] experiments (limit-drop, mass-drop, compliance): sessions with the
QP executor, parallel runs with progress, and a small HTML report writer."""

from __future__ import annotations

import argparse
import html
import json
import os
from collections.abc import Callable, Iterable
from pathlib import Path

import numpy as np
from tqdm import tqdm

from app.core.executors import EXECUTORS
from app.core.provenance import code_text
from app.core.session import Session
from app.headless.sweep.engine import open_executor
from app.scenarios import Scenario
from control.compliance_qp import ComplianceQPExecutor, make_compliance_qp


def qp_session(scenario: Scenario, seed: int = 0) -> Session:
    """A Session of `scenario` on its default robot with the [C] QP executor."""
    if "compliance-qp" not in EXECUTORS:  # registered in app/core/executors.py; kept safe for old trees
        EXECUTORS["compliance-qp"] = lambda robot, model: make_compliance_qp(robot, model)
    session = Session(scenario, executor="compliance-qp", seed=seed)
    if not isinstance(session.executor, ComplianceQPExecutor):
        raise TypeError("the compliance-qp executor is not the [C] QP executor")
    return session


def run_parallel(fn: Callable, jobs_args: list, jobs: int, desc: str) -> list:
    """Map fn over the argument tuples, in `jobs` processes of the sweeps' engine
    (`app.headless.sweep.engine`), with a progress bar; keeps order."""
    jobs = max(1, min(int(jobs), os.cpu_count() or 1, len(jobs_args) or 1))
    results: list = [None] * len(jobs_args)
    with tqdm(total=len(jobs_args), desc=desc, unit="run") as bar:
        if jobs == 1:
            for i, a in enumerate(jobs_args):
                results[i] = fn(*a)
                bar.update()
        else:
            with open_executor(None, jobs) as (pool, _):  # the sweeps' engine
                futures = {pool.submit(fn, *a): i for i, a in enumerate(jobs_args)}
                for fut in _as_completed(futures):
                    results[futures[fut]] = fut.result()
                    bar.update()
    return results


def _as_completed(futures: Iterable):
    from concurrent.futures import as_completed

    return as_completed(list(futures))


def jsonable(obj):
    """Numbers and arrays as plain JSON types (NaN/inf → None)."""
    if isinstance(obj, dict):
        return {k: jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return jsonable(obj.tolist())
    if isinstance(obj, np.bool_ | bool):
        return bool(obj)
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, float | np.floating):
        x = float(obj)
        return x if np.isfinite(x) else None
    return obj


def write_json(path: Path, data) -> None:
    """Write `data` as indented JSON."""
    path.write_text(json.dumps(jsonable(data), indent=2))


def html_table(header: list[str], rows: list[list]) -> str:
    """A plain HTML table; floats printed with 4 significant digits."""

    def cell(v) -> str:
        if isinstance(v, float | np.floating):
            return f"{float(v):.4g}"
        return html.escape(str(v))

    head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{cell(v)}</td>" for v in r) + "</tr>" for r in rows)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


NOT_OPTIONS = ("func", "command", "experiment")  # parser bookkeeping, not options of the run


def command_line(args: argparse.Namespace) -> str:
    """The `torquelab experiment NAME …` command of a run, every option spelled out as parsed (defaults
    included), so the report says exactly what made it."""
    words = ["torquelab", "experiment", str(getattr(args, "experiment", "") or "")]
    for key, value in vars(args).items():
        if key in NOT_OPTIONS or value is None or value is False or (isinstance(value, list | tuple) and not value):
            continue
        flag = "--" + key.replace("_", "-")
        if value is True:
            words.append(flag)
        elif key == "set":  # repeatable: one flag per session parameter
            for item in value:
                words += [flag, str(item)]
        elif isinstance(value, list | tuple):
            words += [flag, ",".join(str(v) for v in value)]
        else:
            words += [flag, str(value)]
    return " ".join(w for w in words if w)


def run_line(args: argparse.Namespace | None) -> str:
    """The report's provenance paragraph: the command and the code version that made it."""
    command = html.escape(command_line(args)) if args is not None else "not recorded"
    return f"<p>Run: <code>{command}</code>, code version <code>{html.escape(code_text())}</code>.</p>"


def write_report(
    out: Path, title: str, sections: list[tuple[str, str]], args: argparse.Namespace | None = None
) -> Path:
    """report.html with a title, the command and code version that made it (`run_line`) and (heading,
    html body) sections."""
    parts = [
        "<!doctype html><html><head><meta charset='utf-8'>",
        f"<title>{html.escape(title)}</title>",
        "<style>body{font-family:sans-serif;max-width:1100px;margin:2em auto;line-height:1.45}"
        "table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #ccc;padding:3px 8px;"
        "text-align:right}th{background:#f4f4f4}img{max-width:100%}.ok{color:#070}.no{color:#a00}"
        ".oracle{color:#a60;font-weight:bold}</style></head><body>",
        f"<h1>{html.escape(title)}</h1>",
        run_line(args),
    ]
    for heading, body in sections:
        parts.append(f"<h2>{html.escape(heading)}</h2>{body}")
    parts.append("</body></html>")
    path = out / "report.html"
    path.write_text("\n".join(parts))
    return path


def verdict(ok: bool, text: str) -> str:
    """A reproduces / does not reproduce line."""
    cls, word = ("ok", "reproduces") if ok else ("no", "does not reproduce")
    return f"<li><span class='{cls}'><b>{word}</b></span>: {text}</li>"
