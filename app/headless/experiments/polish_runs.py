"""The polish experiment's per-run storage: each finished run kept in runs/ as it finishes (its spec,
the code version, its result and series), read back by `--resume` and `--combine`."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np

from app.core.provenance import code_version

RUNS_DIR = "runs"  # one file pair per finished run: <key>.json (spec and result) and <key>.npz (series)


def run_key(spec: dict) -> str:
    """A run's file name in runs/: a hash of its spec."""
    import robots

    robot = robots.chosen("")  # another arm's runs are other runs (the default arm keeps its keys)
    keyed = {**spec, "robot": robot} if robot else spec
    return hashlib.sha1(json.dumps(keyed, sort_keys=True).encode()).hexdigest()[:16]


def save_run(runs_dir: Path, spec: dict, output: dict) -> None:
    """Keep one finished run (written to a temporary name first, so a half-written run is never read)."""
    runs_dir.mkdir(parents=True, exist_ok=True)
    key = run_key(spec)
    with open(runs_dir / f"{key}.tmp.npz", "wb") as f:
        np.savez_compressed(f, **output["series"])
    (runs_dir / f"{key}.tmp.npz").replace(runs_dir / f"{key}.npz")
    doc = {"spec": spec, "code": code_version(), "result": output["result"]}
    (runs_dir / f"{key}.tmp.json").write_text(json.dumps(doc))
    (runs_dir / f"{key}.tmp.json").replace(runs_dir / f"{key}.json")


def load_run(runs_dir: Path, spec: dict) -> dict | None:
    """A run of exactly this spec saved earlier by this code version, or None."""
    key = run_key(spec)
    meta, arrays = runs_dir / f"{key}.json", runs_dir / f"{key}.npz"
    if not (meta.exists() and arrays.exists()):
        return None
    doc = json.loads(meta.read_text())
    if doc.get("spec") != json.loads(json.dumps(spec)) or doc.get("code") != code_version():
        return None
    with np.load(arrays) as z:
        series = {k: z[k] for k in z.files}
    return {"result": doc["result"], "series": series}


def _finished_runs(runs_dir: Path) -> tuple[list[dict], list[dict]]:
    """The runs an invocation saved in runs_dir as they finished (`save_run`), and their series."""
    results, series = [], []
    for meta in sorted(runs_dir.glob("*.json")):
        arrays = meta.with_suffix(".npz")
        if meta.name.endswith(".tmp.json") or not arrays.is_file():
            continue
        results.append(json.loads(meta.read_text())["result"])
        with np.load(arrays) as z:
            series.append({k: z[k] for k in z.files})
    return results, series
