"""`torquelab sweep EXPERIMENT --grid NAME=VALUES ... --out DIR`: parse, validate, run, report."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from app.headless.sweep import experiments
from app.headless.sweep.engine import check_cluster, open_executor
from app.headless.sweep.grid import SweepError, cells, parse_grid
from app.headless.sweep.knobs import build_axes
from app.headless.sweep.report import write_report
from app.headless.sweep.runner import run_sweep


def add_parser(sub) -> None:
    """Add the `sweep` sub-command to the top-level parser's sub-parsers."""
    names = ", ".join(experiments.EXPERIMENTS)
    knob_help = "; ".join(
        e.name
        + ": "
        + ", ".join([k.name for k in e.knobs] + (["GROUP.FIELD (any session parameter)"] if e.any_param else []))
        for e in experiments.EXPERIMENTS.values()
    )
    p = sub.add_parser(
        "sweep",
        help="run an experiment over a parameter grid and map the results",
        description=f"Run one experiment over a grid of parameters. Parameters — {knob_help}.",
    )
    p.add_argument("experiment", help=f"experiment to sweep: {names}")
    p.add_argument(
        "--grid",
        nargs="+",
        action="extend",
        required=True,
        metavar="NAME=VALUES",
        help="a:b:n (n values from a to b), a,b,c (a list) or v (one value); first two axes are mapped",
    )
    p.add_argument("--out", required=True, help="output directory (cells.jsonl, cells.csv, report.html)")
    p.add_argument("--seeds", type=int, default=1, help="noise seeds per grid point, 0 … N−1 (default 1)")
    p.add_argument("--jobs", type=int, default=1, help="local worker processes, or LocalCluster workers (default 1)")
    p.add_argument(
        "--cluster",
        default=None,
        metavar="ADDRESS",
        help="run the cells on a Dask cluster: tcp://HOST:PORT of its scheduler, or local (a LocalCluster)",
    )
    p.add_argument("--retry-failed", action="store_true", help="run again the cells that failed earlier")
    p.add_argument("--report-only", action="store_true", help="run nothing: redraw report.html from cells.jsonl")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_sweep)


def cmd_sweep(args: argparse.Namespace) -> int:
    """Validate everything, run the missing cells, write cells.csv and report.html."""
    exp = experiments.get(args.experiment)
    axes = build_axes(exp.knobs, parse_grid(args.grid), exp.groups, exp.any_param)
    exp.check_combination([a.name for a in axes])
    if args.seeds < 1:
        raise SweepError(f"--seeds must be at least 1, got {args.seeds}")
    if args.jobs < 1:
        raise SweepError(f"--jobs must be at least 1, got {args.jobs}")
    check_cluster(args.cluster)
    if args.cluster is not None and exp.local_only:
        raise SweepError(f"{exp.name}'s cells fork their worker process: it runs on the local pool (--jobs)")
    out = Path(args.out)
    grid = cells(axes, args.seeds)
    meta_path = out / "sweep.json"
    meta = json.loads(meta_path.read_text()) if meta_path.exists() else {"invocations": []}
    if args.report_only:
        return _report_only(exp, axes, args.seeds, out, meta)
    started = time.strftime("%Y-%m-%d %H:%M:%S", time.gmtime())
    t0 = time.perf_counter()
    try:
        with open_executor(args.cluster, args.jobs) as (executor, engine):
            print(f"sweep {exp.name}: {len(grid)} cells on {engine}", file=sys.stderr, flush=True)
            result = run_sweep(
                exp.name,
                exp.cell,
                grid,
                out,
                executor,
                retry_failed=args.retry_failed,
                progress=not args.no_progress,
                group=exp.group_axis,
            )
    except KeyboardInterrupt:
        print(f"sweep interrupted: finished cells are in {out / 'cells.jsonl'}; run the same command to resume")
        raise
    wall = time.perf_counter() - t0
    meta.update(experiment=exp.name, grid=[{"name": a.name, "values": list(a.values)} for a in axes], seeds=args.seeds)
    meta["invocations"].append(
        {
            "started": started,
            "engine": engine,
            "ran": result.ran,
            "failed": result.failed,
            "skipped": result.skipped,
            "wall_s": wall,
        }
    )
    if exp.model_facts is not None:  # the model's figures the report prints, kept beside the cells
        meta["model_facts"] = exp.model_facts()
    meta_path.write_text(json.dumps(meta, indent=2))
    report = write_report(out, exp, axes, args.seeds, result.records, meta["invocations"], meta.get("model_facts"))
    cpu = sum(float(r.get("cpu_s") or 0.0) for r in result.records)
    failed_total = sum(r.get("status") != "ok" for r in result.records)
    print(
        f"{result.total} cells: ran {result.ran} ({result.failed} failed), {result.skipped} done earlier; "
        f"wall {wall:.1f} s, cells' CPU {cpu:.1f} s"
        + (f"; {failed_total} failed cells (--retry-failed runs them again)" if failed_total else "")
    )
    print(f"wrote {out / 'cells.jsonl'}, {out / 'cells.csv'} and {report}")
    return 1 if failed_total else 0


def _report_only(exp, axes, seeds: int, out: Path, meta: dict) -> int:
    """report.html and cells.csv from the cells already in out/cells.jsonl (none is run)."""
    from app.headless.sweep.store import CellStore, cell_key, write_csv

    store = CellStore(out / "cells.jsonl")
    records = [store.records[k] for p, s in cells(axes, seeds) if (k := cell_key(exp.name, p, s)) in store.records]
    if not records:
        raise SweepError(f"no finished cells of this grid in {out / 'cells.jsonl'}")
    write_csv(out / "cells.csv", records)
    if exp.model_facts is not None and "model_facts" not in meta:  # a sweep made before they were kept
        meta["model_facts"] = exp.model_facts()
        (out / "sweep.json").write_text(json.dumps(meta, indent=2))
    report = write_report(out, exp, axes, seeds, records, meta["invocations"], meta.get("model_facts"))
    print(f"{len(records)} of {len(cells(axes, seeds))} cells finished; wrote {report}")
    return 0
